"""Episode summary from running sums equals the direct computation over stored samples."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from quadslam_env.metrics.episode import EpisodeMetrics
from quadslam_env.metrics.step import anees_bounds


def test_episode_summary_matches_direct_statistics() -> None:
    rng = np.random.default_rng(0)
    n = 500
    pos, vel, att, track = (np.abs(rng.normal(size=n)) for _ in range(4))
    nees = rng.chisquare(9, size=n)
    nees[::50] = np.inf  # non-PSD steps are left out of the ANEES
    nees_pos = rng.chisquare(3, size=n)
    acc = EpisodeMetrics()
    for i in range(n):
        acc.add(
            {
                "est_pos_err_m": pos[i],
                "est_vel_err_mps": vel[i],
                "est_att_err_deg": att[i],
                "track_pos_err_m": track[i],
                "est_nees_pose": nees[i],
                "est_nees_pos": nees_pos[i],
                "est_map_rmse_m": 0.1,
                "est_n_mapped": 3.0,
                "est_accel_bias_rel_err": math.nan,
                "est_gyro_bias_rel_err": 0.2,
            }
        )
    out = {key: value[0] for key, value in acc.summary().items()}  # the one lane
    finite = nees[np.isfinite(nees)]
    lo, hi = chi2.ppf(0.025, 9), chi2.ppf(0.975, 9)
    assert out["episode_steps"] == n
    assert out["episode_est_pos_rmse_m"] == pytest.approx(np.sqrt(np.mean(pos**2)))
    assert out["episode_track_pos_rmse_m"] == pytest.approx(np.sqrt(np.mean(track**2)))
    assert out["episode_anees_pose"] == pytest.approx(finite.mean())
    assert out["episode_anees_pos"] == pytest.approx(nees_pos.mean())
    assert out["episode_nees_pose_in_bounds"] == pytest.approx(
        np.mean((finite >= lo) & (finite <= hi))
    )
    assert out["episode_gyro_bias_rel_err"] == 0.2 and math.isnan(out["episode_accel_bias_rel_err"])


def test_anees_bounds_match_scaled_chi2() -> None:
    lo, hi = anees_bounds(9, 20)
    # 20 · ANEES ~ χ²(180): its 2.5% and 97.5% quantiles divided by 20.
    assert lo == pytest.approx(chi2.ppf(0.025, 180) / 20)
    assert hi == pytest.approx(chi2.ppf(0.975, 180) / 20)
    assert lo < 9 < hi
