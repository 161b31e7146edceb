"""iSAM2 with EKF-SLAM's specific-force model (``thrust_axis_accel: true``, seed 001 eq. 25):
only the accelerometer's z axis enters, the horizontal specific force taken as zero.

**The case.** The vehicle rests level (Λ = 0) with no landmark in view, dead-reckoning 5 s
with a keyframe every 10 samples; the gyro reads zero and the accelerometer ``(a_x, a_y, −g)``.
At rest and level the horizontal velocity error obeys ``δv̇ = g [e_z]× δθ + n_a`` (the
accelerometer's white noise ``n_a`` of density ``σ_a² dt`` per axis enters once, whatever the
tilt does), so the two models' horizontal velocity variances after T seconds differ by exactly
``(σ_a² dt − HORIZONTAL_ACCEL_VARIANCE) · T``: what the thrust-axis model no longer takes from
the samples. And with it, the estimate cannot depend on ``a_x, a_y``.
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.settings import HORIZONTAL_ACCEL_VARIANCE
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import GRAVITY, VEL

pytest.importorskip("gtsam")

DT = 0.01
"""IMU sample period, s."""
SECONDS = 5.0
"""Length of the dead reckoning, s."""
ACCEL_SIGMA = 0.02
"""Accelerometer white-noise std per sample, m/s²."""


def _dead_reckon(thrust_axis: bool, horizontal: np.ndarray) -> Isam2Slam:
    """The estimator after ``SECONDS`` at rest, the accelerometer reading ``horizontal`` (n, 2)
    on its x, y axes (repeated cyclically) and −g on z."""
    est = Isam2Slam(thrust_axis_accel=thrust_axis)
    cov0 = np.diag([1e-2] * 3 + [1e-2] * 3 + [1e-8] * 3 + [0.0] * 3)
    no_map = (np.zeros(0), np.zeros((0, 3)))
    est.reset(np.zeros(12), cov0, np.random.default_rng(0), known_landmarks=no_map)
    control = Control(0.0, np.zeros(3))
    steps = round(SECONDS / DT)
    for n in range(1, steps + 1):
        ax, ay = horizontal[n % len(horizontal)]
        accel = np.array([ax, ay, -GRAVITY])
        est.predict(ImuSample(n * DT, accel, np.zeros(3), ACCEL_SIGMA, 1e-4), control, DT)
        if n % 10 == 0:
            est.update(LidarScan(n * DT, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.ones(3)))
    assert est.last_error == ""
    return est


def test_thrust_axis_model_ignores_the_horizontal_accelerometer() -> None:
    readings = np.random.default_rng(1).normal(0.0, 0.5, (37, 2))
    a = _dead_reckon(True, readings).estimate()
    b = _dead_reckon(True, np.zeros((1, 2))).estimate()
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.vel_body, b.vel_body)
    np.testing.assert_array_equal(a.pose_cov, b.pose_cov)
    c = _dead_reckon(False, readings).estimate()  # the three-axis model does use them
    assert np.abs(c.vel_body - b.vel_body).max() > 0.1


def test_thrust_axis_model_removes_the_horizontal_accelerometer_noise() -> None:
    level = np.zeros((1, 2))
    three = _dead_reckon(False, level).estimate().pose_cov[0][VEL, VEL]
    thrust = _dead_reckon(True, level).estimate().pose_cov[0][VEL, VEL]
    expected = (ACCEL_SIGMA**2 * DT - HORIZONTAL_ACCEL_VARIANCE) * SECONDS
    np.testing.assert_allclose(np.diag(three - thrust)[:2], expected, rtol=1e-6)
    assert abs(three[2, 2] - thrust[2, 2]) < 1e-6 * three[2, 2]  # the z axis is the same
