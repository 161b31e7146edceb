"""Divergence detection and IMU saturation (issue: "catch every divergence").

A sustained yaw torque under relaxed limits (no position-error limit, no NEES check) spins the
vehicle far past what a real gyro measures. Without a gyro range the filter's covariance blows
up: the episode must end as an estimator divergence, not run to the time limit. With a
±2000 °/s gyro the readings saturate and the filter's covariance stays sane (its estimate is
wrong, which the NEES check catches when it is on).
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.hardware import ImuConfig
from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation.health import HEALTH_PROBLEMS, health_codes
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.schema import ConfigError
from quadslam_env.sim.imu import Imu
from quadslam_env.types import DEG, GRAVITY

RELAXED = {"max_pos_err_m": 1e6, "nees_threshold": None}


def spin(duration_s: float, **kwargs: Any) -> tuple[dict[str, Any], bool, bool, list[float]]:
    """Hover thrust with full yaw torque until the episode ends.

    Returns:
        ``(last info, terminated, truncated, pose-covariance traces per step)``.
    """
    episode = {**RELAXED, "duration_s": duration_s, **kwargs.pop("episode", {})}
    env = gym.make("QuadSLAM-EKF-v0", **{**kwargs, "episode": episode})
    env.reset(seed=0)
    core = env.unwrapped.core  # type: ignore[attr-defined]
    action = np.array(core.action_map.hover_action, dtype=np.float32)
    action[3] = 1.0  # full yaw torque, held
    traces = []
    while True:
        _, _, terminated, truncated, info = env.step(action)
        traces.append(float(np.trace(core.est.pose_cov[0])))
        if terminated or truncated:
            return info, bool(terminated), bool(truncated), traces


def test_yaw_spin_without_gyro_range_ends_as_estimator_divergence() -> None:
    info, terminated, truncated, _ = spin(30.0)
    assert terminated and not truncated
    assert info["termination_reason"].startswith("estimator_diverged"), info["termination_reason"]
    assert info["t"] < 30.0


def test_yaw_spin_with_saturating_gyro_keeps_the_covariance_sane() -> None:
    info, terminated, truncated, traces = spin(20.0, imu={"preset": "mpu6000"})
    assert truncated and not terminated, info["termination_reason"]
    assert all(math.isfinite(t) and 0.0 < t < 1e3 for t in traces)
    # The vehicle spins far beyond the range, so the estimate is wrong: the NEES shows it.
    assert info["est_nees_pose"] > 1e3


def test_yaw_spin_with_saturating_gyro_is_caught_by_the_nees_check() -> None:
    info, terminated, _, _ = spin(20.0, imu={"preset": "mpu6000"}, episode={"nees_threshold": 1e3})
    assert terminated
    assert info["termination_reason"] == "estimator_diverged: NEES above threshold"


def test_max_cov_trace_ends_the_episode_at_the_configured_magnitude() -> None:
    info, terminated, _, traces = spin(30.0, episode={"max_cov_trace": 10.0})
    assert terminated
    assert info["termination_reason"] == (
        "estimator_diverged: pose covariance trace above episode.max_cov_trace"
    )
    assert traces[-1] > 10.0 and max(traces[:-1]) <= 10.0


def test_saturated_imu_readings_stop_at_the_full_scale() -> None:
    cfg = ImuConfig.from_dict({"preset": "mpu6000"})
    assert cfg.gyro_range_dps == 2000.0 and cfg.accel_range_g == 16.0
    vehicle = VEHICLE_PRESETS["rauniyar2023"]
    imu = Imu(cfg, vehicle, 100.0)
    imu.reset(np.random.default_rng(0))
    thrust = 20.0 * vehicle.mass * GRAVITY  # specific force of 20 g along -b3
    sample = imu.sample(0.0, np.zeros(3), np.array([100.0, -100.0, 0.0]), thrust)
    assert sample.gyro[0] == pytest.approx(2000.0 * DEG)
    assert sample.gyro[1] == pytest.approx(-2000.0 * DEG)
    assert abs(sample.gyro[2]) < 0.01  # inside the range: noise only
    assert sample.accel[2] == pytest.approx(-16.0 * GRAVITY)


def test_default_imu_has_no_range() -> None:
    cfg = ImuConfig.from_dict({"preset": "ideal"})
    imu = Imu(cfg, VEHICLE_PRESETS["rauniyar2023"], 100.0)
    imu.reset(np.random.default_rng(0))
    sample = imu.sample(0.0, np.zeros(3), np.array([100.0, 0.0, 0.0]), 0.0)
    assert sample.gyro[0] == 100.0


@pytest.mark.parametrize(
    ("section", "key", "value"),
    [
        ("imu", "gyro_range_dps", 0.0),
        ("imu", "gyro_range_dps", "fast"),
        ("imu", "accel_range_g", -16.0),
        ("episode", "max_cov_trace", 0.0),
        ("episode", "max_cov_trace", math.inf),
    ],
)
def test_new_settings_are_validated(section: str, key: str, value: Any) -> None:
    with pytest.raises(ConfigError, match=rf"{section}\.{key}: got"):
        load_scenario(None, {section: {key: value}})


def _estimate(covs: np.ndarray) -> BatchEstimate:
    b = covs.shape[0]
    return BatchEstimate(
        position=np.zeros((b, 3)),
        vel_body=np.zeros((b, 3)),
        vel_inertial=np.zeros((b, 3)),
        euler=np.zeros((b, 3)),
        rates=np.zeros((b, 3)),
        pose_cov=covs,
        landmark_means=np.zeros((b, 2, 3)),
        landmark_mapped=np.zeros((b, 2), dtype=bool),
    )


def test_health_check_names_each_covariance_problem() -> None:
    good = np.diag([1.0, 2.0, 3.0, 0.1, 0.1, 0.1, 0.01, 0.01, 0.0])
    round_off = good.copy()
    round_off[8, 8] = -1e-14  # round-off below zero: healthy
    negative = good.copy()
    negative[3, 3] = -0.5
    correlated = good.copy()
    correlated[0, 1] = correlated[1, 0] = 2.0  # |ρ| = 2/√2 > 1
    huge = good * 1e7  # the yaw-spin blow-up: finite, symmetric, PSD, but enormous
    nan = good.copy()
    nan[2, 2] = math.nan
    covs = np.stack([good, round_off, negative, correlated, huge, nan])
    codes = health_codes(_estimate(covs), max_cov_trace=1e6)
    names = [HEALTH_PROBLEMS[c] for c in codes]
    assert names == [
        "",
        "",
        "pose covariance not positive semi-definite (negative variance)",
        "pose covariance not positive semi-definite (correlation beyond ±1)",
        "pose covariance trace above episode.max_cov_trace",
        "non-finite pose covariance",
    ]
    # Without a limit the magnitude alone is no problem.
    assert health_codes(_estimate(covs[4:5]))[0] == 0


def test_health_check_accepts_a_psd_covariance_with_full_correlation() -> None:
    v = np.arange(1.0, 10.0)
    cov = np.outer(v, v)  # rank one: PSD, every correlation exactly ±1 up to round-off
    assert health_codes(_estimate(cov[None]), max_cov_trace=1e6)[0] == 0
