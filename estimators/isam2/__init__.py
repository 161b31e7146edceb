"""iSAM2 smoothing in the loop (``estimator.name: isam2``; needs ``quadslam[gtsam]``).

* :mod:`estimators.isam2.estimator` — :class:`Isam2Slam`, the registered estimator: keyframes
  at the LiDAR scans, IMU preintegration factors between them (Forster et al. 2017), LiDAR
  factors per return, fixed-lag or full iSAM2;
* :mod:`estimators.isam2.factors` — the LiDAR factor's error and analytic Jacobians (seed 001
  eq. 30–31, 40) as GTSAM ``CustomFactor`` error functions;
* :mod:`estimators.isam2.associate` — the data association front end for unlabeled scans
  (χ² gate, JCBB or nearest neighbour on the smoother's marginals, tentative landmarks);
* :mod:`estimators.isam2.transition` — the IMU factor's map from a keyframe's error to the
  predicted state's (covariance between keyframes, cross-covariances for association);
* :mod:`estimators.isam2.graph` — GTSAM's import, the first keyframe's priors and the
  preintegration settings;
* :mod:`estimators.isam2.snapshot` — the estimate in the env's (ρ, v_B, Λ);
* :mod:`estimators.isam2.tangent` — the env's (ρ, v_B, Λ) against GTSAM's tangent space;
* :mod:`estimators.isam2.settings` — :class:`Isam2Settings`, the validated parameters;
* :mod:`estimators.isam2.team` — the team env's vehicles sharing one smoother and one map
  (``team.fusion: centralised``);
* :mod:`estimators.isam2.fde` — the integrity monitor: EKF-SLAM's tests and exclusion on the
  smoother's belief at each scan, and the retired landmarks' keys.

Importing this package does not import GTSAM: building the estimator does, and fails with a
:class:`~quadslam_env.schema.ConfigError` naming the extra when it is missing.
"""

from estimators.isam2.estimator import Isam2Slam
from estimators.isam2.graph import GTSAM_INSTALL, require_gtsam
from estimators.isam2.settings import Isam2Settings

__all__ = ["GTSAM_INSTALL", "Isam2Settings", "Isam2Slam", "require_gtsam"]
