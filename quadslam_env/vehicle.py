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
from quadslam_env.types import STATE_DIM, FloatArray


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
            simulator sets it to its wind's array (:class:`quadslam_env.wind.WindBatch`).
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
        # Writable contiguous copies: the kernel is compiled for one array type.
        self._inertia = np.array(params.inertia)
        self._inertia_inv = np.array(params.inertia_inv)
        self._max_torque = np.array(params.max_torque)
        self._all = np.ones(self.num_lanes, dtype=bool)
        self.wind_n: FloatArray | None = None
        self._drag_quadratic = np.array(params.drag_quadratic)
        self._quadratic = bool(np.any(self._drag_quadratic != 0.0))
        self._still_air = np.zeros((self.num_lanes, 3))
        self.rotor_speed: FloatArray | None = None
        rotors = params.rotors
        if rotors is not None:
            self._hover_speed = rotors.hover_speed(params.hover_thrust)
            self.rotor_speed = np.full((self.num_lanes, 4), self._hover_speed)
            self._body = pack_bodies(
                float(params.mass), float(params.drag), self._inertia[None], self._inertia_inv[None]
            )[0]
            self._mixer = np.array(rotors.mixer)
            self._mixer_inv = np.array(rotors.mixer_inv)
            self._rotor_coeffs = np.array(
                [rotors.k_f, rotors.thrust_min, rotors.thrust_max, rotors.motor_tau]
            )

    def reset(self, lanes: ArrayLike, states: ArrayLike) -> None:
        """Set the true states of ``lanes``; their actuators start at hover thrust, zero torque
        (rotors: all four at the hover speed).

        Args:
            lanes: (k,) int lane indices.
            states: (k, 12) initial states.
        """
        idx = np.asarray(lanes, dtype=int).reshape(-1)
        self.state[idx] = np.asarray(states, dtype=float).reshape(idx.size, STATE_DIM)
        self.applied_thrust[idx] = self.params.hover_thrust
        self.applied_torque[idx] = 0.0
        if self.rotor_speed is not None:
            self.rotor_speed[idx] = self._hover_speed

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
        b, p = self.num_lanes, self.params
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
                self._body,
                self._mixer,
                self._mixer_inv,
                self._rotor_coeffs,
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
            float(p.mass),
            float(p.drag),
            self._inertia,
            self._inertia_inv,
            float(p.max_thrust),
            self._max_torque,
            float(p.actuator_tau),
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
            return self.state[:, 3:6]
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
