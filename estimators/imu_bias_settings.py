"""The IMU-bias settings that EKF-SLAM and the iSAM2 smoother share (``estimator.params``).

Both filters model the accelerometer and gyro biases the same way (a prior at the start and a
random walk, Sadeghzadeh-Nokhodberiz et al. 2021 eq. 5–11), so they read the same keys, with
the same defaults and the same checks, from here.
"""

from __future__ import annotations

import math
from typing import Any

IMU_BIAS_TYPES: dict[str, type | tuple[type, ...]] = {
    "estimate_imu_bias": bool,
    "gyro_bias_sigma0": (float, int),
    "accel_bias_sigma0": (float, int),
    "gyro_bias_walk": (float, int),
    "accel_bias_walk": (float, int),
}
"""Accepted types of the shared keys (for :func:`estimators.settings_check.check_kwargs`)."""

IMU_BIAS_DEFAULTS: dict[str, Any] = {
    "estimate_imu_bias": False,
    "gyro_bias_sigma0": 0.01,  # rad/s, prior std per axis
    "accel_bias_sigma0": 0.05,  # m/s², prior std per axis
    "gyro_bias_walk": 1e-4,  # rad/s/√s, random-walk density
    "accel_bias_walk": 1e-3,  # m/s²/√s, random-walk density
}


def check_nonneg(key: str, value: Any) -> float:
    """``value`` as a float, or a one-line error naming ``estimator.params.<key>``.

    Raises:
        ValueError: ``value`` is not a finite number ≥ 0.
    """
    value = float(value)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"estimator.params.{key}: got {value!r}; allowed: a finite number >= 0")
    return value


def imu_bias_settings(params: dict[str, Any]) -> dict[str, Any]:
    """The validated bias settings of ``params`` (defaults for the missing keys), as keyword
    arguments of the settings dataclasses.

    Raises:
        ValueError: A negative or non-finite std or density.
    """
    out: dict[str, Any] = {
        "estimate_imu_bias": bool(
            params.get("estimate_imu_bias", IMU_BIAS_DEFAULTS["estimate_imu_bias"])
        )
    }
    for key in ("gyro_bias_sigma0", "accel_bias_sigma0", "gyro_bias_walk", "accel_bias_walk"):
        out[key] = check_nonneg(key, params.get(key, IMU_BIAS_DEFAULTS[key]))
    return out
