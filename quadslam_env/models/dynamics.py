"""Compatibility re-export: vehicle parameters and rigid-body dynamics.

Kept because modules elsewhere import these names from here; new code imports from
:mod:`quadslam_env.models.params`, :mod:`quadslam_env.models.rigid_body`,
:mod:`quadslam_env.models.integrators` and :mod:`quadslam_env.types`.
"""

from quadslam_env.models.integrators import rk4_integrate, state_derivative
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams, vehicle_preset
from quadslam_env.models.rigid_body import saturate_inputs, specific_force
from quadslam_env.types import GRAVITY, STATE_DIM

__all__ = [
    "GRAVITY",
    "STATE_DIM",
    "VEHICLE_PRESETS",
    "VehicleParams",
    "rk4_integrate",
    "saturate_inputs",
    "specific_force",
    "state_derivative",
    "vehicle_preset",
]
