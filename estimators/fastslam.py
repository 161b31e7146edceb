"""FastSLAM estimators (DESIGN.md §5; seed 000 §III, Tables 2–4).

Two Rao-Blackwellised particle filters share one implementation (:class:`_FastSLAMBase`):

``fastslam`` (:class:`DynamicFastSLAM`)
    Seed 000's self-calibrating FastSLAM. Each particle i carries the 12-state
    ``x^D = (ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])`` propagated through the quadcopter
    **dynamics** (seed 001 eq. 2 = seed 000 eq. 1–4) with the applied control, a Kalman filter
    over the IMU bias/drift state ``x^B = (b0_a, b0_ω, b1_a, b1_ω)`` (seed 000 eq. 8–12,
    Table 4) and one EKF per landmark (Table 3). Weights multiply the LiDAR and the IMU
    likelihoods (eq. 28). Optional stage 2 (Table 2, step 8) regenerates ω from the gyro inverse
    model and ρ from the LiDAR inverse model.

``fastslam_kinematic`` (:class:`KinematicFastSLAM`)
    FastSLAM 1.0 driven by IMU strapdown kinematics ``v̇ = −ω_m×v + C_NBᵀ g n3 + a_m``,
    ``Λ̇ = D(Λ) ω_m`` with no bias calibration and LiDAR-only weights — seed 000's comparison
    baseline (Fig. 10–14).

Array layout (all particle work is batched; there is no Python loop over particles):

* ``x``      (N, 12) particle states ``x^D``;
* ``logw``   (N,) normalised log-weights;
* ``mu``     (N, L, 3) landmark means ``μ_j^i`` in N, m; ``sigma`` (N, L, 3, 3) their
  covariances ``Σ_j^i`` in m². L grows when a landmark id is seen for the first time; the
  id → slot map is shared by all particles (data association is known, DESIGN.md §3).
* dynamic filter only: ``xb`` (N, 12) bias-KF means and ONE shared (12, 12) covariance ``P``.
  The bias subsystem is linear with the same ``A, H, Q, R`` for every particle (seed 000
  eq. 11–12); the particles only differ in the innovation ``z̄ = z^I − h^d(x^{D,i})``, which
  enters the mean but not the covariance. So ``P`` is particle-independent and is stored once.

Resampling (systematic, when ESS < ``resample_threshold``·N, seed 004 Table 3-2) uses fancy
indexing, so every resampled array is a fresh copy: particles never share memory.

Choices not fixed by the papers (documented here and in the parameter table):

* Particle propagation uses one classical RK4 step per IMU/control period by default
  (``integrator="rk4"``). At 100 Hz and for the rates of a quadcopter the RK4 truncation error
  (O(h⁵) per step) is many orders below the process noise, and one RK4 step on an (N, 12)
  array costs ~0.3 ms at N = 500 — 4 vectorised derivative calls rather than the
  simulator's 20 scalar substeps. ``integrator="euler"`` is 4× cheaper with an O(h²) local
  error (~1e-4 m/s per step at g-level accelerations), offered for very large N.
* Process noise is a white-noise *density*: each step adds ``N(0, σ² dt)`` per state, so the
  filter behaves the same at any control rate.
* The bias drift is discretised exactly, ``b1 ← e^{−T/τ} b1 + N(0, σ_b1²(1 − e^{−2T/τ}))``, with
  σ_b1 the stationary standard deviation (DESIGN.md §3, matching the simulated IMU). Seed 000
  eq. 11 uses the first-order ``1 − T/τ`` and ``Q = T²σ²``; the two agree to O(T/τ).
* The IMU likelihood (eq. 26) is evaluated exactly: with the Gaussian bias prediction the
  integral in eq. 26 is ``N(z̄; H x̂^B_{k|k−1}, H P Hᵀ + R^I)``, which the paper approximates
  by a delta at ``x̂^B`` (i.e. drops ``H P Hᵀ``). Seed 000's ``k = 1`` re-initialisation of
  Table 4 is not used: ``HᵀH`` is singular (b0 and b1 enter the measurement only as a sum), so
  its least-squares re-initialisation is ill-posed; the prior ``P0`` plays its role.
* The LiDAR likelihood of an already-mapped landmark is ``N(z; h(x^{D,i}, μ_j^i), S)`` with
  ``S = H Σ Hᵀ + R`` (the standard FastSLAM 1.0 weight); new landmarks add the same constant
  to every particle and are ignored. Angle residuals are wrapped.
* The IMU sample passed to :meth:`predict` is taken to describe the vehicle at the *end* of
  the period (after the physics step), so it is compared with the propagated particles.
* Not in seed 000's filter, but named there (§IV) as the remedy for model mismatch: the
  principal moments of inertia are identified online from the gyro and the applied torque
  (:mod:`estimators.inertia`, ``estimate_inertia``), and the model and the particles' ω follow
  the estimate. Set ``estimate_inertia=False`` for the paper's fixed-model filter.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from estimators.base import POSE_DIM, Estimate, check_kwargs, register
from estimators.inertia import GyroTorqueRegression
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.dynamics import GRAVITY, VehicleParams
from quadslam_env.models.lidar import body_from_measure, measure_from_body, measure_jacobian_body
from quadslam_env.models.rotations import (
    FloatArray,
    dcm_from_euler,
    dcm_from_euler_batch,
    wrap_angle,
)

STATE_DIM = 12
BIAS_DIM = 12
IMU_DIM = 6
MEAS_DIM = 3
_LOG_2PI = math.log(2.0 * math.pi)
_SIGMA_FLOOR = 1e-9
"""Smallest sensor standard deviation used in R (keeps S invertible for noise-free sensors)."""

_OWNER = "estimator.params"
_FLOAT = (float, int)
_VECTOR = (float, int, list, tuple, np.ndarray)

H_BIAS = np.hstack([np.eye(IMU_DIM), np.eye(IMU_DIM)])
"""(6, 12) ``H^b = [I 0 I 0; 0 I 0 I]`` of seed 000 eq. 12 (x^B = (b0_a, b0_ω, b1_a, b1_ω))."""


# --------------------------------------------------------------------------------------------
# Process models (vectorised over particles)
# --------------------------------------------------------------------------------------------


def _kinematic_part(x: FloatArray, accel: Any) -> FloatArray:
    """Rows ρ̇, v̇, Λ̇ of the rigid-body model for states (..., 12); ω̇ is left as zero.

    ``accel`` is the specific force in B (m/s², broadcastable to (..., 3)), i.e. the term that
    the dynamics write as ``−(f_T/m) b3 − drag v`` and the strapdown model takes from ``a_m``.
    """
    u, v, w = x[..., 3], x[..., 4], x[..., 5]
    cf, sf = np.cos(x[..., 6]), np.sin(x[..., 6])
    ct, st = np.cos(x[..., 7]), np.sin(x[..., 7])
    cp, sp = np.cos(x[..., 8]), np.sin(x[..., 8])
    p, q, r = x[..., 9], x[..., 10], x[..., 11]
    out = np.zeros(x.shape)
    sfst, cfst = sf * st, cf * st
    # ρ̇ = C_NB v
    out[..., 0] = ct * cp * u + (sfst * cp - cf * sp) * v + (cfst * cp + sf * sp) * w
    out[..., 1] = ct * sp * u + (sfst * sp + cf * cp) * v + (cfst * sp - sf * cp) * w
    out[..., 2] = -st * u + sf * ct * v + cf * ct * w
    # v̇ = −ω×v + C_NBᵀ g n3 + f_B
    out[..., 3] = r * v - q * w - GRAVITY * st + accel[..., 0]
    out[..., 4] = p * w - r * u + GRAVITY * sf * ct + accel[..., 1]
    out[..., 5] = q * u - p * v + GRAVITY * cf * ct + accel[..., 2]
    # Λ̇ = D(Λ) ω (seed 001 eq. 3, seed 000 eq. 2)
    sq_cr = sf * q + cf * r
    out[..., 6] = p + sq_cr * st / ct
    out[..., 7] = cf * q - sf * r
    out[..., 8] = sq_cr / ct
    return out


class DynamicsModel:
    """Vectorised quadcopter dynamics with (possibly mismatched) nominal parameters.

    Args:
        vehicle: Nominal vehicle parameters (mass kg, inertia kg·m², drag 1/s).
        mass_scale: Factor on the mass used by the filter model.
        inertia_scale: Factor on the inertia used by the filter model (seed 000 Fig. 14 uses
            2.5, i.e. +150 %).
    """

    def __init__(
        self, vehicle: VehicleParams, mass_scale: float = 1.0, inertia_scale: float = 1.0
    ) -> None:
        self.mass = float(vehicle.mass) * mass_scale
        self.drag = float(vehicle.drag)
        self.set_inertia(np.array(vehicle.inertia, dtype=float) * inertia_scale)

    def set_inertia(self, inertia: FloatArray) -> None:
        """Replace the model inertia: a (3, 3) matrix or (3,) principal moments, kg·m²."""
        inertia = np.asarray(inertia, dtype=float)
        self.inertia = np.diag(inertia) if inertia.ndim == 1 else inertia.copy()
        self.inertia_inv = np.linalg.inv(self.inertia)

    def specific_force(self, x: FloatArray, thrust: float) -> FloatArray:
        """``f_B = −(f_T/m) b3 − drag v`` (..., 3) in m/s² for states (..., 12)."""
        f = -self.drag * x[..., 3:6]
        f[..., 2] -= thrust / self.mass
        return f

    def derivative(self, x: FloatArray, thrust: float, torque: FloatArray) -> FloatArray:
        """Time derivative of states (..., 12) (seed 001 eq. 2; seed 000 eq. 1–3).

        Args:
            x: (..., 12) states ``(ρ, v_B, Λ, ω)``.
            thrust: Collective thrust f_T in N (used as given, no saturation).
            torque: (3,) body torque τ in N·m.

        Returns:
            (..., 12) ``ẋ``; equals :func:`quadslam_env.models.state_derivative` row by row
            when the scales are 1.
        """
        out = _kinematic_part(x, self.specific_force(x, thrust))
        omega = x[..., 9:12]
        h = omega @ self.inertia.T  # J ω
        p, q, r = omega[..., 0], omega[..., 1], omega[..., 2]
        m = np.empty(omega.shape)
        m[..., 0] = torque[0] - (q * h[..., 2] - r * h[..., 1])
        m[..., 1] = torque[1] - (r * h[..., 0] - p * h[..., 2])
        m[..., 2] = torque[2] - (p * h[..., 1] - q * h[..., 0])
        out[..., 9:12] = m @ self.inertia_inv.T  # ω̇ = J⁻¹(τ − ω×Jω)
        return out


def dynamics_derivative_batch(
    x: FloatArray, thrust: float, torque: Any, vehicle: VehicleParams
) -> FloatArray:
    """Vectorised :func:`quadslam_env.models.state_derivative` for states (..., 12)."""
    return DynamicsModel(vehicle).derivative(
        np.asarray(x, dtype=float), float(thrust), np.asarray(torque, dtype=float).reshape(3)
    )


def kinematic_derivative_batch(x: FloatArray, accel: Any) -> FloatArray:
    """Strapdown kinematics for states (..., 12) whose ω slot holds the gyro input.

    ``ρ̇ = C_NB v``, ``v̇ = −ω×v + C_NBᵀ g n3 + a``, ``Λ̇ = D(Λ) ω``, ``ω̇ = 0`` (ω held over the
    period). ``accel`` (..., 3) is the measured specific force in m/s² (B).
    """
    x = np.asarray(x, dtype=float)
    return _kinematic_part(x, np.asarray(accel, dtype=float))


def _integrate(
    f: Callable[[FloatArray], FloatArray], x: FloatArray, h: float, method: str
) -> FloatArray:
    """One explicit step of size ``h`` s: classical RK4 or forward Euler."""
    k1 = f(x)
    if method == "euler":
        return x + h * k1
    k2 = f(x + (0.5 * h) * k1)
    k3 = f(x + (0.5 * h) * k2)
    k4 = f(x + h * k3)
    return x + (h / 6.0) * (k1 + 2.0 * (k2 + k3) + k4)


# --------------------------------------------------------------------------------------------
# Particle-filter primitives
# --------------------------------------------------------------------------------------------


def normalise_log_weights(logw: FloatArray) -> FloatArray:
    """Normalise log-weights with log-sum-exp so that ``Σ exp(logw) = 1``.

    Args:
        logw: (N,) unnormalised log-weights; ``-inf`` allowed, at least one finite.

    Returns:
        (N,) normalised log-weights.
    """
    top = np.max(logw)
    return logw - (top + math.log(float(np.sum(np.exp(logw - top)))))


def effective_sample_size(weights: FloatArray) -> float:
    """``N_eff = 1 / Σ w_i²`` for normalised weights (seed 004 Table 3-2, line 3)."""
    w = np.asarray(weights, dtype=float)
    return float(1.0 / np.dot(w, w))


def systematic_resample(weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform draw, N evenly spaced pointers.

    Particle i is copied either ``⌊N w_i⌋`` or ``⌈N w_i⌉`` times.

    Args:
        weights: (N,) normalised weights.
        rng: Random generator.

    Returns:
        (N,) int indices of the selected particles, ascending.
    """
    w = np.asarray(weights, dtype=float)
    n = w.shape[0]
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    cdf[-1] = 1.0
    pointers = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cdf, pointers, side="right")
    return np.minimum(idx, n - 1)


# --------------------------------------------------------------------------------------------
# Bias Kalman filter (seed 000 Table 4) with one covariance shared by all particles
# --------------------------------------------------------------------------------------------


def bias_transition(
    dt: float, tau: float, accel_drift_sigma: float, gyro_drift_sigma: float
) -> tuple[FloatArray, FloatArray]:
    """Exact discretisation of seed 000 eq. 8, 10 over ``dt`` s (eq. 11 form).

    Returns:
        ``(A, Q)``, each (12, 12): ``A = blkdiag(I, I, a I, a I)`` with ``a = e^{−dt/τ}`` and
        ``Q = blkdiag(0, 0, σ_a²(1 − a²) I, σ_ω²(1 − a²) I)`` (σ the stationary drift std).
    """
    a = math.exp(-dt / tau)
    A = np.diag(np.r_[np.ones(6), np.full(6, a)])
    q = 1.0 - a * a
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
    loglik = -0.5 * (np.sum(white * white, axis=0) + logdet + H.shape[0] * _LOG_2PI)
    ikh = np.eye(P.shape[0]) - K @ H
    P_new = ikh @ P @ ikh.T + K @ R @ K.T
    return mean + innovation @ K.T, 0.5 * (P_new + P_new.T), loglik


# --------------------------------------------------------------------------------------------
# Landmark EKFs (seed 000 Table 3), batched over (particles, landmarks)
# --------------------------------------------------------------------------------------------


def _inv3_sym(S: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse and determinant of symmetric 3×3 matrices (..., 3, 3) by cofactors."""
    a, b, c = S[..., 0, 0], S[..., 0, 1], S[..., 0, 2]
    d, e, f = S[..., 1, 1], S[..., 1, 2], S[..., 2, 2]
    c00 = d * f - e * e
    c01 = c * e - b * f
    c02 = b * e - c * d
    det = a * c00 + b * c01 + c * c02
    inv = np.empty(S.shape)
    inv[..., 0, 0] = c00
    inv[..., 0, 1] = inv[..., 1, 0] = c01
    inv[..., 0, 2] = inv[..., 2, 0] = c02
    inv[..., 1, 1] = a * f - c * c
    inv[..., 1, 2] = inv[..., 2, 1] = b * c - a * e
    inv[..., 2, 2] = a * d - b * b
    inv /= det[..., None, None]
    return inv, det


def _chol3(a: FloatArray) -> FloatArray:
    """Lower Cholesky factors of symmetric PSD 3×3 matrices (..., 3, 3), clipped at zero pivots."""
    out = np.zeros(a.shape)
    l00 = np.sqrt(np.maximum(a[..., 0, 0], 0.0))
    inv00 = np.divide(1.0, l00, out=np.zeros_like(l00), where=l00 > 0.0)
    l10 = a[..., 1, 0] * inv00
    l20 = a[..., 2, 0] * inv00
    l11 = np.sqrt(np.maximum(a[..., 1, 1] - l10 * l10, 0.0))
    inv11 = np.divide(1.0, l11, out=np.zeros_like(l11), where=l11 > 0.0)
    l21 = (a[..., 2, 1] - l20 * l10) * inv11
    l22 = np.sqrt(np.maximum(a[..., 2, 2] - l20 * l20 - l21 * l21, 0.0))
    out[..., 0, 0], out[..., 1, 0], out[..., 2, 0] = l00, l10, l20
    out[..., 1, 1], out[..., 2, 1], out[..., 2, 2] = l11, l21, l22
    return out


def _swap(a: FloatArray) -> FloatArray:
    """Transpose of the last two axes (a view)."""
    return np.swapaxes(a, -1, -2)


def _swap_copy(a: FloatArray) -> FloatArray:
    """Contiguous transpose of the last two axes (stacked matmul is much faster on it)."""
    return np.ascontiguousarray(np.swapaxes(a, -1, -2))


def _mv(a: FloatArray, v: FloatArray) -> FloatArray:
    """Stacked matrix–vector product ``a @ v`` for (..., n, n) and (..., n)."""
    return (a @ v[..., None])[..., 0]


def measure_inverse_jacobian(meas: FloatArray) -> FloatArray:
    """``∂ϱ/∂y`` of ``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` for measurements (..., 3) → (..., 3, 3)."""
    alpha, beta, delta = meas[..., 0], meas[..., 1], meas[..., 2]
    ca, sa, cb, sb = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta)
    out = np.empty((*meas.shape, 3))
    out[..., 0, 0] = -delta * cb * sa
    out[..., 1, 0] = delta * cb * ca
    out[..., 2, 0] = 0.0
    out[..., 0, 1] = -delta * sb * ca
    out[..., 1, 1] = -delta * sb * sa
    out[..., 2, 1] = delta * cb
    out[..., 0, 2] = cb * ca
    out[..., 1, 2] = cb * sa
    out[..., 2, 2] = sb
    return out


def landmark_init(
    pos: FloatArray, dcm: FloatArray, meas: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Initialise landmark EKFs from first observations (seed 000 Table 3, EKF-predict).

    ``μ = h⁻¹(x^D, z) = ρ + C_NB ϱ(z)`` and ``Σ = G R Gᵀ`` with ``G = ∂h⁻¹/∂z = C_NB ∂ϱ/∂z``
    (equal to Table 3's ``H⁻¹ R H⁻ᵀ`` since ``G = H⁻¹`` at the initial point).

    Args:
        pos: (N, 3) particle positions in N, m.
        dcm: (N, 3, 3) particle ``C_NB``.
        meas: (k, 3) measurements (α rad, β rad, δ m).
        R: (3, 3) measurement noise covariance.

    Returns:
        ``(mu, sigma)`` of shapes (N, k, 3) and (N, k, 3, 3).
    """
    body = body_from_measure(meas)  # (k, 3)
    mu = pos[:, None, :] + np.einsum("nij,kj->nki", dcm, body)
    D = measure_inverse_jacobian(meas)  # (k, 3, 3), the same for every particle
    M = D @ R @ _swap(D)  # (k, 3, 3) body-frame covariance
    C = dcm[:, None]
    sigma = C @ M[None] @ _swap(C)
    return mu, 0.5 * (sigma + _swap(sigma))


def landmark_ekf_update(
    mu: FloatArray,
    sigma: FloatArray,
    pos: FloatArray,
    dcm: FloatArray,
    meas: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Batched landmark EKF update (seed 000 Table 3, EKF-update) and the FastSLAM weight.

    All leading dimensions broadcast (typically particles × observed landmarks).

    Args:
        mu: (..., 3) prior landmark means in N, m.
        sigma: (..., 3, 3) prior landmark covariances in m².
        pos: (..., 3) vehicle positions in N, m.
        dcm: (..., 3, 3) ``C_NB`` of each vehicle pose.
        meas: (..., 3) measurements (α, β, δ).
        R: (3, 3) measurement noise covariance.

    Returns:
        ``(mu, sigma, loglik, nis)``: posterior means and covariances, the log of
        ``N(ν; 0, S)`` with ``S = H Σ Hᵀ + R`` and ``ν`` the wrapped innovation, and the NIS
        ``νᵀ S⁻¹ ν``; the last two of shape (...).
    """
    dcm_t = np.ascontiguousarray(_swap(dcm))  # C_NBᵀ; contiguous operands keep matmul fast
    c = _mv(dcm_t, mu - pos)  # C_NBᵀ (μ − ρ), body frame
    nu = meas - measure_from_body(c)
    nu[..., :2] = wrap_angle(nu[..., :2])
    H = measure_jacobian_body(c) @ dcm_t  # ∂h/∂m = ∂h/∂c · C_NBᵀ
    HS = H @ sigma
    PHt = _swap_copy(HS)  # Σ Hᵀ (Σ symmetric)
    S = H @ PHt + R
    S_inv, det = _inv3_sym(S)
    K = PHt @ S_inv  # Σ Hᵀ S⁻¹
    mu_new = mu + _mv(K, nu)
    # Σ − K H Σ (equal to (I − K H) Σ for the optimal gain), symmetrised.
    sig_new = sigma - K @ HS
    sig_new = 0.5 * (sig_new + _swap(sig_new))
    nis = np.sum(nu * _mv(S_inv, nu), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        logdet = np.log(det)  # det <= 0 only for a numerically broken S: the weight becomes NaN
    loglik = -0.5 * (nis + logdet + MEAS_DIM * _LOG_2PI)
    return mu_new, sig_new, loglik, nis


# --------------------------------------------------------------------------------------------
# Parameter handling
# --------------------------------------------------------------------------------------------


def _fail(key: str, value: Any, allowed: str) -> ValueError:
    return ValueError(f"{_OWNER}.{key}: invalid value {value!r}; allowed: {allowed}")


def _positive(key: str, value: Any, strict: bool = True) -> float:
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (strict and v == 0.0):
        raise _fail(key, value, "a finite number > 0" if strict else "a finite number >= 0")
    return v


def _process_noise(key: str, value: Any) -> FloatArray:
    """Expand a scalar, 4 group values (ρ, v, Λ, ω) or 12 values to a (12,) density."""
    allowed = "a number, 4 values (ρ, v, Λ, ω groups) or 12 values, all finite and >= 0"
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise _fail(key, value, allowed) from None
    if arr.size == 1:
        arr = np.full(STATE_DIM, arr[0])
    elif arr.size == 4:
        arr = np.repeat(arr, 3)
    elif arr.size != STATE_DIM:
        raise _fail(key, value, allowed)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise _fail(key, value, allowed)
    return arr


def _wrap_euler(x: FloatArray) -> None:
    x[:, 6:9] = wrap_angle(x[:, 6:9])


def _psd_sqrt(cov: FloatArray) -> FloatArray:
    """A square root ``S`` with ``S Sᵀ = cov`` for a symmetric PSD (possibly singular) matrix."""
    vals, vecs = np.linalg.eigh(0.5 * (cov + cov.T))
    return vecs * np.sqrt(np.clip(vals, 0.0, None))


# --------------------------------------------------------------------------------------------
# Estimators
# --------------------------------------------------------------------------------------------


class _FastSLAMBase:
    """Particles, landmark EKFs, weights, resampling and the estimate (shared machinery).

    Subclasses implement :meth:`_propagate` (motion model) and may override the hooks
    :meth:`_imu_step`, :meth:`_post_predict`, :meth:`_post_update`, :meth:`_resample_extra`.
    """

    _COMMON: ClassVar[dict[str, type | tuple[type, ...]]] = {
        "n_particles": int,
        "resample_threshold": _FLOAT,
        "process_noise": _VECTOR,
        "integrator": str,
        "known_map_sigma": _FLOAT,
        "likelihood_inflation": _FLOAT,
        "roughening": _FLOAT,
        "nis_divergence": _FLOAT,
        "nis_divergence_s": _FLOAT,
    }
    _DEFAULT_NOISE: ClassVar[tuple[float, float, float, float]] = (0.0, 0.0, 0.0, 0.0)
    _DEFAULT_INFLATION: ClassVar[float] = 1.0
    _DEFAULT_ROUGHENING: ClassVar[float] = 0.0

    def __init__(self, params: dict[str, Any], extra: dict[str, type | tuple[type, ...]]) -> None:
        allowed = {**self._COMMON, **extra}
        check_kwargs(_OWNER, params, allowed)
        self.n_particles = int(params.get("n_particles", 500))
        if self.n_particles < 1:
            raise _fail("n_particles", self.n_particles, "an int >= 1")
        self.resample_threshold = float(params.get("resample_threshold", 0.5))
        if not 0.0 <= self.resample_threshold <= 1.0:
            raise _fail("resample_threshold", params["resample_threshold"], "a number in [0, 1]")
        self.process_noise = _process_noise(
            "process_noise", params.get("process_noise", self._DEFAULT_NOISE)
        )
        self.integrator = params.get("integrator", "rk4")
        if self.integrator not in ("rk4", "euler"):
            raise _fail("integrator", self.integrator, "'rk4' or 'euler'")
        self.known_map_sigma = _positive("known_map_sigma", params.get("known_map_sigma", 1e-3))
        self.likelihood_inflation = _positive(
            "likelihood_inflation", params.get("likelihood_inflation", self._DEFAULT_INFLATION)
        )
        if self.likelihood_inflation < 1.0:
            raise _fail(
                "likelihood_inflation", params["likelihood_inflation"], "a finite number >= 1"
            )
        self.roughening = _positive(
            "roughening", params.get("roughening", self._DEFAULT_ROUGHENING), strict=False
        )
        self.nis_divergence = _positive(
            "nis_divergence", params.get("nis_divergence", 1000.0), strict=False
        )
        self.nis_divergence_s = _positive(
            "nis_divergence_s", params.get("nis_divergence_s", 2.0), strict=False
        )
        self._rng = np.random.default_rng(0)
        self._alloc()

    # ---------------------------------------------------------------- state
    def _alloc(self) -> None:
        n = self.n_particles
        self.x = np.zeros((n, STATE_DIM))
        self.logw = np.full(n, -math.log(n))
        self.mu = np.zeros((n, 0, 3))
        self.sigma = np.zeros((n, 0, 3, 3))
        self._slot: dict[int, int] = {}
        self._slot_ids: list[int] = []
        self.n_resamples = 0
        self.n_divergences = 0
        self._diverged = False
        self._nis = math.nan
        self._nis_dof = 0
        self._time = 0.0
        self._nis_high_since: float | None = None
        self._lost = False
        self._best_nis = math.nan

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Draw N particles from ``N(mean0, cov0)`` and clear the map.

        Args:
            mean0: (12,) initial state mean ``(ρ, v_B, Λ, ω)``.
            cov0: (12, 12) initial covariance (PSD; singular allowed).
            rng: The only source of randomness of this estimator.
            known_landmarks: Optional ``(ids (L,), positions (L, 3))``: the landmarks start
                mapped at these positions with covariance ``known_map_sigma² I`` in every
                particle (known-map mode); they are still EKF-updated (negligibly).

        Raises:
            ValueError: On wrong shapes or non-finite values.
        """
        mean = np.asarray(mean0, dtype=float)
        cov = np.asarray(cov0, dtype=float)
        if mean.shape != (STATE_DIM,) or not np.all(np.isfinite(mean)):
            raise ValueError(f"reset: mean0 must be a finite (12,) array, got shape {mean.shape}")
        if cov.shape != (STATE_DIM, STATE_DIM) or not np.all(np.isfinite(cov)):
            raise ValueError(f"reset: cov0 must be a finite (12, 12) array, got shape {cov.shape}")
        self._rng = rng
        self._alloc()
        n = self.n_particles
        self.x = mean + rng.standard_normal((n, STATE_DIM)) @ _psd_sqrt(cov).T
        _wrap_euler(self.x)
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(int).ravel()
            pts = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            if ids.shape[0] != pts.shape[0]:
                raise ValueError(
                    f"reset: known_landmarks has {ids.shape[0]} ids but {pts.shape[0]} positions"
                )
            self._add_slots(ids)
            self.mu = np.broadcast_to(pts, (n, *pts.shape)).copy()
            self.sigma = np.broadcast_to(
                self.known_map_sigma**2 * np.eye(3), (n, pts.shape[0], 3, 3)
            ).copy()
        self._reset_extra()

    def _reset_extra(self) -> None:
        """Hook: reset subclass state after the particles are drawn."""

    def _add_slots(self, ids: np.ndarray) -> None:
        for lid in ids.tolist():
            self._slot[int(lid)] = len(self._slot_ids)
            self._slot_ids.append(int(lid))

    # ---------------------------------------------------------------- weights
    @property
    def weights(self) -> FloatArray:
        """(N,) normalised weights."""
        return np.exp(self.logw)

    def _apply_loglik(self, loglik: FloatArray) -> None:
        """``log w ← log w + log p(z | particle)``, normalised; flags divergence (eq. 28)."""
        new = self.logw + loglik
        new[np.isnan(new) | (new == np.inf)] = -np.inf
        if not np.any(np.isfinite(new)):
            self._diverged = True
            self.n_divergences += 1
            return
        self.logw = normalise_log_weights(new)

    def _maybe_resample(self) -> None:
        w = self.weights
        if effective_sample_size(w) < self.resample_threshold * self.n_particles:
            self._resample(systematic_resample(w, self._rng))

    def _resample(self, idx: np.ndarray) -> None:
        """Copy the selected particles (fancy indexing: fresh arrays, no shared views).

        With ``roughening = K > 0`` every copied vehicle state is then jittered (Gordon et al.
        1993 "roughening", the standard remedy for sample impoverishment after SIR resampling,
        cf. seed 004 §3 on degeneracy/impoverishment): state j gets ``N(0, σ_j²)`` with
        ``σ_j = K E_j N^{−1/d}``, ``E_j`` the weighted standard deviation of state j *before*
        resampling and d = 12. The jitter scales with the current spread, so it re-diversifies
        the duplicates without adding a fixed noise floor; landmark EKFs are not jittered.
        """
        if self.roughening > 0.0:
            w = self.weights
            mean = w @ self.x
            dev = self.x - mean
            dev[:, 6:9] = wrap_angle(dev[:, 6:9])
            spread = np.sqrt(np.maximum(w @ (dev * dev), 0.0))
            scale = self.roughening * spread * self.n_particles ** (-1.0 / STATE_DIM)
        self.x = self.x[idx]
        if self.roughening > 0.0:
            self.x = self.x + self._rng.standard_normal(self.x.shape) * scale
            _wrap_euler(self.x)
        self.mu = self.mu[idx]
        self.sigma = self.sigma[idx]
        self._resample_extra(idx)
        self.logw = np.full(self.n_particles, -math.log(self.n_particles))
        self.n_resamples += 1

    def _resample_extra(self, idx: np.ndarray) -> None:
        """Hook: resample per-particle subclass arrays."""

    # ---------------------------------------------------------------- predict
    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Table 2 steps 1–4 and 6 for one IMU/control period of ``dt`` s.

        Propagates every particle, runs the subclass IMU step (bias KF and IMU likelihood for
        the dynamic filter), resamples if the ESS fell below the threshold, then applies the
        stage-2 hook.
        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"predict: dt must be a finite number > 0, got {dt!r}")
        self._diverged = self._lost
        self._time += dt
        self._nis = math.nan
        self._nis_dof = 0
        x_old = self.x
        x_new = self._propagate(imu, control, dt)
        noise = self.process_noise * math.sqrt(dt)
        x_new += self._rng.standard_normal(x_new.shape) * noise
        _wrap_euler(x_new)
        bad = ~np.all(np.isfinite(x_new), axis=1)
        penalty = None
        if np.any(bad):
            if np.all(bad):
                self._diverged = True
                self.n_divergences += 1
                return
            x_new[bad] = x_old[bad]
            penalty = np.where(bad, -np.inf, 0.0)
        self.x = x_new
        loglik = self._imu_step(imu, control, dt)
        if penalty is not None:
            loglik = penalty if loglik is None else loglik + penalty
        if loglik is not None:
            self._apply_loglik(loglik)
        self._maybe_resample()
        self._post_predict(imu)

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        """Motion model without process noise: (N, 12) new states (a fresh array)."""
        raise NotImplementedError

    def _imu_step(self, imu: ImuSample, control: Control, dt: float) -> FloatArray | None:
        """Hook: IMU log-likelihood (N,) after propagation, or ``None`` for no weighting."""
        return None

    def _post_predict(self, imu: ImuSample) -> None:
        """Hook run after resampling in :meth:`predict` (stage 2)."""

    # ---------------------------------------------------------------- update
    def update(self, scan: LidarScan) -> None:
        """Weight with the LiDAR likelihood, update/initialise landmark EKFs, resample.

        Table 2 steps 3, 5, 6 (and the stage-2 hook) for one scan; an empty scan is a no-op.
        """
        if scan.count == 0:
            return
        scan_ids = np.asarray(scan.ids).astype(int).ravel()
        meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3)
        if np.unique(scan_ids).size != scan_ids.size:  # repeated id: keep its first return
            _, first = np.unique(scan_ids, return_index=True)
            scan_ids, meas = scan_ids[first], meas[first]
        sig = np.maximum(np.asarray(scan.sigma, dtype=float).reshape(3), _SIGMA_FLOOR)
        R = np.diag(sig * sig)
        slots = np.array([self._slot.get(i, -1) for i in scan_ids.tolist()])
        old = slots >= 0
        pos = self.x[:, 0:3]
        dcm = dcm_from_euler_batch(self.x[:, 6:9])
        idx = slots[old]
        if idx.size:
            mu_new, sig_new, loglik, nis = landmark_ekf_update(
                self.mu[:, idx],
                self.sigma[:, idx],
                pos[:, None, :],
                dcm[:, None],
                meas[old][None],
                R,
            )
            ok = np.isfinite(loglik)
            if not np.all(ok):  # keep the prior of any landmark whose update broke down
                mu_new = np.where(ok[..., None], mu_new, self.mu[:, idx])
                sig_new = np.where(ok[..., None, None], sig_new, self.sigma[:, idx])
            self.mu[:, idx] = mu_new
            self.sigma[:, idx] = sig_new
            self._nis = float(self.weights @ nis.sum(axis=1))
            self._nis_dof = MEAS_DIM * int(idx.size)
            self._check_lock(nis.sum(axis=1) / self._nis_dof)
            # Tempering (likelihood inflation λ): the weights use p(z | x)^{1/λ}, i.e. the
            # Gaussian with covariance λ·S up to a particle-independent constant; the EKFs
            # above use the true R.
            self._apply_loglik(loglik.sum(axis=1) / self.likelihood_inflation)
        if not np.all(old):
            new_ids = scan_ids[~old]
            mu0, sig0 = landmark_init(pos, dcm, meas[~old], R)
            self.mu = np.concatenate([self.mu, mu0], axis=1)
            self.sigma = np.concatenate([self.sigma, sig0], axis=1)
            self._add_slots(new_ids)
        self._maybe_resample()
        if idx.size:
            self._post_update(idx, meas[old], R)

    def _post_update(self, idx: np.ndarray, meas: FloatArray, R: FloatArray) -> None:
        """Hook run after resampling in :meth:`update` with the mapped observations."""

    def _check_lock(self, nis_per_dof: FloatArray) -> None:
        """NIS-based loss-of-lock flag (sticky until :meth:`reset`).

        ``nis_per_dof`` (N,) is each particle's LiDAR NIS per degree of freedom. The mean over
        the best 10 % of particles (lowest NIS) is ≈ 1 while the filter is locked; if it stays
        above ``nis_divergence`` for ``nis_divergence_s`` seconds of filter time no particle
        explains the scans any more (the weights are then only relative and the estimate is
        silently wrong), so ``diagnostics["diverged"]`` is set. ``nis_divergence = 0`` disables
        the check.
        """
        k = max(1, self.n_particles // 10)
        best = float(np.mean(np.partition(nis_per_dof, k - 1)[:k]))
        self._best_nis = best
        if self.nis_divergence <= 0.0:
            return
        if not best > self.nis_divergence:  # also catches NaN as "not high"
            self._nis_high_since = None
            return
        if self._nis_high_since is None:
            self._nis_high_since = self._time
        if self._time - self._nis_high_since >= self.nis_divergence_s:
            if not self._lost:
                self.n_divergences += 1
            self._lost = True
            self._diverged = True

    # ---------------------------------------------------------------- estimate
    def _bias_estimate(self, w: FloatArray) -> tuple[FloatArray | None, FloatArray | None]:
        return None, None

    def _extra_diagnostics(self) -> dict[str, float]:
        """Hook: subclass diagnostics added to :attr:`Estimate.diagnostics`."""
        return {}

    def estimate(self) -> Estimate:
        """Weighted particle mean and covariance, and the mixture map (frozen snapshot).

        Euler angles use the weighted circular mean; the (9, 9) pose covariance of
        ``(ρ, v_B, Λ)`` uses wrapped angle deviations. Landmark covariances are the mixture
        covariances ``Σ_i w_i (Σ^i + (μ^i − μ̄)(μ^i − μ̄)ᵀ)``.
        """
        w = self.weights
        x = self.x
        mean = w @ x
        euler = np.arctan2(w @ np.sin(x[:, 6:9]), w @ np.cos(x[:, 6:9]))
        mean[6:9] = euler
        dev = x[:, :POSE_DIM] - mean[:POSE_DIM]
        dev[:, 6:9] = wrap_angle(dev[:, 6:9])
        pose_cov = (dev * w[:, None]).T @ dev
        pose_cov = 0.5 * (pose_cov + pose_cov.T)
        n_lm = len(self._slot_ids)
        ids = np.array(self._slot_ids, dtype=int)
        order = np.argsort(ids, kind="stable")
        if n_lm:
            n = self.n_particles
            lm_mean = (w @ self.mu.reshape(n, -1)).reshape(n_lm, 3)
            lm_cov = (w @ self.sigma.reshape(n, -1)).reshape(n_lm, 3, 3)
            d = (self.mu - lm_mean) * np.sqrt(w)[:, None, None]  # (N, L, 3)
            dt = np.ascontiguousarray(d.transpose(1, 2, 0))  # (L, 3, N)
            lm_cov = lm_cov + dt @ _swap(dt)
            lm_mean, lm_cov = lm_mean[order], lm_cov[order]
        else:
            lm_mean, lm_cov = np.zeros((0, 3)), np.zeros((0, 3, 3))
        accel_bias, gyro_bias = self._bias_estimate(w)
        diagnostics = {
            "ess": effective_sample_size(w),
            "n_resamples": float(self.n_resamples),
            "nis": self._nis,
            "nis_dof": float(self._nis_dof),
            "diverged": 1.0 if (self._diverged or self._lost) else 0.0,
            "best_nis_per_dof": self._best_nis,
            "n_divergences": float(self.n_divergences),
            **self._extra_diagnostics(),
        }
        return Estimate(
            position=mean[0:3].copy(),
            vel_body=mean[3:6].copy(),
            vel_inertial=dcm_from_euler(euler) @ mean[3:6],
            euler=euler.copy(),
            rates=mean[9:12].copy(),
            pose_cov=pose_cov,
            landmark_ids=ids[order],
            landmark_means=lm_mean,
            landmark_covs=lm_cov,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics=diagnostics,
        )


@register("fastslam")
class DynamicFastSLAM(_FastSLAMBase):
    """Dynamics-based FastSLAM with joint IMU bias/drift estimation (seed 000 Table 2).

    Parameters (keyword arguments; unknown keys, wrong types or out-of-range values raise a
    ``ValueError`` naming the key):

    =========================  ==============  ================================================
    key                        default         meaning
    =========================  ==============  ================================================
    ``n_particles``            500             N (seed 000 §IV-B)
    ``resample_threshold``     0.5             resample when ESS < threshold·N, in [0, 1]
    ``process_noise``          (0.02, 0.1,     white-noise density per state added to each
                               0.003, 2e-5)    particle: scalar, 4 groups (ρ m/√s, v m/s/√s,
                                               Λ rad/√s, ω rad/s/√s) or 12 values
    ``integrator``             ``"rk4"``       ``"rk4"`` or ``"euler"`` (one step per period)
    ``bias_tau_s``             100.0           drift time constant τ in s (eq. 8, 10)
    ``accel_drift_sigma``      0.001           stationary std of b1_a in m/s²
    ``gyro_drift_sigma``       0.001           stationary std of b1_ω in rad/s
    ``accel_bias_sigma``       0.01            prior std of b0_a in m/s²
    ``gyro_bias_sigma``        0.01            prior std of b0_ω in rad/s
    ``mass_scale``             1.0             filter mass = scale × nominal mass
    ``inertia_scale``          1.0             filter inertia = scale × nominal (Fig. 14: 2.5)
    ``estimate_inertia``       True if the     identify the principal moments of inertia (and
                               inertia is      the gyro bias) online from the gyro and the
                               diagonal        applied torque (:mod:`estimators.inertia`) and
                                               move the model and the particles' ω to them
    ``inertia_prior_rel_sigma`` 1.0            prior std of 1/J relative to the nominal model
    ``use_imu_likelihood``     True            multiply the weights by p(z^I | x^D, x̂^B)
    ``stage2``                 False           Table 2 step 8 (ω from the gyro, ρ from LiDAR)
    ``stage2_position``        True            with ``stage2``: also regenerate ρ (else ω only)
    ``known_map_sigma``        0.001           landmark std in m in known-map mode
    ``likelihood_inflation``   30.0            λ ≥ 1: LiDAR weights use p(z|x)^{1/λ} (≈ S·λ in
                                               the weights only; EKFs use the true R)
    ``roughening``             0.0             K of Gordon et al. roughening after resampling
                                               (σ_j = K·std_j·N^{−1/12}); 0 = off
    ``nis_divergence``         1000.0          per-DOF NIS of the best 10 % of particles above
                                               which lock is considered lost; 0 = off
    ``nis_divergence_s``       2.0             ... for this long (s): ``diverged`` = 1, sticky
    =========================  ==============  ================================================

    Robustness tuning (paper_fastslam_helix, DF-LQR on the estimate, 4 poles, VLP-16 noise
    3 cm / 0.1°, N = 500, seeds 0–9, 30 s): with the raw FastSLAM 1.0 weight the LiDAR
    likelihood is far narrower than the particle cloud, the weights collapse onto a few
    particles each scan, position σ collapses to millimetres and ~half the seeds lose lock
    (seed 004 §3: degeneracy / sample impoverishment of SIR). Tempering the LiDAR weight with
    λ = 30 (the per-particle NIS ~ 3 then costs ~0.05 in log-weight, so ESS stays high and
    resampling is rare) keeps lock on 10/10 seeds (position RMSE median 0.05 m vs 0.09 m and
    3/10 lost at λ = 30 with the old noise; λ = 10, 100 worse). A larger attitude noise
    (0.003 rad/√s) lets particles absorb attitude errors the LiDAR reveals. Roughening
    (K = 0.2) together with λ = 10 was worse and is off by default; larger velocity noise (0.3)
    was worse.

    Gyro-bias identification (same runs): the gyro pins each particle's ``ω^i + b̂_ω^i`` to
    ``ω_m``; what separates ω from the bias is the dynamics, which predict ω from the applied
    torque *given the initial ω*. An ω offset is not damped by the dynamics and is otherwise
    seen only through its integral, the attitude, by the LiDAR. So the bias is identified
    only if (a) the initial ω is known — the helix scenarios start at rest with a 1e-4 rad/s
    ω prior — and (b) the ω process noise is small enough that ω does not random-walk away
    from the dynamics: a density q_ω wanders by q_ω √T, i.e. 1e-3 rad/s in 30 s at the old
    2e-4. Measured gyro-bias error (median of 10 seeds, biases 0.005): 35 % with a 1e-3 rad/s
    ω prior and q_ω = 2e-4; 17 % with the 1e-4 prior and q_ω = 2e-4; 4–6 % with the 1e-4 prior
    and q_ω ∈ [1e-5, 5e-5] (default 2e-5), at unchanged position accuracy.

    Model mismatch (``inertia_scale=2.5``, seed 000 Fig. 14; measured, see the README). With a
    fixed model the dynamics predict ω wrongly during the controller's initial transient, the
    gyro-bias KF absorbs that model error as "bias" while its prior is still wide, and the
    ω/bias split is never undone; the IMU likelihood, computed through the wrong model, then
    favours the wrong particles (0.26 m median, 2/10 seeds lost; 0.074 m with LiDAR-only
    weights, the gyro bias still wrong). Seed 000 §IV names online inertia estimation as the
    remedy; ``estimate_inertia`` (on by default) implements it: the inertia is identified to
    ~1 % within about a second of flight, and under mismatch the filter keeps lock on every
    seed with the paper's full IMU × LiDAR weights (0.067 vs 0.053 m median for the matched
    model).

    * Stage 2's ω regeneration makes the next KF innovation independent of the bias
      (``ω_m,k+1 − ω^i_{k+1} − b̂`` is pure noise once ``ω^i_k = ω_m,k − b̂``), so the bias is
      then learnt only through resampling. Stage 2's ρ regeneration replaces the dynamic
      position by a LiDAR fix and can leave the velocity uncorrected (large velocity errors
      in some runs); ``stage2_position=False`` keeps only the ω part. Measured on the helix
      at biases 0.005: both variants end every run early (attitude errors 6–8°), so stage 2
      is off by default.
    * Like every FastSLAM 1.0, the filter is over-confident in SLAM mode (NEES ≫ dof):
      resampling slowly collapses the initial pose spread that no relative measurement can
      restore.

    Args:
        vehicle: Nominal vehicle parameters given by the env (required).
        **params: The settings above.

    Raises:
        ValueError: If ``vehicle`` is missing or a setting is invalid.
    """

    _DEFAULT_NOISE = (0.02, 0.1, 0.003, 2e-5)
    _DEFAULT_INFLATION = 30.0
    _EXTRA: ClassVar[dict[str, type | tuple[type, ...]]] = {
        "bias_tau_s": _FLOAT,
        "accel_drift_sigma": _FLOAT,
        "gyro_drift_sigma": _FLOAT,
        "accel_bias_sigma": _FLOAT,
        "gyro_bias_sigma": _FLOAT,
        "mass_scale": _FLOAT,
        "inertia_scale": _FLOAT,
        "use_imu_likelihood": bool,
        "stage2": bool,
        "stage2_position": bool,
        "estimate_inertia": (bool, type(None)),
        "inertia_prior_rel_sigma": _FLOAT,
    }

    def __init__(self, vehicle: VehicleParams | None = None, **params: Any) -> None:
        if vehicle is None:
            raise ValueError(
                "estimator 'fastslam' needs the nominal vehicle parameters: pass "
                "vehicle=VehicleParams (the env does this from its vehicle config)"
            )
        if not isinstance(vehicle, VehicleParams):
            raise ValueError(
                f"estimator 'fastslam': vehicle must be a VehicleParams, got {vehicle!r}"
            )
        super().__init__(params, self._EXTRA)
        self.bias_tau_s = _positive("bias_tau_s", params.get("bias_tau_s", 100.0))
        self.accel_drift_sigma = _positive(
            "accel_drift_sigma", params.get("accel_drift_sigma", 0.001), strict=False
        )
        self.gyro_drift_sigma = _positive(
            "gyro_drift_sigma", params.get("gyro_drift_sigma", 0.001), strict=False
        )
        self.accel_bias_sigma = _positive("accel_bias_sigma", params.get("accel_bias_sigma", 0.01))
        self.gyro_bias_sigma = _positive("gyro_bias_sigma", params.get("gyro_bias_sigma", 0.01))
        mass_scale = _positive("mass_scale", params.get("mass_scale", 1.0))
        inertia_scale = _positive("inertia_scale", params.get("inertia_scale", 1.0))
        self.use_imu_likelihood = bool(params.get("use_imu_likelihood", True))
        self.stage2 = bool(params.get("stage2", False))
        self.stage2_position = bool(params.get("stage2_position", True))
        self.vehicle = vehicle
        self.model = DynamicsModel(vehicle, mass_scale=mass_scale, inertia_scale=inertia_scale)
        self._inertia0 = np.diag(self.model.inertia).copy()
        diagonal = bool(np.allclose(self.model.inertia, np.diag(self._inertia0)))
        wanted = params.get("estimate_inertia")
        self.estimate_inertia = diagonal if wanted is None else bool(wanted)
        if self.estimate_inertia and not diagonal:
            raise _fail(
                "estimate_inertia",
                True,
                "False for a vehicle whose inertia has products of inertia (the identification "
                "models principal moments only)",
            )
        self.inertia_id = GyroTorqueRegression(
            self._inertia0,
            _positive("inertia_prior_rel_sigma", params.get("inertia_prior_rel_sigma", 1.0)),
            bias_sigma=math.hypot(self.gyro_bias_sigma, self.gyro_drift_sigma),
            # Random walk with the Gauss–Markov drift's short-term variance growth 2σ²/τ.
            bias_rate_sigma=self.gyro_drift_sigma * math.sqrt(2.0 / self.bias_tau_s),
        )
        self._bias_cache: tuple[float, FloatArray, FloatArray] | None = None
        self._reset_extra()

    def _reset_extra(self) -> None:
        self.inertia_id.reset()
        self.model.set_inertia(self._inertia0)
        self.xb = np.zeros((self.n_particles, BIAS_DIM))
        self.P = np.diag(
            np.r_[
                np.full(3, self.accel_bias_sigma**2),
                np.full(3, self.gyro_bias_sigma**2),
                np.full(3, self.accel_drift_sigma**2),
                np.full(3, self.gyro_drift_sigma**2),
            ]
        )

    def _resample_extra(self, idx: np.ndarray) -> None:
        self.xb = self.xb[idx]

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        thrust = float(control.thrust)
        torque = np.asarray(control.torque, dtype=float).reshape(3)
        model = self.model
        return _integrate(
            lambda s: model.derivative(s, thrust, torque), self.x, dt, self.integrator
        )

    def _transition(self, dt: float) -> tuple[FloatArray, FloatArray]:
        if self._bias_cache is None or self._bias_cache[0] != dt:
            A, Q = bias_transition(
                dt, self.bias_tau_s, self.accel_drift_sigma, self.gyro_drift_sigma
            )
            self._bias_cache = (dt, A, Q)
        return self._bias_cache[1], self._bias_cache[2]

    def _imu_step(self, imu: ImuSample, control: Control, dt: float) -> FloatArray | None:
        """Table 2 steps 2–4: bias KF predict, IMU likelihood (eq. 26), bias KF update."""
        if self.estimate_inertia:
            self._identify_inertia(imu, control, dt)
        A, Q = self._transition(dt)
        self.xb, self.P = bias_kf_predict(self.xb, self.P, A, Q)
        z = np.r_[np.asarray(imu.accel, dtype=float), np.asarray(imu.gyro, dtype=float)]
        hd = np.empty((self.n_particles, IMU_DIM))
        hd[:, 0:3] = self.model.specific_force(self.x, float(control.thrust))
        hd[:, 3:6] = self.x[:, 9:12]
        innovation = z - hd - (self.xb[:, 0:6] + self.xb[:, 6:12])  # z̄ − H x̂^B
        sa = max(float(imu.accel_sigma), _SIGMA_FLOOR)
        sg = max(float(imu.gyro_sigma), _SIGMA_FLOOR)
        R = np.diag([sa * sa] * 3 + [sg * sg] * 3)
        self.xb, self.P, loglik = bias_kf_update(self.xb, self.P, innovation, H_BIAS, R)
        return loglik if self.use_imu_likelihood else None

    def _identify_inertia(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Update the inertia identification and move the model and the particles to it.

        The particles' ω were integrated with the old θ̂; under the new one the same torque
        history gives ``ω + (θ̂_new − θ̂_old) ⊙ Φ`` (the ω part of the dynamics is linear in θ),
        so that shift is applied to every particle before the IMU step compares ω with the
        gyro. Without it, the model error made while θ̂ was still wrong would stay in the
        particles' ω and be absorbed by the gyro-bias KF. The model follows the estimate only
        while it explains the data (:attr:`GyroTorqueRegression.usable`), else the nominal.
        """
        reg = self.inertia_id
        reg.update(imu.gyro, float(imu.gyro_sigma), control.torque, dt)
        # While the data contradict the rigid-body model, fall back to the nominal inertia.
        theta = reg.theta if reg.usable else 1.0 / self._inertia0
        theta_old = 1.0 / np.diag(self.model.inertia)
        if np.array_equal(theta, theta_old):
            return
        self.x[:, 9:12] += (theta - theta_old) * reg.phi
        self.model.set_inertia(1.0 / theta)

    def _post_predict(self, imu: ImuSample) -> None:
        """Stage 2 (Table 2 step 8, eq. 32–34): ``ω^i ~ N(ω_m − b̂_ω^i, σ_g² I)``."""
        if not self.stage2:
            return
        bias = self.xb[:, 3:6] + self.xb[:, 9:12]
        sg = float(imu.gyro_sigma)
        self.x[:, 9:12] = (
            np.asarray(imu.gyro, dtype=float)
            - bias
            + sg * self._rng.standard_normal((self.n_particles, 3))
        )

    def _post_update(self, idx: np.ndarray, meas: FloatArray, R: FloatArray) -> None:
        """Stage 2 (Table 2 step 8): regenerate ρ from the LiDAR inverse model.

        Each mapped observation j gives ``ρ_j = μ_j^i − C_NB^i ϱ(z_j)`` with covariance
        ``Σ_j^i + C_NB^i (∂ϱ/∂z) R (∂ϱ/∂z)ᵀ C_NB^iᵀ``; the per-landmark estimates are fused by
        their information and ``ρ^i`` is drawn from the fused Gaussian.
        """
        if not (self.stage2 and self.stage2_position):
            return
        dcm = dcm_from_euler_batch(self.x[:, 6:9])
        body = body_from_measure(meas)  # (m, 3)
        rho = self.mu[:, idx] - np.einsum("nij,kj->nki", dcm, body)  # (N, m, 3)
        D = measure_inverse_jacobian(meas)
        M = D @ R @ _swap(D)
        C = dcm[:, None]
        cov = self.sigma[:, idx] + C @ M[None] @ _swap(C)
        info, _ = _inv3_sym(cov)  # (N, m, 3, 3)
        info_sum = info.sum(axis=1)
        eta = np.einsum("nkij,nkj->ni", info, rho)
        fused_cov, _ = _inv3_sym(info_sum)
        fused = np.einsum("nij,nj->ni", fused_cov, eta)
        draw = _mv(_chol3(fused_cov), self._rng.standard_normal((self.n_particles, 3)))
        self.x[:, 0:3] = fused + draw

    def _extra_diagnostics(self) -> dict[str, float]:
        """The model's principal moments of inertia in kg·m² (identified or nominal)."""
        j = np.diag(self.model.inertia)
        return {"inertia_x": float(j[0]), "inertia_y": float(j[1]), "inertia_z": float(j[2])}

    def _bias_estimate(self, w: FloatArray) -> tuple[FloatArray | None, FloatArray | None]:
        total = w @ self.xb
        return total[0:3] + total[6:9], total[3:6] + total[9:12]


@register("fastslam_kinematic")
class KinematicFastSLAM(_FastSLAMBase):
    """FastSLAM 1.0 driven by IMU strapdown kinematics, no bias calibration (seed 000 §IV-B).

    Each particle is propagated with ``v̇ = −ω×v + C_NBᵀ g n3 + a``, ``Λ̇ = D(Λ) ω``,
    ``ρ̇ = C_NB v`` where ``a = a_m + ε_a`` and ``ω = ω_m + ε_ω`` are the IMU readings perturbed by
    the sample's white noise (σ × ``imu_noise_scale``), i.e. samples from the motion model with
    noisy inputs. The ω slot of each particle holds its input ω. Weights use the LiDAR only.

    Parameters: ``n_particles`` (500), ``resample_threshold`` (0.5), ``process_noise`` (white-
    noise density per state, default (0.02, 0.05, 0.005, 0.0); the ω group is unused since ω is
    the input), ``integrator`` (``"rk4"``), ``imu_noise_scale`` (1.0, factor on the IMU sample
    σ used as input noise), ``known_map_sigma`` (0.001 m), and the robustness settings shared
    with ``fastslam`` (``likelihood_inflation`` default 1.0 here — the unmodified FastSLAM 1.0
    baseline —, ``roughening`` 0.0, ``nis_divergence`` 1000.0, ``nis_divergence_s`` 2.0).

    Args:
        vehicle: Accepted for a uniform interface; not used (kinematics need no parameters).
        **params: The settings above.
    """

    _DEFAULT_NOISE = (0.02, 0.05, 0.005, 0.0)

    def __init__(self, vehicle: VehicleParams | None = None, **params: Any) -> None:
        super().__init__(params, {"imu_noise_scale": _FLOAT})
        self.imu_noise_scale = _positive(
            "imu_noise_scale", params.get("imu_noise_scale", 1.0), strict=False
        )
        self.vehicle = vehicle

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        n = self.n_particles
        noise = self._rng.standard_normal((n, 6))
        accel = (
            np.asarray(imu.accel, dtype=float)
            + (float(imu.accel_sigma) * self.imu_noise_scale) * noise[:, 0:3]
        )
        x = self.x.copy()
        x[:, 9:12] = (
            np.asarray(imu.gyro, dtype=float)
            + (float(imu.gyro_sigma) * self.imu_noise_scale) * noise[:, 3:6]
        )
        return _integrate(lambda s: _kinematic_part(s, accel), x, dt, self.integrator)
