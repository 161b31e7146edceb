"""Differential flatness of the quadcopter: flat outputs to thrust and attitude (seed 001 §2.2).

The inverse mapping (seed 001 eq. 15–19) takes a desired acceleration ``u_p`` (the flat
outputs' ``ρ̈ − g n3`` plus any feedback) written in the reference-heading frame (rotated by
``C3(ψ_d)ᵀ``) and a yaw-rate command ``u_ψ`` to the thrust ``f_T = m ‖u_p‖`` and the attitude
that points the thrust along ``u_p``: ``z = −(m/f_T) u_p``, ``φ_d = asin(−z2)``,
``θ_d = atan2(z1, z3)``, ``r_d = u_ψ cos θ_d / cos φ_d`` (``p_d = q_d = 0``).

Two users share the one kernel: the DF-LQR baseline (``agents.control.dflqr``, on the feedback
command) and the simulator's start on the reference (:func:`state_on_reference`, on
the feed-forward alone), so a vehicle started on the reference has exactly the attitude the
baseline would command there.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.jit import kernel
from quadslam_env.types import EUL, GRAVITY, POS, STATE_DIM, VEL, FloatArray


@kernel
def inverse_map(ux: float, uy: float, uz: float, u_psi: float, mass: float) -> tuple:
    """Seed 001 eq. 15–19 for one command.

    Args:
        ux, uy, uz: ``u_p`` in the reference-heading frame, m/s² (NED axes turned by ψ_d).
        u_psi: Yaw-rate command u_ψ, rad/s.
        mass: Vehicle mass, kg.

    Returns:
        ``(f_T N, φ_d rad, θ_d rad, r_d rad/s)``.
    """
    thrust = mass * math.sqrt(ux * ux + uy * uy + uz * uz)
    scale = -mass / max(thrust, 1e-9)
    z1, z2, z3 = scale * ux, scale * uy, scale * uz
    phi_d = math.asin(min(1.0, max(-1.0, -z2)))
    theta_d = math.atan2(z1, z3)
    return thrust, phi_d, theta_d, u_psi * math.cos(theta_d) / math.cos(phi_d)


def inverse_mapping(
    u: FloatArray, mass: float
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """:func:`inverse_map` over a batch of commands.

    Args:
        u: (n, 4) commands ``(u_p in the heading frame [m/s²], u_ψ [rad/s])``.
        mass: Vehicle mass in kg.

    Returns:
        ``(f_T (n,) N, φ_d (n,) rad, θ_d (n,) rad, r_d (n,) rad/s)``.
    """
    rows = np.array(
        [
            inverse_map(float(r[0]), float(r[1]), float(r[2]), float(r[3]), mass)
            for r in np.asarray(u, dtype=float)
        ]
    )
    return rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3]


def state_on_reference(
    pos: ArrayLike, vel: ArrayLike, acc: ArrayLike, yaw: float, yaw_rate: float, mass: float
) -> FloatArray:
    """The 12-state that flies the reference at one instant (feed-forward of seed 001 eq. 5).

    Position and inertial velocity are the reference's; the attitude points the thrust along
    ``ρ̈_d − g n3`` with heading ψ_d (:func:`inverse_map` on the feed-forward command); the body
    rates are ``(0, 0, r_d)``, the rates of the same map.

    Args:
        pos: (3,) ρ_d, NED, m.
        vel: (3,) ρ̇_d, NED, m/s.
        acc: (3,) ρ̈_d, NED, m/s².
        yaw: ψ_d, rad.
        yaw_rate: ψ̇_d, rad/s.
        mass: Vehicle mass, kg.

    Returns:
        (12,) state ``(ρ m NED, v m/s body, Λ rad, ω rad/s body)``.
    """
    c, s = math.cos(yaw), math.sin(yaw)
    a = np.asarray(acc, dtype=float)
    # ρ̈_d − g n3 turned into the heading frame by C3(ψ_d)ᵀ (n3 is unchanged by it).
    ux, uy, uz = c * a[0] + s * a[1], -s * a[0] + c * a[1], a[2] - GRAVITY
    _, phi, theta, r = inverse_map(ux, uy, uz, float(yaw_rate), mass)
    euler = np.array([phi, theta, yaw])
    state = np.zeros(STATE_DIM)
    state[POS] = pos
    state[VEL] = dcm_from_euler(euler).T @ np.asarray(vel, dtype=float)
    state[EUL] = euler
    state[11] = r
    return state
