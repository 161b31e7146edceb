"""Graceful degradation: EKF-SLAM dead-reckons honestly with no landmark in
view and re-locks when they return, through the iterated update (estimators.ekf.correction)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.lab.estimator_studies.degradation import record, summarise
from estimators.ekf.filter import EkfSlamBatch
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.lidar import lidar_measure

SIGMA = np.array([math.radians(0.33), math.radians(0.3), 0.1])
LANDMARK = np.array([[15.0, 0.0, -1.0]])


def _one_update(tol: float, offset: tuple[float, float, float]) -> EkfSlamBatch:
    """A known-map EKF whose prior mean is ``offset`` m from the true pose (the origin, level,
    σ 5 m), corrected once with a noise-free scan of one landmark 15 m ahead."""
    f = EkfSlamBatch(1, 1, relinearise_tolerance=tol, process_noise=[0.0] * 9)
    mean0 = np.zeros((1, 12))
    mean0[0, :3] = offset
    cov0 = np.diag([25.0] * 3 + [1.0] * 3 + [1e-6] * 6)[None]
    f.reset_lanes(np.array([0]), mean0, cov0, [None], [(np.array([0]), LANDMARK)])
    y = lidar_measure(np.zeros((1, 1, 3)), np.eye(3)[None, None], LANDMARK[None])
    f.update(np.zeros(1), np.array([0]), np.ones((1, 1), bool), y.reshape(1, 1, 3), SIGMA)
    return f


def test_iterated_update_reaches_the_fix_a_first_order_update_stops_short_of() -> None:
    iterated, first_order = (
        _one_update(2.0, (3.0, 4.0, 0.0)),
        _one_update(math.inf, (3.0, 4.0, 0.0)),
    )
    e_it, e_fo = iterated.lane_estimate(0), first_order.lane_estimate(0)
    sigma_it = np.sqrt(np.diag(e_it.pose_cov[0])[:3])
    # Gauss–Newton lands on the truth within its own σ; one linearisation 5 m off does not.
    assert np.all(np.abs(e_it.position[0]) < 2.0 * sigma_it), (e_it.position[0], sigma_it)
    assert np.linalg.norm(e_fo.position[0]) > 0.5
    # Both report the NIS of the prior linearisation.
    assert e_it.diagnostics["nis"][0] == e_fo.diagnostics["nis"][0]


def test_small_corrections_are_the_first_order_update_bit_for_bit() -> None:
    a, b = _one_update(2.0, (0.01, -0.02, 0.0)), _one_update(math.inf, (0.01, -0.02, 0.0))
    np.testing.assert_array_equal(a.full_state()[0], b.full_state()[0])
    np.testing.assert_array_equal(a.full_state()[1], b.full_state()[1])


def test_ordinary_flight_does_not_iterate() -> None:
    """The paper's scenario with and without the iteration: the same rollout, bit for bit."""
    runs = []
    for tol in (2.0, math.inf):
        env = gym.make(
            "QuadSLAM-EKF-v0",
            episode={"duration_s": 5.0},
            estimator={"params": {"relinearise_tolerance": tol}},
        )
        policy = DFLQRPolicy.from_env(env)
        obs, _ = env.reset(seed=1)
        for _ in range(env.unwrapped.core.max_steps):
            obs, *_ = env.step(policy.predict(obs)[0])
        runs.append(obs)
        env.close()
    np.testing.assert_array_equal(runs[0], runs[1])


@pytest.mark.parametrize(
    ("key", "value"),
    [("relinearise_tolerance", 0.0), ("relinearise_tolerance", -1.0), ("max_iterations", 0)],
)
def test_iteration_settings_are_validated(key, value) -> None:
    with pytest.raises(ValueError, match=f"estimator.params.{key}"):
        EkfSlamBatch(1, 1, **{key: value})


def test_scenario_hides_the_landmarks_for_most_of_each_lap() -> None:
    cfg = load_scenario("ekf_out_of_view_600s")
    assert cfg.episode.duration_s == 600.0 and cfg.description
    assert cfg.landmarks.azimuth_deg == (60.0, 120.0)
    assert cfg.trajectory.kind == "circle" and cfg.trajectory.yaw_mode == "tangent"


@pytest.mark.slow
def test_ekf_dead_reckons_honestly_and_relocks_over_600s() -> None:
    summary = summarise(record("ekf_out_of_view_600s", [0, 1, 2], {}))
    assert summary["episodes_ended_early"] == 0, [s["end"] for s in summary["per_seed"]]
    assert summary["blind_share"] > 0.5 and summary["n_gaps"] >= 40
    # Dead-reckoning: the position NEES of the gaps is that of a consistent filter (3 DOF).
    assert 1.5 <= summary["nees_pos_in_gaps"] <= 6.0, summary["nees_pos_in_gaps"]
    assert summary["nees_pos_in_gaps_inside_95"] >= 0.85
    # The drift is metres; 5 s after the landmarks return the error is centimetres again.
    assert summary["pos_err_at_gap_end_m"]["max"] > 2.0
    assert summary["pos_err_5s_after_gap_m"]["max"] < 0.2
    assert summary["nees_pos_after_gap"] <= 6.0
    assert summary["max_nees_pos"] < 50.0


@pytest.mark.slow
def test_first_order_updates_lose_lock_on_the_same_flights() -> None:
    """Without the iteration the same seeds re-lock badly: the test above is not vacuous."""
    over = {"estimator": {"params": {"relinearise_tolerance": math.inf}}}
    summary = summarise(record("ekf_out_of_view_600s", [0, 1, 2], over))
    assert summary["max_nees_pos"] > 50.0 or summary["episodes_ended_early"] > 0
