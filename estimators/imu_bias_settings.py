"""The IMU-bias settings that EKF-SLAM and the iSAM2 smoother share (``estimator.params``).

Both filters model the accelerometer and gyro biases the same way (a prior at the start and a
random walk, Sadeghzadeh-Nokhodberiz et al. 2021 eq. 5–11), so their settings classes inherit
these fields, with the same defaults and the same checks, from :class:`ImuBiasFields`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from quadslam_env.schema import Section, spec

GYRO_BIAS_MAX = 1.0
"""Largest gyro-bias std or walk density, rad/s (/√s): the bound of ``imu.gyro_bias``."""

ACCEL_BIAS_MAX = 10.0
"""Largest accelerometer-bias std or walk density, m/s² (/√s): about 1 g, twice the bound of
``imu.accel_bias``."""


@dataclass(frozen=True)
class ImuBiasFields(Section):
    """The bias model's five ``estimator.params`` keys (a base of the settings classes)."""

    SECTION: ClassVar[str] = "estimator.params"
    estimate_imu_bias: bool = spec(
        False, kind="bool", doc="estimate the IMU biases as states with a random walk"
    )
    gyro_bias_sigma0: float = spec(
        0.01,
        lo=0.0,
        hi=GYRO_BIAS_MAX,
        doc="prior std per axis of the gyro bias, rad/s (at most 1 rad/s, the largest "
        "imu.gyro_bias)",
    )
    accel_bias_sigma0: float = spec(
        0.05,
        lo=0.0,
        hi=ACCEL_BIAS_MAX,
        doc="prior std of the accelerometer bias, m/s² (at most 10 m/s², about 1 g)",
    )
    gyro_bias_walk: float = spec(
        1e-4,
        lo=0.0,
        hi=GYRO_BIAS_MAX,
        doc="random-walk density of the gyro bias, rad/s/√s (at most 1: the largest bias "
        "reached in a second)",
    )
    accel_bias_walk: float = spec(
        1e-3,
        lo=0.0,
        hi=ACCEL_BIAS_MAX,
        doc="random-walk density of the accelerometer bias, m/s²/√s (at most 10: the largest "
        "bias reached in a second)",
    )
