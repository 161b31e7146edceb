"""Per-particle landmark EKFs of FastSLAM (seed 000 Table 3), batched over particles × landmarks.

The EKF update is one numba kernel per (pose, landmark) pair, :func:`landmark_ekf_one`, on the
LiDAR model's kernels (:mod:`quadslam_env.models.lidar`); :func:`landmark_ekf_particles` loops
it over the particles and the observed landmarks in place. Initialisation (a landmark's first
sighting) stays NumPy: it runs once per landmark.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_from_trig, wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.lidar import (
    body_from_measure,
    measure_inverse_jacobian,
    spherical_from_body,
    spherical_jacobian,
)
from quadslam_env.models.linalg import LOG_2PI, inv3_sym_one, swap
from quadslam_env.types import MEAS_DIM, POS, FloatArray

Vec3 = tuple[float, float, float]
Mat3 = tuple[Vec3, Vec3, Vec3]
"""A 3×3 matrix as a tuple of rows (kept in registers inside the kernels)."""


def offset_in_inertial(dcm: FloatArray, meas: FloatArray) -> FloatArray:
    """``C_NB ϱ(z)``: each measurement's landmark offset from each particle, in N.

    Args:
        dcm: (N, 3, 3) particle ``C_NB``.
        meas: (k, 3) measurements (α rad, β rad, δ m).

    Returns:
        (N, k, 3) offsets in m (seed 001 eq. 44–45: ``l = ρ + C_NB ϱ(z)``).
    """
    return np.einsum("nij,kj->nki", dcm, body_from_measure(meas))


def inverse_model_cov(dcm: FloatArray, meas: FloatArray, R: FloatArray) -> FloatArray:
    """Covariance in N of ``C_NB ϱ(z)`` from the measurement noise: ``C (∂ϱ/∂z) R (∂ϱ/∂z)ᵀ Cᵀ``.

    Args:
        dcm: (N, 3, 3) particle ``C_NB``.
        meas: (k, 3) measurements (α rad, β rad, δ m).
        R: (3, 3) measurement noise covariance.

    Returns:
        (N, k, 3, 3) covariances in m².
    """
    D = measure_inverse_jacobian(meas)  # (k, 3, 3), the same for every particle
    M = D @ R @ swap(D)  # (k, 3, 3) body-frame covariance
    C = dcm[:, None]
    return C @ M[None] @ swap(C)


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
    mu = pos[:, None, :] + offset_in_inertial(dcm, meas)
    sigma = inverse_model_cov(dcm, meas, R)
    return mu, 0.5 * (sigma + swap(sigma))


@kernel
def _dot(a: Vec3, b: Vec3) -> float:
    """``a · b`` of two 3-vectors."""
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


@kernel
def _mul_bt(A: Mat3, B: Mat3) -> Mat3:
    """``A Bᵀ`` of 3×3 matrices given as row tuples (entry (r, c) is ``A_r · B_c``)."""
    return (
        (_dot(A[0], B[0]), _dot(A[0], B[1]), _dot(A[0], B[2])),
        (_dot(A[1], B[0]), _dot(A[1], B[1]), _dot(A[1], B[2])),
        (_dot(A[2], B[0]), _dot(A[2], B[1]), _dot(A[2], B[2])),
    )


@kernel
def _t(A: Mat3) -> Mat3:
    """Transpose of a 3×3 matrix given as row tuples."""
    return (A[0][0], A[1][0], A[2][0]), (A[0][1], A[1][1], A[2][1]), (A[0][2], A[1][2], A[2][2])


@kernel
def rows_of(M: FloatArray) -> Mat3:
    """Rows of a (3, 3) array as tuples."""
    return (M[0, 0], M[0, 1], M[0, 2]), (M[1, 0], M[1, 1], M[1, 2]), (M[2, 0], M[2, 1], M[2, 2])


@inline_kernel
def landmark_prediction(
    mu: FloatArray, sigma: FloatArray, pos: FloatArray, C: Mat3, R: Mat3
) -> tuple[Vec3, Mat3, Mat3, float]:
    """Predicted measurement of one landmark EKF from one pose (seed 000 Table 3).

    ``c = C_NBᵀ (μ − ρ)``, ``h = h(c)``, ``H = (∂h/∂c) C_NBᵀ``, ``S = H Σ Hᵀ + R``; the LiDAR
    model is :mod:`quadslam_env.models.lidar`'s. Used by the EKF update
    (:func:`landmark_ekf_one`) and by the per-particle data association
    (:mod:`estimators.fastslam.associate`).

    Args:
        mu: (3,) landmark mean in N, m. sigma: (3, 3) its covariance in m².
        pos: (3,) vehicle position in N, m. C: Rows of ``C_NB``.
        R: Rows of the measurement noise covariance.

    Returns:
        ``(h, HΣ, S⁻¹, det S)``: ``h`` (α rad, β rad, δ m), ``H Σ`` and ``S⁻¹`` as rows.
    """
    d = (mu[0] - pos[0], mu[1] - pos[1], mu[2] - pos[2])
    Ct = _t(C)
    c1, c2, c3 = _dot(Ct[0], d), _dot(Ct[1], d), _dot(Ct[2], d)
    h = spherical_from_body(c1, c2, c3)
    H = _mul_bt(spherical_jacobian(c1, c2, c3), C)  # ∂h/∂c · C_NBᵀ
    HS = _mul_bt(H, _t(rows_of(sigma)))  # H Σ
    HHS = _mul_bt(H, HS)  # H Σ Hᵀ (Σ symmetric)
    S = (
        (HHS[0][0] + R[0][0], HHS[0][1] + R[0][1], HHS[0][2] + R[0][2]),
        (HHS[1][0] + R[1][0], HHS[1][1] + R[1][1], HHS[1][2] + R[1][2]),
        (HHS[2][0] + R[2][0], HHS[2][1] + R[2][1], HHS[2][2] + R[2][2]),
    )
    S_inv, det = inv3_sym_one(S)
    return h, HS, S_inv, det


@inline_kernel
def innovation_loglik(
    meas: FloatArray, h: Vec3, S_inv: Mat3, log_det: float
) -> tuple[Vec3, float, float]:
    """Innovation of one measurement against one prediction and its Gaussian likelihood.

    ``ν = z − h`` (angles wrapped to (−π, π]), ``q = νᵀ S⁻¹ ν`` and
    ``log N(ν; 0, S) = −½ (q + log det S + 3 log 2π)``.

    Args:
        meas: (3,) measurement (α rad, β rad, δ m). h: The prediction.
        S_inv: Rows of ``S⁻¹``. log_det: ``log det S``.

    Returns:
        ``(ν, q, log N(ν; 0, S))``.
    """
    nu = (wrap_pi(meas[0] - h[0]), wrap_pi(meas[1] - h[1]), meas[2] - h[2])
    nis = _dot(nu, (_dot(S_inv[0], nu), _dot(S_inv[1], nu), _dot(S_inv[2], nu)))
    loglik = -0.5 * (nis + log_det + MEAS_DIM * LOG_2PI)
    return nu, nis, loglik


@kernel
def landmark_ekf_one(
    mu: FloatArray,
    sigma: FloatArray,
    pos: FloatArray,
    C: Mat3,
    meas: FloatArray,
    R: Mat3,
) -> tuple[float, float]:
    """EKF update of one landmark from one pose in place (seed 000 Table 3, EKF-update).

    :func:`landmark_prediction` and :func:`innovation_loglik`, then ``K = Σ Hᵀ S⁻¹``,
    ``μ ← μ + K ν``, ``Σ ← Σ − K H Σ`` (symmetrised). If the likelihood is not finite
    (a numerically broken S, det ≤ 0), μ and Σ keep their prior.

    Args:
        mu: (3,) mean in N, m, updated in place. sigma: (3, 3) covariance in m², in place.
        pos: (3,) vehicle position in N, m. C: Rows of ``C_NB``.
        meas: (3,) measurement (α rad, β rad, δ m). R: Rows of the measurement noise.

    Returns:
        ``(log N(ν; 0, S), νᵀ S⁻¹ ν)``.
    """
    h, HS, S_inv, det = landmark_prediction(mu, sigma, pos, C, R)
    nu, nis, loglik = innovation_loglik(meas, h, S_inv, math.log(det))
    if not math.isfinite(loglik):
        return loglik, nis
    HSt = _t(HS)  # Σ Hᵀ
    K = _mul_bt(HSt, _t(S_inv))  # Σ Hᵀ S⁻¹
    KHS = _mul_bt(K, HSt)  # K H Σ
    for a in range(3):
        mu[a] = mu[a] + _dot(K[a], nu)
    for a in range(3):
        sigma[a, a] = sigma[a, a] - KHS[a][a]
        for b in range(a):
            lower, upper = sigma[a, b] - KHS[a][b], sigma[b, a] - KHS[b][a]
            sigma[a, b] = sigma[b, a] = 0.5 * (lower + upper)
    return loglik, nis


@kernel
def particle_dcm(state: FloatArray) -> Mat3:
    """Rows of ``C_NB(Λ)`` of one particle state (12,) ``(ρ, v_B, Λ, ω)``."""
    c = dcm_from_trig(
        math.cos(state[6]),
        math.sin(state[6]),
        math.cos(state[7]),
        math.sin(state[7]),
        math.cos(state[8]),
        math.sin(state[8]),
    )
    return (c[0], c[1], c[2]), (c[3], c[4], c[5]), (c[6], c[7], c[8])


@kernel
def _landmark_ekf_pairs(
    mu: FloatArray,
    sigma: FloatArray,
    pos: FloatArray,
    dcm: FloatArray,
    meas: FloatArray,
    R: FloatArray,
    loglik: FloatArray,
    nis: FloatArray,
) -> None:
    """:func:`landmark_ekf_one` for M independent (pose, landmark, measurement) triples."""
    noise = rows_of(R)
    for i in range(mu.shape[0]):
        loglik[i], nis[i] = landmark_ekf_one(
            mu[i], sigma[i], pos[i], rows_of(dcm[i]), meas[i], noise
        )


@kernel
def landmark_ekf_particles(
    x: FloatArray,
    mu: FloatArray,
    sigma: FloatArray,
    slots: np.ndarray,
    meas: FloatArray,
    R: FloatArray,
    loglik: FloatArray,
    nis: FloatArray,
) -> None:
    """Update the observed landmark EKFs of every particle in place (Table 3, EKF-update).

    A landmark whose update breaks down (non-finite likelihood) keeps its prior.

    Args:
        x: (N, 12) particle states (ρ and Λ are used).
        mu: (N, L, 3) landmark means in N, m; ``sigma`` (N, L, 3, 3) covariances in m²;
            the observed slots are updated in place.
        slots: (k,) int slots of the observed landmarks (distinct).
        meas: (k, 3) their measurements (α rad, β rad, δ m). R: (3, 3) measurement noise.
        loglik: (N,) receives each particle's ``Σ_j log N(ν_j; 0, S_j)``.
        nis: (N,) receives each particle's ``Σ_j ν_jᵀ S_j⁻¹ ν_j``.
    """
    noise = rows_of(R)
    for i in range(x.shape[0]):
        C = particle_dcm(x[i])
        ll_sum, nis_sum = 0.0, 0.0
        for j in range(slots.shape[0]):
            s = slots[j]
            ll, q = landmark_ekf_one(mu[i, s], sigma[i, s], x[i, POS], C, meas[j], noise)
            ll_sum += ll
            nis_sum += q
        loglik[i], nis[i] = ll_sum, nis_sum


def landmark_ekf_update(
    mu: FloatArray,
    sigma: FloatArray,
    pos: FloatArray,
    dcm: FloatArray,
    meas: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Batched landmark EKF update (seed 000 Table 3, EKF-update) and the FastSLAM weight.

    :func:`landmark_ekf_one` over broadcast leading dimensions (typically particles ×
    observed landmarks); the filter itself calls :func:`landmark_ekf_particles`. A landmark
    whose update breaks down (non-finite likelihood) is returned with its prior.

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
    vecs = [np.asarray(a, dtype=float) for a in (mu, pos, meas)]
    mats = [np.asarray(a, dtype=float) for a in (sigma, dcm)]
    lead = np.broadcast_shapes(*(a.shape[:-1] for a in vecs), *(a.shape[:-2] for a in mats))
    m_mu, m_pos, m_meas = (_flat(a, lead, (3,)) for a in vecs)
    m_sigma, m_dcm = (_flat(a, lead, (3, 3)) for a in mats)
    m = m_mu.shape[0]
    loglik, nis = np.empty(m), np.empty(m)
    R = np.ascontiguousarray(R, dtype=float)
    _landmark_ekf_pairs(m_mu, m_sigma, m_pos, m_dcm, m_meas, R, loglik, nis)
    return (
        m_mu.reshape((*lead, 3)),
        m_sigma.reshape((*lead, 3, 3)),
        loglik.reshape(lead),
        nis.reshape(lead),
    )


def _flat(a: FloatArray, lead: tuple[int, ...], core: tuple[int, ...]) -> FloatArray:
    """A fresh copy of ``a`` broadcast to ``lead + core``, leading axes flattened to one."""
    return np.array(np.broadcast_to(a, (*lead, *core))).reshape((-1, *core))
