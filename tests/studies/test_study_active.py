"""The active-perception study's measurements, against recomputations from per-step info."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401
from agents.control.lookat import LookAtPolicy
from agents.evaluation.episodes import Trace
from agents.lab.control_studies.active import (
    CLAIMS,
    ENV_ID,
    fly,
    format_study,
    plot_study,
    row_result,
    run_study,
)
from agents.rl.saved.run_folder import run_config
from agents.rl.wrappers import ResidualDFLQRWrapper

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


TINY_PPO = {"n_envs": 2, "n_steps": 32, "batch_size": 64, "n_epochs": 1}
"""One rollout of 64 steps and one epoch: what the study does with a training (save, reload,
fly, aggregate) does not depend on its size."""


def test_the_study_reports_the_learned_row_over_its_training_seeds(tmp_path: Path) -> None:
    """Two tiny trainings and 6 s flights (1 s of steady state): the learned row's per-seed
    scores are its seeds' medians over their episodes, and each claim is counted against the
    baseline row's median."""
    result = run_study(tmp_path, training_seeds=2, episodes=2, timesteps=64, jobs=1,
                       duration_s=6.0, hyperparams=TINY_PPO)  # fmt: skip
    assert result["settings"]["training_seeds"] == [0, 1]
    rows = {r["config"]: r for r in result["rows"]}
    assert list(rows) == ["dflqr_fixed", "dflqr_tangent", "lookat", "ppo"]
    assert all("seed_stats" not in r for c, r in rows.items() if c != "ppo")
    ppo = rows["ppo"]
    key = "track_pos_rmse_steady_m"
    medians = [np.median([e[key] for e in ppo["episodes"][2 * i : 2 * i + 2]]) for i in range(2)]
    stats = ppo["seed_stats"][key]
    assert stats["per_seed"] == pytest.approx(medians) and stats["undefined"] is None
    assert stats["iqm"] == pytest.approx(np.mean(medians))  # two seeds: the plain mean
    assert stats["iqm_ci"] == pytest.approx(sorted(medians))
    claims = {c["claim"]: c for c in ppo["claims"]}
    assert list(claims) == ["<= 0.8 x dflqr_tangent", "<= 1 x lookat"]
    for (base, factor), c in zip(CLAIMS, ppo["claims"], strict=True):
        baseline = rows[base][key]["median"]
        assert c["baseline"] == baseline
        assert c["per_seed"] == [bool(m <= factor * baseline) for m in medians]
        assert c["holds"] == f"{sum(c['per_seed'])}/2 seeds"
    text = format_study(result)
    assert "<= 0.8 x dflqr_tangent" in text and "<= 1 x lookat" in text
    (run,) = (tmp_path / "train" / "s1").iterdir()
    saved = run_config(run)
    assert saved is not None and saved["hyperparams"]["n_steps"] == 32
    assert saved["hyperparams"]["env_kwargs"]["episode"]["duration_s"] == 6.0
