"""IMU bias Kalman filter of seed 000 (eq. 8–12, Table 4), one covariance for all particles.

The bias subsystem ``x^B = (b0_a, b0_ω, b1_a, b1_ω)`` is linear with the same ``A, H, Q, R`` for
every particle; the particles only differ in the innovation, which enters the means but not the
covariance. So the (12, 12) covariance is stored once and the (N, 12) means are updated together.

The equations are numba kernels: :func:`kf_covariance_predict` and
:func:`kf_covariance_update` (shared covariance, gain, Cholesky factor of S),
:func:`kf_means_update` (the particles' means and likelihoods) and
:func:`imu_bias_step` (all particles' IMU innovation, mean prediction and update in one loop).
The transition is diagonal (each bias is a random constant or a first-order Gauss–Markov
process), so it is stored as the diagonal ``a`` of A.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.imu_noise import gauss_markov_discretisation
from quadslam_env.models.jit import kernel
from quadslam_env.models.linalg import LOG_2PI, cholesky_lower
from quadslam_env.models.rigid_body import AirTuple, state_specific_force
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


@kernel
def kf_predict_means(mean: FloatArray, a: FloatArray) -> None:
    """``x̂ ← A x̂`` for the rows of ``mean`` (N, n) in place; ``a`` (n,) is the diagonal of A."""
    for i in range(mean.shape[0]):
        for j in range(mean.shape[1]):
            mean[i, j] = a[j] * mean[i, j]


@kernel
def kf_covariance_predict(P: FloatArray, a: FloatArray, Q: FloatArray) -> None:
    """``P ← A P Aᵀ + Q`` in place for a diagonal ``A = diag(a)``; P, Q (n, n), a (n,)."""
    for r in range(P.shape[0]):
        for c in range(P.shape[1]):
            P[r, c] = a[r] * P[r, c] * a[c] + Q[r, c]


@kernel
def _mul(A: FloatArray, B: FloatArray, transpose_b: bool) -> FloatArray:
    """``A B`` or, with ``transpose_b``, ``A Bᵀ`` of small matrices (a fresh array)."""
    rows, inner = A.shape
    cols = B.shape[0] if transpose_b else B.shape[1]
    out = np.empty((rows, cols))
    for r in range(rows):
        for c in range(cols):
            acc = 0.0
            for k in range(inner):
                acc += A[r, k] * (B[c, k] if transpose_b else B[k, c])
            out[r, c] = acc
    return out


@kernel
def kf_covariance_update(
    P: FloatArray, H: FloatArray, R: FloatArray, K: FloatArray, L: FloatArray
) -> float:
    """Shared-covariance KF update in place (seed 000 Table 4, KF-update).

    ``S = H P Hᵀ + R = L Lᵀ``, ``K = P Hᵀ S⁻¹``, ``P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ``
    (Joseph form), symmetrised. The Cholesky factorisation is the EKF's
    (:func:`quadslam_env.models.linalg.cholesky_lower`).

    Args:
        P: (n, n) predicted covariance (symmetric), updated in place.
        H: (m, n) measurement matrix. R: (m, m) measurement noise.
        K: (n, m) receives the gain. L: (m, m) receives the Cholesky factor of S in its lower
            triangle (the strict upper triangle holds S).

    Returns:
        ``log det S``, or NaN if S is not positive definite (then K and P are not written).
    """
    n, m = P.shape[0], H.shape[0]
    HP = _mul(H, P, False)
    HPHt = _mul(HP, H, True)
    for r in range(m):
        for c in range(m):
            L[r, c] = HPHt[r, c] + R[r, c]
    if not cholesky_lower(L):
        return np.nan
    logdet = 0.0
    for j in range(m):
        logdet += math.log(L[j, j])
    for c in range(n):  # K = (S⁻¹ H P)ᵀ, column by column: L y = (H P)_c, Lᵀ k = y
        for r in range(m):
            s = HP[r, c]
            for k in range(r):
                s -= L[r, k] * K[c, k]
            K[c, r] = s / L[r, r]
        for r in range(m - 1, -1, -1):
            s = K[c, r]
            for k in range(r + 1, m):
                s -= L[k, r] * K[c, k]
            K[c, r] = s / L[r, r]
    ikh = _mul(K, H, False)  # → I − K H
    for r in range(n):
        for c in range(n):
            ikh[r, c] = (1.0 if r == c else 0.0) - ikh[r, c]
    joseph = _mul(_mul(ikh, P, False), ikh, True)
    noise = _mul(_mul(K, R, False), K, True)
    for r in range(n):
        for c in range(r + 1):
            P[r, c] = P[c, r] = 0.5 * ((joseph[r, c] + noise[r, c]) + (joseph[c, r] + noise[c, r]))
    return 2.0 * logdet


@kernel
def sparsity(M: FloatArray, strict_lower: bool, cols: np.ndarray, counts: np.ndarray) -> None:
    """Column indices of the non-zero entries of each row of ``M`` (r, c), ascending.

    For finite operands, sums over these equal the full sums exactly (a skipped term is an
    exact zero), so the particle loops use them to skip the gain's and the factor's
    structural zeros (with diagonal A, Q, R and P₀, each innovation component touches two bias
    states and S is diagonal).

    Args:
        M: (r, c) matrix. strict_lower: Only columns ``k < row`` (a triangular factor).
        cols: (r, c) int, receives the indices in ``cols[row, :counts[row]]``.
        counts: (r,) int, receives the number of non-zeros per row.
    """
    for r in range(M.shape[0]):
        t = 0
        for k in range(r if strict_lower else M.shape[1]):
            if M[r, k] != 0.0:
                cols[r, t] = k
                t += 1
        counts[r] = t


KfGain = tuple[FloatArray, np.ndarray, np.ndarray, FloatArray, np.ndarray, np.ndarray, float]
"""``(K, K's non-zero columns, their counts, L, L's strictly lower non-zero columns, their
counts, log det S)``: everything a particle's mean update needs (:func:`kf_gain`)."""


def kf_gain(K: FloatArray, L: FloatArray, logdet: float) -> KfGain:
    """Bundle the gain (n, m) and the Cholesky factor (m, m) of S with their sparsity."""
    k_cols, k_counts = np.empty(K.shape, dtype=np.int64), np.empty(K.shape[0], dtype=np.int64)
    l_cols, l_counts = np.empty(L.shape, dtype=np.int64), np.empty(L.shape[0], dtype=np.int64)
    sparsity(K, False, k_cols, k_counts)
    sparsity(L, True, l_cols, l_counts)
    return K, k_cols, k_counts, L, l_cols, l_counts, logdet


@kernel
def kf_means_update(mean: FloatArray, nu: FloatArray, gain: KfGain, loglik: FloatArray) -> None:
    """Every particle: ``x̂_i ← x̂_i + K ν_i`` in place and the likelihood of its innovation.

    Args:
        mean: (N, n) predicted means, updated in place.
        nu: (N, m) innovations ``ν_i = z̄_i − H x̂_i`` (overwritten with ``L⁻¹ ν_i``).
        gain: From :func:`kf_gain`.
        loglik: (N,) receives ``log N(ν_i; 0, S) = −(|L⁻¹ν_i|² + log det S + m log 2π) / 2``
            (seed 000 eq. 26, exact).
    """
    K, k_cols, k_counts, L, l_cols, l_counts, logdet = gain
    m_log_2pi = L.shape[0] * LOG_2PI
    for i in range(mean.shape[0]):
        for r in range(K.shape[0]):
            acc = 0.0
            for t in range(k_counts[r]):
                k = k_cols[r, t]
                acc += K[r, k] * nu[i, k]
            mean[i, r] += acc
        quad = 0.0
        for r in range(L.shape[0]):
            s = nu[i, r]
            for t in range(l_counts[r]):
                k = l_cols[r, t]
                s -= L[r, k] * nu[i, k]
            nu[i, r] = s / L[r, r]
            quad += nu[i, r] * nu[i, r]
        loglik[i] = -0.5 * (quad + logdet + m_log_2pi)


@kernel
def imu_bias_step(
    x: FloatArray,
    x_prev: FloatArray,
    xb: FloatArray,
    P: FloatArray,
    a: FloatArray,
    Q: FloatArray,
    R: FloatArray,
    accel: FloatArray,
    gyro: FloatArray,
    thrust: float,
    mass: float,
    drag: float,
    air: AirTuple,
    aero: bool,
    K: FloatArray,
    L: FloatArray,
    k_cols: np.ndarray,
    k_counts: np.ndarray,
    l_cols: np.ndarray,
    l_counts: np.ndarray,
    nu: FloatArray,
    loglik: FloatArray,
) -> None:
    """Table 2 steps 2–4 for every particle: bias KF predict, IMU likelihood, bias KF update.

    The shared covariance is predicted and updated once (:func:`kf_covariance_predict`,
    :func:`kf_covariance_update` with ``H = H_BIAS``); then per particle i: ``x̂^B ← A x̂^B``,
    ``ν = z − h^d(x^{D,i}) − H x̂^B`` with ``h^d = (f_B, ω̄)`` and ``H x̂^B = b0 + b1`` (eq. 12),
    and :func:`kf_means_update`. ``f_B`` is the specific force of the particle's velocity and
    the applied thrust (with a known wind, of its velocity relative to the air: the simulator's
    drag, :func:`~quadslam_env.models.rigid_body.state_specific_force`).
    ``ω̄ = (ω_start + ω_end) / 2`` is the particle's mean body rate over the
    IMU period (trapezoid), not eq. 12's rate at its end: the gyro reports the mean rate over
    its period (:mod:`quadslam_env.sim.imu`), and during a manoeuvre the two differ by about
    ``ω̇ Δt / 2``, a systematic innovation the bias KF would otherwise learn as gyro bias.

    Args:
        x: (N, 12) particle states at the end of the period. x_prev: (N, 12) at its start.
        xb: (N, 12) bias means, updated in place.
        P: (12, 12) shared covariance, updated in place.
        a: (12,) diagonal of A. Q: (12, 12) process noise. R: (6, 6) IMU noise ``R^I``.
        accel: (3,) accelerometer reading in m/s². gyro: (3,) gyro reading in rad/s.
        thrust: Applied f_T in N. mass: Filter model mass in kg. drag: 1/s.
        air, aero: A known wind and the quadratic drag (``aero``), or still air
            (:func:`~quadslam_env.models.rigid_body.rigid_body_derivative`).
        K: (12, 6), L: (6, 6) receive the gain and the Cholesky factor of S.
        k_cols: (12, 6), k_counts: (12,), l_cols: (6, 6), l_counts: (6,) int scratch for
            their sparsity (:func:`sparsity`).
        nu: (N, 6) scratch for the innovations. loglik: (N,) receives ``log p(z^I | x^{D,i}, x̂^B)``.

    Raises:
        numpy.linalg.LinAlgError: If ``S = H P Hᵀ + R`` is not positive definite.
    """
    kf_covariance_predict(P, a, Q)
    logdet = kf_covariance_update(P, H_BIAS, R, K, L)
    if math.isnan(logdet):
        raise np.linalg.LinAlgError("bias KF: S = H P Hᵀ + R is not positive definite")
    sparsity(K, False, k_cols, k_counts)
    sparsity(L, True, l_cols, l_counts)
    gain = (K, k_cols, k_counts, L, l_cols, l_counts, logdet)
    kf_predict_means(xb, a)
    for i in range(x.shape[0]):
        f = state_specific_force(x[i], thrust, mass, drag, air, aero)
        for j in range(3):
            nu[i, j] = accel[j] - f[j] - (xb[i, j] + xb[i, 6 + j])
            rate = 0.5 * (x_prev[i, 9 + j] + x[i, 9 + j])
            nu[i, 3 + j] = gyro[j] - rate - (xb[i, 3 + j] + xb[i, 9 + j])
    kf_means_update(xb, nu, gain, loglik)


def _diagonal(A: FloatArray) -> FloatArray:
    a = np.ascontiguousarray(np.diag(A), dtype=float)
    if not np.array_equal(A, np.diag(a)):
        raise ValueError("bias KF: the transition A must be diagonal")
    return a


def bias_kf_predict(
    mean: FloatArray, P: FloatArray, A: FloatArray, Q: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """KF prediction for all particles: ``x̂ ← A x̂`` (rows of (N, n)), ``P ← A P Aᵀ + Q``.

    ``A`` (n, n) must be diagonal (as from :func:`bias_transition`); inputs are not modified.
    """
    a = _diagonal(np.asarray(A, dtype=float))
    out = np.array(mean, dtype=float)
    kf_predict_means(out, a)
    P_new = np.array(P, dtype=float)
    kf_covariance_predict(P_new, a, np.ascontiguousarray(Q, dtype=float))
    return out, P_new


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
    H = np.ascontiguousarray(H, dtype=float)
    m, n = H.shape
    P_new = np.array(P, dtype=float)
    K, L = np.empty((n, m)), np.empty((m, m))
    logdet = kf_covariance_update(P_new, H, np.ascontiguousarray(R, dtype=float), K, L)
    if math.isnan(logdet):
        raise np.linalg.LinAlgError("bias KF: S = H P Hᵀ + R is not positive definite")
    out = np.array(mean, dtype=float)
    loglik = np.empty(out.shape[0])
    nu = np.array(innovation, dtype=float)
    kf_means_update(out, nu, kf_gain(K, L, logdet), loglik)
    return out, P_new, loglik
