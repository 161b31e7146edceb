"""Faults of the simulated world of B lanes: one per episode (docs/integrity.md "Faults").

The ``faults`` section (:class:`~quadslam_env.config.faults.FaultsConfig`) picks the kind;
:class:`FaultBatch` holds each lane's fault and applies it to the truth and the scans:

- ``landmark_moves``: the true landmark (a row of ``SimCore.landmarks``) moves horizontally at
  ``magnitude`` m/s while the fault is active and stays where it got to afterwards; the scans
  and the map metrics see its current position.
- ``phantom_landmark``: a false return that moves with the vehicle: a landmark row whose true
  position is ``ρ + C_NB · offset_m`` at each scan, added to the scans only
  (:meth:`FaultBatch.scan_world`), never to ``SimCore.landmarks``. In lane b it takes the id
  L_b after the lane's L_b landmarks (the estimator's map has room for one more id): labeled
  scans carry it as landmark L_b; unlabeled ones carry it as a false return (true id -1). It
  is left out of the map metrics (:meth:`FaultBatch.metric_estimate`).
- ``range_bias``: ``magnitude`` m added to the range δ of the affected returns of each scan.
- ``imu_bias_step``: ``magnitude`` added to one axis of the IMU's constant bias ``bias0`` (so
  to ``ImuBatch.total_bias``, the metrics' truth), removed again after the fault.

Timing: the fault's state is evaluated once per control step, at the step's end time t (the
time of its IMU sample, scan and ``info``), before the vehicle flies the step
(:meth:`FaultBatch.advance`), and held over the step; at reset, at t = 0. A fault is active
on the steps with ``onset − ε ≤ t < onset + duration − ε`` (ε = :data:`TIME_TOL_S`).

Random stream per lane (the contract with the single env): only with a fault, at reset a
generator is spawned from the lane's world child after the wind's (spawning takes nothing
from that child's stream, so the landmarks, the sensors, the wind and every later episode draw
exactly what they draw without the fault); from it, in order: ``uniform(onset_s,
onset_max_s)`` (only with ``onset_max_s``); for ``landmark_moves`` ``integers(n)`` among the n
candidate landmarks (only with ``landmark`` null) and ``uniform(-π, π)`` for the heading (only
with ``direction_deg`` null); for ``range_bias`` with ``fraction`` < 1 ``permutation(L)``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.flatness import state_on_reference
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.schema import ConfigError
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.scans import Scans
from quadslam_env.sim.sensor_lanes import lane_indices
from quadslam_env.sim.trajectories import Trajectory
from quadslam_env.types import DEG, EUL, POS, FloatArray

FAULT_KEYS = ("fault_active", "fault_kind", "fault_landmark", "fault_in_view")
"""``info`` terms of every step with a fault (module docstring of the timing): 1.0 where the
fault is active, else 0.0; the kind where active, else ``""`` (text, like
``termination_reason``); the id of the landmark it moves or the phantom's, where active (NaN
otherwise); 1.0 where that landmark is among the step's returns, else 0.0 (0.0 for the kinds
without one)."""

ONSET_KEY = "episode_fault_onset_s"
"""The episode summary of the episode's onset, s (drawn or fixed; also when the episode ended
before it)."""

TIME_TOL_S = 1e-9
"""A step at ``t ≥ onset − TIME_TOL_S`` is past the onset (``t`` is ``steps · dt``)."""

REFERENCE_INSTANTS = 1000
"""Most scan instants of the reference at which the landmarks it sees are looked for."""

_CHUNK = 1 << 18
"""Most (instant, landmark) pairs measured at once in :meth:`ReferenceView.seen`."""

_AXES = {"accel": 0, "gyro": 3}


class ReferenceView:
    """The reference trajectory's poses at an episode's scan instants, and the landmarks the
    LiDAR sees from them (where ``faults.landmark`` is null: the moving landmark's candidates).

    The pose at each instant is the reference's own state (:func:`state_on_reference`: its
    position, the attitude of the flatness map with heading ψ_d); the instants are every
    scan's, thinned to at most :data:`REFERENCE_INSTANTS`.

    Args:
        scenario: The validated scenario.
        trajectory: Its reference.
        mass: Vehicle mass, kg (enters the flatness map).
    """

    def __init__(self, scenario: ScenarioConfig, trajectory: Trajectory, mass: float) -> None:
        every = scenario.lidar_every
        count = scenario.max_steps // every
        stride = max(1, math.ceil(count / REFERENCE_INSTANTS))
        period = every / scenario.episode.control_hz
        self.times: FloatArray = np.arange(1, count + 1, stride, dtype=np.float64) * period
        ref = trajectory.batch(self.times)
        yaw, rate = np.asarray(ref.yaw), np.asarray(ref.yaw_rate)
        states = np.array(
            [
                state_on_reference(ref.pos[i], ref.vel[i], ref.acc[i], float(yaw[i]),
                                   float(rate[i]), mass)
                for i in range(self.times.shape[0])
            ]
        ).reshape(-1, 12)  # fmt: skip
        self.pos = np.ascontiguousarray(states[:, POS])
        self.dcm = dcm_from_euler_batch(np.ascontiguousarray(states[:, EUL]))
        lidar = scenario.lidar
        self.limits = (lidar.azimuth_fov_deg * DEG, lidar.elevation_fov_deg * DEG,
                       lidar.range_min_m, lidar.range_max_m)  # fmt: skip

    def seen(self, points: FloatArray, onset: float, end: float) -> np.ndarray:
        """(k,) int the ``points`` (n, 3) (N, m) in view from the reference at some scan
        instant in ``[onset, end)`` (s), ascending; all of them when none is."""
        window = (self.times >= onset - TIME_TOL_S) & (self.times < end - TIME_TOL_S)
        pos, dcm = self.pos[window], self.dcm[window]
        n = points.shape[0]
        seen = np.zeros(n, dtype=bool)
        step = max(1, _CHUNK // max(n, 1))
        az, el, lo, hi = self.limits
        for i in range(0, pos.shape[0], step):
            y = lidar_measure(pos[i : i + step, None], dcm[i : i + step, None], points[None])
            view = (np.abs(y[..., 0]) <= az) & (np.abs(y[..., 1]) <= el)
            view &= (y[..., 2] >= lo) & (y[..., 2] <= hi)
            seen |= view.any(axis=0)
        return np.flatnonzero(seen) if seen.any() else np.arange(n)


class FaultBatch:
    """The fault of each of B lanes (or none: every method a no-op, one check per call).

    Args:
        scenario: The validated scenario (its ``faults`` section and the LiDAR's association).
        trajectory: Its reference (the moving landmark's candidates).
        mass: Vehicle mass, kg.
        num_lanes: B.

    Attributes:
        enabled: Whether there is a fault (``faults.kind`` is not ``none``).
        active: (B,) bool, the fault is active at the lane's current step.
        onset: (B,) the episode's onset, s. end: (B,) its end, s (inf: the episode's end).
        target: (B,) int, the moving landmark's id or the phantom's (-1: none).
        in_view: (B,) bool, the active fault's landmark is among the step's returns.
        affected: Per lane, the (k,) ids of the landmarks whose ranges are biased (``None``:
            every return, false returns too).
    """

    def __init__(
        self, scenario: ScenarioConfig, trajectory: Trajectory, mass: float, num_lanes: int
    ) -> None:
        cfg = self.cfg = scenario.faults
        b = int(num_lanes)
        self.enabled = cfg.enabled
        self.kind = cfg.kind
        self.active = np.zeros(b, dtype=bool)
        self.onset = np.zeros(b)
        self.end = np.full(b, math.inf)
        self.target = np.full(b, -1, dtype=np.int64)
        self.in_view = np.zeros(b, dtype=bool)
        self.affected: list[np.ndarray | None] = [None] * b
        self._start = np.zeros((b, 3))  # the moving landmark's position at the onset, N m
        self._velocity = np.zeros((b, 3))  # its velocity while active, N m/s
        self._base_bias = np.zeros((b, 6))  # the IMU's constant bias without the step
        self._step = np.zeros(6)
        if cfg.kind == "imu_bias_step":
            self._step[_AXES[cfg.sensor] + cfg.axis] = cfg.magnitude
        self._offset = np.array(cfg.offset_m, dtype=float)
        self._world = np.zeros((b, 0, 3))  # the landmarks with the phantom row (scan_world)
        self._known = scenario.lidar.association == "known"
        self._view: ReferenceView | None = None
        free = scenario.trajectory.yaw_mode == "free"  # a free heading is the agent's
        if cfg.kind == "landmark_moves" and cfg.landmark is None and not free:
            self._view = ReferenceView(scenario, trajectory, mass)

    @property
    def extra_landmarks(self) -> int:
        """Landmark ids the fault adds to the scans (1 for the phantom, else 0)."""
        return self.cfg.extra_landmarks

    def reset(
        self,
        lanes: Sequence[int] | np.ndarray,
        parents: Sequence[np.random.Generator],
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        imu: ImuBatch,
    ) -> None:
        """Draw the fault of the ``lanes`` (k,) for their new episodes and apply it at t = 0.

        Args:
            lanes: (k,) lane indices (their landmarks and IMU already reset).
            parents: (k,) generators the faults' generators are spawned from (the world
                children, after the wind's spawn: module docstring).
            landmarks: (B, Lmax, 3) true landmark positions, N, m (moved in place).
            n_landmarks: (B,) int landmarks per lane.
            imu: The lanes' IMUs (their constant bias stepped in place).

        Raises:
            ConfigError: ``faults.landmark`` beyond a lane's map (brought by a reset option).
        """
        if not self.enabled:
            return
        idx = lane_indices(lanes)
        cfg = self.cfg
        for lane, parent in zip(idx.tolist(), parents, strict=True):
            rng = parent.spawn(1)[0]
            onset = cfg.onset_s
            if cfg.onset_max_s is not None:
                onset = float(rng.uniform(cfg.onset_s, cfg.onset_max_s))
            self.onset[lane] = onset
            self.end[lane] = math.inf if cfg.duration_s is None else onset + cfg.duration_s
            n = int(n_landmarks[lane])
            if self.kind == "landmark_moves":
                self._draw_motion(lane, landmarks[lane, :n], rng)
            elif self.kind == "phantom_landmark":
                self.target[lane] = n
            elif self.kind == "range_bias" and cfg.fraction < 1.0:
                k = max(1, math.floor(cfg.fraction * n + 0.5))
                self.affected[lane] = np.sort(rng.permutation(n)[:k]) if n else np.zeros(0, int)
            elif self.kind == "imu_bias_step":
                self._base_bias[lane] = imu.bias0[lane]
        self.in_view[idx] = False
        self._apply(idx, np.zeros(idx.shape[0]), landmarks, imu)

    def _draw_motion(self, lane: int, points: FloatArray, rng: np.random.Generator) -> None:
        """The moving landmark of ``lane`` among its ``points`` (n, 3) (N, m), its start and
        its velocity."""
        cfg, n = self.cfg, points.shape[0]
        if cfg.landmark is None:
            if n == 0:
                raise ConfigError(
                    "faults.kind: got 'landmark_moves' with a map of 0 landmarks (reset option "
                    "landmarks); allowed: a map with a landmark to move"
                )
            view = self._view
            ids = np.arange(n) if view is None else view.seen(points, self.onset[lane],
                                                               self.end[lane])  # fmt: skip
            landmark = int(ids[rng.integers(ids.shape[0])])
        elif cfg.landmark >= n:
            raise ConfigError(
                f"faults.landmark: got {cfg.landmark} with a map of {n} landmark(s) in lane "
                f"{lane} (reset option landmarks); allowed: null or an index from 0 to {n - 1}"
            )
        else:
            landmark = cfg.landmark
        if cfg.direction_deg is None:
            heading = float(rng.uniform(-math.pi, math.pi))
        else:
            heading = math.radians(cfg.direction_deg)
        self.target[lane] = landmark
        self._start[lane] = points[landmark]
        self._velocity[lane] = cfg.magnitude * np.array([math.cos(heading), math.sin(heading), 0.0])

    def advance(
        self, t: FloatArray, active: np.ndarray, landmarks: FloatArray, imu: ImuBatch
    ) -> None:
        """The fault's state at the step about to be flown, in the ``active`` (B,) lanes.

        Args:
            t: (B,) the lanes' times at the end of the step, s.
            active: (B,) bool lanes that step.
            landmarks: (B, Lmax, 3) true landmark positions (the moving one set in place).
            imu: The lanes' IMUs (the constant bias set in place).
        """
        if not self.enabled:
            return
        idx = np.flatnonzero(active)
        self.in_view[idx] = False  # until this step's scan returns the landmark
        self._apply(idx, t[idx], landmarks, imu)

    def _apply(self, idx: np.ndarray, t: FloatArray, landmarks: FloatArray, imu: ImuBatch) -> None:
        """Set the fault of the lanes ``idx`` (k,) at their times ``t`` (k,) s."""
        on = (t >= self.onset[idx] - TIME_TOL_S) & (t < self.end[idx] - TIME_TOL_S)
        self.active[idx] = on
        if self.kind == "landmark_moves":
            elapsed = np.maximum(np.minimum(t, self.end[idx]) - self.onset[idx], 0.0)
            moved = self._start[idx] + elapsed[:, None] * self._velocity[idx]
            landmarks[idx, self.target[idx]] = moved
        elif self.kind == "imu_bias_step":
            base = self._base_bias[idx]
            imu.bias0[idx] = np.where(on[:, None], base + self._step, base)

    def scan_world(
        self, pos: FloatArray, dcm: FloatArray, landmarks: FloatArray, n_landmarks: np.ndarray
    ) -> tuple[FloatArray, np.ndarray]:
        """The world the LiDAR scans: the true landmarks, with the phantom where active.

        Args:
            pos: (B, 3) true positions ρ, N, m. dcm: (B, 3, 3) true ``C_NB``.
            landmarks: (B, Lmax, 3) true landmark positions, N, m.
            n_landmarks: (B,) int landmarks per lane.

        Returns:
            ``(points (B, Lmax + 1, 3), counts (B,))`` with the phantom at ``ρ + C_NB ·
            offset_m`` in row L_b of each lane where active (counted there); the arguments
            themselves without a phantom fault.
        """
        if self.kind != "phantom_landmark":
            return landmarks, n_landmarks
        b, lmax = landmarks.shape[0], landmarks.shape[1]
        if self._world.shape[1] != lmax + 1:
            self._world = np.zeros((b, lmax + 1, 3))
        world = self._world
        world[:, :lmax] = landmarks
        lanes = np.flatnonzero(self.active)
        world[lanes, self.target[lanes]] = pos[lanes] + dcm[lanes] @ self._offset
        return world, n_landmarks + self.active

    def corrupt(self, scans: Scans) -> None:
        """Bias the ranges of the affected returns of the active lanes of ``scans`` in place
        (``range_bias``), or mark the phantom's unlabeled returns as false ones (true id -1:
        it is no landmark); nothing for the other kinds. Notes where the active fault's
        landmark is among the returns (``fault_in_view``)."""
        if self.target.max() >= 0:
            lanes = scans.lanes[self.active[scans.lanes]]
            hit = scans.returned[lanes] & (scans.true_ids[lanes] == self.target[lanes, None])
            self.in_view[lanes] = hit.any(axis=1)
        if self.kind == "phantom_landmark" and not self._known:
            ids = scans.true_ids  # the returns' truth (unlabeled scans), writable
            ids[ids == self.target[:, None]] = -1
            return
        if self.kind != "range_bias":
            return
        lanes = scans.lanes[self.active[scans.lanes]]
        returned, meas, ids = scans.returned, scans.meas, scans.true_ids
        for lane in lanes.tolist():
            rows = returned[lane]
            affected = self.affected[lane]
            if affected is not None:
                rows = rows & np.isin(ids[lane], affected)
            meas[lane, rows, 2] += self.cfg.magnitude

    def metric_estimate(self, est: BatchEstimate) -> BatchEstimate:
        """``est`` as the map metrics score it: with known association the phantom's id is
        not mapped (it is no landmark); ``est`` itself otherwise."""
        if self.kind != "phantom_landmark" or not self._known:
            return est
        mapped = est.landmark_mapped.copy()
        lanes = np.flatnonzero((self.target >= 0) & (self.target < mapped.shape[1]))
        mapped[lanes, self.target[lanes]] = False
        return dataclasses.replace(est, landmark_mapped=mapped)

    def info(self) -> dict[str, Any]:
        """The :data:`FAULT_KEYS` terms of the current step, (B,) each (``fault_kind`` an
        object array of strings); none without a fault (terms are defined where they apply)."""
        if not self.enabled:
            return {}
        kind = np.full(self.active.shape[0], "", dtype=object)
        kind[self.active] = self.kind
        landmark = np.where(self.active & (self.target >= 0), self.target, math.nan)
        return {
            "fault_active": self.active.astype(float),
            "fault_kind": kind,
            "fault_landmark": landmark,
            "fault_in_view": self.in_view.astype(float),
        }

    def summary(self) -> dict[str, FloatArray]:
        """The episode summary :data:`ONSET_KEY` of every lane, (B,); none without a fault."""
        return {ONSET_KEY: self.onset.copy()} if self.enabled else {}
