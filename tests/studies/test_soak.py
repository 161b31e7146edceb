"""Shortened soak runs (the hour-long version is ``quadslam study soak``, see its
docstring): long flights stay finite, covariances stay symmetric PSD, and memory does not grow
per step beyond the map."""

from __future__ import annotations

import gc
import json
import math
import tracemalloc

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.estimator_studies.soak import cov_health, main, run_soak

RSS_GROWTH_LIMIT_MB = 25.0
"""Allowed RSS growth over a shortened soak: a few MiB of map, caches and allocator slack."""
ASYM_REL_LIMIT = 1e-9
MIN_EIG_REL_LIMIT = -1e-12


def _check_healthy(rep: dict, sim_seconds: float) -> None:
    assert not rep["terminated"], rep["termination_reason"]
    assert rep["truncated"]
    assert rep["sim_seconds"] == pytest.approx(sim_seconds)
    assert rep["steps"] == round(sim_seconds * 100)
    assert not rep["any_non_finite"]
    assert rep["health_problem"] == ""
    for key in ("final_est_pos_err_m", "final_est_att_err_deg", "rms_est_pos_err_m"):
        assert rep[key] is not None and math.isfinite(rep[key]), key


def _check_covariance(block: dict) -> None:
    assert block["samples"] > 0
    assert block["max_rel_asymmetry"] < ASYM_REL_LIMIT
    assert block["min_rel_eigenvalue"] >= MIN_EIG_REL_LIMIT


@pytest.fixture(scope="module")
def ekf_report() -> dict:
    return run_soak("ekf_slam", 60.0, seed=0, progress=False, sample_every=50)


@pytest.fixture(scope="module")
def fastslam_report() -> dict:
    # The DF-LQR flies on the truth here: flying on FastSLAM's estimate on this scenario leaves
    # the 10 m position-error limit after ~30 s (a known accuracy issue of the filter, see
    # docs/results/fastslam_helix.txt), and this test is about numerical health, not accuracy.
    return run_soak(
        "fastslam", 30.0, n_particles=200, seed=0, progress=False, sample_every=50, control="truth"
    )


def test_ekf_soak_stays_finite(ekf_report):
    _check_healthy(ekf_report, 60.0)


def test_ekf_soak_pose_covariance_symmetric_psd(ekf_report):
    _check_covariance(ekf_report["pose_cov"])


def test_ekf_soak_full_covariance_symmetric_psd(ekf_report):
    _check_covariance(ekf_report["full_cov"])
    _check_covariance(ekf_report["landmark_covs"])


def test_ekf_soak_memory_bounded(ekf_report):
    assert ekf_report["rss_end_mb"] - ekf_report["rss_start_mb"] < RSS_GROWTH_LIMIT_MB


def test_ekf_soak_tracks_after_two_laps(ekf_report):
    # Two figure-8 laps and more: the filter is still accurate (seed-001 scale, centimetres).
    assert ekf_report["final_est_pos_err_m"] < 0.5
    assert ekf_report["final_est_att_err_deg"] < 2.0


def test_fastslam_soak_stays_finite(fastslam_report):
    _check_healthy(fastslam_report, 30.0)
    assert fastslam_report["n_particles"] == 200


def test_fastslam_soak_pose_covariance_symmetric_psd(fastslam_report):
    _check_covariance(fastslam_report["pose_cov"])
    _check_covariance(fastslam_report["landmark_covs"])


def test_fastslam_soak_memory_bounded(fastslam_report):
    assert fastslam_report["rss_end_mb"] - fastslam_report["rss_start_mb"] < RSS_GROWTH_LIMIT_MB


# ----------------------------------------------------------------------------- per-step memory


def _traced_growth_per_step(env: gym.Env, warmup: int, steps: int, pattern: str) -> float:
    """Bytes retained per step by allocations in files matching ``pattern`` (tracemalloc).

    Two windows of ``steps`` steps are traced and the second is measured, so allocations made
    once (caches, the first use of a code path) do not count.
    """
    env.reset(seed=0)
    action = env.unwrapped.hover_action.astype(np.float32)
    for _ in range(warmup):
        env.step(action)
    only = [tracemalloc.Filter(True, pattern)]
    snapshots = []
    tracemalloc.start()
    try:
        for window in range(3):
            for _ in range(steps if window else 0):
                env.step(action)
            gc.collect()
            snapshots.append(tracemalloc.take_snapshot().filter_traces(only))
    finally:
        tracemalloc.stop()
    return sum(s.size_diff for s in snapshots[2].compare_to(snapshots[1], "filename")) / steps


def test_env_stores_no_history_without_render_mode():
    """With ``render_mode=None`` nothing in ``quadslam_env`` keeps per-step data."""
    env = gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 100.0})
    assert _traced_growth_per_step(env, 200, 250, "*/quadslam_env/*") < 4.0


def test_ekf_memory_does_not_grow_per_step_once_mapped():
    """Hovering, the visible landmarks are mapped within a second; after that the EKF's
    buffers keep their size."""
    env = gym.make("QuadSLAM-EKF-v0", episode={"duration_s": 100.0})
    assert _traced_growth_per_step(env, 200, 250, "*/estimators/ekf/*") < 4.0


def test_episode_metrics_memory_does_not_grow_per_step():
    """The episode summary keeps running sums, not per-step lists (those cost ~190 B/step,
    84 MiB of RSS over the first 1-hour soak)."""
    env = gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 100.0})
    assert _traced_growth_per_step(env, 200, 250, "*/estimators/*") < 4.0


# ----------------------------------------------------------------------------- the script


def test_cov_health_detects_asymmetry_and_negative_eigenvalues():
    asym, min_eig, scale = cov_health(np.array([[2.0, 1.0], [1.0 + 1e-3, -0.5]]))
    assert asym == pytest.approx(1e-3)
    assert min_eig < 0.0
    assert scale == 2.0


def test_soak_script_writes_json(tmp_path, capsys):
    path = tmp_path / "soak.json"
    code = main(["--estimator", "ekf_slam", "--seconds", "2", "--no-progress", "--json", str(path)])
    assert code == 0
    rep = json.loads(path.read_text())
    assert rep["steps"] == 200
    assert rep["estimator"] == "ekf_slam"
    assert "rss_start_mb" in rep and "rss_end_mb" in rep
    assert "soak ekf_slam" in capsys.readouterr().out


def test_soak_script_rejects_particles_for_ekf(capsys):
    code = main(["--estimator", "ekf_slam", "--seconds", "1", "--particles", "5", "--no-progress"])
    assert code == 2
    assert "n_particles" in capsys.readouterr().err
