"""Vehicle simulator: true states of B quadcopters integrated over a control period.

:class:`VehicleBatch` holds (B, …) arrays and steps them with the compiled lane kernel
:func:`quadslam_env.models.integrators.vehicle_step_lanes`; :class:`Vehicle` is its one-lane
case with the scalar API of the single env. A vehicle with rotors (``params.rotors``) steps with
:func:`quadslam_env.models.integrators.vehicle_step_rotor_lanes` instead: the commanded thrust
and torque go through the inverse mixer and the motor lag (:mod:`quadslam_env.models.rotors`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from quadslam_env.models.integrators import vehicle_step_lanes, vehicle_step_rotor_lanes
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import air_velocity_lanes, lane_array, pack_bodies
from quadslam_env.types import STATE_DIM, VEL, FloatArray


def inertia_factor(scale: ArrayLike) -> FloatArray:
    """The factor on the row-major inertia J (9 entries) of an inertia scale per lane.

    One scale s of all axes gives ``J' = s J``; scales (s_x, s_y, s_z) of the body axes give
    ``J' = D^½ J D^½`` with ``D = diag(s)``: ``J'_ij = J_ij √(s_i s_j)``, so the diagonal
    scales by s_i and J' stays symmetric positive definite (``J'⁻¹`` is ``J⁻¹`` divided by the
    same factor).

    Args:
        scale: (k,) one scale per lane, or (k, 3) per body axis; > 0.

    Returns:
        (k, 1) or (k, 9), broadcasting against (k, 9) rows of J.
    """
    s = np.asarray(scale, dtype=float)
    if s.ndim == 1:
        return s[:, None]
    return np.sqrt(s[:, :, None] * s[:, None, :]).reshape(-1, 9)


class VehicleBatch:
    """True states of B quadcopters, RK4 at a fixed physics substep (seed 001 eq. 2–3).

    Inputs are saturated to the vehicle limits and held over the control period (zero-order
    hold); with ``actuator_tau > 0`` the applied inputs follow the command through an exact
    first-order lag per substep. Drag acts on the velocity relative to the air: with a wind
    (:attr:`wind_n`) or a quadratic drag (``params.drag_quadratic``) the kernel takes its
    aerodynamic path, otherwise the still-air model (docs/design.md §3).

    Attributes:
        state: (B, 12) true states ``(ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])``.
        applied_thrust: (B,) thrust acting on each body in N (after saturation and lag).
        applied_torque: (B, 3) torque acting on each body in N·m.
        wind_n: (B, 3) wind in N (m/s) held over the next step, or ``None`` (still air). The
            simulator sets it to its wind's array (:class:`quadslam_env.sim.wind.WindBatch`).
        rotor_speed: (B, 4) rotor speeds in rad/s (rotors 1–4 of
            :mod:`~quadslam_env.models.rotors`), or ``None`` for a vehicle without rotors.

    Args:
        params: Vehicle parameters (shared by all lanes).
        physics_dt: Maximum RK4 substep in s (default scenario: 2 ms).
        num_lanes: B.
    """

    def __init__(self, params: VehicleParams, physics_dt: float, num_lanes: int) -> None:
        self.params = params
        self.physics_dt = float(physics_dt)
        self.num_lanes = int(num_lanes)
        self.state = np.zeros((self.num_lanes, STATE_DIM))
        self.applied_thrust = np.full(self.num_lanes, params.hover_thrust)
        self.applied_torque = np.zeros((self.num_lanes, 3))
        b = self.num_lanes
        inertia, inertia_inv = np.array(params.inertia)[None], np.array(params.inertia_inv)[None]
        body = pack_bodies(float(params.mass), float(params.drag), inertia, inertia_inv)
        self._nominal_body = body[0].copy()
        self._bodies = np.tile(self._nominal_body, (b, 1))  # (B, 20) per-lane bodies
        self._hover_thrust = np.full(b, float(params.hover_thrust))
        self._all = np.ones(b, dtype=bool)
        self.wind_n: FloatArray | None = None
        self._drag_quadratic = np.array(params.drag_quadratic)
        self._quadratic = bool(np.any(self._drag_quadratic != 0.0))
        self._still_air = np.zeros((b, 3))
        self.rotor_speed: FloatArray | None = None
        rotors = params.rotors
        if rotors is not None:
            self._hover_speed = np.full(b, rotors.hover_speed(params.hover_thrust))
            self.rotor_speed = np.tile(self._hover_speed[:, None], (1, 4))
            self._mixer = np.array(rotors.mixer)
            self._mixer_inv = np.array(rotors.mixer_inv)
            k_f, tau = rotors.k_f, rotors.motor_tau
            coeffs = [k_f, rotors.thrust_min, rotors.thrust_max, tau, k_f]
            self._nominal_coeffs = np.array(coeffs, dtype=float)
            self._coeffs = np.tile(self._nominal_coeffs, (b, 1))  # (B, 5) per lane
        else:
            limits = [params.max_thrust, *params.max_torque, params.actuator_tau, 1.0]
            self._nominal_coeffs = np.array(limits, dtype=float)
            self._coeffs = np.tile(self._nominal_coeffs, (b, 1))  # (B, 6) per lane

    @property
    def lane_mass(self) -> FloatArray:
        """(B,) true mass of each lane in kg (the nominal mass times its drawn scale)."""
        return self._bodies[:, 0].copy()

    @property
    def lane_inertia(self) -> FloatArray:
        """(B, 3, 3) true inertia of each lane in kg·m²."""
        return self._bodies[:, 2:11].reshape(-1, 3, 3).copy()

    def set_scales(
        self,
        lanes: ArrayLike,
        mass: ArrayLike,
        inertia: ArrayLike,
        thrust: ArrayLike,
        lag: ArrayLike,
    ) -> None:
        """Set the true parameters of ``lanes`` (k,) to the nominal ones times the scales.

        Applies until the next call for those lanes (the simulator calls it at every reset
        with domain randomisation, :mod:`quadslam_env.sim.randomize`). Call before :meth:`reset`:
        the actuators start at the lane's own hover thrust.

        Args:
            lanes: (k,) lane indices.
            mass: (k,) scale of m, > 0.
            inertia: (k,) scale of J, or (k, 3) scales of its body axes
                (:func:`inertia_factor`; J⁻¹ scales by the inverse), > 0.
            thrust: (k,) scale of the thrust and torque produced for a command (collective:
                the gain on the saturated command; rotors: k_f and k_m), > 0.
            lag: (k,) scale of the actuator or motor time constant, ≥ 0.
        """
        idx = np.asarray(lanes, dtype=int).reshape(-1)
        ms, js = np.asarray(mass, dtype=float), np.asarray(inertia, dtype=float)
        ts, ls = np.asarray(thrust, dtype=float), np.asarray(lag, dtype=float)
        nominal = self._nominal_body
        self._bodies[idx, 0] = nominal[0] * ms
        factor = inertia_factor(js)
        self._bodies[idx, 2:11] = nominal[2:11] * factor
        self._bodies[idx, 11:20] = nominal[11:20] / factor
        self._hover_thrust[idx] = self.params.hover_thrust * ms
        c = self._nominal_coeffs
        if self.params.rotors is not None:
            self._coeffs[idx, 3] = c[3] * ls
            self._coeffs[idx, 4] = c[4] * ts
            rotors = self.params.rotors
            need = self._hover_thrust[idx] / ts  # the nominal-k_f thrust of the true hover
            self._hover_speed[idx] = [rotors.hover_speed(float(f)) for f in need]
        else:
            self._coeffs[idx, 4] = c[4] * ls
            self._coeffs[idx, 5] = c[5] * ts

    def reset(self, lanes: ArrayLike, states: ArrayLike) -> None:
        """Set the true states of ``lanes``; their actuators start at hover thrust, zero torque
        (rotors: all four at the hover speed).

        Args:
            lanes: (k,) int lane indices.
            states: (k, 12) initial states.
        """
        idx = np.asarray(lanes, dtype=int).reshape(-1)
        self.state[idx] = np.asarray(states, dtype=float).reshape(idx.size, STATE_DIM)
        self.applied_thrust[idx] = self._hover_thrust[idx]
        self.applied_torque[idx] = 0.0
        if self.rotor_speed is not None:
            self.rotor_speed[idx] = self._hover_speed[idx, None]

    def step(
        self,
        thrust_cmd: ArrayLike,
        torque_cmd: ArrayLike,
        duration: float,
        active: np.ndarray | None = None,
    ) -> FloatArray:
        """Advance the ``active`` lanes by ``duration`` seconds; other lanes are untouched.

        Args:
            thrust_cmd: (B,) commanded thrust in N (saturated to [0, max_thrust]; with rotors
                the inverse mixer and the rotor limits apply instead).
            torque_cmd: (B, 3) commanded torque in N·m (saturated per axis; rotors: as above).
            duration: Control period in s.
            active: (B,) bool lanes to step (default: all).

        Returns:
            (B, 3) body rates averaged over the period (trapezoid over substeps), rad/s: what
            an integrating IMU reports for this sample; zero rows for inactive lanes.
        """
        b = self.num_lanes
        mask = self._all if active is None else np.ascontiguousarray(active, dtype=bool)
        mean_rates = np.zeros((b, 3))
        wind = self._still_air if self.wind_n is None else self.wind_n
        aero = self.wind_n is not None or self._quadratic
        if self.rotor_speed is not None:
            vehicle_step_rotor_lanes(
                self.state,
                self.rotor_speed,
                self.applied_thrust,
                self.applied_torque,
                lane_array(thrust_cmd, b),
                lane_array(torque_cmd, b, 3),
                mask,
                self._bodies,
                self._mixer,
                self._mixer_inv,
                self._coeffs,
                float(duration),
                self.physics_dt,
                mean_rates,
                wind,
                self._drag_quadratic,
                aero,
            )
            return mean_rates
        vehicle_step_lanes(
            self.state,
            self.applied_thrust,
            self.applied_torque,
            lane_array(thrust_cmd, b),
            lane_array(torque_cmd, b, 3),
            mask,
            self._bodies,
            self._coeffs,
            float(duration),
            self.physics_dt,
            mean_rates,
            wind,
            self._drag_quadratic,
            aero,
        )
        return mean_rates

    def air_velocity(self) -> FloatArray:
        """(B, 3) velocity relative to the air ``v − C_NBᵀ w`` in B, m/s (what the drag and
        the accelerometer feel); in still air a view of the state's v."""
        if self.wind_n is None:
            return self.state[:, VEL]
        out = np.empty((self.num_lanes, 3))
        air_velocity_lanes(self.state, self.wind_n, out)
        return out


class Vehicle:
    """One quadcopter: the one-lane case of :class:`VehicleBatch` with scalar inputs.

    ``state``, ``applied_thrust``, ``applied_torque`` and ``rotor_speed`` (4,) rad/s or ``None``
    are plain attributes replaced by
    fresh objects on every step (callers may keep references to earlier states) and read
    back into the batch before stepping (callers may assign them).

    Args:
        params: Vehicle parameters.
        physics_dt: Maximum RK4 substep in s (default 2 ms).
    """

    _LANE0 = np.zeros(1, dtype=int)

    def __init__(self, params: VehicleParams, physics_dt: float) -> None:
        self.params = params
        self.physics_dt = physics_dt
        self._batch = VehicleBatch(params, physics_dt, 1)
        self.state = np.zeros(STATE_DIM)
        self.applied_thrust = params.hover_thrust
        self.applied_torque = np.zeros(3)
        self.rotor_speed: FloatArray | None = self._rotor_row()

    def _rotor_row(self) -> FloatArray | None:
        speed = self._batch.rotor_speed
        return None if speed is None else speed[0].copy()

    def reset(self, state: FloatArray) -> None:
        """Set the true state (12,); the actuators start at hover thrust and zero torque."""
        self._batch.reset(self._LANE0, state)
        self._read_back()

    def _read_back(self) -> None:
        batch = self._batch
        self.state = batch.state[0].copy()
        self.applied_thrust = float(batch.applied_thrust[0])
        self.applied_torque = batch.applied_torque[0].copy()
        self.rotor_speed = self._rotor_row()

    def step(self, thrust_cmd: float, torque_cmd: FloatArray, duration: float) -> FloatArray:
        """Advance the true state by ``duration`` seconds.

        Args:
            thrust_cmd: Commanded thrust in N (saturated to [0, max_thrust]).
            torque_cmd: (3,) commanded torque in N·m (saturated per axis).
            duration: Control period in s.

        Returns:
            (3,) body rates averaged over the period (trapezoid over substeps), rad/s: what an
            integrating IMU reports for this sample.
        """
        batch = self._batch
        batch.state[0] = self.state
        batch.applied_thrust[0] = self.applied_thrust
        batch.applied_torque[0] = self.applied_torque
        if batch.rotor_speed is not None and self.rotor_speed is not None:
            batch.rotor_speed[0] = self.rotor_speed
        mean_rates = batch.step(thrust_cmd, np.asarray(torque_cmd, dtype=float)[None], duration)
        self._read_back()
        return mean_rates[0]
