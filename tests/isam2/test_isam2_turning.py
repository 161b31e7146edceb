"""iSAM2's preintegration of a vehicle that turns within each IMU period.

**The case.** The vehicle starts level at rest and pitches at a constant rate ω for one
second, its accelerometer reading a constant specific force ``a`` in B: ``(0.3, −0.2, −c)``,
of which the thrust-axis model keeps ``(0, 0, −c)`` (noise-free samples, a keyframe every 10
with no landmark in view: dead reckoning). The body turns
within every sample's period, so the velocity it gains is ``∫₀^T Exp(ωt) a dt = T J_l(ωT) a``
plus ``g T`` (J_l the left Jacobian of SO(3), written here in its closed form), whatever the
sample period. Taking each sample at its period's start orientation (GTSAM's rectangle rule
alone) is off by about ``|a| |ω| dt T / 2`` (about 0.05 m/s here).
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.history import KeptSample
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import skew
from quadslam_env.types import GRAVITY

pytest.importorskip("gtsam")

DT = 0.01
"""IMU sample period, s."""
RATE = np.array([0.0, 0.8, 0.0])
"""Body rate, rad/s (a pitch-up)."""
THRUST = 12.0
"""Specific force along −z_B, m/s²."""
SECONDS = 1.0


def _left_jacobian(phi: np.ndarray) -> np.ndarray:
    """J_l(φ) = I + (1 − cos θ)/θ² [φ]× + (θ − sin θ)/θ³ [φ]×², θ = |φ|."""
    theta = float(np.linalg.norm(phi))
    k = skew(phi)
    return (
        np.eye(3) + (1 - np.cos(theta)) / theta**2 * k + (theta - np.sin(theta)) / theta**3 * k @ k
    )


@pytest.mark.parametrize("thrust_axis", [False, True])
def test_velocity_of_a_turning_thrust_is_integrated_exactly(thrust_axis: bool) -> None:
    est = Isam2Slam(thrust_axis_accel=thrust_axis)
    cov0 = np.diag([1e-4] * 9 + [0.0] * 3)
    no_map = (np.zeros(0), np.zeros((0, 3)))
    est.reset(np.zeros(12), cov0, np.random.default_rng(0), known_landmarks=no_map)
    reading = np.array([0.3, -0.2, -THRUST])
    accel = np.array([0.0, 0.0, -THRUST]) if thrust_axis else reading  # what the model keeps
    steps = round(SECONDS / DT)
    for n in range(1, steps + 1):
        est.predict(ImuSample(n * DT, reading, RATE, 1e-3, 1e-5), Control(0.0, np.zeros(3)), DT)
        if n % 10 == 0:
            est.update(LidarScan(n * DT, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.ones(3)))
    assert est.last_error == ""
    out = est.estimate()
    turned = _left_jacobian(RATE * SECONDS)
    expected = SECONDS * turned @ accel + np.array([0.0, 0.0, GRAVITY * SECONDS])
    np.testing.assert_allclose(out.vel_inertial[0], expected, atol=1e-9)


def test_turn_uses_the_bias_corrected_sample() -> None:
    """With a bias estimate the sample is turned by the corrected rate and the corrected
    specific force: the preintegrated velocity (in the keyframe's frame, at that bias) is the
    closed form of the true rate and thrust, the biases removed."""
    import gtsam

    b_accel, b_gyro = np.array([0.1, -0.2, 0.15]), np.array([0.05, -0.03, 0.02])
    est = Isam2Slam(thrust_axis_accel=False)
    no_map = (np.zeros(0), np.zeros((0, 3)))
    est.reset(np.zeros(12), np.diag([1e-4] * 9 + [0.0] * 3), np.random.default_rng(0), no_map)
    est._kf_bias = gtsam.imuBias.ConstantBias(b_accel, b_gyro)  # as a solved keyframe's
    accel = np.array([0.0, 0.0, -THRUST])
    pim = None
    for n in range(1, round(SECONDS / DT) + 1):
        sample = KeptSample(n * DT, accel + b_accel, RATE + b_gyro, 1e-3, 1e-5, DT, n * DT)
        pim = est._preintegrate(pim, sample)
    expected = SECONDS * _left_jacobian(RATE * SECONDS) @ accel
    np.testing.assert_allclose(pim.deltaVij(), expected, atol=1e-9)
