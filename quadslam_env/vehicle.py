"""Vehicle simulator: holds the true state and integrates the dynamics over a control period."""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.dynamics import VehicleParams, _coeffs, rk4_steps, saturate_inputs
from quadslam_env.models.rotations import FloatArray, wrap_angle


class Vehicle:
    """True quadcopter state integrated with RK4 at a fixed physics substep.

    Inputs are saturated to the vehicle limits and held over the control period (zero-order
    hold); with ``actuator_tau > 0`` the applied inputs follow the command through an exact
    first-order lag per substep.

    Args:
        params: Vehicle parameters.
        physics_dt: Maximum RK4 substep in s (default 2 ms).
    """

    def __init__(self, params: VehicleParams, physics_dt: float) -> None:
        self.params = params
        self.physics_dt = physics_dt
        self._coeffs = _coeffs(params)
        self.state = np.zeros(12)
        self.applied_thrust = params.hover_thrust
        self.applied_torque = np.zeros(3)

    def reset(self, state: FloatArray) -> None:
        """Set the true state; the actuators start at hover thrust and zero torque."""
        self.state = np.array(state, dtype=float)
        self.applied_thrust = self.params.hover_thrust
        self.applied_torque = np.zeros(3)

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
        thrust, torque = saturate_inputs(thrust_cmd, torque_cmd, self.params)
        n_sub = max(1, math.ceil(duration / self.physics_dt - 1e-9))
        h = duration / n_sub
        x = self.state.tolist()
        # Trapezoid over the substep end points: half weight on the first and the last.
        p_sum, q_sum, r_sum = 0.5 * x[9], 0.5 * x[10], 0.5 * x[11]
        tau_lag = self.params.actuator_tau
        if tau_lag > 0.0:
            keep = math.exp(-h / tau_lag)
        else:
            f, t3 = thrust, (float(torque[0]), float(torque[1]), float(torque[2]))
        for _ in range(n_sub):
            if tau_lag > 0.0:
                self.applied_thrust = thrust + (self.applied_thrust - thrust) * keep
                self.applied_torque = torque + (self.applied_torque - torque) * keep
                f, t3 = self.applied_thrust, tuple(self.applied_torque.tolist())
            x = rk4_steps(x, f, t3, self._coeffs, h, 1)
            p_sum += x[9]
            q_sum += x[10]
            r_sum += x[11]
        if tau_lag <= 0.0:
            self.applied_thrust, self.applied_torque = thrust, torque
        # Keep roll and yaw in (-π, π] so long flights don't accumulate unbounded angles.
        x[6] = wrap_angle(x[6])
        x[8] = wrap_angle(x[8])
        self.state = np.array(x)
        return np.array([p_sum - 0.5 * x[9], q_sum - 0.5 * x[10], r_sum - 0.5 * x[11]]) / n_sub
