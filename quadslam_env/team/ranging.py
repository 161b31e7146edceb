"""The ranges between the team's vehicles: who measures which distance when, and whom each
range reaches (docs/team-fusion.md "Ranges between vehicles").

With ``team.ranges``, at each range epoch (the end of a step on which ⌊t · rate⌋ grows,
``team.range_rate_hz``) every pair (i, j), i < j, of vehicles live after the step whose true
distance is at most ``team.range_max_m`` gets one range ``‖ρ_i − ρ_j‖ + n``,
``n ~ N(0, σ²)`` (``team.range_sigma_m``), lost with ``team.range_dropout``; both draws come
from vehicle i's range generator, spawned from the vehicle's stream at each reset after every
other spawn of the reset (the core's, then the messages'), so the vehicles' other draws and the
messages' drops are those without ranges. Both ends of the pair measure the range (two-way
ranging).

With ``team.range_fusion: ci`` each end broadcasts its position estimate with its 3×3
covariance at the epoch (3 + 6 floats, counted once per vehicle in ``team_bytes_sent``; with
``factor``, one end sends the range to the team's one graph, 3 floats), and at
the start of the next step, before the step's prediction, each live vehicle fuses every range
it measured with the other's broadcast estimate, by the estimator's
:class:`~quadslam_env.estimation.protocol.FusesRanges` (the math is the estimator's:
:mod:`estimators.ekf.ranging`). With ``none`` the ranges are only in the ``info``.

Coordination only: no estimation math here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import cast

import numpy as np

from quadslam_env.estimation.lane_loop import LaneLoop
from quadslam_env.estimation.protocol import BatchEstimator, FusesRanges
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.team.comms import rate_ticks
from quadslam_env.team.config import BEACON_FLOATS, FLOAT_BYTES, RANGE_FLOATS, TeamConfig
from quadslam_env.types import FloatArray

VEHICLE_KEYS = (
    "team_ranges_measured",
    "team_ranges_fused",
    "team_range_ci_weight",
    "team_range_residual_rms_m",
)
"""The per-vehicle ``info`` terms of the ranges (:meth:`Ranges.vehicle_terms`), with
``team_range_to_vehicle_<j>_m`` for each other vehicle j."""


@dataclass(frozen=True)
class Range:
    """One measured range of an epoch, with both ends' broadcast position estimates.

    Attributes:
        i: The lower-numbered vehicle.
        j: The other vehicle.
        measured_m: The range, m.
        beacons: (2, 3) the position estimates of i and j at the epoch, m, N frame.
        beacon_covs: (2, 3, 3) their covariances, m².
    """

    i: int
    j: int
    measured_m: float
    beacons: FloatArray
    beacon_covs: FloatArray


class Ranges:
    """The ranges of one episode (module docstring).

    Args:
        team: The team settings (``team.ranges`` true).
        n_vehicles: N.
        control_hz: Control steps per second.
    """

    def __init__(self, team: TeamConfig, n_vehicles: int, control_hz: float) -> None:
        self.n_vehicles = n_vehicles
        self.fusion = team.range_fusion
        self.sigma_m = team.range_sigma_m
        self._per_step = team.range_rate_hz / control_hz
        self._dropout = team.range_dropout
        self._max_m = team.range_max_m
        self._rngs: list[np.random.Generator] = []
        self._pending: list[Range] = []
        self.bytes_sent = 0
        self.measured = np.zeros(n_vehicles, dtype=np.int64)
        """(N,) the ranges each vehicle measured at the end of the last step."""
        self.fused = np.zeros(n_vehicles, dtype=np.int64)
        """(N,) the ranges each vehicle fused at the start of the last step."""
        self.omega = np.full(n_vehicles, math.nan)
        """(N,) the mean CI weight ω of the ranges each vehicle fused at the start of the last
        step (NaN: none)."""
        self.ranges_m = np.full((n_vehicles, n_vehicles), math.nan)
        """(N, N) the ranges measured at the end of the last step, m (symmetric; NaN: none)."""
        self.residual_rms_m = np.full(n_vehicles, math.nan)
        """(N,) each vehicle's RMS over the ranges of its latest epoch of ``r − ‖ρ̂_i − ρ̂_j‖``
        (the estimates at the epoch), m; NaN before its first range."""

    def reset(self, rngs: list[np.random.Generator]) -> None:
        """Start an episode: no range pending, the counts at 0, and each vehicle's range
        generator spawned from its stream ``rngs`` (N,) (after every other spawn of the reset:
        module docstring)."""
        self._rngs = [rng.spawn(1)[0] for rng in rngs]
        self._pending = []
        self.bytes_sent = 0
        self.measured[:] = 0
        self.fused[:] = 0
        self.omega[:] = math.nan
        self.ranges_m[:] = math.nan
        self.residual_rms_m[:] = math.nan

    def due(self, steps_done: int) -> bool:
        """Whether the end of step ``steps_done`` (≥ 1) is a range epoch (⌊t · rate⌋ grows)."""
        return bool(rate_ticks(np.asarray(steps_done), self._per_step))

    def measure(
        self, positions: FloatArray, est: BatchEstimate, live: np.ndarray, steps_done: int
    ) -> None:
        """At the end of a step: the ranges of the epoch, if it is one.

        Args:
            positions: (N, 3) true positions after the step, m, N frame.
            est: The core's snapshot after the step (B = N: ``position`` (N, 3) m and
                ``pose_cov`` (N, 9, 9), whose first 3×3 block is the broadcast covariance).
            live: (N,) bool the vehicles still in the episode after the step.
            steps_done: The team's steps so far.
        """
        self.measured[:] = 0
        self.ranges_m[:] = math.nan
        if not self.due(steps_done):
            return
        sq: list[list[float]] = [[] for _ in range(self.n_vehicles)]
        broadcast = np.zeros(self.n_vehicles, dtype=bool)
        lanes = np.flatnonzero(live).tolist()
        for a, i in enumerate(lanes):
            for j in lanes[a + 1 :]:
                true_m = float(np.linalg.norm(positions[i] - positions[j]))
                if true_m > self._max_m:
                    continue
                noise, lost = self._rngs[i].standard_normal(), self._rngs[i].random()
                if lost < self._dropout:
                    continue
                measured = true_m + self.sigma_m * float(noise)
                self.ranges_m[i, j] = self.ranges_m[j, i] = measured
                pair = [i, j]
                beacons = np.array(est.position[pair], dtype=float)
                covs = np.zeros((2, 3, 3))
                if est.pose_cov is not None:
                    covs = np.array(est.pose_cov[pair, :3, :3], dtype=float)
                residual = measured - float(np.linalg.norm(beacons[0] - beacons[1]))
                for k in pair:
                    self.measured[k] += 1
                    sq[k].append(residual * residual)
                broadcast[pair] = True
                if self.fusion != "none":
                    self._pending.append(Range(i, j, measured, beacons, covs))
        for k in np.flatnonzero(self.measured).tolist():
            self.residual_rms_m[k] = math.sqrt(sum(sq[k]) / len(sq[k]))
        if self.fusion == "ci":
            self.bytes_sent += FLOAT_BYTES * BEACON_FLOATS * int(broadcast.sum())
        elif self.fusion == "factor":  # one end sends each range to the team's one graph
            self.bytes_sent += FLOAT_BYTES * RANGE_FLOATS * len(self._pending)

    def deliver(self, estimator: BatchEstimator, live: np.ndarray) -> None:
        """At the start of a step: each ``live`` (N,) vehicle fuses the ranges of the last
        epoch with the other end's broadcast estimate (``range_fusion: ci``), or each range of
        two live vehicles enters the team's one graph (``factor``); sets :attr:`fused` (N,)."""
        self.fused[:] = 0
        self.omega[:] = math.nan
        if not self._pending:
            return
        if self.fusion == "factor":
            self._deliver_factors(cast(LaneLoop, estimator), live)
            return
        fuser = cast(FusesRanges, estimator)  # the team settings' check saw its flag
        weights = np.zeros(self.n_vehicles)
        for rng in self._pending:
            for me, other in ((0, 1), (1, 0)):
                lane = (rng.i, rng.j)[me]
                if not live[lane]:
                    continue
                omega, _ = fuser.fuse_range(
                    lane, rng.beacons[other], rng.beacon_covs[other], rng.measured_m, self.sigma_m
                )
                if omega == omega:  # not NaN: fused
                    self.fused[lane] += 1
                    weights[lane] += omega
        self._pending = []
        some = self.fused > 0
        self.omega[some] = weights[some] / self.fused[some]

    def _deliver_factors(self, estimator: LaneLoop, live: np.ndarray) -> None:
        """The ranges of the last epoch as factors of the team's graph (``factor``; the team
        settings' check saw ``fusion: centralised``), each counted as fused by both ends."""
        for rng in self._pending:
            both = bool(live[rng.i] and live[rng.j])
            if both and estimator.range_between(rng.i, rng.j, rng.measured_m, self.sigma_m):
                self.fused[[rng.i, rng.j]] += 1
        self._pending = []

    def vehicle_terms(self) -> dict[str, FloatArray]:
        """Each vehicle's terms (:data:`VEHICLE_KEYS`) as (N,) floats (NaN: does not apply),
        then its range to each vehicle j of the last step, ``team_range_to_vehicle_<j>_m``."""
        none = np.full(self.n_vehicles, math.nan)
        out = {
            "team_ranges_measured": self.measured.astype(float),
            "team_ranges_fused": none if self.fusion == "none" else self.fused.astype(float),
            "team_range_ci_weight": self.omega.copy(),
            "team_range_residual_rms_m": self.residual_rms_m.copy(),
        }
        for j in range(self.n_vehicles):
            out[f"team_range_to_vehicle_{j}_m"] = self.ranges_m[:, j].copy()
        return out
