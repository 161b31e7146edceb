"""Oracle estimator: reports the true state (DESIGN.md §5), for ablations.

It is the one estimator the env feeds with the truth (through :meth:`OracleEstimator.set_truth`);
it has no covariance, so NEES is reported as NaN by the metrics.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.base import Estimate, check_kwargs, register
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.rotations import FloatArray, dcm_from_euler


@register("oracle")
class OracleEstimator:
    """Returns the true vehicle state and, if given, the true map.

    Args:
        vehicle: Nominal vehicle parameters (unused; accepted like every estimator).
    """

    uses_truth = True

    def __init__(self, vehicle: Any = None, **params: Any) -> None:
        check_kwargs("estimator.params", params, {})
        self._state = np.zeros(12)
        self._landmarks: tuple[np.ndarray, FloatArray] = (np.zeros(0, int), np.zeros((0, 3)))

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start; the state is overwritten by :meth:`set_truth` before every use."""
        self._state = np.array(mean0, dtype=float)
        if known_landmarks is not None:
            self._landmarks = (np.asarray(known_landmarks[0]), np.asarray(known_landmarks[1]))

    def set_truth(self, state: FloatArray, landmark_ids: np.ndarray, landmarks: FloatArray) -> None:
        """Receive the true 12-state and map (called by the env only for this estimator)."""
        self._state = np.array(state, dtype=float)
        self._landmarks = (landmark_ids, landmarks)

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Nothing to do: the truth arrives through :meth:`set_truth`."""

    def update(self, scan: LidarScan) -> None:
        """Nothing to do: the truth arrives through :meth:`set_truth`."""

    def estimate(self) -> Estimate:
        """The true state as an :class:`Estimate` with no covariance."""
        s = self._state
        ids, pts = self._landmarks
        return Estimate(
            position=s[0:3].copy(),
            vel_body=s[3:6].copy(),
            vel_inertial=dcm_from_euler(s[6:9]) @ s[3:6],
            euler=s[6:9].copy(),
            rates=s[9:12].copy(),
            pose_cov=None,
            landmark_ids=np.array(ids, dtype=int),
            landmark_means=np.array(pts, dtype=float),
            landmark_covs=np.zeros((len(ids), 3, 3)),
        )
