"""Pure models (layer 1): rotations, rigid-body dynamics, the LiDAR model. No RNG, no state."""

from quadslam_env.models.dynamics import (
    GRAVITY,
    STATE_DIM,
    VEHICLE_PRESETS,
    VehicleParams,
    rk4_integrate,
    saturate_inputs,
    specific_force,
    state_derivative,
    vehicle_preset,
)
from quadslam_env.models.lidar import (
    body_from_measure,
    inverse_jacobians,
    lidar_inverse,
    lidar_jacobians,
    lidar_measure,
    measurement_residual,
)
from quadslam_env.models.rotations import (
    dcm_euler_partials,
    dcm_from_euler,
    dcm_from_euler_batch,
    euler_from_dcm,
    euler_rate_matrix,
    rotation_angle_between,
    skew,
    wrap_angle,
)

__all__ = [
    "GRAVITY",
    "STATE_DIM",
    "VEHICLE_PRESETS",
    "VehicleParams",
    "body_from_measure",
    "dcm_euler_partials",
    "dcm_from_euler",
    "dcm_from_euler_batch",
    "euler_from_dcm",
    "euler_rate_matrix",
    "inverse_jacobians",
    "lidar_inverse",
    "lidar_jacobians",
    "lidar_measure",
    "measurement_residual",
    "rk4_integrate",
    "rotation_angle_between",
    "saturate_inputs",
    "skew",
    "specific_force",
    "state_derivative",
    "vehicle_preset",
    "wrap_angle",
]
