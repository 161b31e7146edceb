"""EKF-SLAM of seed 001 §2.3 (docs/design.md §5, §9), batched over lanes and compiled with numba.

* :mod:`estimators.ekf.filter` — :class:`EkfSlamBatch` (state, reset, predict, estimate),
  registered as the native batched ``"ekf_slam"``;
* :mod:`estimators.ekf.update` — the correction kernel (stacked observation model, χ² gate,
  stacked update, registration);
* :mod:`estimators.ekf.kernels` — the prediction kernel, angle wrap and outputs;
* :mod:`estimators.ekf.settings` — :class:`EkfSlamSettings`, the validated parameters.

The process model (seed 001 eq. 24, 28) is :mod:`quadslam_env.models.strapdown`; the LiDAR
model of one landmark and its inverse (eq. 31, 40, 44–50), numba kernels the correction calls
per landmark, are :mod:`quadslam_env.models.lidar`.
"""

from estimators.ekf.filter import EkfSlamBatch
from estimators.ekf.settings import BIAS_DIM, EkfSlamSettings

__all__ = ["BIAS_DIM", "EkfSlamBatch", "EkfSlamSettings"]
