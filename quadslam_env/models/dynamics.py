"""Rigid-body quadcopter dynamics (seed 001 eq. 2–3) and vehicle presets.

State vector (12,), DESIGN.md §2: ``x = (ρ, v, Λ, ω)`` with
    ρ  position of the centre of mass in N (NED), m;
    v  velocity expressed in B (FRD), m/s;
    Λ  3-2-1 Euler angles (φ, θ, ψ), rad;
    ω  body rates (p, q, r) in B, rad/s.
Inputs: collective thrust ``f_T`` (N, along -b3) and body torque ``τ`` (N·m).

The integrator works on Python floats because, for 12 states, scalar arithmetic is several
times faster than NumPy's per-call overhead and the env calls it 20 times per control step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.rotations import FloatArray

GRAVITY = 9.81
"""Gravitational acceleration g in m/s² (DESIGN.md §2)."""

STATE_DIM = 12
POS, VEL, EUL, RATE = slice(0, 3), slice(3, 6), slice(6, 9), slice(9, 12)


@dataclass(frozen=True)
class VehicleParams:
    """Physical parameters of a quadcopter.

    Attributes:
        name: Preset name or ``"custom"``.
        mass: Mass m in kg.
        inertia: (3, 3) inertia matrix J in kg·m² (body frame).
        max_thrust: Upper thrust limit in N (the lower limit is 0).
        max_torque: (3,) symmetric torque limits in N·m per body axis.
        drag: Linear drag coefficient in 1/s (``v̇ += -drag · v``); 0 disables it.
        actuator_tau: First-order actuator time constant in s; 0 disables the lag.
    """

    name: str
    mass: float
    inertia: FloatArray
    max_thrust: float
    max_torque: FloatArray
    drag: float = 0.0
    actuator_tau: float = 0.0
    inertia_inv: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        inertia = np.array(self.inertia, dtype=float).reshape(3, 3)
        inertia.setflags(write=False)
        torque = np.array(self.max_torque, dtype=float).reshape(3)
        torque.setflags(write=False)
        inv = np.linalg.inv(inertia)
        inv.setflags(write=False)
        object.__setattr__(self, "inertia", inertia)
        object.__setattr__(self, "max_torque", torque)
        object.__setattr__(self, "inertia_inv", inv)

    @property
    def hover_thrust(self) -> float:
        """Thrust that balances gravity, ``m g`` in N."""
        return self.mass * GRAVITY


def _preset(
    name: str,
    mass: float,
    inertia_diag: tuple[float, float, float],
    torque: float,
    yaw_torque: float,
) -> VehicleParams:
    # Thrust limit 2.5 m g: a typical thrust-to-weight ratio for research quadcopters.
    return VehicleParams(
        name=name,
        mass=mass,
        inertia=np.diag(inertia_diag),
        max_thrust=2.5 * mass * GRAVITY,
        max_torque=np.array([torque, torque, yaw_torque]),
    )


VEHICLE_PRESETS: dict[str, VehicleParams] = {
    # Seed 001 Table 1. Torque limits: ~0.25 m arm with a quarter of the thrust margin.
    "rauniyar2023": _preset("rauniyar2023", 1.56, (0.1147, 0.0576, 0.1712), 2.0, 1.0),
    # Seed 000 §IV (Hector quadrotor): smaller inertia, so smaller torque limits.
    "sadeghzadeh2021": _preset("sadeghzadeh2021", 1.477, (0.01152, 0.01152, 0.0218), 0.5, 0.25),
}


def vehicle_preset(name: str) -> VehicleParams:
    """Return the vehicle preset ``name`` (``rauniyar2023`` or ``sadeghzadeh2021``).

    Raises:
        ValueError: If the name is unknown; the message lists the allowed names.
    """
    try:
        return VEHICLE_PRESETS[name]
    except KeyError:
        raise ValueError(
            f"vehicle.preset: unknown preset {name!r}; allowed: {sorted(VEHICLE_PRESETS)}"
        ) from None


def saturate_inputs(
    thrust: float, torque: ArrayLike, params: VehicleParams
) -> tuple[float, FloatArray]:
    """Clip thrust to ``[0, max_thrust]`` N and each torque to ``±max_torque`` N·m."""
    thrust_sat = min(max(float(thrust), 0.0), params.max_thrust)
    torque_sat = np.clip(np.asarray(torque, dtype=float), -params.max_torque, params.max_torque)
    return thrust_sat, torque_sat


def _derivative(
    x: list[float], thrust: float, tau: tuple[float, float, float], coeffs: tuple[float, ...]
) -> list[float]:
    """Scalar implementation of seed 001 eq. 2 (see :func:`state_derivative`)."""
    _x, _y, _z, u, v, w, phi, theta, psi, p, q, r = x
    (
        m,
        drag,
        j00,
        j01,
        j02,
        j10,
        j11,
        j12,
        j20,
        j21,
        j22,
        i00,
        i01,
        i02,
        i10,
        i11,
        i12,
        i20,
        i21,
        i22,
    ) = coeffs
    cf, sf = math.cos(phi), math.sin(phi)
    ct, st = math.cos(theta), math.sin(theta)
    cp, sp = math.cos(psi), math.sin(psi)
    # ρ̇ = C_NB v
    xd = ct * cp * u + (sf * st * cp - cf * sp) * v + (cf * st * cp + sf * sp) * w
    yd = ct * sp * u + (sf * st * sp + cf * cp) * v + (cf * st * sp - sf * cp) * w
    zd = -st * u + sf * ct * v + cf * ct * w
    # v̇ = -ω×v + C_NBᵀ g n3 - (f_T/m) b3 - drag v ; C_NBᵀ n3 is the third row of C_NB.
    ud = -(q * w - r * v) - GRAVITY * st - drag * u
    vd = -(r * u - p * w) + GRAVITY * sf * ct - drag * v
    wd = -(p * v - q * u) + GRAVITY * cf * ct - thrust / m - drag * w
    # Λ̇ = D(Λ) ω (eq. 3)
    tt = st / ct
    phid = p + (sf * q + cf * r) * tt
    thetad = cf * q - sf * r
    psid = (sf * q + cf * r) / ct
    # ω̇ = J⁻¹(-ω×Jω + τ)
    h0 = j00 * p + j01 * q + j02 * r
    h1 = j10 * p + j11 * q + j12 * r
    h2 = j20 * p + j21 * q + j22 * r
    m0 = tau[0] - (q * h2 - r * h1)
    m1 = tau[1] - (r * h0 - p * h2)
    m2 = tau[2] - (p * h1 - q * h0)
    pd = i00 * m0 + i01 * m1 + i02 * m2
    qd = i10 * m0 + i11 * m1 + i12 * m2
    rd = i20 * m0 + i21 * m1 + i22 * m2
    return [xd, yd, zd, ud, vd, wd, phid, thetad, psid, pd, qd, rd]


def _coeffs(params: VehicleParams) -> tuple[float, ...]:
    return (
        params.mass,
        params.drag,
        *params.inertia.ravel().tolist(),
        *params.inertia_inv.ravel().tolist(),
    )


def state_derivative(
    state: ArrayLike, thrust: float, torque: ArrayLike, params: VehicleParams
) -> FloatArray:
    """Time derivative of the 12-state (seed 001 eq. 2, with D(Λ) from eq. 3).

    ``ρ̇ = C_NB v``, ``v̇ = -ω×v + C_NBᵀ g n3 - (f_T/m) b3 (- drag v)``, ``Λ̇ = D(Λ) ω``,
    ``ω̇ = J⁻¹(-ω×Jω + τ)``. Inputs are used as given (no saturation).

    Args:
        state: (12,) state ``(ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])``.
        thrust: Collective thrust f_T in N.
        torque: (3,) body torque τ in N·m.
        params: Vehicle parameters (mass in kg, inertia 3×3 in kg·m²).

    Returns:
        (12,) derivative of the state.
    """
    x = np.asarray(state, dtype=float).reshape(STATE_DIM).tolist()
    tau = tuple(float(t) for t in np.asarray(torque, dtype=float).reshape(3))
    return np.array(_derivative(x, float(thrust), tau, _coeffs(params)))


def rk4_integrate(
    state: ArrayLike,
    thrust: float,
    torque: ArrayLike,
    params: VehicleParams,
    duration: float,
    substep: float,
) -> FloatArray:
    """Integrate the dynamics with classical RK4 over ``duration`` with fixed substeps.

    Inputs are held constant (zero-order hold). ``duration`` is split into
    ``ceil(duration / substep)`` equal substeps.

    Args:
        state: (12,) initial state.
        thrust: Thrust f_T in N (held constant).
        torque: (3,) torque τ in N·m (held constant).
        params: Vehicle parameters.
        duration: Integration horizon in s.
        substep: Maximum RK4 step in s.

    Returns:
        (12,) state after ``duration`` seconds.
    """
    x = np.asarray(state, dtype=float).reshape(STATE_DIM).tolist()
    tau = tuple(float(t) for t in np.asarray(torque, dtype=float).reshape(3))
    n_sub = max(1, math.ceil(duration / substep - 1e-9))
    x = rk4_steps(x, float(thrust), tau, _coeffs(params), duration / n_sub, n_sub)
    return np.array(x)


def rk4_steps(
    x: list[float],
    thrust: float,
    tau: tuple[float, float, float],
    coeffs: tuple[float, ...],
    h: float,
    n_steps: int,
) -> list[float]:
    """``n_steps`` RK4 steps of size ``h`` on a Python-float state (the simulator's hot path)."""
    half = 0.5 * h
    sixth = h / 6.0
    for _ in range(n_steps):
        k1 = _derivative(x, thrust, tau, coeffs)
        k2 = _derivative([a + half * b for a, b in zip(x, k1, strict=True)], thrust, tau, coeffs)
        k3 = _derivative([a + half * b for a, b in zip(x, k2, strict=True)], thrust, tau, coeffs)
        k4 = _derivative([a + h * b for a, b in zip(x, k3, strict=True)], thrust, tau, coeffs)
        x = [
            a + sixth * (b + 2.0 * (c + d) + e)
            for a, b, c, d, e in zip(x, k1, k2, k3, k4, strict=True)
        ]
    return x


def specific_force(vel_body: ArrayLike, thrust: float, params: VehicleParams) -> FloatArray:
    """Specific force ``f_B = C_NBᵀ(ρ̈ - g n3)`` sensed by an accelerometer, in m/s² (B frame).

    From eq. 2, ``C_NBᵀ ρ̈ = v̇ + ω×v``, so ``f_B = -(f_T/m) b3 - drag · v`` (seed 000 eq. 7
    with a physical accelerometer, DESIGN.md §3).
    """
    v = np.asarray(vel_body, dtype=float)
    out = -params.drag * v
    out[2] -= thrust / params.mass
    return out
