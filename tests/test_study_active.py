"""The active-perception study's measurements, against recomputations from per-step info."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401
from agents.control.lookat import LookAtPolicy
from agents.evaluation.episodes import Trace
from agents.rl.wrappers import ResidualDFLQRWrapper
from agents.studies.active import ENV_ID, fly, format_study, plot_study, row_result

SHORT = {"episode": {"duration_s": 6.0}}  # the study's 5 s transient, then 1 s steady


def test_landmarks_per_scan_is_the_mean_return_count_of_the_scans() -> None:
    seeds = [5, 6]
    trace = Trace()
    records = fly(LookAtPolicy, SHORT, seeds, trace)
    env = gym.make(ENV_ID, **SHORT)
    every = env.unwrapped.scenario.lidar_every
    for seed, record in zip(seeds, records, strict=True):
        policy = LookAtPolicy(env)
        obs, _ = env.reset(seed=seed)
        counts, k = [], 0
        while True:
            obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
            k += 1
            if k % every == 0:
                counts.append(info["est_n_visible"])
            if terminated or truncated:
                break
        assert record["landmarks_per_scan"] == pytest.approx(np.mean(counts))
    env.close()
    assert len(trace.true_state) == 601  # the first seed's reset and its 600 steps


def test_rows_format_and_figure(tmp_path: Path) -> None:
    trace = Trace()
    records = fly(LookAtPolicy, SHORT, [1, 2, 3], trace)
    row = row_result("lookat", "look-at", [records])
    for key in ("track_pos_rmse_steady_m", "track_pos_rmse_transient_m"):
        values = [r[key] for r in records]
        assert row[key]["n"] == 3
        assert row[key]["median"] == pytest.approx(np.median(values))
    result = {"rows": [row], "traces": {"lookat": trace}, "settings": {}}
    assert "lookat" in format_study(result)
    assert plot_study(result, tmp_path).exists()


def test_residual_on_the_look_at_heuristic_with_zero_residual_is_the_heuristic() -> None:
    env = gym.make(ENV_ID, **SHORT)
    wrapped = ResidualDFLQRWrapper(gym.make(ENV_ID, **SHORT), base="lookat")
    heuristic = LookAtPolicy(env)
    obs, _ = env.reset(seed=0)
    obs_w, _ = wrapped.reset(seed=0)
    assert wrapped.action_space.shape == (5,)
    for _ in range(150):
        obs, *_ = env.step(heuristic.predict(obs)[0])
        obs_w, *_ = wrapped.step(np.zeros(5, np.float32))
        np.testing.assert_array_equal(obs_w, obs)
    env.close()
    wrapped.close()
