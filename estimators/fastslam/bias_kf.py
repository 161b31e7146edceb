"""IMU bias Kalman filter of seed 000 (eq. 8–12, Table 4), one covariance for all particles.

The bias subsystem ``x^B = (b0_a, b0_ω, b1_a, b1_ω)`` is linear with the same ``A, H, Q, R`` for
every particle; the particles only differ in the innovation, which enters the means but not the
covariance. So the (12, 12) covariance is stored once and the (N, 12) means are updated together.
"""

from __future__ import annotations

import numpy as np

from quadslam_env.models.imu_noise import gauss_markov_discretisation
from quadslam_env.models.linalg import LOG_2PI
from quadslam_env.types import IMU_DIM, FloatArray

BIAS_DIM = 2 * IMU_DIM
"""Size of x^B = (b0_a, b0_ω, b1_a, b1_ω)."""

H_BIAS = np.hstack([np.eye(IMU_DIM), np.eye(IMU_DIM)])
"""(6, 12) ``H^b = [I 0 I 0; 0 I 0 I]`` of seed 000 eq. 12 (x^B = (b0_a, b0_ω, b1_a, b1_ω))."""


def bias_transition(
    dt: float, tau: float, accel_drift_sigma: float, gyro_drift_sigma: float
) -> tuple[FloatArray, FloatArray]:
    """Exact discretisation of seed 000 eq. 8, 10 over ``dt`` s (eq. 11 form).

    Uses :func:`quadslam_env.models.imu_noise.gauss_markov_discretisation`, the simulated
    IMU's discretisation.

    Args:
        dt: Period in s. tau: Drift time constant τ in s.
        accel_drift_sigma: Stationary drift std σ_a in m/s².
        gyro_drift_sigma: Stationary drift std σ_ω in rad/s.

    Returns:
        ``(A, Q)``, each (12, 12): ``A = blkdiag(I, I, a I, a I)`` with ``a = e^{−dt/τ}`` and
        ``Q = blkdiag(0, 0, σ_a²(1 − a²) I, σ_ω²(1 − a²) I)``.
    """
    a, q = gauss_markov_discretisation(dt, tau)
    A = np.diag(np.r_[np.ones(6), np.full(6, a)])
    drift_var = np.r_[np.full(3, accel_drift_sigma**2 * q), np.full(3, gyro_drift_sigma**2 * q)]
    Q = np.diag(np.r_[np.zeros(6), drift_var])
    return A, Q


def bias_kf_predict(
    mean: FloatArray, P: FloatArray, A: FloatArray, Q: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """KF prediction for all particles: ``x̂ ← A x̂`` (rows of (N, n)), ``P ← A P Aᵀ + Q``."""
    return mean @ A.T, A @ P @ A.T + Q


def bias_kf_update(
    mean: FloatArray, P: FloatArray, innovation: FloatArray, H: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """KF update of N particle means sharing one covariance (seed 000 Table 4, KF-update).

    Args:
        mean: (N, n) predicted means ``x̂_{k|k−1}``.
        P: (n, n) shared predicted covariance.
        innovation: (N, m) innovations ``ν_i = z̄_i − H x̂_i`` (``z̄_i = z − h^d(x^{D,i})``).
        H: (m, n) measurement matrix.
        R: (m, m) measurement noise covariance.

    Returns:
        ``(mean, P, loglik)``: updated (N, n) means, updated (n, n) covariance (Joseph form)
        and (N,) ``log N(ν_i; 0, S)`` with ``S = H P Hᵀ + R`` — the exact eq. 26 likelihood.
    """
    S = H @ P @ H.T + R
    L = np.linalg.cholesky(S)
    K = np.linalg.solve(S, H @ P).T  # P Hᵀ S⁻¹ (S symmetric)
    white = np.linalg.solve(L, innovation.T)  # L⁻¹ νᵀ, (m, N)
    logdet = 2.0 * float(np.sum(np.log(np.diag(L))))
    loglik = -0.5 * (np.sum(white * white, axis=0) + logdet + H.shape[0] * LOG_2PI)
    ikh = np.eye(P.shape[0]) - K @ H
    P_new = ikh @ P @ ikh.T + K @ R @ K.T
    return mean + innovation @ K.T, 0.5 * (P_new + P_new.T), loglik
