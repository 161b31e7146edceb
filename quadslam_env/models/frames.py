"""Frames and attitude: C_NB, its elementary rotations and partials, D(Λ), angle wrapping.

Conventions (docs/design.md §2): inertial frame N is NED, body frame B is FRD and
``C_NB = C3(ψ) C2(θ) C1(φ)`` (seed 001 eq. 1) maps body-frame components to inertial-frame
components. All angles are in radians.

Each formula is written once, as a numba kernel on scalars (``dcm_from_trig``,
``dcm_and_partials``, ``euler_rates_from_trig``, ``wrap_pi``); the NumPy-facing functions below
lift those kernels over a leading batch axis, and the kernels of
:mod:`quadslam_env.models.rigid_body`, :mod:`quadslam_env.models.lidar` and the EKF call them
directly. Kernels are compiled with ``cache=True`` and without ``fastmath`` so the
results are reproducible (IEEE arithmetic, no reassociation or fused multiply–adds).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.jit import elementwise, kernel
from quadslam_env.types import FloatArray

_TWO_PI = 2.0 * math.pi


@kernel
def _ieee_remainder(x: float, y: float) -> float:
    """``math.remainder(x, y)`` (IEEE 754 remainder, exact), which numba does not provide.

    A port of CPython's ``m_remainder``: ``x − n y`` with ``n`` the integer nearest ``x / y``,
    ties to even. For positive operands ``%`` is the exact ``fmod``.
    """
    absx, absy = abs(x), abs(y)
    m = absx % absy
    c = absy - m
    if m < c:
        r = m
    elif m > c:
        r = -c
    else:  # half-way: pick the even multiple
        r = m - 2.0 * ((0.5 * (absx - m)) % absy)
    return math.copysign(1.0, x) * r


@kernel
def wrap_pi(angle: float) -> float:
    """Wrap one angle in rad to (-π, π] exactly (the remainder is exact; -π maps to +π).

    Angles already in the interval are returned as they are without computing the remainder
    (which would return them unchanged too): the filters call this on mostly wrapped angles.
    """
    if -math.pi < angle <= math.pi:
        return angle
    wrapped = _ieee_remainder(angle, _TWO_PI)
    return math.pi if wrapped == -math.pi else wrapped


@elementwise("float64(float64)")
def _wrap_ufunc(angle: float) -> float:
    return wrap_pi(angle)


def wrap_angle(angle: ArrayLike) -> FloatArray | float:
    """Wrap angles to the interval (-π, π].

    Args:
        angle: Scalar or array (any shape, e.g. (B, k)) of angles in rad.

    Returns:
        The wrapped angle(s), same shape as the input (a Python float for scalar input).
        Angles already inside the interval are returned unchanged, bit for bit.
    """
    if isinstance(angle, float | int):
        return wrap_pi(float(angle))
    return _wrap_ufunc(np.asarray(angle, dtype=float))


@kernel
def dcm_from_trig(
    cf: float, sf: float, ct: float, st: float, cp: float, sp: float
) -> tuple[float, float, float, float, float, float, float, float, float]:
    """Entries of ``C_NB = C3(ψ) C2(θ) C1(φ)`` (seed 001 eq. 1), row-major.

    Args:
        cf, sf, ct, st, cp, sp: cos and sin of φ, θ, ψ.

    Returns:
        9-tuple ``(C00, C01, C02, C10, …, C22)``; row 3 is ``C_NBᵀ n3`` (gravity direction in B).
    """
    return (
        ct * cp,
        sf * st * cp - cf * sp,
        cf * st * cp + sf * sp,
        ct * sp,
        sf * st * sp + cf * cp,
        cf * st * sp - sf * cp,
        -st,
        sf * ct,
        cf * ct,
    )


@kernel
def dcm_and_partials(phi: float, theta: float, psi: float, C: FloatArray, dC: FloatArray) -> None:
    """``C_NB(Λ)`` (seed 001 eq. 1) and its partials ``∂C_NB/∂Λ_i`` for one attitude.

    Args:
        phi, theta, psi: Euler angles (φ, θ, ψ) in rad.
        C: (3, 3) receives ``C_NB`` (B → N).
        dC: (3, 3, 3) receives ``dC[i] = ∂C_NB/∂Λ_i`` in 1/rad.
    """
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    c = dcm_from_trig(cf, sf, ct, st, cp, sp)
    for k in range(9):
        C[k // 3, k % 3] = c[k]
    for a in range(3):
        # ∂C/∂φ = C C1(φ)ᵀ ∂C1/∂φ: column 0 vanishes, columns 1, 2 rotate into each other.
        dC[0, a, 0], dC[0, a, 1], dC[0, a, 2] = 0.0, C[a, 2], -C[a, 1]
        # ∂C/∂ψ = ∂C3/∂ψ C3ᵀ C: rows 0, 1 rotate into each other, row 2 vanishes.
        dC[2, 0, a], dC[2, 1, a], dC[2, 2, a] = -C[1, a], C[0, a], 0.0
    dC[1, 0, 0], dC[1, 0, 1], dC[1, 0, 2] = -st * cp, sf * ct * cp, cf * ct * cp
    dC[1, 1, 0], dC[1, 1, 1], dC[1, 1, 2] = -st * sp, sf * ct * sp, cf * ct * sp
    dC[1, 2, 0], dC[1, 2, 1], dC[1, 2, 2] = -ct, -sf * st, -cf * st


@kernel
def euler_rates_from_trig(
    cf: float, sf: float, ct: float, st: float, p: float, q: float, r: float
) -> tuple[float, float, float]:
    """``Λ̇ = D(Λ) ω`` (seed 001 eq. 3, seed 000 eq. 2); singular at ``cos θ = 0``.

    Args:
        cf, sf, ct, st: cos and sin of φ and θ.
        p, q, r: Body rates in rad/s (B).

    Returns:
        ``(φ̇, θ̇, ψ̇)`` in rad/s.
    """
    sq_cr = sf * q + cf * r
    return p + sq_cr * (st / ct), cf * q - sf * r, sq_cr / ct


@kernel
def _dcm_lanes(euler: FloatArray) -> FloatArray:
    """C_NB for each row of ``euler`` (M, 3) → (M, 3, 3)."""
    out = np.empty((euler.shape[0], 3, 3))
    for i in range(euler.shape[0]):
        cf, sf = math.cos(euler[i, 0]), math.sin(euler[i, 0])
        ct, st = math.cos(euler[i, 1]), math.sin(euler[i, 1])
        c = dcm_from_trig(cf, sf, ct, st, math.cos(euler[i, 2]), math.sin(euler[i, 2]))
        for k in range(9):
            out[i, k // 3, k % 3] = c[k]
    return out


@kernel
def euler_rate_matrix_kernel(phi: float, theta: float) -> FloatArray:
    """D(Λ) as a (3, 3) matrix: column j is ``D(Λ) e_j`` from :func:`euler_rates_from_trig`."""
    cf, sf, ct, st = math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta)
    out = np.empty((3, 3))
    for j in range(3):
        rates = euler_rates_from_trig(
            cf, sf, ct, st, 1.0 if j == 0 else 0.0, 1.0 if j == 1 else 0.0, 1.0 if j == 2 else 0.0
        )
        for i in range(3):
            out[i, j] = rates[i]
    return out


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
    return _dcm_lanes(np.ascontiguousarray(euler, dtype=float).reshape(1, 3))[0]


def dcm_from_euler_batch(euler: FloatArray) -> FloatArray:
    """:func:`dcm_from_euler` lifted over leading axes.

    Args:
        euler: (..., 3) Euler angles (φ, θ, ψ) in rad, e.g. (B, 3) or (N, 3).

    Returns:
        (..., 3, 3) matrices ``C_NB``.
    """
    arr = np.asarray(euler, dtype=float)
    flat = np.ascontiguousarray(arr.reshape(-1, 3))
    return _dcm_lanes(flat).reshape(*arr.shape[:-1], 3, 3)


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
    angles = np.asarray(euler, dtype=float)
    return euler_rate_matrix_kernel(float(angles[0]), float(angles[1]))


@kernel
def skew_from_components(x: float, y: float, z: float) -> FloatArray:
    """Cross-product matrix (3, 3) of the vector ``(x, y, z)``: ``[a]× b == a × b``."""
    out = np.zeros((3, 3))
    out[0, 1], out[0, 2] = -z, y
    out[1, 0], out[1, 2] = z, -x
    out[2, 0], out[2, 1] = -y, x
    return out


def skew(vec: ArrayLike) -> FloatArray:
    """Cross-product matrix (3, 3): ``skew(a) @ b == a × b`` for (3,) vectors."""
    x, y, z = (float(a) for a in np.asarray(vec, dtype=float))
    return skew_from_components(x, y, z)


def rotation_angle_between(dcm_a: ArrayLike, dcm_b: ArrayLike) -> float:
    """Angle of the relative rotation ``C_aᵀ C_b`` in rad, in [0, π].

    This is the attitude error metric of docs/design.md §5: it does not depend on the
    Euler parametrisation and has no wrap-around.

    Args:
        dcm_a, dcm_b: (3, 3) direction cosine matrices.
    """
    rel = np.asarray(dcm_a, dtype=float).T @ np.asarray(dcm_b, dtype=float)
    cos_angle = 0.5 * (float(np.trace(rel)) - 1.0)
    return math.acos(max(-1.0, min(1.0, cos_angle)))


def dcm_euler_partials(euler: ArrayLike) -> FloatArray:
    """Partial derivatives of ``C_NB`` with respect to (φ, θ, ψ) (:func:`dcm_and_partials`).

    Args:
        euler: (3,) Euler angles in rad.

    Returns:
        (3, 3, 3) array ``D`` with ``D[i] = ∂C_NB/∂Λ_i`` in 1/rad.
    """
    phi, theta, psi = (float(a) for a in np.asarray(euler, dtype=float))
    dC = np.empty((3, 3, 3))
    dcm_and_partials(phi, theta, psi, np.empty((3, 3)), dC)
    return dC
