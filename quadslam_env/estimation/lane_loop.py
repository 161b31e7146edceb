"""The one adapter from a scalar :class:`~quadslam_env.estimation.protocol.Estimator` to the
batched boundary: a Python loop over B scalar estimators (docs/design.md §9)."""

from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.protocol import (
    ChecksMemory,
    EstimatesState,
    Estimator,
    HasParticles,
    IntArray,
    JoinsTeam,
    KnownMaps,
    LabelsReturns,
    ModelsDrag,
    MonitorsIntegrity,
    UsesVehicle,
)
from quadslam_env.estimation.snapshot import BatchEstimate, empty_batch, id_width, stack_lanes
from quadslam_env.models.params import VehicleParams
from quadslam_env.types import FloatArray


def _check_memory(lane: Estimator, num_lanes: int, landmark_capacity: int) -> None:
    """Ask ``lane`` whether ``num_lanes`` of it fit in memory, if it has a check."""
    if isinstance(lane, ChecksMemory):  # the filters of the whole batch, before they grow
        lane.check_memory(num_lanes, landmark_capacity)


class LaneLoop:
    """A :class:`BatchEstimator` over B scalar estimators, one per lane (a Python loop).

    This is how estimators without a batched implementation (FastSLAM, plug-ins) run in the
    vector env; its cost is the scalar estimator's times B plus the per-lane conversion of
    samples and scans and the copy of each lane's one-lane snapshot into the batch.

    An estimator that :class:`~quadslam_env.estimation.protocol.ChecksMemory` (FastSLAM) is
    asked whether B of it fit in memory: :meth:`build` asks the first lane before it builds
    the others, so a batch that cannot fit fails fast with one line instead of allocating
    lane after lane. :meth:`build` over particle filters
    (:class:`~quadslam_env.estimation.protocol.HasParticles`) returns a
    :class:`ParticleLaneLoop`, which shows their particles. A one-vehicle estimator never
    receives the truth (``uses_truth`` is False; the oracle is batched).

    Args:
        estimators: The B scalar estimators.
        landmark_capacity: Initial Lmax of the landmark output arrays (grows as needed).
        check_memory: Ask the first lane whether the batch fits (:meth:`build` has asked).
    """

    uses_truth = False

    def __init__(
        self,
        estimators: Sequence[Estimator],
        landmark_capacity: int,
        *,
        check_memory: bool = True,
    ) -> None:
        self.lanes = list(estimators)
        self.num_lanes = len(self.lanes)
        if check_memory:
            _check_memory(self.lanes[0], self.num_lanes, landmark_capacity)
        b = self.num_lanes
        self._estimates: list[BatchEstimate | None] = [None] * b
        # Lanes whose per-step snapshot may leave the landmark covariances out (iSAM2).
        self._states_only = [isinstance(e, EstimatesState) for e in self.lanes]
        self._out = empty_batch(b, max(landmark_capacity, 0))
        self._joined = False  # one estimator of a team: an update changes every lane's map
        self.last_association = np.zeros((b, 0), dtype=np.int64)
        """(B, R) int the scalar estimators' labels of their last unlabeled scans' returns."""

    @classmethod
    def build(
        cls, factory: Callable[[], Estimator], num_lanes: int, landmark_capacity: int
    ) -> LaneLoop:
        """B estimators made by ``factory()``, checked for memory before all but one exist.

        The first lane is built (a filter checks its own arrays before allocating them), then
        asked whether ``num_lanes`` of it fit with ``landmark_capacity`` landmarks; only then
        are the other lanes built. Particle filters get a :class:`ParticleLaneLoop`.

        Raises:
            ValueError: The batch would not fit in memory (from the estimator's check).
        """
        first = factory()
        _check_memory(first, num_lanes, landmark_capacity)
        lanes = [first, *(factory() for _ in range(num_lanes - 1))]
        kind = ParticleLaneLoop if isinstance(first, HasParticles) else cls
        return kind(lanes, landmark_capacity, check_memory=False)

    def reset_lanes(
        self,
        lanes: IntArray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Reset each listed lane's scalar estimator (see :class:`BatchEstimator`)."""
        for j, lane in enumerate(np.asarray(lanes).tolist()):
            known = None if known_landmarks is None else known_landmarks[j]
            self.lanes[lane].reset(mean0[j], cov0[j], rngs[j], known_landmarks=known)
            self._estimates[lane] = None

    def set_vehicle(self, lanes: IntArray, vehicles: Sequence[VehicleParams]) -> None:
        """Pass ``vehicles`` (k,) to the listed lanes that
        :class:`~quadslam_env.estimation.protocol.UsesVehicle` (the others use none)."""
        for lane, vehicle in zip(np.asarray(lanes).tolist(), vehicles, strict=True):
            est = self.lanes[lane]
            if isinstance(est, UsesVehicle):
                est.set_vehicle(vehicle)

    def set_wind(self, wind: FloatArray) -> None:
        """Pass each lane its row of the wind (B, 3) in N, m/s if it
        :class:`~quadslam_env.estimation.protocol.ModelsDrag`."""
        for lane, est in enumerate(self.lanes):
            if isinstance(est, ModelsDrag):
                est.set_wind(wind[lane])

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
        """Call each active lane's ``predict`` with its :class:`ImuSample` and :class:`Control`."""
        for lane in np.flatnonzero(active).tolist():
            imu = ImuSample(
                t=float(t[lane]),
                accel=accel[lane].copy(),
                gyro=gyro[lane].copy(),
                accel_sigma=accel_sigma,
                gyro_sigma=gyro_sigma,
            )
            control = Control(thrust=float(thrust[lane]), torque=torque[lane].copy())
            self.lanes[lane].predict(imu, control, dt)
            self._estimates[lane] = None

    def update(
        self,
        t: FloatArray,
        lanes: IntArray,
        visible: np.ndarray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Call each listed lane's ``update`` with its :class:`LidarScan` (ids ascending)."""
        for lane in np.asarray(lanes).tolist():
            ids = np.flatnonzero(visible[lane])
            scan = LidarScan(t=float(t[lane]), ids=ids, meas=meas[lane, ids], sigma=sigma)
            self.lanes[lane].update(scan)
            self._changed(lane)

    def _changed(self, lane: int) -> None:
        """Forget lane ``lane``'s cached snapshot (every lane's, joined in a team)."""
        if self._joined:
            self._estimates = [None] * self.num_lanes
        else:
            self._estimates[lane] = None

    def join_team(self) -> None:
        """Make the lanes' estimators one estimator of the team, lane i its vehicle i
        (:class:`~quadslam_env.estimation.protocol.JoinsTeam`; ``team.fusion: centralised``).

        Raises:
            TypeError: A lane's estimator cannot join (its class lacks ``join``).
        """
        for index, est in enumerate(self.lanes):
            if not isinstance(est, JoinsTeam):
                raise TypeError(f"lane {index}: {type(est).__name__} cannot join a team")
            est.join(self.lanes, index)  # type: ignore[arg-type]
        self._joined = True

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Give every lane's estimator the integrity monitor's ``settings``
        (:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity`; the scenario check has
        read its class flag).

        Raises:
            TypeError: A lane's estimator has no monitor.
        """
        for index, est in enumerate(self.lanes):
            if not isinstance(est, MonitorsIntegrity):
                raise TypeError(f"lane {index}: {type(est).__name__} has no integrity monitor")
            est.set_monitor(settings)
            self._estimates[index] = None

    def range_between(self, lane: int, other: int, measured_m: float, sigma_m: float) -> bool:
        """Fuse a range between lanes ``lane`` and ``other`` of a team's one estimator (after
        :meth:`join_team`; ``team.range_fusion: factor``); returns whether it was fused."""
        est = self.lanes[lane]
        if not isinstance(est, JoinsTeam):
            raise TypeError(f"lane {lane}: {type(est).__name__} is not a team's estimator")
        fused = est.range_to(other, measured_m, sigma_m)
        self._changed(lane)
        return fused

    @property
    def associates_unlabeled(self) -> bool:
        """Whether the scalar estimators accept unlabeled scans (unknown association)."""
        return bool(getattr(self.lanes[0], "associates_unlabeled", False))

    @property
    def takes_late_scans(self) -> bool:
        """Whether the scalar estimators' ``update`` takes a scan measured in the past and
        keeps their present (their class flag;
        :class:`~quadslam_env.estimation.protocol.TakesLateScans`)."""
        return bool(getattr(self.lanes[0], "takes_late_scans", False))

    def update_unlabeled(
        self,
        t: FloatArray,
        lanes: IntArray,
        count: np.ndarray,
        returns: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Call each listed lane's ``update`` with an unlabeled :class:`LidarScan`
        (``ids=None``) and collect its ``last_association`` (k,) into :attr:`last_association`."""
        width = returns.shape[1]
        old = self.last_association
        if old.shape[1] < width:  # wider: keep the labels of lanes updated earlier this step
            self.last_association = np.full((self.num_lanes, width), -1, dtype=np.int64)
            self.last_association[:, : old.shape[1]] = old
        for lane in np.asarray(lanes).tolist():
            k = int(count[lane])
            scan = LidarScan(t=float(t[lane]), ids=None, meas=returns[lane, :k].copy(), sigma=sigma)
            est = self.lanes[lane]
            est.update(scan)
            self.last_association[lane] = -1
            if isinstance(est, LabelsReturns):  # else no return is labeled
                self.last_association[lane, :k] = est.last_association
            self._changed(lane)

    def lane_estimate(self, lane: int) -> BatchEstimate:
        """The scalar estimator's own one-lane snapshot (cached until the lane changes)."""
        est = self._estimates[lane]
        if est is None:
            est = self.lanes[lane].estimate()
            self._estimates[lane] = est
        return est

    def _lane_state(self, lane: int) -> BatchEstimate:
        """Lane ``lane``'s snapshot for the batch: its cached one-lane snapshot, else, from an
        :class:`~quadslam_env.estimation.protocol.EstimatesState` estimator, one without
        landmark covariances (the batch leaves them out; the estimator caches it)."""
        est = self._estimates[lane]
        if est is not None:
            return est
        if self._states_only[lane]:
            return self.lanes[lane].state_estimate()  # type: ignore[attr-defined]
        return self.lane_estimate(lane)

    def estimate(self) -> BatchEstimate:
        """Copy lane 0 of every lane's one-lane snapshot into the batch arrays (without the
        landmark covariances)."""
        snaps = [self._lane_state(lane) for lane in range(self.num_lanes)]
        need = id_width(snaps)
        if need > self._out.landmark_means.shape[1]:
            self._out = empty_batch(self.num_lanes, need)
        stack_lanes(self._out, snaps)
        return self._out


class ParticleLaneLoop(LaneLoop):
    """A :class:`LaneLoop` over particle filters (FastSLAM), which also
    :class:`~quadslam_env.estimation.protocol.ShowsParticles` (for display)."""

    def lane_particles(self, lane: int) -> FloatArray:
        """(N, 3) particle positions ρ of lane ``lane`` in N, m (a copy)."""
        est = self.lanes[lane]
        if not isinstance(est, HasParticles):
            raise TypeError(f"lane {lane}: {type(est).__name__} is not a particle filter")
        return est.particle_positions()
