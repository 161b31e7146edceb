"""Strapdown process model of EKF-SLAM (seed 001 eq. 24–28), compiled with numba.

The vehicle state is ``s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])`` (seed 001 eq. 21)
and the input the IMU-derived ``λ = (a_z, ω)`` (eq. 25): the specific force along b3 in m/s²
(``-g`` in hover) and the body rates ``ω = (p, q, r)`` in rad/s. The process (eq. 24) is

    ρ̇ = C_NB v,    v̇ = -ω×v + C_NBᵀ g n3 + a_z b3,    Λ̇ = D(Λ) ω,

with ``C_NB = C3(ψ) C2(θ) C1(φ)`` (eq. 1) and ``D(Λ)`` the Euler-rate matrix (eq. 3).

The kernels work on one vehicle and write into caller-provided arrays, so filters can call
them inside their own compiled loops over lanes or particles without allocating; the
NumPy-facing :func:`process_derivative` and :func:`process_jacobians` wrap them for tests and
interactive use. ``fastmath`` stays off so results are IEEE-reproducible.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from quadslam_env.models.dynamics import GRAVITY
from quadslam_env.models.rotations import FloatArray

STRAPDOWN_DIM = 9
"""Size of the strapdown state s = (ρ, v_B, Λ)."""


@njit(cache=True)
def strapdown_derivative(
    s: FloatArray, accel_z: float, p: float, q: float, r: float, out: FloatArray
) -> None:
    """``ṡ = f_s(s, λ)`` of seed 001 eq. 24 (noise-free), written into ``out``.

    Args:
        s: (9,) state (ρ [m, N], v_B [m/s, B], Λ [rad]); ρ does not enter.
        accel_z: Specific force along b3 in m/s².
        p: Body rate about b1 in rad/s.
        q: Body rate about b2 in rad/s.
        r: Body rate about b3 in rad/s.
        out: (9,) receives ṡ (may not alias ``s``).
    """
    u, v, w, phi, theta, psi = s[3], s[4], s[5], s[6], s[7], s[8]
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    g = GRAVITY
    a = sf * q + cf * r
    # ρ̇ = C_NB v with the rows of C_NB (eq. 1) written out.
    out[0] = ct * cp * u + (sf * st * cp - cf * sp) * v + (cf * st * cp + sf * sp) * w
    out[1] = ct * sp * u + (sf * st * sp + cf * cp) * v + (cf * st * sp - sf * cp) * w
    out[2] = -st * u + sf * ct * v + cf * ct * w
    # v̇ = -ω×v + g C_NBᵀ n3 + a_z b3; C_NBᵀ n3 is the last row of C_NB.
    out[3] = r * v - q * w - g * st
    out[4] = p * w - r * u + g * sf * ct
    out[5] = q * u - p * v + g * cf * ct + accel_z
    # Λ̇ = D(Λ) ω (eq. 3).
    out[6] = p + a * st / ct
    out[7] = cf * q - sf * r
    out[8] = a / ct


@njit(cache=True)
def strapdown_rk4(
    s: FloatArray,
    accel_z: float,
    p: float,
    q: float,
    r: float,
    dt: float,
    work: FloatArray,
    out: FloatArray,
) -> None:
    """One classical RK4 step of eq. 24 with the input λ held over ``dt`` (eq. 26).

    Args:
        s: (9,) state at the start of the step.
        accel_z: Specific force along b3 in m/s².
        p: Body rate about b1 in rad/s.
        q: Body rate about b2 in rad/s.
        r: Body rate about b3 in rad/s.
        dt: Step in s.
        work: (5, 9) scratch (the four stages and the stage state).
        out: (9,) receives ``s(t + dt)`` (may alias ``s``); angles are not wrapped.
    """
    k1, k2, k3, k4, y = work[0], work[1], work[2], work[3], work[4]
    h2 = 0.5 * dt
    strapdown_derivative(s, accel_z, p, q, r, k1)
    for i in range(STRAPDOWN_DIM):
        y[i] = s[i] + h2 * k1[i]
    strapdown_derivative(y, accel_z, p, q, r, k2)
    for i in range(STRAPDOWN_DIM):
        y[i] = s[i] + h2 * k2[i]
    strapdown_derivative(y, accel_z, p, q, r, k3)
    for i in range(STRAPDOWN_DIM):
        y[i] = s[i] + dt * k3[i]
    strapdown_derivative(y, accel_z, p, q, r, k4)
    h6 = dt / 6.0
    for i in range(STRAPDOWN_DIM):
        out[i] = s[i] + h6 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i])


@njit(cache=True)
def strapdown_jacobians(
    s: FloatArray, p: float, q: float, r: float, F: FloatArray, G: FloatArray
) -> None:
    """Analytic Jacobians of eq. 24: ``F = ∂f_s/∂s`` (eq. 28) and ``G = ∂f_s/∂λ``.

    ``a_z`` enters f_s linearly, so neither Jacobian depends on it.

    Args:
        s: (9,) state (ρ [m, N], v_B [m/s, B], Λ [rad]).
        p: Body rate about b1 in rad/s.
        q: Body rate about b2 in rad/s.
        r: Body rate about b3 in rad/s.
        F: (9, 9) receives ∂f_s/∂s (every entry is written).
        G: (9, 4) receives ∂f_s/∂λ for λ = (a_z, p, q, r) (every entry is written).
    """
    u, v, w, phi, theta, psi = s[3], s[4], s[5], s[6], s[7], s[8]
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    g = GRAVITY
    c00, c01, c02 = ct * cp, sf * st * cp - cf * sp, cf * st * cp + sf * sp
    c10, c11, c12 = ct * sp, sf * st * sp + cf * cp, cf * st * sp - sf * cp
    c20, c21, c22 = -st, sf * ct, cf * ct
    xd = c00 * u + c01 * v + c02 * w
    yd = c10 * u + c11 * v + c12 * w
    # ∂C/∂φ v = C (e1 × v); ∂C/∂θ v = C ((C1ᵀ e2) × v); ∂C/∂ψ v = e3 × (C v).
    e0, e1, e2 = cf * w + sf * v, -sf * u, -cf * u
    sec = 1.0 / ct
    tt = st * sec
    a = sf * q + cf * r
    b = cf * q - sf * r
    F[:, :] = 0.0
    F[0, 3], F[0, 4], F[0, 5] = c00, c01, c02
    F[1, 3], F[1, 4], F[1, 5] = c10, c11, c12
    F[2, 3], F[2, 4], F[2, 5] = c20, c21, c22
    F[0, 6], F[0, 7], F[0, 8] = c02 * v - c01 * w, c00 * e0 + c01 * e1 + c02 * e2, -yd
    F[1, 6], F[1, 7], F[1, 8] = c12 * v - c11 * w, c10 * e0 + c11 * e1 + c12 * e2, xd
    F[2, 6], F[2, 7] = c22 * v - c21 * w, c20 * e0 + c21 * e1 + c22 * e2
    F[3, 4], F[3, 5], F[3, 7] = r, -q, -g * ct
    F[4, 3], F[4, 5], F[4, 6], F[4, 7] = -r, p, g * c22, -g * sf * st
    F[5, 3], F[5, 4], F[5, 6], F[5, 7] = q, -p, -g * c21, -g * cf * st
    F[6, 6], F[6, 7] = b * tt, a * sec * sec
    F[7, 6] = -a
    F[8, 6], F[8, 7] = b * sec, a * tt * sec
    G[:, :] = 0.0
    G[3, 2], G[3, 3] = -w, v
    G[4, 1], G[4, 3] = w, -u
    G[5, 0], G[5, 1], G[5, 2] = 1.0, -v, u
    G[6, 1], G[6, 2], G[6, 3] = 1.0, sf * tt, cf * tt
    G[7, 2], G[7, 3] = cf, -sf
    G[8, 2], G[8, 3] = sf * sec, cf * sec


def process_derivative(s: FloatArray, accel_z: float, gyro: FloatArray) -> FloatArray:
    """Process model ``ṡ = f_s(s, λ)`` of seed 001 eq. 24 (noise-free).

    ``ρ̇ = C_NB v``, ``v̇ = -ω×v + C_NBᵀ g n3 + a_z b3``, ``Λ̇ = D(Λ) ω``.

    Args:
        s: (9,) vehicle state (ρ [m, N], v_B [m/s, B], Λ [rad]).
        accel_z: Bias-corrected specific force along b3 in m/s² (``-g`` in hover).
        gyro: (3,) bias-corrected body rates ω in rad/s.

    Returns:
        (9,) time derivative of s.
    """
    out = np.empty(STRAPDOWN_DIM)
    p, q, r = (float(c) for c in gyro)
    strapdown_derivative(np.ascontiguousarray(s, dtype=float), float(accel_z), p, q, r, out)
    return out


def process_jacobians(
    s: FloatArray, accel_z: float, gyro: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Analytic Jacobians of :func:`process_derivative` (seed 001 eq. 28).

    Args:
        s: (9,) vehicle state.
        accel_z: Specific force along b3 in m/s² (does not enter the Jacobians).
        gyro: (3,) body rates in rad/s.

    Returns:
        ``(F, G)``: ``F = ∂f_s/∂s`` (9, 9) and ``G = ∂f_s/∂λ`` (9, 4) for ``λ = (a_z, ω)``.
        With bias states ``b = (b_ω, b_az)`` and ``λ = λ̃ - b``, ``∂f/∂b_ω = -G[:, 1:4]`` and
        ``∂f/∂b_az = -G[:, 0]``.
    """
    del accel_z
    F = np.empty((STRAPDOWN_DIM, STRAPDOWN_DIM))
    G = np.empty((STRAPDOWN_DIM, 4))
    p, q, r = (float(c) for c in gyro)
    strapdown_jacobians(np.ascontiguousarray(s, dtype=float), p, q, r, F, G)
    return F, G
