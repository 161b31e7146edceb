"""One step's LiDAR scans of B lanes, typed by what the estimator is told (docs/design.md §4).

With known association (``lidar.association: known``) a scan is labeled: slot j of a lane's
row is landmark j, and :class:`LabeledScans` marks which slots returned. With unknown
association it is a list of unlabeled returns in random order, false returns among them:
:class:`UnlabeledScans` wraps the LiDAR's
:class:`~quadslam_env.estimation.measurements.ScanReturns`, whose true ids stay with the simulator
for the association metrics and never reach the estimator. Both offer the same operations
(:class:`Scans`): the core, the slow-IMU filter (:mod:`quadslam_env.runtime.imu_replay`) and the
delayed-LiDAR filter (:mod:`quadslam_env.runtime.scan_delay`) apply, log and replay either kind
without asking which it is.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Protocol, cast

import numpy as np

from quadslam_env.estimation.measurements import ScanReturns
from quadslam_env.estimation.protocol import AssociatesUnlabeled, BatchEstimator
from quadslam_env.sim.sensor_lanes import LANE0
from quadslam_env.types import MEAS_DIM, FloatArray


class Scans(Protocol):
    """The scans of the lanes that scanned in one step (what both kinds offer)."""

    @property
    def lanes(self) -> np.ndarray:
        """(k,) int lanes that scanned, ascending; other lanes' rows are empty."""

    @property
    def meas(self) -> FloatArray:
        """(B, W, 3) measurements (α rad, β rad, δ m); rows outside :attr:`returned` unused."""

    @property
    def returned(self) -> np.ndarray:
        """(B, W) bool: the rows of :attr:`meas` that hold a return."""

    @property
    def n_returns(self) -> np.ndarray:
        """(B,) int returns per lane (0 for lanes that did not scan)."""

    @property
    def true_ids(self) -> np.ndarray:
        """(B, W) int the true landmark id of each row of :attr:`meas` (-1: a false return;
        rows outside :attr:`returned` unused), for the simulator only (the faults of
        :mod:`quadslam_env.sim.faults`); never passed to an estimator."""

    def apply(self, estimator: BatchEstimator, t: FloatArray, sigma: FloatArray) -> None:
        """Correct ``estimator``'s :attr:`lanes` with their scans.

        Args:
            estimator: The batch estimator.
            t: (B,) scan times in s.
            sigma: (3,) LiDAR noise stds (σ_α rad, σ_β rad, σ_δ m).
        """

    def only(self, lanes: np.ndarray) -> Scans:
        """The same scans, of ``lanes`` (k,) int (a subset of :attr:`lanes`) only."""

    def lane(self, lane: int) -> Scans:
        """A copy of lane ``lane``'s scan as a one-lane container (its lane 0 scanned)."""

    def stack(self, rows: Mapping[int, Scans], num_lanes: int) -> Scans:
        """Scans of ``num_lanes`` lanes from one-lane scans of this kind (:meth:`lane`).

        Args:
            rows: Lane → its one-lane scan; the lanes scanned, the others did not.
            num_lanes: B.

        Returns:
            A container of this kind, as wide as the widest row.
        """


@dataclass(frozen=True)
class LabeledScans:
    """Labeled scans (known association), as :meth:`LidarBatch.scan` takes them.

    Attributes:
        lanes: (k,) int lanes that scanned.
        visible: (B, Lmax) bool, landmark id j returned (the estimator's ``visible``).
        meas: (B, Lmax, 3) measurements of the returned landmarks by id, 0 elsewhere.
    """

    lanes: np.ndarray
    visible: np.ndarray
    meas: FloatArray

    @property
    def returned(self) -> np.ndarray:
        return self.visible

    @property
    def n_returns(self) -> np.ndarray:
        return cast(np.ndarray, self.visible.sum(axis=1))

    @property
    def true_ids(self) -> np.ndarray:
        """Slot j is landmark j: a read-only (B, Lmax) view of the slot indices."""
        return np.broadcast_to(np.arange(self.visible.shape[1]), self.visible.shape)

    def apply(self, estimator: BatchEstimator, t: FloatArray, sigma: FloatArray) -> None:
        estimator.update(t, self.lanes, self.visible, self.meas, sigma)

    def only(self, lanes: np.ndarray) -> LabeledScans:
        return replace(self, lanes=lanes)

    def lane(self, lane: int) -> LabeledScans:
        one = slice(lane, lane + 1)
        return LabeledScans(LANE0, self.visible[one].copy(), self.meas[one].copy())

    def stack(self, rows: Mapping[int, Scans], num_lanes: int) -> LabeledScans:
        width = max(row.meas.shape[1] for row in rows.values())
        visible = np.zeros((num_lanes, width), dtype=bool)
        meas = np.zeros((num_lanes, width, MEAS_DIM))
        for lane, row in rows.items():
            visible[lane, : row.returned.shape[1]] = row.returned[0]
            meas[lane, : row.meas.shape[1]] = row.meas[0]
        return LabeledScans(np.array(sorted(rows), dtype=np.int64), visible, meas)


@dataclass(frozen=True)
class UnlabeledScans:
    """Unlabeled scans (unknown association), as :meth:`LidarBatch.returns` takes them.

    Attributes:
        lanes: (k,) int lanes that scanned.
        returns: Each lane's returns and their true ids (the truth for the association
            metrics only; :meth:`apply` passes the estimator the count and the returns).
            From the LiDAR, a buffer it reuses at its next scan: :meth:`lane` copies.
    """

    lanes: np.ndarray
    returns: ScanReturns

    @property
    def meas(self) -> FloatArray:
        return self.returns.meas

    @property
    def returned(self) -> np.ndarray:
        return np.arange(self.returns.meas.shape[1]) < self.returns.count[:, None]

    @property
    def n_returns(self) -> np.ndarray:
        return self.returns.count

    @property
    def true_ids(self) -> np.ndarray:
        """The returns' true ids (``returns.truth``, the array itself: writable)."""
        return self.returns.truth

    def apply(self, estimator: BatchEstimator, t: FloatArray, sigma: FloatArray) -> None:
        # the scenario check let only an estimator that AssociatesUnlabeled through
        returns = self.returns
        cast(AssociatesUnlabeled, estimator).update_unlabeled(
            t, self.lanes, returns.count, returns.meas, sigma
        )

    def only(self, lanes: np.ndarray) -> UnlabeledScans:
        return replace(self, lanes=lanes)

    def lane(self, lane: int) -> UnlabeledScans:
        k = int(self.returns.count[lane])
        one = ScanReturns(
            count=self.returns.count[lane : lane + 1].copy(),
            meas=self.returns.meas[lane : lane + 1, :k].copy(),
            truth=self.returns.truth[lane : lane + 1, :k].copy(),
        )
        return UnlabeledScans(LANE0, one)

    def stack(self, rows: Mapping[int, Scans], num_lanes: int) -> UnlabeledScans:
        width = max(row.meas.shape[1] for row in rows.values())
        out = ScanReturns(
            count=np.zeros(num_lanes, dtype=np.int64),
            meas=np.zeros((num_lanes, width, MEAS_DIM)),
            truth=np.full((num_lanes, width), -1, dtype=np.int64),
        )
        for lane, row in rows.items():
            one = cast(UnlabeledScans, row).returns  # rows of this kind (:meth:`lane`)
            k = int(one.count[0])
            out.count[lane] = k
            out.meas[lane, :k] = one.meas[0]
            out.truth[lane, :k] = one.truth[0]
        return UnlabeledScans(np.array(sorted(rows), dtype=np.int64), out)
