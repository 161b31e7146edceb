"""The team's communication model: which vehicle sends what, when, and what reaches whom
(docs/team.md "Communication").

With ``team.fusion`` ``ci`` or ``naive`` every live vehicle broadcasts a message at the end of
a step on which it is due (after every m-th of its scans, ``team.message_every_scans``, or at a
rate, ``team.message_rate_hz``): its ``team.landmarks_per_message`` best-known landmarks (the
smallest covariance traces, then the smallest ids; every mapped landmark by default), each as
its id and mean (3), and their covariance, read from its estimator's lane: the sender's joint
(3k, 3k) covariance of them (``team.message_covariance: joint``, the default), or only each
landmark's 3×3 block (``blocks``). Each
other live vehicle misses the message with ``team.drop_probability``, one draw per receiver
from the sender's own generator (spawned from the vehicle's stream at reset, so the drops
repeat with the seed), and with ``team.comm_range_m`` a receiver farther from the sender than
that when it sends (true positions) does not hear it (after its drop draw, so a range changes
no draw); a message that reaches it is fused at the start of the step
``team.latency_steps`` steps after the next one, by the estimator's
:class:`~quadslam_env.estimation.protocol.FusesLandmarks` (the math is the estimator's:
:mod:`estimators.ekf.fusion`). A message for a vehicle that has ended is discarded.

With ``centralised`` the vehicles' estimators are one, and what they send is their
measurements (:class:`Uplink`).

Coordination only: no estimation math here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import cast

import numpy as np

from quadslam_env.estimation.protocol import BatchEstimator, FusesLandmarks
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.sim.scans import Scans
from quadslam_env.team.config import (
    FLOAT_BYTES,
    IMU_SAMPLE_FLOATS,
    RETURN_FLOATS,
    TeamConfig,
    message_floats,
)
from quadslam_env.types import FloatArray

COUNT_KEYS = (
    "team_messages_sent",
    "team_messages_delivered",
    "team_messages_dropped",
    "team_messages_out_of_range",
    "team_bytes_sent",
)
"""The episode's message counts so far (a broadcast counts once in ``sent`` and its bytes; each
receiver's copy once in ``delivered``, ``dropped`` or ``out_of_range``)."""


def rate_ticks(steps: np.ndarray, per_step: float) -> np.ndarray:
    """(…,) bool: whether the end of step ``steps`` (…,) int is an event of a rate of
    ``per_step`` events per control step: the step on which ⌊t · rate⌋ grows (never step 0).
    The team's messages at ``team.message_rate_hz`` and its range epochs use it."""
    ticks = np.floor(steps * per_step + 1e-9)
    before = np.floor((steps - 1) * per_step + 1e-9)
    return (ticks > before) & (steps > 0)


@dataclass(frozen=True)
class Message:
    """One vehicle's landmark estimates for one receiver.

    Attributes:
        sender: The sending vehicle.
        receiver: The receiving vehicle.
        due: The number of steps after which the receiver fuses it (at the start of the next).
        ids: (k,) int landmark ids.
        means: (k, 3) means, m, N frame.
        covs: (3k, 3k) their joint covariance, or (k, 3, 3) their blocks, m².
    """

    sender: int
    receiver: int
    due: int
    ids: np.ndarray
    means: FloatArray
    covs: FloatArray


class Comms:
    """The messages of one episode (module docstring).

    Args:
        team: The team settings.
        n_vehicles: N.
        lidar_every: Control steps per scan.
        control_hz: Control steps per second.
    """

    def __init__(self, team: TeamConfig, n_vehicles: int, lidar_every: int, control_hz: float):
        self.mode = team.fusion
        self.n_vehicles = n_vehicles
        self._every = team.message_every_scans or 1
        self._rate = team.message_rate_hz
        self._lidar_every = lidar_every
        self._control_hz = control_hz
        self._latency = team.latency_steps
        self._drop = team.drop_probability
        self._range_m = team.comm_range_m
        self._k = team.landmarks_per_message
        self._covariance = team.message_covariance
        self._rngs: list[np.random.Generator] = []
        self._queue: list[Message] = []
        self.counts = dict.fromkeys(COUNT_KEYS, 0)
        self.fused = np.zeros(n_vehicles, dtype=np.int64)

    def reset(self, rngs: list[np.random.Generator]) -> None:
        """Start an episode: no message in flight, the counts at 0, and each vehicle's drop
        generator spawned from its stream ``rngs`` (N,) (after the core's reset spawned its
        own, so the vehicles' other draws are those of independent fusion)."""
        self._rngs = [rng.spawn(1)[0] for rng in rngs]
        self._queue = []
        self.counts = dict.fromkeys(COUNT_KEYS, 0)
        self.fused[:] = 0

    def due(self, steps: np.ndarray) -> np.ndarray:
        """(N,) bool: the vehicles due to send after their ``steps`` (N,) int steps."""
        if self._rate is None:
            scans = steps // self._lidar_every
            return (steps % self._lidar_every == 0) & (scans % self._every == 0) & (steps > 0)
        return rate_ticks(steps, self._rate / self._control_hz)

    def send(
        self,
        estimator: BatchEstimator,
        steps: np.ndarray,
        live: np.ndarray,
        positions: FloatArray,
    ) -> None:
        """At the end of a step: the ``live`` (N,) vehicles due after ``steps`` (N,) send.

        Args:
            estimator: The core's estimator (each sender's lane snapshot is read).
            steps: (N,) int each vehicle's steps so far.
            live: (N,) bool the vehicles still in the episode after the step.
            positions: (N, 3) the true positions after the step, m, N frame (the radio's
                reach, ``team.comm_range_m``).
        """
        for i in np.flatnonzero(self.due(steps) & live).tolist():
            ids, means, covs = self._best(estimator.lane_estimate(i))
            if self._covariance == "joint":
                covs = cast(FusesLandmarks, estimator).landmark_covariance(i, ids)
            self.counts["team_messages_sent"] += 1
            self.counts["team_bytes_sent"] += FLOAT_BYTES * message_floats(
                ids.size, self._covariance
            )
            due = int(steps[i]) + self._latency
            for j in range(self.n_vehicles):
                if j == i or not live[j]:
                    continue
                if self._rngs[i].random() < self._drop:
                    self.counts["team_messages_dropped"] += 1
                    continue
                reach = self._range_m
                if reach is not None and np.linalg.norm(positions[j] - positions[i]) > reach:
                    self.counts["team_messages_out_of_range"] += 1
                    continue
                self._queue.append(Message(i, j, due, ids, means, covs))

    def _best(self, est: BatchEstimate) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """The message's landmarks from a lane snapshot (B = 1): the k smallest covariance
        traces (ties: smaller id first), every mapped landmark without k."""
        ids, means, covs = est.mapped_landmarks(0)
        if self._k is not None and ids.size > self._k:
            order = np.lexsort((ids, np.trace(covs, axis1=1, axis2=2)))[: self._k]
            order.sort()
            ids, means, covs = ids[order], means[order], covs[order]
        return ids.copy(), means.copy(), covs.copy()

    def deliver(self, estimator: BatchEstimator, steps_done: int, live: np.ndarray) -> None:
        """At the start of a step: fuse the messages due after ``steps_done`` steps into
        their ``live`` (N,) receivers, in the order they were sent; sets :attr:`fused` (N,),
        the landmarks fused into each vehicle now."""
        self.fused[:] = 0
        if not self._queue:
            return
        now = [m for m in self._queue if m.due <= steps_done]
        self._queue = [m for m in self._queue if m.due > steps_done]
        fuser = cast(FusesLandmarks, estimator)  # the team settings' check saw its flag
        for msg in now:
            if not live[msg.receiver]:
                continue
            self.counts["team_messages_delivered"] += 1
            fused, _ = fuser.fuse_landmarks(msg.receiver, msg.ids, msg.means, msg.covs, self.mode)
            self.fused[msg.receiver] += fused

    def terms(self) -> dict[str, float]:
        """The episode's counts so far (:data:`COUNT_KEYS`) as floats."""
        return {key: float(value) for key, value in self.counts.items()}


class Uplink:
    """What the vehicles of a centralised team (``team.fusion: centralised``) send to the one
    estimator: each step every IMU sample (:data:`~quadslam_env.team.config.IMU_SAMPLE_FLOATS`
    floats) and every scan (its time and each return's id and measurement,
    :data:`~quadslam_env.team.config.RETURN_FLOATS`), :data:`FLOAT_BYTES` per float: the
    measurements the one graph needs from each vehicle, had it run elsewhere.

    Args:
        imu_per_step: IMU samples per control step.
    """

    def __init__(self, imu_per_step: int) -> None:
        self.imu_per_step = imu_per_step
        self.bytes_sent = 0

    def reset(self) -> None:
        """A new episode: nothing sent."""
        self.bytes_sent = 0

    def send(self, stepped: np.ndarray, scans: Scans | None) -> None:
        """Count the step's samples of the ``stepped`` (N,) bool vehicles and their ``scans``
        (the core's last scan: ``None`` when no vehicle scanned)."""
        floats = int(stepped.sum()) * self.imu_per_step * IMU_SAMPLE_FLOATS
        if scans is not None:
            lanes = scans.lanes[stepped[scans.lanes]]
            floats += int((1 + RETURN_FLOATS * scans.n_returns[lanes]).sum())
        self.bytes_sent += FLOAT_BYTES * floats
