"""An estimator fed by an IMU slower than the control: filter at the IMU's instants, output
predicted at the control rate (docs/design.md §3; docs/timing.md "IMU rate").

An IMU m times slower than the control (``imu.rate_hz = episode.control_hz / m``) reports at
``t_k = k T`` the average of its inputs over ``[t_k − T, t_k]``. That sample belongs to the
period it covers, not to the next one: propagating the next period with it (a plain
zero-order hold) lags the input by a whole IMU period, and on the paper's figure-8 a 10 Hz
IMU then drives EKF-SLAM to NEES in the thousands within seconds even with the controller on
the true state. So the estimator is run twice, as flight software with a slow IMU runs an
output predictor beside its filter:

- **the filter** (:attr:`ImuReplay.filter`) stays at each lane's last IMU instant. When the
  sample covering the last m control periods arrives, it is replayed over them: m
  predictions of one control period dt each, with that sample held, each period's applied
  thrust and torque (so a dynamics-driven filter gets the right inputs) and the period's
  scans in time order.
- **the output** (the env's estimator) is a copy of the filter at the last instant, carried
  forward over every control period with the latest sample held and updated with each scan as
  it comes; it is what the env reports and the controller flies on, and it is replaced by a
  fresh copy of the filter at the next IMU instant.

Every replayed prediction passes the white-noise std of the input per control period,
``σ = ND √f_control = σ_IMU √m`` (:class:`~quadslam_env.core.SimCore`): the m predictions
between two samples then add up the variance ``(σ_IMU T)²`` of one held sample's noise over T,
and a filter that treats the IMU as a measurement counts each sample's information once.
The output's predictions also carry the error of holding the input: over the next period the
true mean input is the *next* sample, so the held one is off by the change between two
consecutive samples. Its variance s² is tracked per lane and sensor (largest axis, running
mean with weight :data:`CHANGE_MEMORY` on the past; over a lane's first period, before two
samples exist, what the actuators can reach) and added to the output's input noise as
``σ_out² = σ² + m s²`` (a held offset of std s over T, spread over m periods as above). On the
figure-8 with a 10 Hz IMU this gives a pose ANEES of 5–7 between instants (9 DOF; 8–9 at the
instants); without it, hundreds.

Lanes keep their own IMU phase (a lane samples every m of *its* steps since reset), so lane i of
a vector env equals the scalar env step for step.
"""

from __future__ import annotations

import copy
import math
from typing import Any

import numpy as np

from quadslam_env.estimation.protocol import BatchEstimator
from quadslam_env.runtime.period_log import EstimatorCopies, PeriodLog, Sample
from quadslam_env.sim.scans import Scans
from quadslam_env.types import FloatArray

CHANGE_MEMORY = 0.5
"""Weight of the previous estimate in the running mean square of the sample-to-sample change
(the latest change gets 1 − this: a memory of about two IMU periods)."""


class ImuReplay(EstimatorCopies):
    """The filter-at-IMU-instants and its log of the control periods since (module docstring).

    Args:
        estimator: The env's (output) estimator right after construction; the filter starts
            as a deep copy of it.
        steps_per_imu: m ≥ 2, control periods per IMU sample.
        dt: Control period in s.
        change_var0: Variance of the input error (accel m²/s⁴, gyro rad²/s²) over a lane's
            first IMU period, before two samples show how fast the input changes.

    Attributes:
        filter: Every lane's belief at its last IMU instant.
        output: The output estimator :meth:`step` last returned (the env's).
        log: Each lane's last m control periods.
        refreshed: (B,) bool lanes whose IMU sample arrived in the last :meth:`step` (their
            output is a fresh copy of the filter).
    """

    def __init__(
        self,
        estimator: BatchEstimator,
        steps_per_imu: int,
        dt: float,
        change_var0: tuple[float, float] = (0.0, 0.0),
    ) -> None:
        super().__init__(estimator, PeriodLog(int(steps_per_imu), estimator.num_lanes))
        self.change_var0 = change_var0
        self.m = int(steps_per_imu)
        self.dt = float(dt)
        b = estimator.num_lanes
        self.num_lanes = b
        self._previous = np.zeros((b, 6))  # the sample before the held one
        self._change_var = np.zeros((b, 2))  # (accel m²/s⁴, gyro rad²/s²)

    @classmethod
    def for_vehicle(
        cls, estimator: BatchEstimator, steps_per_imu: int, dt: float, params: Any, rate_hz: float
    ) -> ImuReplay:
        """The filter for ``params``' vehicle (:class:`~quadslam_env.models.params.VehicleParams`)
        and an IMU at ``rate_hz``: over a lane's first IMU period T the output's input error is
        taken as uniform over what the actuators can reach, the specific force over
        [0, f_max/m] and the rates over ±T max(τ_max/J) (variance span²/3)."""
        torque_per_inertia = np.asarray(params.max_torque) / np.diag(params.inertia)
        reach_g = float(np.max(torque_per_inertia)) / rate_hz
        reach_a = params.max_thrust / params.mass
        return cls(estimator, steps_per_imu, dt, (reach_a**2 / 3.0, reach_g**2 / 3.0))

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
        """Log this control period, then advance: the output by one period, or — in lanes
        whose IMU sample arrived now — the filter by the m periods it covers, the output then
        becoming a copy of it.

        Args:
            output: The env's estimator.
            steps: (B,) control steps since each lane's reset (after this one).
            active: (B,) bool lanes that stepped.
            samples: One :data:`~quadslam_env.runtime.period_log.Sample`: the times (B,) in s, each
                lane's latest IMU sample (held) and the thrust and torque applied over the
                period.
            sigma: White-noise std per control period (accel m/s², gyro rad/s).
            scan: This period's scans, or ``None``.
            lidar_sigma: (3,) LiDAR noise stds.

        Returns:
            The estimator to report from now on (``output``, or the filter's fresh copy).
        """
        self.log.record(steps, active, samples, scan)
        self.applied = scan  # the last scan each lane's output takes, directly or replayed
        ((t, accel, gyro, thrust, torque),) = samples
        held, controls = (accel, gyro), (thrust, torque)
        due = self.refreshed = active & (steps % self.m == 0)
        self._track_changes(steps, due, held)
        if not due.any():
            self._predict(output, active, t, held, sigma, controls, output=True)
            if scan is not None:
                scan.apply(output, t, lidar_sigma)
            return output
        self._replay(self.filter, due, self.m, held, sigma, lidar_sigma)
        output = self.output = copy.deepcopy(self.filter)
        # Lanes between two samples (out of phase after an autoreset): carry the copy of
        # their last instant forward again over their periods since.
        behind = (steps % self.m) * ~due
        if behind.any():
            lanes = behind > 0
            self._replay(output, lanes, int(behind.max()), held, sigma, lidar_sigma, behind)
        return output

    # ------------------------------------------------------------------ internals
    def _track_changes(
        self, steps: np.ndarray, due: np.ndarray, held: tuple[FloatArray, FloatArray]
    ) -> None:
        """Per lane, the recent mean square change between consecutive samples (largest axis;
        accel, gyro): the variance of the output's input error over the next period."""
        first = steps == 1  # the sample held since reset (m ≥ 2: never due at step 1)
        sample = np.hstack(held)
        self._previous[first] = sample[first]
        self._change_var[first] = self.change_var0  # no history yet: the actuators' reach
        if due.any():
            change = (sample[due] - self._previous[due]) ** 2
            now = np.column_stack((change[:, 0:3].max(axis=1), change[:, 3:6].max(axis=1)))
            keep = np.where(steps[due] > self.m, CHANGE_MEMORY, 0.0)[:, None]
            self._change_var[due] = keep * self._change_var[due] + (1.0 - keep) * now
            self._previous[due] = sample[due]

    def _predict(
        self,
        estimator: BatchEstimator,
        lanes: np.ndarray,
        t: FloatArray,
        held: tuple[FloatArray, FloatArray],
        sigma: tuple[float, float],
        controls: tuple[FloatArray, FloatArray],
        output: bool = False,
    ) -> None:
        """One control period of ``lanes`` (B,) bool; the ``output``'s with the input noise
        widened by the lane's sample-change variance (see the module docstring)."""
        if not output:
            estimator.predict(t, held[0], held[1], sigma[0], sigma[1], *controls, self.dt, lanes)
            return
        for lane in np.flatnonzero(lanes).tolist():
            one = np.zeros(self.num_lanes, dtype=bool)
            one[lane] = True
            var_a, var_g = self._change_var[lane] * self.m
            sa, sg = math.sqrt(sigma[0] ** 2 + var_a), math.sqrt(sigma[1] ** 2 + var_g)
            estimator.predict(t, held[0], held[1], sa, sg, *controls, self.dt, one)

    def _replay(
        self,
        estimator: BatchEstimator,
        lanes: np.ndarray,
        count: int,
        held: tuple[FloatArray, FloatArray],
        sigma: tuple[float, float],
        lidar_sigma: FloatArray,
        upto: np.ndarray | None = None,
    ) -> None:
        """Predict and correct ``lanes`` (B,) bool over their logged slots ``0 … count-1``
        (per lane only the first ``upto[lane]`` when given), in time order."""
        log = self.log
        for slot in range(count):
            act = lanes & log.active[slot]
            if upto is not None:
                act &= slot < upto
            if not act.any():
                continue
            t = log.t[slot, 0]
            controls = (log.thrust[slot, 0], log.torque[slot, 0])
            self._predict(estimator, act, t, held, sigma, controls, output=upto is not None)
            scan = log.scan(np.full(self.num_lanes, slot), act)
            if scan is not None:
                scan.apply(estimator, t, lidar_sigma)
