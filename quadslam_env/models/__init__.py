"""Pure models (layer 1): frames, rigid-body dynamics, integrators, IMU noise, the LiDAR model.

No RNG, no state. The per-vehicle math is numba kernels lifted over a leading batch axis
(docs/design.md §9); the modules:

- :mod:`~quadslam_env.models.frames`: C_NB, elementary rotations, ∂C/∂Λ, D(Λ), angle wrap.
- :mod:`~quadslam_env.models.params`: vehicle parameters and presets.
- :mod:`~quadslam_env.models.rigid_body`: seed 001 eq. 2–3, specific force and drag on the
  air-relative velocity, saturation, RK4 step.
- :mod:`~quadslam_env.models.integrators`: RK4/Euler over lanes (simulator and FastSLAM).
- :mod:`~quadslam_env.models.imu_noise`: noise density → σ, exact Gauss–Markov discretisation.
- :mod:`~quadslam_env.models.lidar`: measurement, inverse and Jacobians (per-landmark kernels,
  gufuncs over leading axes).
- :mod:`~quadslam_env.models.linalg`: stacked small-matrix helpers.
- :mod:`~quadslam_env.models.wind`: Dryden turbulence (MIL-F-8785C), exact discretisation.
"""

from quadslam_env.models.frames import (
    dcm_euler_partials,
    dcm_from_euler,
    dcm_from_euler_batch,
    euler_from_dcm,
    euler_rate_matrix,
    rotation_angle_between,
    skew,
    wrap_angle,
)
from quadslam_env.models.integrators import (
    RigidBodyLanes,
    kinematic_derivative,
    kinematic_propagate,
    rk4_integrate,
    state_derivative,
)
from quadslam_env.models.lidar import (
    body_from_measure,
    inverse_jacobians,
    lidar_inverse,
    lidar_jacobians,
    lidar_measure,
    lidar_measure_jacobian,
    measure_inverse_jacobian,
    measurement_residual,
)
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams, vehicle_preset
from quadslam_env.models.rigid_body import saturate_inputs, specific_force, specific_force_lanes
from quadslam_env.types import GRAVITY, STATE_DIM

__all__ = [
    "GRAVITY",
    "STATE_DIM",
    "VEHICLE_PRESETS",
    "RigidBodyLanes",
    "VehicleParams",
    "body_from_measure",
    "dcm_euler_partials",
    "dcm_from_euler",
    "dcm_from_euler_batch",
    "euler_from_dcm",
    "euler_rate_matrix",
    "inverse_jacobians",
    "kinematic_derivative",
    "kinematic_propagate",
    "lidar_inverse",
    "lidar_jacobians",
    "lidar_measure",
    "lidar_measure_jacobian",
    "measure_inverse_jacobian",
    "measurement_residual",
    "rk4_integrate",
    "rotation_angle_between",
    "saturate_inputs",
    "skew",
    "specific_force",
    "specific_force_lanes",
    "state_derivative",
    "vehicle_preset",
    "wrap_angle",
]
