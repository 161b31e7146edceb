"""The estimator boundary: what the simulation core needs from an estimator.

See docs/design.md §5 and §9. The core steps B independent episodes ("lanes") in lockstep and
talks to its estimator through :class:`BatchEstimator`: arrays in, arrays out, with a lane mask
wherever lanes differ (a lane that scans this step, a lane that is being reset). An estimator
written for one vehicle implements :class:`Estimator` instead and enters through the one
adapter, :class:`~quadslam_env.estimation.lane_loop.LaneLoop`. Estimators never receive the
true state (the oracle, which says ``uses_truth = True``, is the one exception).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from quadslam_env.estimation.snapshot import BatchEstimate, Estimate
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import FloatArray

IntArray = np.ndarray
KnownMaps = Sequence[tuple[np.ndarray, FloatArray]] | None


@runtime_checkable
class Estimator(Protocol):
    """What the env needs from an estimator. Estimators never receive the true state."""

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start from a 12-state mean ``(ρ, v_B, Λ, ω)`` and its (12, 12) covariance.

        ``known_landmarks`` is ``(ids (L,), positions (L, 3))`` for known-map modes; ``rng`` is
        the only source of randomness the estimator may use.
        """

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Propagate over ``dt`` seconds with one IMU sample and the applied control."""

    def update(self, scan: LidarScan) -> None:
        """Correct with one LiDAR scan (an empty scan is allowed)."""

    def estimate(self) -> Estimate:
        """Return a frozen snapshot of the current belief."""


@runtime_checkable
class BatchEstimator(Protocol):
    """What the simulation core needs from an estimator of B lanes.

    Every method acts on the lanes it is told about and leaves the other lanes' state
    untouched, so lanes of one batch may be at different times of different episodes.
    """

    num_lanes: int
    uses_truth: bool

    def reset_lanes(
        self,
        lanes: IntArray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Start new episodes in ``lanes`` (k,) from means (k, 12) and covariances (k, 12, 12).

        ``rngs[j]`` is lane ``lanes[j]``'s only source of randomness; ``known_landmarks[j]`` is
        ``(ids (L,), positions (L, 3))`` in known-map mode, else ``None``.
        """

    def predict(
        self,
        t: FloatArray,
        accel: FloatArray,
        gyro: FloatArray,
        accel_sigma: float,
        gyro_sigma: float,
        thrust: FloatArray,
        torque: FloatArray,
        dt: float,
        active: np.ndarray,
    ) -> None:
        """Propagate the ``active`` (B,) lanes over ``dt`` s with one IMU sample each.

        ``t`` (B,) sample times in s; ``accel``/``gyro`` (B, 3) measured specific force (m/s²)
        and rates (rad/s) in B, held over ``dt``; ``accel_sigma``/``gyro_sigma`` the white-noise
        std of that input per step of ``dt``, ``ND/√dt`` (the per-sample std when the IMU
        samples every ``dt``; with an IMU slower than the control, the held sample's std
        scaled so that the steps between two samples add up its variance:
        :mod:`quadslam_env.imu_replay`); ``thrust`` (B,) N and ``torque`` (B, 3) N·m applied.
        """

    def update(
        self,
        t: FloatArray,
        lanes: IntArray,
        visible: np.ndarray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Correct ``lanes`` (k,) with their scans: ``visible`` (B, Lmax) bool marks the
        returned landmark ids, ``meas`` (B, Lmax, 3) their (α rad, β rad, δ m); ``sigma`` (3,)."""

    # Estimators that set ``associates_unlabeled = True`` (``lidar.association: unknown``)
    # also implement ``update_unlabeled(t, lanes, count (B,), returns (B, R, 3), sigma)``:
    # the returns of lane b are ``returns[b, :count[b]]``, unlabeled and in any order; and
    # ``last_association`` (B, R) int: the label (index into ``landmark_means``) each return
    # was paired with, -1 for none. A one-vehicle :class:`Estimator` gets a :class:`LidarScan`
    # with ``ids=None`` and exposes ``last_association`` (k,).

    def estimate(self) -> BatchEstimate:
        """The belief of every lane."""

    def lane_estimate(self, lane: int) -> Estimate:
        """A frozen :class:`Estimate` (copies) of one lane, with landmark covariances."""
