"""iSAM2 with the IMU biases held (``estimate_imu_bias: false``): dead reckoning adds only the
IMU's white noise to the attitude covariance, with no bias random walk behind it.

**The case.** The vehicle rests level (Λ = 0) with no landmark in view: the gyro reads exactly
zero and the accelerometer ``(0, 0, −g)`` (the data are noise-free, the estimator is told
their white-noise stds), and a scan without returns makes a keyframe every 10 samples. At rest
and level the rotation error obeys ``δθ_{n+1} = δθ_n − (n_ω + b_ω) dt`` (Forster et al. 2017,
eq. 44–45 with ΔR = I): it is not coupled to position or velocity. With the biases held at
zero, the only input is the gyro's white noise of density ``σ_ω² dt``, so after T seconds the
attitude's covariance is exactly

    Σ_θ(T) = (σ_θ0² + σ_ω² dt · T) I₃,

which is also the Euler angles' covariance at Λ = 0 (``D(0) = I``). The prior on every
keyframe's bias (:func:`estimators.isam2.graph.held_bias_prior`) keeps the bias's variance
below ``FIXED_BIAS_SIGMA²``, which adds at most ``T · FIXED_BIAS_SIGMA² · 0.1 s`` ≈ 2e-10 rad²
here (3e-4 of Σ_θ); a bias held by its first prior alone random-walks and adds
``FIXED_BIAS_SIGMA² (T² + T³/3)`` ≈ 3e-7 rad² (half of Σ_θ).
"""

from __future__ import annotations

import numpy as np
import pytest

from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.settings import FIXED_BIAS_SIGMA
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import EUL, GRAVITY

pytest.importorskip("gtsam")

DT = 0.01
"""IMU sample period, s."""
SECONDS = 20.0
"""Length of the dead reckoning, s."""
GYRO_SIGMA = 0.01 * np.pi / 180.0 * np.sqrt(1.0 / DT)
"""Gyro white-noise std per sample, rad/s: the paper IMU's 0.01 °/s/√Hz at 100 Hz."""
ATTITUDE_VAR0 = 1e-8
"""Prior variance per Euler angle, rad² (the estimator's floor)."""


@pytest.mark.parametrize("window_s", [3.0, None], ids=["fixed-lag", "full"])
def test_held_bias_dead_reckoning_attitude_covariance(window_s: float | None) -> None:
    est = Isam2Slam(window_s=window_s)
    mean0 = np.zeros(12)
    cov0 = np.diag([1e-2] * 3 + [1e-2] * 3 + [ATTITUDE_VAR0] * 3 + [0.0] * 3)
    est.reset(
        mean0, cov0, np.random.default_rng(0), known_landmarks=(np.zeros(0), np.zeros((0, 3)))
    )
    control = Control(0.0, np.zeros(3))
    accel = np.array([0.0, 0.0, -GRAVITY])
    steps = round(SECONDS / DT)
    for n in range(1, steps + 1):
        est.predict(ImuSample(n * DT, accel, np.zeros(3), 1e-3, GYRO_SIGMA), control, DT)
        if n % 10 == 0:
            est.update(LidarScan(n * DT, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.ones(3)))
    assert est.last_error == ""
    snap = est.estimate()
    assert snap.pose_cov is not None
    expected = ATTITUDE_VAR0 + GYRO_SIGMA**2 * DT * SECONDS
    walk = FIXED_BIAS_SIGMA**2 * (SECONDS**2 + SECONDS**3 / 3.0)
    assert walk > 0.3 * expected  # the random walk this guards against would show
    np.testing.assert_allclose(
        snap.pose_cov[0][EUL, EUL], expected * np.eye(3), rtol=1e-3, atol=1e-3 * expected
    )
