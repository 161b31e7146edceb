"""Particle process models of the FastSLAM filters: the shared rigid-body kernels over N particles.

Both filters propagate their (N, 12) particle array with
:class:`quadslam_env.models.integrators.RigidBodyLanes` — the kernels that also step the
simulated vehicle — so the filter model is the simulator's model with (possibly mismatched)
nominal parameters.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from quadslam_env.models.integrators import RigidBodyLanes, kinematic_derivative
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import specific_force_lanes
from quadslam_env.types import FloatArray


class DynamicsModel(RigidBodyLanes):
    """Quadcopter dynamics over particles with (possibly mismatched) nominal parameters.

    Args:
        vehicle: Nominal vehicle parameters (mass kg, inertia kg·m², drag 1/s).
        mass_scale: Factor on the mass used by the filter model.
        inertia_scale: Factor on the inertia used by the filter model (seed 000 Fig. 14 uses
            2.5, i.e. +150 %).
    """

    def __init__(
        self, vehicle: VehicleParams, mass_scale: float = 1.0, inertia_scale: float = 1.0
    ) -> None:
        inertia = np.array(vehicle.inertia, dtype=float) * inertia_scale
        super().__init__(float(vehicle.mass) * mass_scale, float(vehicle.drag), inertia)

    def specific_force(self, x: FloatArray, thrust: float) -> FloatArray:
        """``f_B = −(f_T/m) b3 − drag v`` (..., 3) in m/s² for states (..., 12)."""
        return specific_force_lanes(x[..., 3:6], thrust, self.mass, self.drag)


def dynamics_derivative_batch(
    x: FloatArray, thrust: float, torque: Any, vehicle: VehicleParams
) -> FloatArray:
    """:func:`quadslam_env.models.state_derivative` for states (..., 12), nominal parameters."""
    return DynamicsModel(vehicle).derivative(
        np.asarray(x, dtype=float), float(thrust), np.asarray(torque, dtype=float).reshape(3)
    )


kinematic_derivative_batch = kinematic_derivative
"""Strapdown kinematics of the kinematic filter (an alias kept for the FastSLAM API)."""
