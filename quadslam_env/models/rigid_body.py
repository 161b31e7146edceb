"""Rigid-body quadcopter dynamics (seed 001 eq. 2–3) as numba kernels on one vehicle.

State vector (12,), docs/design.md §2: ``x = (ρ, v, Λ, ω)`` with
    ρ  position of the centre of mass in N (NED), m;
    v  velocity expressed in B (FRD), m/s;
    Λ  3-2-1 Euler angles (φ, θ, ψ), rad;
    ω  body rates (p, q, r) in B, rad/s.
Inputs: collective thrust ``f_T`` (N, along -b3) and body torque ``τ`` (N·m).

Each equation is one ``@njit(cache=True)`` kernel on one vehicle; the lane kernels of
:mod:`quadslam_env.models.integrators` loop them over a leading batch axis B — vehicles of a
vector env or particles of FastSLAM — so the simulator and the filters integrate the same
code. No ``fastmath``: results are reproducible bit for bit.

The kernels take the input as one vector ``u = (f_T, τ, a)`` with an extra body-frame specific
force ``a`` (m/s²), the parameters as one vector (:func:`pack_bodies`), and a ``hold_rates``
flag: with ``f_T = 0``, ``drag = 0``, ``a = a_m`` and ``ω̇ = 0`` the same kinematics are the
IMU strapdown model of seed 000's kinematic FastSLAM (§IV-B), so it needs no copy of them.

Aerodynamics (docs/design.md §3): drag acts on the air-relative velocity ``v_a = v − C_NBᵀ w``
for a wind ``w`` (N, m/s): a linear part ``−drag · v_a`` and a quadratic part
``−c_q ∘ (‖v_a‖ v_a)`` (:func:`aero_specific_force`). The kernels take them as ``air = (w (3),
c_q (3))`` with an ``aero`` flag; with ``aero`` False (still air, no quadratic drag; every
estimator's model) they compute exactly what they did before wind existed.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.frames import dcm_from_trig, euler_rates_from_trig
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.types import GRAVITY, STATE_DIM, FloatArray

Vec3 = tuple[float, float, float]
Vec4 = tuple[float, float, float, float]
Vec9 = tuple[float, float, float, float, float, float, float, float, float]

INPUT_DIM = 7
"""Input vector ``u = (f_T [N], τ [N·m] (3), a [m/s²] (3))`` of the kernels, B frame."""

AirTuple = tuple[float, float, float, float, float, float]

NO_AIR: AirTuple = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
"""``air`` of still air without quadratic drag (pass it with ``aero = False``)."""

BODY_DIM = 20
"""Body parameter vector ``(m [kg], drag [1/s], J (9), J⁻¹ (9))``, matrices row-major."""


@kernel
def substep_count(duration: float, max_step: float) -> int:
    """Number of equal RK4 substeps no longer than ``max_step`` s covering ``duration`` s.

    The ``1e-9`` guard keeps e.g. ``0.01 / 0.002`` at 5 substeps despite round-off.
    """
    return max(1, math.ceil(duration / max_step - 1e-9))


@kernel
def saturate(
    thrust: float, tau: Vec3, max_thrust: float, max_torque: FloatArray
) -> tuple[float, Vec3]:
    """Clip thrust to ``[0, max_thrust]`` N and torque component i to ``±max_torque[i]`` N·m."""
    return min(max(thrust, 0.0), max_thrust), (
        min(max(tau[0], -max_torque[0]), max_torque[0]),
        min(max(tau[1], -max_torque[1]), max_torque[1]),
        min(max(tau[2], -max_torque[2]), max_torque[2]),
    )


@inline_kernel
def specific_force_body(
    u: float, v: float, w: float, thrust: float, mass: float, drag: float
) -> Vec3:
    """Specific force ``f_B = C_NBᵀ(ρ̈ − g n3) = −(f_T/m) b3 − drag · v`` in m/s² (B frame).

    From eq. 2, ``C_NBᵀ ρ̈ = v̇ + ω×v``; this is what an accelerometer senses (seed 000 eq. 7
    with a physical accelerometer, docs/design.md §3).
    """
    return -drag * u, -drag * v, -drag * w - thrust / mass


@inline_kernel
def aero_specific_force(
    ua: float, va: float, wa: float, thrust: float, mass: float, drag: float, cq: Vec3
) -> Vec3:
    """Specific force with quadratic drag, m/s² (B frame), from the air-relative velocity.

    ``f_B = −(f_T/m) b3 − drag · v_a − c_q ∘ (‖v_a‖ v_a)``: :func:`specific_force_body` on
    ``v_a = (ua, va, wa)`` (m/s, B) plus a quadratic drag with per-axis coefficients ``cq``
    (1/m; a body at relative speed s feels ``c_q s²`` per unit mass along the flow).
    """
    f = specific_force_body(ua, va, wa, thrust, mass, drag)
    speed = math.sqrt(ua * ua + va * va + wa * wa)
    return f[0] - cq[0] * speed * ua, f[1] - cq[1] * speed * va, f[2] - cq[2] * speed * wa


@inline_kernel
def air_velocity_body(x: FloatArray, c: Vec9, wn: float, we: float, wd: float) -> Vec3:
    """``v_a = v − C_NBᵀ w``: velocity relative to the air in B, m/s.

    Args:
        x: (12,) state (v read from ``x[VEL]``). c: C_NB row-major (9 entries).
        wn, we, wd: Wind w in N (north, east, down), m/s.
    """
    return (
        x[3] - (c[0] * wn + c[3] * we + c[6] * wd),
        x[4] - (c[1] * wn + c[4] * we + c[7] * wd),
        x[5] - (c[2] * wn + c[5] * we + c[8] * wd),
    )


@inline_kernel
def air_specific_force(
    x: FloatArray, c: Vec9, thrust: float, mass: float, drag: float, air: AirTuple
) -> Vec3:
    """:func:`aero_specific_force` of state ``x`` (12,) with ``C_NB`` ``c`` (row-major) in the
    ``air`` ``(w (3) m/s in N, c_q (3) 1/m)``: the drag on ``v − C_NBᵀ w``, m/s² (B frame)."""
    va = air_velocity_body(x, c, air[0], air[1], air[2])
    cq = (air[3], air[4], air[5])
    return aero_specific_force(va[0], va[1], va[2], thrust, mass, drag, cq)


@inline_kernel
def state_specific_force(
    x: FloatArray, thrust: float, mass: float, drag: float, air: AirTuple, aero: bool
) -> Vec3:
    """The specific force of state ``x`` (12,), m/s² (B frame): in the ``air`` with ``aero``
    (:func:`air_specific_force`), else still air (:func:`specific_force_body`)."""
    if not aero:
        return specific_force_body(x[3], x[4], x[5], thrust, mass, drag)
    c = dcm_from_trig(
        math.cos(x[6]), math.sin(x[6]), math.cos(x[7]), math.sin(x[7]),
        math.cos(x[8]), math.sin(x[8]),
    )  # fmt: skip
    return air_specific_force(x, c, thrust, mass, drag, air)


@inline_kernel
def kinematics_dcm(x: FloatArray, c: Vec9, trig: Vec4, f_b: Vec3, out: FloatArray) -> None:
    """:func:`kinematics` with C_NB (row-major, 9) and ``trig = (cos φ, sin φ, cos θ, sin θ)``
    already computed."""
    u, v, w = x[3], x[4], x[5]
    p, q, r = x[9], x[10], x[11]
    out[0] = c[0] * u + c[1] * v + c[2] * w
    out[1] = c[3] * u + c[4] * v + c[5] * w
    out[2] = c[6] * u + c[7] * v + c[8] * w
    # C_NBᵀ n3 is the third row of C_NB.
    out[3] = -(q * w - r * v) + GRAVITY * c[6] + f_b[0]
    out[4] = -(r * u - p * w) + GRAVITY * c[7] + f_b[1]
    out[5] = -(p * v - q * u) + GRAVITY * c[8] + f_b[2]
    out[6], out[7], out[8] = euler_rates_from_trig(trig[0], trig[1], trig[2], trig[3], p, q, r)


@inline_kernel
def kinematics(x: FloatArray, f_b: Vec3, out: FloatArray) -> None:
    """Rows ρ̇, v̇, Λ̇ of seed 001 eq. 2 for one state, written to ``out[0:9]``.

    ``ρ̇ = C_NB v``, ``v̇ = −ω×v + C_NBᵀ g n3 + f_B``, ``Λ̇ = D(Λ) ω`` (eq. 3).

    Args:
        x: (12,) state; ω is read from ``x[RATE]``.
        f_b: Specific force in B, m/s².
        out: (12,) derivative; entries 9–11 are not touched.
    """
    cf, sf = math.cos(x[6]), math.sin(x[6])
    ct, st = math.cos(x[7]), math.sin(x[7])
    c = dcm_from_trig(cf, sf, ct, st, math.cos(x[8]), math.sin(x[8]))
    kinematics_dcm(x, c, (cf, sf, ct, st), f_b, out)


@kernel
def pack_bodies(mass: float, drag: float, J: FloatArray, J_inv: FloatArray) -> FloatArray:
    """Body parameter vectors (K, 20): ``(m [kg], drag [1/s], J (9) [kg·m²], J⁻¹ (9))``.

    Args:
        mass: m in kg, shared. drag: Linear drag in 1/s, shared.
        J, J_inv: (K, 3, 3) inertia in B and its inverse (K = 1: one body for all lanes).
    """
    out = np.empty((J.shape[0], BODY_DIM))
    for k in range(J.shape[0]):
        out[k, 0], out[k, 1] = mass, drag
        for i in range(3):
            for j in range(3):
                out[k, 2 + 3 * i + j] = J[k, i, j]
                out[k, 11 + 3 * i + j] = J_inv[k, i, j]
    return out


@inline_kernel
def euler_equation(p: float, q: float, r: float, tau: Vec3, body: FloatArray) -> Vec3:
    """``ω̇ = J⁻¹(τ − ω×Jω)`` (seed 001 eq. 2) in rad/s², τ (3,) in N·m, ``body`` (20,)."""
    h0 = body[2] * p + body[3] * q + body[4] * r
    h1 = body[5] * p + body[6] * q + body[7] * r
    h2 = body[8] * p + body[9] * q + body[10] * r
    m0 = tau[0] - (q * h2 - r * h1)
    m1 = tau[1] - (r * h0 - p * h2)
    m2 = tau[2] - (p * h1 - q * h0)
    return (
        body[11] * m0 + body[12] * m1 + body[13] * m2,
        body[14] * m0 + body[15] * m1 + body[16] * m2,
        body[17] * m0 + body[18] * m1 + body[19] * m2,
    )


@inline_kernel
def rigid_body_derivative(
    x: FloatArray,
    u: FloatArray,
    body: FloatArray,
    hold_rates: bool,
    out: FloatArray,
    air: AirTuple,
    aero: bool,
) -> None:
    """``ẋ`` of seed 001 eq. 2 (= seed 000 eq. 1–4) for one state, into ``out`` (12,).

    Args:
        x: (12,) state ``(ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])``.
        u: (7,) input ``(f_T [N], τ [N·m] (3), a [m/s²] (3))``, used as given (no
            saturation); ``a`` is an extra specific force in B added to ``−(f_T/m) b3 − drag v``.
        body: (20,) parameters from :func:`pack_bodies`.
        hold_rates: If True, ``ω̇ = 0`` (ω is an input held over the step).
        out: (12,) output.
        air: ``(w (3) m/s in N, c_q (3) 1/m)``: the wind and the quadratic drag coefficients,
            read only when ``aero``; then the drag acts on ``v − C_NBᵀ w``
            (:func:`aero_specific_force`).
        aero: False: still air and no quadratic drag (:data:`NO_AIR`).
    """
    if aero:
        cf, sf = math.cos(x[6]), math.sin(x[6])
        ct, st = math.cos(x[7]), math.sin(x[7])
        c = dcm_from_trig(cf, sf, ct, st, math.cos(x[8]), math.sin(x[8]))
        f = air_specific_force(x, c, u[0], body[0], body[1], air)
        kinematics_dcm(x, c, (cf, sf, ct, st), (f[0] + u[4], f[1] + u[5], f[2] + u[6]), out)
    else:
        f = specific_force_body(x[3], x[4], x[5], u[0], body[0], body[1])
        kinematics(x, (f[0] + u[4], f[1] + u[5], f[2] + u[6]), out)
    if hold_rates:
        out[9], out[10], out[11] = 0.0, 0.0, 0.0
    else:
        out[9], out[10], out[11] = euler_equation(x[9], x[10], x[11], (u[1], u[2], u[3]), body)


@inline_kernel
def rk4_stages(
    derivative: Callable[[FloatArray, Any, FloatArray], None],
    args: Any,
    x: FloatArray,
    n: int,
    h: float,
    work: FloatArray,
) -> None:
    """One classical RK4 step of size ``h`` s of ``ẋ[:n] = derivative(x, args)`` on ``x[:n]``
    in place, ``args`` held: the RK4 stages of every model (:func:`rk4_step`, the strapdown
    drag model of :mod:`quadslam_env.models.strapdown`).

    ``derivative`` is a kernel called as ``derivative(x, args, out)``, writing ``ẋ[:n]`` into
    ``out``. numba compiles this function (inlined into its caller) for the kernel passed,
    so the derivative is a direct call, not one dispatched at run time. The entries of ``x``
    from ``n`` on are held over the step: every stage state carries them unchanged (inputs
    the derivative reads from the state, e.g. body rates held as an input).

    Args:
        derivative: The derivative kernel.
        args: Tuple of the derivative's other arguments.
        x: (m,) state; ``x[:n]`` is advanced, ``x[n:]`` held.
        n: Number of leading entries of ``x`` integrated.
        h: Step in s.
        work: (≥5, ≥m) scratch (rows: the four stages, the stage state).
    """
    k1, k2, k3, k4, tmp = work[0], work[1], work[2], work[3], work[4]
    half = 0.5 * h
    for j in range(n, x.shape[0]):
        tmp[j] = x[j]
    derivative(x, args, k1)
    for j in range(n):
        tmp[j] = x[j] + half * k1[j]
    derivative(tmp, args, k2)
    for j in range(n):
        tmp[j] = x[j] + half * k2[j]
    derivative(tmp, args, k3)
    for j in range(n):
        tmp[j] = x[j] + h * k3[j]
    derivative(tmp, args, k4)
    sixth = h / 6.0
    for j in range(n):
        x[j] = x[j] + sixth * (k1[j] + 2.0 * (k2[j] + k3[j]) + k4[j])


@inline_kernel
def _rigid_body_stage(x: FloatArray, args: Any, out: FloatArray) -> None:
    """:func:`rigid_body_derivative` with ``args = (u, body, hold_rates, air, aero)``, in the
    form :func:`rk4_stages` calls."""
    u, body, hold_rates, air, aero = args
    rigid_body_derivative(x, u, body, hold_rates, out, air, aero)


@kernel
def rk4_step(
    x: FloatArray,
    u: FloatArray,
    body: FloatArray,
    hold_rates: bool,
    h: float,
    work: FloatArray,
    air: AirTuple,
    aero: bool,
) -> None:
    """One classical RK4 step of size ``h`` s on ``x`` (12,) in place, input and wind held
    (:func:`rk4_stages` on :func:`rigid_body_derivative`).

    ``work`` is (5, 12) scratch; other arguments as in :func:`rigid_body_derivative`.
    """
    rk4_stages(_rigid_body_stage, (u, body, hold_rates, air, aero), x, STATE_DIM, h, work)


@kernel
def _specific_force_kernel(
    vel: FloatArray, thrust: FloatArray, mass: float, drag: float, out: FloatArray
) -> None:
    for i in range(vel.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = specific_force_body(
            vel[i, 0], vel[i, 1], vel[i, 2], thrust[i], mass, drag
        )


@kernel
def air_velocity_lanes(states: FloatArray, wind: FloatArray, out: FloatArray) -> None:
    """:func:`air_velocity_body` of B lanes: states (B, 12), wind (B, 3) in N, out (B, 3)."""
    for i in range(states.shape[0]):
        x = states[i]
        cf, sf = math.cos(x[6]), math.sin(x[6])
        ct, st = math.cos(x[7]), math.sin(x[7])
        c = dcm_from_trig(cf, sf, ct, st, math.cos(x[8]), math.sin(x[8]))
        va = air_velocity_body(x, c, wind[i, 0], wind[i, 1], wind[i, 2])
        out[i, 0], out[i, 1], out[i, 2] = va


# --------------------------------------------------------------------------------------------
# NumPy-facing API for one vehicle or a stack of them.
# --------------------------------------------------------------------------------------------


def lane_array(value: ArrayLike, n: int, width: int = 0) -> FloatArray:
    """Broadcast ``value`` to a fresh C-contiguous float array of (n,) or (n, width).

    The kernels are compiled for contiguous arrays; broadcasting views would compile again.
    """
    shape = (n,) if width == 0 else (n, width)
    out = np.empty(shape)
    out[...] = np.asarray(value, dtype=float)
    return out


def saturate_inputs(
    thrust: float, torque: ArrayLike, params: VehicleParams
) -> tuple[float, FloatArray]:
    """Clip thrust to ``[0, max_thrust]`` N and each torque to ``±max_torque`` N·m.

    Args:
        thrust: Commanded f_T in N. torque: (3,) commanded τ in N·m.
        params: Vehicle limits.

    Returns:
        ``(thrust, torque (3,))`` after saturation.
    """
    t = np.asarray(torque, dtype=float).reshape(3)
    f, tau = saturate(
        float(thrust),
        (float(t[0]), float(t[1]), float(t[2])),
        float(params.max_thrust),
        np.array(params.max_torque),
    )
    return f, np.array(tau)


def specific_force_lanes(
    vel_body: ArrayLike, thrust: ArrayLike, mass: float, drag: float
) -> FloatArray:
    """Specific force ``f_B = −(f_T/m) b3 − drag · v`` sensed by an accelerometer (B frame).

    Args:
        vel_body: (..., 3) body velocity in m/s, e.g. (3,), (B, 3) or (N, 3).
        thrust: f_T in N, a scalar or an array broadcastable to ``vel_body.shape[:-1]``.
        mass: m in kg. drag: Linear drag in 1/s.

    Returns:
        (..., 3) specific force in m/s².
    """
    vel = np.asarray(vel_body, dtype=float)
    flat = np.ascontiguousarray(vel.reshape(-1, 3))
    n = flat.shape[0]
    out = np.empty((n, 3))
    thrust_arr = np.asarray(thrust, dtype=float)
    if thrust_arr.shape == (n,) and thrust_arr.flags.c_contiguous:
        thrust_lanes = thrust_arr
    else:
        thrust_lanes = lane_array(np.broadcast_to(thrust_arr, vel.shape[:-1]).reshape(-1), n)
    _specific_force_kernel(flat, thrust_lanes, float(mass), float(drag), out)
    return out.reshape(vel.shape)


def specific_force(vel_body: ArrayLike, thrust: ArrayLike, params: VehicleParams) -> FloatArray:
    """:func:`specific_force_lanes` with the mass and drag of ``params``.

    Args:
        vel_body: (..., 3) body velocity in m/s.
        thrust: f_T in N, scalar or broadcastable to ``vel_body.shape[:-1]``.
        params: Vehicle parameters.

    Returns:
        (..., 3) specific force in m/s² (B frame).
    """
    return specific_force_lanes(vel_body, thrust, params.mass, params.drag)
