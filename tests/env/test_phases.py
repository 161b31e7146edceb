"""Episode metrics split by phase (transient t ≤ settle_s, steady t > settle_s) and the start on
the reference, checked against independent recomputations from the per-step ``info``."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr
from scipy.stats import chi2

import quadslam_env  # noqa: F401
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import STEADY_KEYS, TRANSIENT_KEYS, run_episode, summarize
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY


def _fly(env: gym.Env, seed: int) -> tuple[list[dict], dict]:
    """DF-LQR for one episode: the per-step infos and the last one."""
    steps, _ = fly_dflqr(env, seed)
    return steps, steps[-1]


def _rms(values: np.ndarray) -> float:
    return float(np.sqrt(np.mean(values**2)))


def test_steady_and_transient_summaries_equal_a_recomputation_from_the_steps() -> None:
    env = gym.make(
        "QuadSLAM-EKF-v0",
        scenario="paper_ekf_figure8",
        episode={"duration_s": 6.0, "settle_s": 2.5},
    )
    steps, last = _fly(env, seed=3)
    env.close()
    t = np.array([s["t"] for s in steps])
    steady = t > 2.5
    assert 0 < steady.sum() < len(t)
    for name, err in (("track_pos", "track_pos_err_m"), ("est_pos", "est_pos_err_m")):
        values = np.array([s[err] for s in steps])
        assert last[f"episode_{name}_rmse_steady_m"] == pytest.approx(_rms(values[steady]))
        assert last[f"episode_{name}_rmse_transient_m"] == pytest.approx(_rms(values[~steady]))
        assert last[f"episode_{name}_rmse_m"] == pytest.approx(_rms(values))
    nees = np.array([s.get("est_nees_pose", math.nan) for s in steps])
    lo, hi = chi2.ppf(0.025, 9), chi2.ppf(0.975, 9)
    finite = np.isfinite(nees) & steady
    assert last["episode_anees_pose_steady"] == pytest.approx(nees[finite].mean())
    inside = (nees[finite] >= lo) & (nees[finite] <= hi)
    assert last["episode_nees_pose_in_bounds_steady"] == pytest.approx(inside.mean())
    assert last["episode_steps_steady"] == steady.sum()
    assert last["episode_steps_transient"] == (~steady).sum()


def test_an_episode_that_ends_in_the_transient_has_no_steady_metrics() -> None:
    # The figure-8 starts 2 m below the reference: the default transient is 10 s, longer than
    # this 3 s episode.
    env = gym.make("QuadSLAM-EKF-v0", scenario="paper_ekf_figure8", episode={"duration_s": 3.0})
    assert env.unwrapped.core.settle_s == 10.0  # type: ignore[attr-defined]
    _, last = _fly(env, seed=0)
    assert last["episode_steps_steady"] == 0
    assert not [k for k in last if k.startswith("episode_") and "_steady" in k and "steps" not in k]
    records = [run_episode(env, DFLQRPolicy.from_env(env), seed) for seed in (0, 1)]
    env.close()
    for record in records:
        assert not set(STEADY_KEYS) & set(record)
        assert set(TRANSIENT_KEYS) <= set(record)
    summary = summarize(records)
    assert summary["track_pos_rmse_steady_m"] == {"median": None, "min": None, "max": None, "n": 0}
    assert summary["track_pos_rmse_transient_m"]["n"] == 2


@pytest.mark.parametrize(
    ("episode", "fragment"),
    [
        ({"settle_s": -1.0}, "episode.settle_s"),
        ({"settle_s": 50.0, "duration_s": 50.0}, "settle_s < episode.duration_s"),
        ({"settle_s": 60.0}, "got 60.0"),
    ],
)
def test_bad_settle_time_names_the_key_and_what_is_allowed(episode: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match="settle_s") as err:
        load_scenario("paper_ekf_figure8", {"episode": episode})
    assert fragment in str(err.value)
    assert "allowed" in str(err.value)


@pytest.mark.parametrize("scenario", ["paper_ekf_figure8", "paper_fastslam_helix"])
def test_start_on_the_reference_is_the_reference_state(scenario: str) -> None:
    env = gym.make(
        "QuadSLAM-Oracle-v0",
        scenario=scenario,
        trajectory={"start_on_reference": True},
        episode={"duration_s": 4.0},
    )
    env.reset(seed=0)
    core = env.unwrapped.core  # type: ignore[attr-defined]
    assert core.settle_s == 0.0  # nothing to settle: the default transient is empty
    state, ref = core.vehicle.state[0], core.reference()
    dcm = dcm_from_euler(state[6:9])
    np.testing.assert_allclose(state[0:3], ref.pos[0], atol=1e-12)
    np.testing.assert_allclose(dcm @ state[3:6], ref.vel[0], atol=1e-12)  # inertial velocity
    assert state[8] == pytest.approx(ref.yaw[0])
    # The thrust (along −body z) points along ρ̈_d − g n3: the acceleration the reference needs.
    need = ref.acc[0] - np.array([0.0, 0.0, GRAVITY])
    np.testing.assert_allclose(dcm @ np.array([0.0, 0.0, -1.0]), need / np.linalg.norm(need))
    env.close()


def test_starting_on_the_reference_removes_the_transient() -> None:
    def first_two_seconds(start_on_reference: bool) -> float:
        env = gym.make(
            "QuadSLAM-Oracle-v0",
            scenario="paper_ekf_figure8",
            trajectory={"start_on_reference": start_on_reference},
            episode={"duration_s": 2.0, "settle_s": 1.0},
        )
        _, last = _fly(env, seed=0)
        env.close()
        return float(last["episode_track_pos_rmse_transient_m"])

    # DF-LQR on the truth: metres of climb from below, centimetres when started on it.
    assert first_two_seconds(False) > 1.0
    assert first_two_seconds(True) < 0.02


def test_estimate_starts_around_the_reference_state() -> None:
    env = gym.make(
        "QuadSLAM-EKF-v0",
        scenario="paper_ekf_figure8",
        trajectory={"start_on_reference": True},
        estimator={"sample_initial_error": False},
        episode={"duration_s": 1.0},
    )
    _, info = env.reset(seed=0)
    base = env.unwrapped
    est, truth = base.last_estimate, base.true_state  # type: ignore[attr-defined]
    np.testing.assert_allclose(est.position[0], truth[0:3])
    np.testing.assert_allclose(est.vel_body[0], truth[3:6])
    np.testing.assert_allclose(est.euler[0], truth[6:9])
    assert info["est_pos_err_m"] == 0.0
    env.close()
