"""An estimator fed by a LiDAR whose scans arrive late: the scan updates the belief of its own
time, and the output is re-propagated from there (docs/design.md §3; docs/timing.md "Latency").

A scan measured at a lane's step s reaches the estimator at step s + d (``lidar.delay_steps``
= d). Applying it then as if it were current puts a measurement of the pose d periods ago on
the pose of now, an error the filter's covariance knows nothing about. Instead the estimator
is run twice from copies, by re-propagation (the out-of-sequence measurement handling of flight
software that keeps a short buffer of its inputs):

- **the filter** (:attr:`ScanDelay.filter`) lags: each lane has processed every control period
  up to the time of its newest delivered scan, that scan included. When the scan of step
  s − d arrives, the filter is advanced over the lane's logged periods up to step s − d (the
  predictions it skipped, with the IMU samples and applied controls of their time) and
  corrected with the scan.
- **the output** (the env's estimator: what it reports and the controller flies on) becomes a
  copy of the filter carried forward over the logged periods since, predictions only (the
  scans in that window have not arrived). Between arrivals it predicts one period a step.

So at a step with no scan in flight the output has done exactly the operations, in the same
order, that an undelayed filter would have done: the same belief (tests/env/test_latency.py). With
unknown association (``lidar.association: unknown``) the logged scans are unlabeled returns,
which the filter associates (χ²/JCBB) against its belief of their time, as the undelayed filter
would; the scans that arrived in a step are :attr:`ScanDelay.applied`, so the association
bookkeeping scores the estimator's labels of those returns and re-matches the lanes rebuilt
from the filter (:attr:`ScanDelay.refreshed`; tests/env/test_latency_unknown.py).
Scans still in flight when an episode ends are dropped with the lane's log. Every lane keeps
its own phase (its own step count since reset), so lane i of a vector env equals the scalar
env. The estimator must be deep-copyable: the scenario check refuses a delay with one whose class
says ``copyable = False`` (:func:`quadslam_env.config.scenario.check_copyable`), unless it takes
late scans itself.

A smoother needs no copy (:class:`LateScans`): an estimator that
:class:`~quadslam_env.estimation.protocol.TakesLateScans` (iSAM2, whose class says
``takes_late_scans = True``) predicts every period as it comes, and each lane's scan is held d
steps and then handed to it with its measurement time; the smoother puts the scan's factors
on a keyframe at that time and carries its present (the IMU samples since) forward from there
(docs/isam2.md "A delayed LiDAR"; tests/isam2/test_isam2_latency.py).
"""

from __future__ import annotations

import copy
from collections.abc import Sequence
from typing import Any

import numpy as np

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.estimation.protocol import BatchEstimator, TakesLateScans
from quadslam_env.runtime.imu_replay import ImuReplay
from quadslam_env.runtime.period_log import EstimatorCopies, PeriodLog, Sample, predict_samples
from quadslam_env.sim.scans import Scans
from quadslam_env.types import FloatArray


def copies_for(
    scenario: ScenarioConfig, estimator: BatchEstimator, params: Any
) -> ImuReplay | ScanDelay | LateScans | None:
    """The second run of ``estimator`` (the env's output) a scenario needs: the delayed-LiDAR
    filter, the slow-IMU filter, or none (never both: ``config.check_delays``); or, for a
    delayed LiDAR and an estimator that takes late scans, the scans' buffer.

    Args:
        scenario: The validated scenario.
        estimator: The env's estimator right after construction or a swap.
        params: The nominal :class:`~quadslam_env.models.params.VehicleParams`.

    Returns:
        A :class:`LateScans` (``lidar.delay_steps`` > 0 and an estimator that
        :class:`~quadslam_env.estimation.protocol.TakesLateScans`), a :class:`ScanDelay`
        (``lidar.delay_steps`` > 0), an :class:`~quadslam_env.runtime.imu_replay.ImuReplay`
        (``imu.rate_hz`` below the control rate) or ``None``; the core steps any of them
        through its ``step``.
    """
    dt, m = 1.0 / scenario.episode.control_hz, scenario.imu_per_step
    if (delay := scenario.lidar.delay_steps) > 0:
        if isinstance(estimator, TakesLateScans) and estimator.takes_late_scans:
            return LateScans(estimator, delay, dt, m)
        return ScanDelay(estimator, delay, scenario.lidar_every, dt / m, m)
    if scenario.steps_per_imu == 1:
        return None
    rate = scenario.imu_rate_hz
    return ImuReplay.for_vehicle(estimator, scenario.steps_per_imu, dt, params, rate)


def _arriving(
    log: PeriodLog, steps: np.ndarray, active: np.ndarray, delay: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where this step's arriving scans are: each lane's scan measured ``delay`` steps ago.

    Args:
        log: The lanes' period log.
        steps: (B,) control steps since each lane's reset (after this one).
        active: (B,) bool lanes that stepped.
        delay: d, in control steps.

    Returns:
        ``(measured (B,) int, due (B,) bool, slots (B,) int)``: the step each lane's arriving
        scan was measured at, the active lanes for which that step exists (≥ 1), and its log
        slots (of step 1 where it does not exist).
    """
    measured = steps - delay
    return measured, active & (measured >= 1), log.slots(np.maximum(measured, 1))


class ScanDelay(EstimatorCopies):
    """The lagging filter, its log of the periods since, and the output it re-propagates
    (module docstring).

    Args:
        estimator: The env's (output) estimator right after construction; the filter starts
            as a deep copy of it.
        delay_steps: d ≥ 1, control steps between a scan's measurement and its arrival.
        lidar_every: L ≥ 1, control steps between scans (the log keeps L + d periods: the
            most a lane's filter can lag behind its present).
        h: Prediction step in s (the control period over the IMU samples per period).
        per_period: IMU samples per control period.

    Attributes:
        filter: Every lane's belief at the time of its newest delivered scan.
        output: The output estimator :meth:`step` last returned (the env's).
        filter_step: (B,) int, the step (since the lane's reset) the filter's lane is at.
        refreshed: (B,) bool lanes whose delayed scan arrived in the last :meth:`step`.
        applied: The scans that arrived in the last :meth:`step` (measured d steps earlier;
            lanes :attr:`refreshed`), or ``None``.
    """

    def __init__(
        self,
        estimator: BatchEstimator,
        delay_steps: int,
        lidar_every: int,
        h: float,
        per_period: int = 1,
    ) -> None:
        b, self.delay, self.h = estimator.num_lanes, int(delay_steps), float(h)
        super().__init__(estimator, PeriodLog(int(lidar_every) + self.delay, b, per_period))
        self.filter_step = np.zeros(b, dtype=np.int64)

    def reset_lanes(
        self,
        lanes: np.ndarray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known: Any,
    ) -> None:
        """Reset the filter's ``lanes`` (k,) as the output's were; their scans in flight and
        their log are dropped.

        ``rngs`` must be copies of the generators the output's lanes were reset with, taken
        before that reset drew from them, so that filter and output draw the same numbers.
        """
        super().reset_lanes(lanes, mean0, cov0, rngs, known)
        self.filter_step[lanes] = 0

    def step(
        self,
        output: BatchEstimator,
        steps: np.ndarray,
        active: np.ndarray,
        samples: list[Sample],
        sigma: tuple[float, float],
        scan: Scans | None,
        lidar_sigma: FloatArray,
    ) -> BatchEstimator:
        """Log this control period and its scans (measured now, delivered d steps later),
        then advance: the output by one period, or — when a lane's delayed scan arrives — the
        filter to that scan's time, the output then becoming a copy of it carried forward.

        Args:
            output: The env's estimator.
            steps: (B,) control steps since each lane's reset (after this one).
            active: (B,) bool lanes that stepped.
            samples: This period's IMU samples and applied controls (:data:`Sample`).
            sigma: White-noise std of the input per prediction step (accel m/s², gyro rad/s).
            scan: The scans measured this period, or ``None``.
            lidar_sigma: (3,) LiDAR noise stds.

        Returns:
            The estimator to report from now on (``output``, or the filter's fresh copy).
        """
        log = self.log
        log.record(steps, active, samples, scan)
        measured, due, slots = _arriving(log, steps, active, self.delay)
        if due.any():
            due &= log.has_scan(slots)
        self.refreshed = due
        if not due.any():
            self.applied = None
            predict_samples(output, samples, sigma, self.h, active)
            return output
        self.applied = log.scan(slots, due)  # the scans that arrive now
        self._advance(self.filter, due, measured, sigma, lidar_sigma)
        self.filter_step[due] = measured[due]
        output = self.output = copy.deepcopy(self.filter)
        # Every lane (not only those whose scan arrived: the copy replaced them all) from its
        # filter's time to now, without the scans in flight.
        self._advance(output, steps > self.filter_step, steps, sigma, None)
        return output

    def _advance(
        self,
        estimator: BatchEstimator,
        lanes: np.ndarray,
        until: np.ndarray,
        sigma: tuple[float, float],
        lidar_sigma: FloatArray | None,
    ) -> None:
        """Run ``lanes`` (B,) bool of ``estimator`` over their logged periods after
        :attr:`filter_step` up to their steps ``until`` (B,), in time order; with
        ``lidar_sigma`` each period's logged scans are applied after its predictions."""
        count = np.where(lanes, until - self.filter_step, 0)
        for j in range(int(count.max())):
            act = j < count
            slots = self.log.slots(self.filter_step + j + 1)
            samples = self.log.samples(slots)
            predict_samples(estimator, samples, sigma, self.h, act)
            if lidar_sigma is None:
                continue
            scan = self.log.scan(slots, act)
            if scan is not None:
                scan.apply(estimator, samples[-1][0], lidar_sigma)


class LateScans:
    """A delayed LiDAR for an estimator that takes late scans itself (module docstring): each
    lane's scans held d steps, then handed to the env's estimator with their measurement time.
    The same interface as :class:`ScanDelay` (what the core calls), with no copy.

    Args:
        estimator: The env's estimator
            (:class:`~quadslam_env.estimation.protocol.TakesLateScans`).
        delay_steps: d ≥ 1, control steps between a scan's measurement and its arrival.
        dt: The control period in s (a scan measured at a lane's step s has the time s·dt, as
            the core gives an undelayed scan).
        per_period: IMU samples per control period.

    Attributes:
        output: The env's estimator, which :meth:`step` updates in place and returns.
        held: The estimators run beside the output: none.
        refreshed: (B,) bool, all False: the belief changes by the predictions and the scans
            that arrive only (never rebuilt from a copy).
        applied: The scans that arrived in the last :meth:`step` (measured d steps earlier),
            or ``None``.
    """

    held: tuple[BatchEstimator, ...] = ()

    def __init__(
        self, estimator: BatchEstimator, delay_steps: int, dt: float, per_period: int = 1
    ) -> None:
        b, self.delay, self.dt = estimator.num_lanes, int(delay_steps), float(dt)
        self.h = self.dt / per_period
        self.output = estimator
        # d + 1 periods: a scan is read d steps after it was logged, before its slot is reused.
        self.log = PeriodLog(self.delay + 1, b, per_period)
        self.refreshed = np.zeros(b, dtype=bool)
        self.applied: Scans | None = None

    def reset_lanes(
        self,
        lanes: np.ndarray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known: Any,
    ) -> None:
        """Drop the scans in flight of ``lanes`` (k,) (the core resets the estimator itself;
        the other arguments are :class:`ScanDelay`'s, unused)."""
        del mean0, cov0, rngs, known
        self.log.forget(lanes)

    def reserve_landmarks(self, count: int) -> None:
        """Nothing to size: the core sizes the env's estimator (no copy is held)."""
        del count

    def step(
        self,
        output: BatchEstimator,
        steps: np.ndarray,
        active: np.ndarray,
        samples: list[Sample],
        sigma: tuple[float, float],
        scan: Scans | None,
        lidar_sigma: FloatArray,
    ) -> BatchEstimator:
        """Log this period's scans (delivered d steps later), propagate ``output`` over the
        period, then hand it the scans measured d steps ago with their times.

        Args and returns as :meth:`ScanDelay.step` (``output`` is returned, updated).
        """
        log = self.log
        log.record(steps, active, samples, scan)
        predict_samples(output, samples, sigma, self.h, active)
        measured, due, slots = _arriving(log, steps, active, self.delay)
        self.applied = log.scan(slots, due) if due.any() else None
        if self.applied is not None:
            self.applied.apply(output, measured * self.dt, lidar_sigma)
        return output
