"""iSAM2 in the env: a non-finite IMU sample, or a GTSAM exception while preintegrating one,
ends the episode as diverged (as EKF-SLAM and FastSLAM do) instead of raising from ``step``,
in the scalar env and in one lane of the vector env."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy

pytest.importorskip("gtsam")

KWARGS: dict[str, Any] = {
    "scenario": "paper_ekf_figure8_known",
    "estimator": {"name": "isam2"},
    "episode": {"duration_s": 2.0},
}
DIVERGED = "estimator_diverged: estimator reported divergence"
BAD_STEP = 5  # between the first two keyframes (a scan every 10 steps)


def _spoil_imu(env: Any, monkeypatch: pytest.MonkeyPatch, lane: int, entry: tuple[int, float]):
    """Make the IMU reading of ``lane`` on the env's ``BAD_STEP``-th control step non-finite:
    ``entry = (column, value)`` of the (accel, gyro) columns 0-5."""
    imu = env.unwrapped.core.imu
    sample: Callable[..., tuple[np.ndarray, np.ndarray]] = imu.sample
    calls = {"n": 0}

    def spoiled(*args: Any, **kwargs: Any) -> tuple[np.ndarray, np.ndarray]:
        accel, gyro = sample(*args, **kwargs)
        calls["n"] += 1
        if calls["n"] == BAD_STEP:
            col, value = entry
            (accel if col < 3 else gyro)[lane, col % 3] = value
        return accel, gyro

    monkeypatch.setattr(imu, "sample", spoiled)


@pytest.mark.parametrize("entry", [(2, math.nan), (4, math.inf)], ids=["accel_nan", "gyro_inf"])
def test_non_finite_imu_sample_ends_the_episode_as_diverged(
    monkeypatch: pytest.MonkeyPatch, entry: tuple[int, float]
) -> None:
    env = gym.make("QuadSLAM-v0", **KWARGS)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    _spoil_imu(env, monkeypatch, 0, entry)
    for step in range(1, BAD_STEP + 1):
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        assert np.isfinite(obs).all() and math.isfinite(reward)
        assert terminated == (step == BAD_STEP) and not truncated
    assert info["termination_reason"] == DIVERGED
    est = env.unwrapped.estimator.lanes[0]
    assert est.last_error.startswith("FloatingPointError: isam2: non-finite IMU sample")
    snap = est.estimate()
    assert snap.diagnostics["diverged"][0] == 1.0
    assert np.isfinite(snap.position[0]).all() and np.isfinite(snap.pose_cov[0]).all()


def test_gtsam_exception_while_preintegrating_ends_the_episode_as_diverged(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    env = gym.make("QuadSLAM-v0", **KWARGS)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    est = env.unwrapped.estimator.lanes[0]
    for _ in range(3):
        obs, *_ = env.step(policy.predict(obs)[0])

    def broken(pim: Any, sample: Any) -> Any:
        raise RuntimeError("gtsam: integrateMeasurement failed")

    monkeypatch.setattr(est, "_preintegrate", broken)
    obs, _, terminated, _, info = env.step(policy.predict(obs)[0])
    assert terminated and info["termination_reason"] == DIVERGED
    assert np.isfinite(obs).all()
    assert est.last_error == "RuntimeError: gtsam: integrateMeasurement failed"


def test_non_finite_imu_sample_ends_only_its_lane_of_the_vector_env(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    vec = gym.make_vec("QuadSLAM-v0", num_envs=2, vectorization_mode="vector_entry_point", **KWARGS)
    scalar = gym.make("QuadSLAM-v0", **KWARGS)
    policy = DFLQRPolicy.from_env(scalar)
    obs, _ = vec.reset(seed=3)  # lane 0 is the scalar env seeded 3
    one, _ = scalar.reset(seed=3)
    _spoil_imu(vec, monkeypatch, 1, (0, math.nan))
    for step in range(1, BAD_STEP + 1):
        obs, _, terminated, truncated, info = vec.step(policy.predict(obs)[0])
        one, _, _, _, one_info = scalar.step(policy.predict(one)[0])
        assert np.isfinite(obs).all()
        assert terminated.tolist() == [False, step == BAD_STEP] and not truncated.any()
        np.testing.assert_array_equal(obs[0], one)
        assert info["est_pos_err_m"][0] == one_info["est_pos_err_m"]
    assert info["termination_reason"][1] == DIVERGED
    assert vec.unwrapped.core.estimator.lanes[0].last_error == ""
