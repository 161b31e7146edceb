"""Per-particle landmark EKFs of FastSLAM (seed 000 Table 3), batched over particles × landmarks."""

from __future__ import annotations

import numpy as np

from quadslam_env.models.frames import wrap_angle
from quadslam_env.models.lidar import (
    body_from_measure,
    measure_from_body,
    measure_inverse_jacobian,
    measure_jacobian_body,
)
from quadslam_env.models.linalg import LOG_2PI, inv3_sym, mv, swap, swap_copy
from quadslam_env.types import MEAS_DIM, FloatArray


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
    dcm_t = np.ascontiguousarray(swap(dcm))  # C_NBᵀ; contiguous operands keep matmul fast
    c = mv(dcm_t, mu - pos)  # C_NBᵀ (μ − ρ), body frame
    nu = meas - measure_from_body(c)
    nu[..., :2] = wrap_angle(nu[..., :2])
    H = measure_jacobian_body(c) @ dcm_t  # ∂h/∂m = ∂h/∂c · C_NBᵀ
    HS = H @ sigma
    PHt = swap_copy(HS)  # Σ Hᵀ (Σ symmetric)
    S = H @ PHt + R
    S_inv, det = inv3_sym(S)
    K = PHt @ S_inv  # Σ Hᵀ S⁻¹
    mu_new = mu + mv(K, nu)
    # Σ − K H Σ (equal to (I − K H) Σ for the optimal gain), symmetrised.
    sig_new = sigma - K @ HS
    sig_new = 0.5 * (sig_new + swap(sig_new))
    nis = np.sum(nu * mv(S_inv, nu), axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        logdet = np.log(det)  # det <= 0 only for a numerically broken S: the weight becomes NaN
    loglik = -0.5 * (nis + logdet + MEAS_DIM * LOG_2PI)
    return mu_new, sig_new, loglik, nis
