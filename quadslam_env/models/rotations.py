"""Rotation utilities for 3-2-1 Euler angles (seed 001 eq. 1 and 3).

Conventions (DESIGN.md §2): inertial frame N is NED, body frame B is FRD and
``C_NB = C3(ψ) C2(θ) C1(φ)`` maps body-frame components to inertial-frame components.
All angles are in radians.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

FloatArray = NDArray[np.float64]


def wrap_angle(angle: ArrayLike) -> FloatArray | float:
    """Wrap angles to the interval (-π, π].

    Args:
        angle: Scalar or array of angles in radians.

    Returns:
        The wrapped angle(s), same shape as the input (a Python float for scalar input).
    """
    if isinstance(angle, float | int):
        wrapped = math.remainder(float(angle), 2.0 * math.pi)
        # math.remainder maps to [-π, π]; move -π to +π so the interval is half-open.
        return math.pi if wrapped == -math.pi else wrapped
    arr = np.asarray(angle, dtype=float)
    wrapped = np.remainder(arr + math.pi, 2.0 * math.pi) - math.pi
    return np.where(wrapped == -math.pi, math.pi, wrapped)


def rot1(phi: float) -> FloatArray:
    """Elementary rotation ``C1(φ)`` about axis 1 (seed 001 eq. 1)."""
    c, s = math.cos(phi), math.sin(phi)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot2(theta: float) -> FloatArray:
    """Elementary rotation ``C2(θ)`` about axis 2 (seed 001 eq. 1)."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot3(psi: float) -> FloatArray:
    """Elementary rotation ``C3(ψ)`` about axis 3 (seed 001 eq. 1)."""
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def dcm_from_euler(euler: ArrayLike) -> FloatArray:
    """Direction cosine matrix ``C_NB = C3(ψ) C2(θ) C1(φ)`` (seed 001 eq. 1).

    Args:
        euler: (3,) Euler angles (φ, θ, ψ) in rad.

    Returns:
        (3, 3) matrix mapping body-frame (FRD) vectors to the inertial frame (NED).
    """
    phi, theta, psi = (float(a) for a in euler)
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    return np.array(
        [
            [ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp],
            [ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp],
            [-st, sf * ct, cf * ct],
        ]
    )


def dcm_from_euler_batch(euler: FloatArray) -> FloatArray:
    """Vectorised :func:`dcm_from_euler`.

    Args:
        euler: (..., 3) Euler angles (φ, θ, ψ) in rad.

    Returns:
        (..., 3, 3) matrices ``C_NB``.
    """
    phi, theta, psi = euler[..., 0], euler[..., 1], euler[..., 2]
    cf, sf = np.cos(phi), np.sin(phi)
    ct, st = np.cos(theta), np.sin(theta)
    cp, sp = np.cos(psi), np.sin(psi)
    out = np.empty((*euler.shape[:-1], 3, 3))
    out[..., 0, 0] = ct * cp
    out[..., 0, 1] = sf * st * cp - cf * sp
    out[..., 0, 2] = cf * st * cp + sf * sp
    out[..., 1, 0] = ct * sp
    out[..., 1, 1] = sf * st * sp + cf * cp
    out[..., 1, 2] = cf * st * sp - sf * cp
    out[..., 2, 0] = -st
    out[..., 2, 1] = sf * ct
    out[..., 2, 2] = cf * ct
    return out


def euler_from_dcm(dcm: ArrayLike) -> FloatArray:
    """Inverse of :func:`dcm_from_euler` for ``|θ| < π/2``.

    Args:
        dcm: (3, 3) matrix ``C_NB``.

    Returns:
        (3,) Euler angles (φ, θ, ψ) in rad, φ and ψ in (-π, π], θ in [-π/2, π/2].
    """
    c = np.asarray(dcm, dtype=float)
    theta = -math.asin(max(-1.0, min(1.0, c[2, 0])))
    phi = math.atan2(c[2, 1], c[2, 2])
    psi = math.atan2(c[1, 0], c[0, 0])
    return np.array([phi, theta, psi])


def euler_rate_matrix(euler: ArrayLike) -> FloatArray:
    """Kinematic matrix ``D(Λ)`` with ``Λ̇ = D(Λ) ω`` (seed 001 eq. 3).

    Args:
        euler: (3,) Euler angles (φ, θ, ψ) in rad; singular at ``cos θ = 0``.

    Returns:
        (3, 3) matrix mapping body rates (p, q, r) in rad/s to Euler-angle rates.
    """
    phi, theta = float(euler[0]), float(euler[1])
    cf, sf = math.cos(phi), math.sin(phi)
    ct, tt = math.cos(theta), math.tan(theta)
    return np.array(
        [[1.0, sf * tt, cf * tt], [0.0, cf, -sf], [0.0, sf / ct, cf / ct]],
    )


def skew(vec: ArrayLike) -> FloatArray:
    """Cross-product matrix: ``skew(a) @ b == a × b``."""
    x, y, z = (float(a) for a in vec)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def rotation_angle_between(dcm_a: ArrayLike, dcm_b: ArrayLike) -> float:
    """Angle of the relative rotation ``C_aᵀ C_b`` in rad, in [0, π].

    This is the attitude error metric of DESIGN.md §5: it does not depend on the
    Euler parametrisation and has no wrap-around.
    """
    rel = np.asarray(dcm_a, dtype=float).T @ np.asarray(dcm_b, dtype=float)
    cos_angle = 0.5 * (float(np.trace(rel)) - 1.0)
    return math.acos(max(-1.0, min(1.0, cos_angle)))


def dcm_euler_partials(euler: ArrayLike) -> FloatArray:
    """Partial derivatives of ``C_NB`` with respect to (φ, θ, ψ).

    Args:
        euler: (3,) Euler angles in rad.

    Returns:
        (3, 3, 3) array ``D`` with ``D[i] = ∂C_NB/∂Λ_i``.
    """
    phi, theta, psi = (float(a) for a in euler)
    c1, c2, c3 = rot1(phi), rot2(theta), rot3(psi)
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    d1 = np.array([[0.0, 0.0, 0.0], [0.0, -sf, -cf], [0.0, cf, -sf]])
    d2 = np.array([[-st, 0.0, ct], [0.0, 0.0, 0.0], [-ct, 0.0, -st]])
    d3 = np.array([[-sp, -cp, 0.0], [cp, -sp, 0.0], [0.0, 0.0, 0.0]])
    return np.stack([c3 @ c2 @ d1, c3 @ d2 @ c1, d3 @ c2 @ c1])
