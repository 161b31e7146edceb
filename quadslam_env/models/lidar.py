"""LiDAR range–bearing model, its inverse and analytic Jacobians (seed 001 §2.3.3–2.3.4).

A measurement of landmark ``l`` from pose ``(ρ, Λ)`` is ``y = (α, β, δ)``:
``c = C_NBᵀ (l - ρ)`` (landmark in the body frame, FRD),
``α = atan2(c2, c1)`` (azimuth, positive to the right),
``β = atan2(c3, √(c1² + c2²))`` (elevation, positive *below* the horizon since b3 points down),
``δ = ‖c‖`` (range). Seed 001 eq. 31 lists the azimuth as ``atan(c1/c2)``; DESIGN.md §3 fixes it.
The inverse (eq. 44–45) is ``l = ρ + C_NB ϱ(y)`` with ``ϱ = δ (cβ cα, cβ sα, sβ)``.

All functions broadcast over leading dimensions, so one call evaluates B vehicles × L
landmarks (the simulator's LiDAR) or N particles × k landmarks (FastSLAM).
"""

from __future__ import annotations

import numpy as np

from quadslam_env.models.frames import dcm_euler_partials, wrap_angle
from quadslam_env.types import FloatArray


def body_vector(pos: FloatArray, dcm: FloatArray, landmarks: FloatArray) -> FloatArray:
    """Landmark positions in the body frame, ``c = C_NBᵀ (l - ρ)``.

    Args:
        pos: (..., 3) vehicle position ρ in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        landmarks: (..., 3) landmark positions l in N, m.

    Returns:
        (..., 3) vectors c in B, m.
    """
    diff = landmarks - pos
    return np.einsum("...ji,...j->...i", dcm, diff)


def measure_from_body(c: FloatArray) -> FloatArray:
    """Spherical coordinates ``(α, β, δ)`` of body-frame vectors ``c`` (..., 3)."""
    horiz = np.hypot(c[..., 0], c[..., 1])
    out = np.empty(c.shape)
    out[..., 0] = np.arctan2(c[..., 1], c[..., 0])
    out[..., 1] = np.arctan2(c[..., 2], horiz)
    out[..., 2] = np.sqrt(horiz * horiz + c[..., 2] * c[..., 2])
    return out


def lidar_measure(pos: FloatArray, dcm: FloatArray, landmarks: FloatArray) -> FloatArray:
    """Noise-free LiDAR measurement ``h_o(s, l)`` (seed 001 eq. 30–31, azimuth corrected).

    Args:
        pos: (..., 3) vehicle position in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        landmarks: (..., 3) landmark positions in N, m.

    Returns:
        (..., 3) measurements (α rad, β rad, δ m).
    """
    return measure_from_body(body_vector(pos, dcm, landmarks))


def body_from_measure(meas: FloatArray) -> FloatArray:
    """``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` (seed 001 eq. 45), (..., 3) → (..., 3) in B, m."""
    alpha, beta, delta = meas[..., 0], meas[..., 1], meas[..., 2]
    cb = np.cos(beta)
    return np.stack(
        [delta * cb * np.cos(alpha), delta * cb * np.sin(alpha), delta * np.sin(beta)], axis=-1
    )


def lidar_inverse(pos: FloatArray, dcm: FloatArray, meas: FloatArray) -> FloatArray:
    """Inverse model ``l = g(s, y) = ρ + C_NB ϱ(y)`` (seed 001 eq. 44).

    Args:
        pos: (..., 3) vehicle position in N, m.
        dcm: (..., 3, 3) ``C_NB``.
        meas: (..., 3) measurements (α, β, δ).

    Returns:
        (..., 3) landmark positions in N, m.
    """
    return pos + np.einsum("...ij,...j->...i", dcm, body_from_measure(meas))


def measure_jacobian_body(c: FloatArray) -> FloatArray:
    """Jacobian ``∂(α, β, δ)/∂c`` at body vectors ``c`` (..., 3) → (..., 3, 3)."""
    c1, c2, c3 = c[..., 0], c[..., 1], c[..., 2]
    # Floor: the azimuth is undefined straight above/below (c1 = c2 = 0); a 360° LiDAR can see it.
    h2 = np.maximum(c1 * c1 + c2 * c2, 1e-12)
    h = np.sqrt(h2)
    d2 = h2 + c3 * c3
    jac = np.zeros((*c.shape, 3))
    jac[..., 0, 0] = -c2 / h2
    jac[..., 0, 1] = c1 / h2
    jac[..., 1, 0] = -c1 * c3 / (d2 * h)
    jac[..., 1, 1] = -c2 * c3 / (d2 * h)
    jac[..., 1, 2] = h / d2
    d = np.sqrt(d2)
    jac[..., 2, 0] = c1 / d
    jac[..., 2, 1] = c2 / d
    jac[..., 2, 2] = c3 / d
    return jac


def lidar_jacobians(
    pos: FloatArray, euler: FloatArray, dcm: FloatArray, landmarks: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Analytic Jacobians of the measurement of k landmarks from one pose (seed 001 eq. 40).

    Args:
        pos: (3,) vehicle position in N, m.
        euler: (3,) Euler angles (φ, θ, ψ) in rad.
        dcm: (3, 3) ``C_NB`` at ``euler``.
        landmarks: (k, 3) landmark positions in N, m.

    Returns:
        ``(H_pos, H_euler, H_lm)``, each (k, 3, 3): ``∂h/∂ρ``, ``∂h/∂Λ`` and ``∂h/∂l``.
        ``∂h/∂v`` is zero.
    """
    diff = landmarks - pos  # (k, 3)
    c = diff @ dcm  # rows are C_NBᵀ (l - ρ)
    dh_dc = measure_jacobian_body(c)  # (k, 3, 3)
    H_lm = dh_dc @ dcm.T  # ∂c/∂l = C_NBᵀ
    partials = dcm_euler_partials(euler)  # (3, 3, 3): ∂C/∂Λ_i
    # ∂c/∂Λ_i = (∂C/∂Λ_i)ᵀ (l - ρ) → (k, 3, i)
    dc_deuler = np.einsum("iab,ka->kbi", partials, diff)
    H_euler = dh_dc @ dc_deuler
    return -H_lm, H_euler, H_lm


def measure_inverse_jacobian(meas: FloatArray) -> FloatArray:
    """``∂ϱ/∂y`` of ``ϱ(y) = δ (cβ cα, cβ sα, sβ)`` (seed 001 eq. 50, body-frame part).

    Args:
        meas: (..., 3) measurements (α rad, β rad, δ m).

    Returns:
        (..., 3, 3) Jacobians, columns ∂/∂α, ∂/∂β, ∂/∂δ, in m/rad and m/m (B frame).
    """
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


def inverse_jacobians(
    euler: FloatArray, dcm: FloatArray, meas: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Jacobians of the inverse model ``g(s, y)`` for k measurements (seed 001 eq. 49–50).

    Args:
        euler: (3,) Euler angles in rad.
        dcm: (3, 3) ``C_NB``.
        meas: (k, 3) measurements (α, β, δ).

    Returns:
        ``(G_euler, G_meas)``, each (k, 3, 3): ``∂g/∂Λ`` and ``∂g/∂y = C_NB ∂ϱ/∂y``.
        ``∂g/∂ρ = I`` and ``∂g/∂v = 0``.
    """
    rho = body_from_measure(meas)  # (k, 3)
    partials = dcm_euler_partials(euler)
    G_euler = np.einsum("iab,kb->kai", partials, rho)
    return G_euler, dcm @ measure_inverse_jacobian(meas)


def measurement_residual(measured: FloatArray, predicted: FloatArray) -> FloatArray:
    """Innovation ``y - h`` with the azimuth and elevation differences wrapped to (-π, π]."""
    res = measured - predicted
    res[..., :2] = wrap_angle(res[..., :2])
    return res
