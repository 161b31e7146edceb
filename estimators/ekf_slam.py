"""EKF-SLAM for a quadcopter with an IMU and a range–bearing LiDAR (seed 001 §2.3).

The implementation lives in :mod:`estimators.ekf` (batched over lanes, numba kernels) and the
process model in :mod:`quadslam_env.models.strapdown`; this module is the name
:mod:`estimators.base` imports for ``"ekf_slam"`` and keeps the public names importable.
"""

from estimators.ekf import BIAS_DIM, EkfSlam, EkfSlamBatch
from quadslam_env.models.strapdown import process_derivative, process_jacobians
from quadslam_env.types import POSE_DIM

__all__ = [
    "BIAS_DIM",
    "POSE_DIM",
    "EkfSlam",
    "EkfSlamBatch",
    "process_derivative",
    "process_jacobians",
]
