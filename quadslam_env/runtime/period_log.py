"""A per-lane log of the last control periods and the estimator calls that replay it
(docs/design.md §3; docs/timing.md "IMU rate" and "Latency").

Two parts of the core run an estimator over periods it has already seen once, from a copy:
the slow-IMU filter (:mod:`quadslam_env.runtime.imu_replay`) when a sample covering the last periods
arrives, and the delayed-LiDAR filter (:mod:`quadslam_env.runtime.scan_delay`) when a scan measured
some steps ago arrives. Both keep what they need in a :class:`PeriodLog`: a ring of each
lane's last n control periods, slot ``(own step − 1) % n``, so lanes keep their own phase
after an autoreset (lane i of a vector env equals the scalar env). An estimator that takes late
scans itself is not copied; its scans wait in a :class:`PeriodLog` too
(:class:`~quadslam_env.runtime.scan_delay.LateScans`).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from quadslam_env.estimation.protocol import BatchEstimator, ReservesLandmarks
from quadslam_env.sim.scans import Scans
from quadslam_env.types import FloatArray

Sample = tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]
"""``(t (B,) s, accel (B, 3) m/s², gyro (B, 3) rad/s, thrust (B,) N, torque (B, 3) N·m)``: one
IMU sample of every lane and the thrust and torque applied over its period."""


def predict_samples(
    estimator: BatchEstimator,
    samples: list[Sample],
    sigma: tuple[float, float],
    h: float,
    lanes: np.ndarray,
) -> None:
    """Propagate ``lanes`` (B,) bool over one control period: one prediction of ``h`` s per
    sample of ``samples`` (m of them with an IMU m times faster than the control), in order.

    Args:
        estimator: The batch estimator.
        samples: The period's samples (:data:`Sample`).
        sigma: White-noise std of the input per step h (accel m/s², gyro rad/s).
        h: Prediction step in s.
        lanes: (B,) bool lanes to propagate.
    """
    for t, accel, gyro, thrust, torque in samples:
        estimator.predict(t, accel, gyro, sigma[0], sigma[1], thrust, torque, h, lanes)


class PeriodLog:
    """Each lane's last ``size`` control periods: their IMU samples, controls and scans.

    Args:
        size: n, periods kept per lane.
        num_lanes: B.
        per_period: IMU samples per control period (m ≥ 1 with an IMU m times faster).

    Attributes:
        active: (n, B) bool, slot holds a period of the lane's current episode.
        t, thrust: (n, m, B) sample times (s) and thrusts (N).
        accel, gyro, torque: (n, m, B, 3) samples (m/s², rad/s) and torques (N·m).
    """

    def __init__(self, size: int, num_lanes: int, per_period: int = 1) -> None:
        n, b, m = int(size), int(num_lanes), int(per_period)
        self.size, self.num_lanes, self.per_period = n, b, m
        self.active = np.zeros((n, b), dtype=bool)
        self.t = np.zeros((n, m, b))
        self.accel = np.zeros((n, m, b, 3))
        self.gyro = np.zeros((n, m, b, 3))
        self.thrust = np.zeros((n, m, b))
        self.torque = np.zeros((n, m, b, 3))
        self._scans: list[dict[int, Scans]] = [{} for _ in range(n)]  # lane → one-lane copy
        self._lane = np.arange(b)

    def forget(self, lanes: np.ndarray) -> None:
        """Drop every logged period (and scan) of ``lanes`` (k,): their episodes restart."""
        self.active[:, lanes] = False
        for slot in self._scans:
            for lane in np.asarray(lanes).tolist():
                slot.pop(lane, None)

    def slots(self, steps: np.ndarray) -> np.ndarray:
        """The ring slots (same shape, int) of each lane's own step numbers ``steps`` ≥ 1."""
        return (np.asarray(steps) - 1) % self.size

    def record(
        self, steps: np.ndarray, active: np.ndarray, samples: list[Sample], scan: Scans | None
    ) -> None:
        """Log the period just stepped by the ``active`` (B,) lanes (``steps`` (B,) their step
        numbers after it): its ``samples`` and the lanes' scans of ``scan``."""
        lanes = np.flatnonzero(active)
        slots = self.slots(steps[lanes])
        self.active[slots, lanes] = True
        for j, (t, accel, gyro, thrust, torque) in enumerate(samples):
            self.t[slots, j, lanes] = t[lanes]
            self.accel[slots, j, lanes] = accel[lanes]
            self.gyro[slots, j, lanes] = gyro[lanes]
            self.thrust[slots, j, lanes] = thrust[lanes]
            self.torque[slots, j, lanes] = torque[lanes]
        for lane, slot in zip(lanes.tolist(), slots.tolist(), strict=True):
            self._scans[slot].pop(lane, None)
        if scan is None:
            return
        for lane in scan.lanes.tolist():
            self._scans[int(self.slots(steps[lane]))][lane] = scan.lane(lane)

    def has_scan(self, slots: np.ndarray) -> np.ndarray:
        """(B,) bool: lane i logged a scan in its slot ``slots[i]``."""
        return np.array([lane in self._scans[int(s)] for lane, s in enumerate(slots.tolist())])

    def samples(self, slots: np.ndarray) -> list[Sample]:
        """The logged samples of each lane's slot ``slots`` (B,) int, as m :data:`Sample`."""
        lane = self._lane
        return [
            (
                self.t[slots, j, lane],
                self.accel[slots, j, lane],
                self.gyro[slots, j, lane],
                self.thrust[slots, j, lane],
                self.torque[slots, j, lane],
            )
            for j in range(self.per_period)
        ]

    def scan(self, slots: np.ndarray, lanes: np.ndarray) -> Scans | None:
        """The logged scans of ``lanes`` (B,) bool, each from its slot ``slots`` (B,) int, as
        one :class:`~quadslam_env.sim.scans.Scans` (``None``: none of them scanned there)."""
        rows = {}
        for lane in np.flatnonzero(lanes).tolist():
            row = self._scans[int(slots[lane])].get(lane)
            if row is not None:
                rows[lane] = row
        if not rows:
            return None
        return next(iter(rows.values())).stack(rows, self.num_lanes)


class EstimatorCopies:
    """What the slow-IMU and the delayed-LiDAR runs share: the filter, a deep copy of the
    env's estimator that lags behind it, the output (the env's estimator, replaced by fresh
    copies of the filter), and the log of the periods the filter has not run yet.

    Args:
        estimator: The env's (output) estimator right after construction.
        log: The subclass's :class:`PeriodLog`.

    Attributes:
        filter: The lagging copy.
        output: The output estimator the subclass's ``step`` last returned (the env's).
        log: The periods logged since.
        refreshed: (B,) bool lanes whose output the last ``step`` rebuilt from the filter
            (their IMU sample or their delayed scan arrived): their belief, map included,
            changed by more than the period's prediction and its own scan.
        applied: The scans whose update the output's belief took last in the last ``step``
            (the slow IMU: that period's; the delayed LiDAR: those measured d steps earlier
            that arrived then), or ``None``. The association scores the estimator's labels of
            their returns (:class:`~quadslam_env.runtime.association.UnknownAssociation`).
    """

    def __init__(self, estimator: BatchEstimator, log: PeriodLog) -> None:
        self.filter = copy.deepcopy(estimator)
        self.output = estimator
        self.log = log
        self.refreshed = np.zeros(estimator.num_lanes, dtype=bool)
        self.applied: Scans | None = None

    @property
    def held(self) -> tuple[BatchEstimator, ...]:
        """The estimators run beside the output (the filter), which a reset informs too."""
        return (self.filter,)

    def reset_lanes(
        self,
        lanes: np.ndarray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known: Any,
    ) -> None:
        """Reset the filter's ``lanes`` (k,) as the output's were and forget their log.

        ``rngs`` must be copies of the generators the output's lanes were reset with, taken
        before that reset drew from them, so that filter and output draw the same numbers.
        """
        self.filter.reset_lanes(lanes, mean0, cov0, rngs, known)
        self.log.forget(lanes)
        self.refreshed[lanes] = False

    def reserve_landmarks(self, count: int) -> None:
        """Pass a reset's map size on to a filter that
        :class:`~quadslam_env.estimation.protocol.ReservesLandmarks`."""
        if isinstance(self.filter, ReservesLandmarks):
            self.filter.reserve_landmarks(count)
