"""RK4/Euler over a leading lane axis: the simulator's physics step and FastSLAM's propagation.

The lane kernels loop the single-vehicle kernels of :mod:`quadslam_env.models.rigid_body` over
B lanes (vehicles of a vector env, or N particles of FastSLAM); the NumPy-facing functions at the
bottom broadcast their inputs to lanes and call them. Kernels are ``@njit(cache=True)`` without
``fastmath``, so lane i of a B-lane call equals a one-lane call bit for bit.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import (
    INPUT_DIM,
    NO_AIR,
    AirTuple,
    pack_bodies,
    rigid_body_derivative,
    rk4_step,
    saturate,
    substep_count,
)
from quadslam_env.models.rotors import allocate, motor_lag, rotor_wrench
from quadslam_env.types import STATE_DIM, FloatArray


@inline_kernel
def _lane_air(wind: FloatArray, drag_quadratic: FloatArray, i: int, aero: bool) -> AirTuple:
    """Lane ``i``'s air for :func:`~quadslam_env.models.rigid_body.rk4_step`: its wind (N,
    m/s) and the quadratic drag coefficients, or still air without ``aero``."""
    if not aero:
        return NO_AIR
    cq = drag_quadratic
    return (wind[i, 0], wind[i, 1], wind[i, 2], cq[0], cq[1], cq[2])


@inline_kernel
def _end_period(
    x: FloatArray,
    p_sum: float,
    q_sum: float,
    r_sum: float,
    n_sub: int,
    mean_rates_out: FloatArray,
    i: int,
) -> None:
    """End lane ``i``'s control period: roll and yaw wrapped to (-π, π] (long flights must not
    accumulate unbounded angles) and the rates' trapezoid over the substep end points (the sums
    hold half the first point and every later one) into ``mean_rates_out[i]``."""
    x[6] = wrap_pi(x[6])
    x[8] = wrap_pi(x[8])
    mean_rates_out[i, 0] = (p_sum - 0.5 * x[9]) / n_sub
    mean_rates_out[i, 1] = (q_sum - 0.5 * x[10]) / n_sub
    mean_rates_out[i, 2] = (r_sum - 0.5 * x[11]) / n_sub


@kernel
def vehicle_step_lanes(
    states: FloatArray,
    applied_thrust: FloatArray,
    applied_torque: FloatArray,
    thrust_cmd: FloatArray,
    torque_cmd: FloatArray,
    active: np.ndarray,
    bodies: FloatArray,
    actuators: FloatArray,
    duration: float,
    physics_dt: float,
    mean_rates_out: FloatArray,
    wind: FloatArray,
    drag_quadratic: FloatArray,
    aero: bool,
) -> None:
    """Advance every active vehicle lane by ``duration`` s (the simulator's physics step).

    Per lane: saturate the command to the (nominal) limits and multiply it by the lane's
    actuator gain (the thrust and torque the actuators produce for it), then
    ``n = substep_count(duration, physics_dt)`` RK4 substeps with the input held (zero-order
    hold) or, with ``actuator_tau > 0``, following the command through an exact first-order lag
    updated at the start of each substep; the lane's wind is held over the period. Roll and
    yaw are wrapped to (-π, π] at the end. Inactive lanes are not touched. Every parameter is
    per lane (the nominal vehicle: the same row in every lane, gain 1).

    Args:
        states: (B, 12) true states, updated in place.
        applied_thrust: (B,) thrust acting on the body in N, updated in place.
        applied_torque: (B, 3) torque acting on the body in N·m, updated in place.
        thrust_cmd: (B,) commanded thrust in N. torque_cmd: (B, 3) commanded torque in N·m.
        active: (B,) bool, lanes to step.
        bodies: (B, 20) rigid-body parameters per lane
            (:func:`~quadslam_env.models.rigid_body.pack_bodies`: m kg, drag 1/s, J, J⁻¹).
        actuators: (B, 6) per lane ``(max_thrust [N], max_torque (3) [N·m], actuator_tau [s]
            (0 = no lag), gain [-])``.
        duration: Control period in s. physics_dt: Maximum RK4 substep in s.
        mean_rates_out: (B, 3) body rates averaged over the period (trapezoid over the
            substep end points), rad/s — what an integrating gyro reports; active rows only.
        wind: (B, 3) wind in N, m/s (read only with ``aero``).
        drag_quadratic: (3,) quadratic drag coefficients c_q per body axis, 1/m.
        aero: Drag on the air-relative velocity plus the quadratic drag
            (:func:`~quadslam_env.models.rigid_body.aero_specific_force`); False: still air,
            no quadratic drag, the model without wind.
    """
    n_sub = substep_count(duration, physics_dt)
    h = duration / n_sub
    u = np.zeros(INPUT_DIM)  # (f_T, τ, a = 0)
    work = np.empty((5, STATE_DIM))
    for i in range(states.shape[0]):
        if not active[i]:
            continue
        x, body, act = states[i], bodies[i], actuators[i]
        actuator_tau, gain = act[4], act[5]
        lag = actuator_tau > 0.0
        keep = math.exp(-h / actuator_tau) if lag else 0.0
        cmd_tau = (torque_cmd[i, 0], torque_cmd[i, 1], torque_cmd[i, 2])
        thrust, sat = saturate(thrust_cmd[i], cmd_tau, act[0], act[1:4])
        thrust = gain * thrust
        tau = (gain * sat[0], gain * sat[1], gain * sat[2])
        air = _lane_air(wind, drag_quadratic, i, aero)
        # Trapezoid over the substep end points: half weight on the first and the last.
        p_sum, q_sum, r_sum = 0.5 * x[9], 0.5 * x[10], 0.5 * x[11]
        u[0], u[1], u[2], u[3] = thrust, tau[0], tau[1], tau[2]
        for _ in range(n_sub):
            if lag:
                applied_thrust[i] = thrust + (applied_thrust[i] - thrust) * keep
                for j in range(3):
                    applied_torque[i, j] = tau[j] + (applied_torque[i, j] - tau[j]) * keep
                u[0] = applied_thrust[i]
                u[1], u[2], u[3] = applied_torque[i, 0], applied_torque[i, 1], applied_torque[i, 2]
            rk4_step(x, u, body, False, h, work, air, aero)
            p_sum += x[9]
            q_sum += x[10]
            r_sum += x[11]
        if not lag:
            applied_thrust[i] = thrust
            applied_torque[i, 0], applied_torque[i, 1], applied_torque[i, 2] = tau
        _end_period(x, p_sum, q_sum, r_sum, n_sub, mean_rates_out, i)


@kernel
def vehicle_step_rotor_lanes(
    states: FloatArray,
    rotor_speed: FloatArray,
    applied_thrust: FloatArray,
    applied_torque: FloatArray,
    thrust_cmd: FloatArray,
    torque_cmd: FloatArray,
    active: np.ndarray,
    bodies: FloatArray,
    mixer: FloatArray,
    mixer_inv: FloatArray,
    rotor_coeffs: FloatArray,
    duration: float,
    physics_dt: float,
    mean_rates_out: FloatArray,
    wind: FloatArray,
    drag_quadratic: FloatArray,
    aero: bool,
) -> None:
    """:func:`vehicle_step_lanes` of a vehicle with rotors (:mod:`~quadslam_env.models.rotors`).

    Per lane: the commanded wrench goes through the inverse mixer with the rotor limits
    (:func:`~quadslam_env.models.rotors.allocate`) to rotor speed commands
    ``ω_cmd = √(T/k_f)``, held over the period; at the start of each of the n RK4 substeps the
    rotor speeds follow them through the exact motor lag and the wrench ``M k_f ω²`` is held
    over the substep. No collective saturation: the rotor limits bound the wrench. The speed
    commands use the nominal k_f (what the motor controller believes) and the wrench the
    lane's true one (k_f and k_m scaled together, so the mixer is unchanged).

    Args:
        states: (B, 12) true states, updated in place.
        rotor_speed: (B, 4) rotor speeds in rad/s, updated in place.
        applied_thrust: (B,) thrust of the rotors in N after the step (updated in place).
        applied_torque: (B, 3) torque of the rotors in N·m in B after the step.
        thrust_cmd: (B,) commanded thrust in N. torque_cmd: (B, 3) commanded torque in N·m.
        active: (B,) bool, lanes to step.
        bodies: (B, 20) rigid-body parameters per lane
            (:func:`~quadslam_env.models.rigid_body.pack_bodies`).
        mixer, mixer_inv: (4, 4) M and M⁻¹.
        rotor_coeffs: (B, 5) per lane ``(k_f [N/(rad/s)²] nominal, T_min [N], T_max [N],
            τ_m [s], k_f [N/(rad/s)²] true)``.
        duration, physics_dt, mean_rates_out, wind, drag_quadratic, aero: as in
            :func:`vehicle_step_lanes`.
    """
    n_sub = substep_count(duration, physics_dt)
    h = duration / n_sub
    u = np.zeros(INPUT_DIM)
    work = np.empty((5, STATE_DIM))
    cmd = np.empty(4)
    for i in range(states.shape[0]):
        if not active[i]:
            continue
        x, body, c = states[i], bodies[i], rotor_coeffs[i]
        k_f, t_min, t_max, tau, k_true = c[0], c[1], c[2], c[3], c[4]
        keep = math.exp(-h / tau) if tau > 0.0 else 0.0
        w_cmd = (thrust_cmd[i], torque_cmd[i, 0], torque_cmd[i, 1], torque_cmd[i, 2])
        allocate(w_cmd, mixer_inv, t_min, t_max, cmd)
        for j in range(4):
            cmd[j] = math.sqrt(cmd[j] / k_f)
        air = _lane_air(wind, drag_quadratic, i, aero)
        p_sum, q_sum, r_sum = 0.5 * x[9], 0.5 * x[10], 0.5 * x[11]
        speed = rotor_speed[i]
        for _ in range(n_sub):
            motor_lag(speed, cmd, keep)
            u[0], u[1], u[2], u[3] = rotor_wrench(speed, mixer, k_true)
            rk4_step(x, u, body, False, h, work, air, aero)
            p_sum += x[9]
            q_sum += x[10]
            r_sum += x[11]
        applied_thrust[i] = u[0]
        applied_torque[i, 0], applied_torque[i, 1], applied_torque[i, 2] = u[1], u[2], u[3]
        _end_period(x, p_sum, q_sum, r_sum, n_sub, mean_rates_out, i)


@kernel
def propagate_lanes(
    states: FloatArray,
    inputs: FloatArray,
    bodies: FloatArray,
    hold_rates: bool,
    h: float,
    n_steps: int,
    use_rk4: bool,
    air: AirTuple,
    aero: bool,
) -> None:
    """``n_steps`` explicit steps of size ``h`` s for N lanes in place (FastSLAM particles).

    No saturation, no actuator lag, no angle wrapping: the model as written.

    Args:
        states: (N, 12) states, advanced in place.
        inputs: (M, 7) inputs ``u = (f_T, τ, a)`` (see :func:`rigid_body_derivative`), held;
            M = 1 (one input for all lanes, e.g. FastSLAM's particles) or N (per lane).
        bodies: (K, 20) parameters from :func:`pack_bodies`, K = 1 (shared) or N (per lane).
        hold_rates: ``ω̇ = 0`` (strapdown model) instead of Euler's equation.
        use_rk4: Classical RK4 if True, forward Euler otherwise.
        air, aero: The air all lanes fly in, as in
            :func:`~quadslam_env.models.rigid_body.rigid_body_derivative` (a known wind).
    """
    work = np.empty((5, STATE_DIM))
    shared, shared_u = bodies.shape[0] == 1, inputs.shape[0] == 1
    for i in range(states.shape[0]):
        x, u, body = states[i], inputs[0 if shared_u else i], bodies[0 if shared else i]
        for _ in range(n_steps):
            if use_rk4:
                rk4_step(x, u, body, hold_rates, h, work, air, aero)
            else:
                rigid_body_derivative(x, u, body, hold_rates, work[0], air, aero)
                for j in range(STATE_DIM):
                    x[j] = x[j] + h * work[0, j]


@kernel
def derivative_lanes(
    states: FloatArray, inputs: FloatArray, bodies: FloatArray, hold_rates: bool, out: FloatArray
) -> None:
    """:func:`rigid_body_derivative` for N lanes into ``out`` (N, 12).

    Arguments as in :func:`propagate_lanes`.
    """
    shared, shared_u = bodies.shape[0] == 1, inputs.shape[0] == 1
    for i in range(states.shape[0]):
        u = inputs[0 if shared_u else i]
        body = bodies[0 if shared else i]
        rigid_body_derivative(states[i], u, body, hold_rates, out[i], NO_AIR, False)


# --------------------------------------------------------------------------------------------
# NumPy-facing API
# --------------------------------------------------------------------------------------------


def lane_inputs(n: int, thrust: ArrayLike, torque: ArrayLike, accel: ArrayLike = 0.0) -> FloatArray:
    """Kernel inputs ``(f_T [N], τ [N·m] (3), a [m/s²] (3))`` broadcast from the parts.

    Args:
        n: Number of lanes.
        thrust: Scalar or (n,). torque: (3,) or (n, 3). accel: Scalar, (3,) or (n, 3).

    Returns:
        (1, 7) if no part has a lane axis (the kernels share that row), else (n, 7).
    """
    per_lane = np.ndim(thrust) > 0 or np.ndim(torque) > 1 or np.ndim(accel) > 1
    u = np.empty((n if per_lane else 1, INPUT_DIM))
    u[:, 0] = thrust
    u[:, 1:4] = torque
    u[:, 4:7] = accel
    return u


class RigidBodyLanes:
    """The rigid-body model of the kernels with fixed parameters, applied to N lanes at once.

    Args:
        mass: m in kg. drag: Linear drag in 1/s.
        inertia: J in kg·m² (B frame): (3, 3) shared by all lanes or (N, 3, 3) per lane.
        hold_rates: ``ω̇ = 0`` instead of Euler's equation (the strapdown model, where ω is the
            gyro input held over the step).
    """

    def __init__(
        self, mass: float, drag: float, inertia: ArrayLike, hold_rates: bool = False
    ) -> None:
        self.mass = float(mass)
        self.drag = float(drag)
        self.hold_rates = bool(hold_rates)
        self.set_inertia(inertia)

    @classmethod
    def from_params(cls, params: VehicleParams) -> RigidBodyLanes:
        """The model of a vehicle preset or custom :class:`VehicleParams`."""
        return cls(params.mass, params.drag, params.inertia)

    def set_inertia(self, inertia: ArrayLike) -> None:
        """Replace J: (3, 3), (N, 3, 3), or (3,) principal moments (a diagonal J), kg·m²."""
        J = np.asarray(inertia, dtype=float)
        self.inertia = np.diag(J) if J.ndim == 1 else J.copy()
        self.inertia_inv = np.linalg.inv(self.inertia)
        stack = (self.inertia.reshape(-1, 3, 3), self.inertia_inv.reshape(-1, 3, 3))
        self._bodies = pack_bodies(self.mass, self.drag, *stack)  # (K, 20), packed once

    def derivative(
        self, states: ArrayLike, thrust: ArrayLike, torque: ArrayLike, accel: ArrayLike = 0.0
    ) -> FloatArray:
        """Time derivative of states (..., 12) (seed 001 eq. 2; seed 000 eq. 1–4).

        Args:
            states: (..., 12) states ``(ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])``.
            thrust: f_T in N, scalar or (N,) for N states (used as given, no saturation).
            torque: τ in N·m, (3,) or (N, 3).
            accel: Extra specific force in B, m/s²: scalar, (3,) or (N, 3).

        Returns:
            (..., 12) ``ẋ``.
        """
        x = np.asarray(states, dtype=float)
        flat = np.ascontiguousarray(x.reshape(-1, STATE_DIM))
        out = np.empty(flat.shape)
        u = lane_inputs(flat.shape[0], thrust, torque, accel)
        derivative_lanes(flat, u, self._bodies, self.hold_rates, out)
        return out.reshape(x.shape)

    def propagate(
        self,
        states: ArrayLike,
        thrust: ArrayLike,
        torque: ArrayLike,
        h: float,
        n_steps: int = 1,
        method: str = "rk4",
        accel: ArrayLike = 0.0,
        air: AirTuple | None = None,
    ) -> FloatArray:
        """``n_steps`` explicit steps of size ``h`` s with the inputs held.

        Args:
            states: (N, 12) initial states (not modified).
            thrust, torque, accel: As in :meth:`derivative`.
            h: Step in s. n_steps: Number of steps.
            method: ``"rk4"`` (classical) or ``"euler"`` (forward).
            air: ``(w (3) m/s in N, c_q (3) 1/m)``: the drag on the air-relative velocity in
                a known wind w, plus the quadratic drag (the simulator's drag,
                :func:`~quadslam_env.models.rigid_body.aero_specific_force`); ``None``: still
                air, no quadratic drag.

        Returns:
            (N, 12) fresh array of final states (no saturation, angles not wrapped).
        """
        out = np.array(states, dtype=float).reshape(-1, STATE_DIM)
        u = lane_inputs(out.shape[0], thrust, torque, accel)
        args = (self._bodies, self.hold_rates, float(h), int(n_steps), method == "rk4")
        propagate_lanes(out, u, *args, NO_AIR if air is None else air, air is not None)
        return out


STRAPDOWN = RigidBodyLanes(mass=1.0, drag=0.0, inertia=np.eye(3), hold_rates=True)
"""Strapdown kinematics: no thrust (the input ``a`` is the specific force), ω held; the mass
and inertia are never used."""


def kinematic_derivative(states: ArrayLike, accel: ArrayLike) -> FloatArray:
    """Strapdown kinematics for states (..., 12) whose ω slot holds the gyro input.

    ``ρ̇ = C_NB v``, ``v̇ = −ω×v + C_NBᵀ g n3 + a``, ``Λ̇ = D(Λ) ω``, ``ω̇ = 0``: the rigid-body
    kinematics with the measured specific force ``a`` (..., 3) in m/s² (B) as input and no
    thrust, drag or Euler equation (seed 000 §IV-B's kinematic FastSLAM).
    """
    return STRAPDOWN.derivative(states, 0.0, 0.0, np.asarray(accel, dtype=float).reshape(-1, 3))


def kinematic_propagate(states: ArrayLike, accel: ArrayLike, h: float, method: str) -> FloatArray:
    """One step of :func:`kinematic_derivative` of size ``h`` s for (N, 12) states.

    Args:
        states: (N, 12) states, ω slot = input rates in rad/s (held).
        accel: (N, 3) or (3,) specific force input in m/s² (B).
        h: Step in s. method: ``"rk4"`` or ``"euler"``.

    Returns:
        (N, 12) fresh array.
    """
    return STRAPDOWN.propagate(states, 0.0, 0.0, h, 1, method, accel)


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
    x = np.asarray(state, dtype=float).reshape(STATE_DIM)
    return RigidBodyLanes.from_params(params).derivative(x, thrust, torque)


def rk4_integrate(
    state: ArrayLike,
    thrust: float,
    torque: ArrayLike,
    params: VehicleParams,
    duration: float,
    substep: float,
) -> FloatArray:
    """Integrate the dynamics with classical RK4 over ``duration`` with fixed substeps.

    Inputs are held constant (zero-order hold), not saturated; angles are not wrapped.
    ``duration`` is split into :func:`~quadslam_env.models.rigid_body.substep_count` equal
    substeps.

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
    n_sub = substep_count(float(duration), float(substep))
    x = np.asarray(state, dtype=float).reshape(1, STATE_DIM)
    model = RigidBodyLanes.from_params(params)
    return model.propagate(x, thrust, torque, float(duration) / n_sub, n_sub)[0]
