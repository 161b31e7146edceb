"""The estimator boundary: what the simulation core needs from an estimator.

See docs/design.md §5 and §9. The core steps B independent episodes ("lanes") in lockstep and
talks to its estimator through :class:`BatchEstimator`: arrays in, arrays out, with a lane mask
wherever lanes differ (a lane that scans this step, a lane that is being reset). An estimator
written for one vehicle implements :class:`Estimator` instead and enters through the one
adapter, :class:`~quadslam_env.estimation.lane_loop.LaneLoop`. Estimators never receive the
true state (the oracle, which says ``uses_truth = True``, is the one exception).

Abilities that only some estimators have are protocols of their own, checked with
``isinstance(estimator, Ability)`` where they are used (docs/design.md §5): of a batch,
:class:`ReservesLandmarks`, :class:`AssociatesUnlabeled`, :class:`UsesTruth`,
:class:`ShowsParticles`, :class:`HasFullState`, :class:`TakesVehicle`, :class:`TakesWind`,
:class:`TakesLateScans`, :class:`MonitorsIntegrity`, :class:`FusesLandmarks` and
:class:`FusesRanges`;
of one vehicle's estimator (what :class:`~quadslam_env.estimation.lane_loop.LaneLoop` asks its
lanes), :class:`ChecksMemory`, :class:`LabelsReturns`, :class:`HasParticles`,
:class:`UsesVehicle`, :class:`ModelsDrag` and :class:`JoinsTeam`. A runtime-checkable protocol's
``isinstance`` only checks that the names exist, not their signatures or types, and no
estimator names these protocols as bases, so nothing checks an implementation's signature
against them; the call sites are typed by the protocol, and
``tests/estimators/test_estimator_abilities.py`` checks which built-in has which ability. What the
scenario check must know before any estimator is built is a class flag that the registry
reads instead: ``associates_unlabeled``, ``uses_truth``, ``copyable = False`` (an estimator
the env cannot deep-copy for a slow IMU or a delayed LiDAR), ``takes_late_scans`` (one that
takes a delayed LiDAR's scans at their own time without a copy), ``models_drag`` (a process
model with drag, which ``wind.inform_estimator`` needs), ``monitors_integrity``,
``fuses_landmarks`` (the team env's map fusion), ``fuses_ranges`` (its ranges between
vehicles) and ``joins_team`` (one estimator of the whole team).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np

from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.params import VehicleParams
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

    def estimate(self) -> BatchEstimate:
        """A snapshot of the current belief with B = 1, with landmark covariances
        (:meth:`BatchEstimate.one_lane`), whose arrays nothing writes to afterwards."""


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
        :mod:`quadslam_env.runtime.imu_replay`); ``thrust`` (B,) N and ``torque`` (B, 3) N·m
        applied.
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
    # also implement :class:`AssociatesUnlabeled`; a one-vehicle :class:`Estimator` then gets
    # a :class:`LidarScan` with ``ids=None`` and implements :class:`LabelsReturns`.

    def estimate(self) -> BatchEstimate:
        """The belief of every lane."""

    def lane_estimate(self, lane: int) -> BatchEstimate:
        """A snapshot of lane ``lane`` alone (B = 1, copies), with landmark covariances."""


# ---------------------------------------------------------------- abilities of a batch
@runtime_checkable
class ReservesLandmarks(Protocol):
    """A batch estimator that sizes its map ahead of the scans (EKF-SLAM)."""

    def reserve_landmarks(self, count: int) -> None:
        """Make room for landmark ids ``0 … count-1`` now: the env calls it at a reset that
        brings a map, so a map that cannot fit in memory fails there, not at the first scan.

        Raises:
            ValueError: The map would not fit.
        """


@runtime_checkable
class AssociatesUnlabeled(Protocol):
    """A batch estimator that takes unlabeled scans (``lidar.association: unknown``).

    Its class also says ``associates_unlabeled = True``, which the scenario check reads
    (:func:`~quadslam_env.estimation.registry.associates_unlabeled`) before any estimator is
    built; the env calls :meth:`update_unlabeled` only then.
    """

    @property
    def last_association(self) -> np.ndarray:
        """(B, R) int the label (index into ``landmark_means``) each return of every lane's
        last unlabeled scan was paired with, -1 for none."""

    def update_unlabeled(
        self,
        t: FloatArray,
        lanes: IntArray,
        count: np.ndarray,
        returns: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Correct ``lanes`` (k,) with unlabeled scans: lane b's returns are
        ``returns[b, :count[b]]`` of ``returns`` (B, R, 3) (α rad, β rad, δ m), in any
        order, with false returns among them; ``count`` (B,) int; ``sigma`` (3,)."""


@runtime_checkable
class UsesTruth(Protocol):
    """The one batch estimator the env feeds with the truth (the oracle, for ablations).

    Its class also says ``uses_truth = True`` (:class:`BatchEstimator`); the env calls
    :meth:`set_truth` before every snapshot.
    """

    def set_truth(self, states: FloatArray, landmarks: FloatArray, counts: np.ndarray) -> None:
        """Receive the true states (B, 12) and maps (B, L, 3) N m, ``counts`` (B,) landmarks."""


@runtime_checkable
class ShowsParticles(Protocol):
    """A batch estimator whose lanes are particle clouds the renderer draws (FastSLAM)."""

    def lane_particles(self, lane: int) -> FloatArray:
        """(N, 3) particle positions ρ of lane ``lane`` in N, m (a copy)."""


@runtime_checkable
class HasFullState(Protocol):
    """A batch estimator with one Gaussian over the whole state (EKF-SLAM), for inspection."""

    def full_state(self, lane: int = 0) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Lane ``lane``'s mean (n,), covariance (n, n) and the landmark id of each map slot."""


@runtime_checkable
class ReportsLandmarkCovariances(Protocol):
    """A batch estimator that gives every lane's landmark covariances at once (EKF-SLAM); the
    team env's map terms read them each step (without it, one lane snapshot per vehicle)."""

    def landmark_covariances(self) -> FloatArray:
        """(B, Lmax, 3, 3) m² each lane's landmark covariances by id: those of the landmarks
        :meth:`BatchEstimator.estimate` reports mapped; the other rows are undefined."""


@runtime_checkable
class TakesVehicle(Protocol):
    """A batch estimator that can be told each lane's vehicle (``randomize.inform_estimator``).

    A batch whose model uses no vehicle parameter may implement it as a no-op;
    :class:`~quadslam_env.estimation.lane_loop.LaneLoop` passes each vehicle on to the lanes
    that :class:`UsesVehicle`.
    """

    def set_vehicle(self, lanes: IntArray, vehicles: Sequence[VehicleParams]) -> None:
        """Use ``vehicles[j]`` as lane ``lanes[j]``'s model (k,) from its next reset on; the
        env calls it just before :meth:`BatchEstimator.reset_lanes` of those lanes."""


@runtime_checkable
class TakesWind(Protocol):
    """A batch estimator that takes the wind as a known disturbance input
    (``wind.inform_estimator``); its class says ``models_drag = True``."""

    def set_wind(self, wind: FloatArray) -> None:
        """The wind (B, 3) in N, m/s held over the next predictions (the simulator's wind of
        the step being predicted), read, not kept."""


@runtime_checkable
class TakesLateScans(Protocol):
    """A batch estimator that takes a scan measured in the past (a delayed LiDAR,
    ``lidar.delay_steps``) without a copy of itself: its ``update`` (and ``update_unlabeled``)
    of a scan whose time ``t`` is before the lanes' latest IMU samples applies the scan to the
    belief of time ``t`` and keeps the lanes' present, the IMU samples since ``t`` included
    (the iSAM2 smoother inserts a keyframe at ``t``). A scan at the time of the latest sample
    is an ordinary update. Scans of a lane must arrive in time order, each after the scans
    measured before it.

    Its class also says ``takes_late_scans = True``, which the scenario check reads
    (:func:`~quadslam_env.estimation.registry.takes_late_scans`) before any estimator is built.
    """

    @property
    def takes_late_scans(self) -> bool:
        """Whether ``update`` of a past scan keeps the present (a batch of one-vehicle
        estimators: their class flag)."""


@runtime_checkable
class MonitorsIntegrity(Protocol):
    """A batch estimator with an integrity monitor (the scenario's ``integrity`` section): it
    tests each scan, leaves out the landmarks found faulty and reports the counts and the
    solution separations of :mod:`quadslam_env.estimation.integrity` in its diagnostics; its
    class says ``monitors_integrity = True``."""

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Monitor every later scan with ``settings`` (``None``: no monitor, the default)."""


@runtime_checkable
class FusesLandmarks(Protocol):
    """A batch estimator that fuses another vehicle's landmark estimates into a lane's state
    (the team env's ``team.fusion`` ``ci`` and ``naive``, docs/team.md); its class says
    ``fuses_landmarks = True``, which the team settings' check reads before any estimator is
    built."""

    def fuse_landmarks(
        self, lane: int, ids: np.ndarray, means: FloatArray, covs: FloatArray, mode: str
    ) -> tuple[int, float]:
        """Fuse the landmarks ``ids`` (k,) with means (k, 3) m and covariances (k, 3, 3) m²,
        N frame, by the rule ``mode`` (``ci``: covariance intersection; ``naive``: a Kalman
        update as if independent) into lane ``lane``; returns how many were fused (those the
        lane has mapped) and the CI weight ω (1 for ``naive``, NaN if none or failed).
        ``covs`` may also be the landmarks' joint covariance (3k, 3k)."""

    def landmark_covariance(self, lane: int, ids: np.ndarray) -> FloatArray:
        """The joint covariance (3k, 3k) m² of lane ``lane``'s mapped landmarks ``ids`` (k,),
        in their order (what a message with ``team.message_covariance: joint`` carries)."""


@runtime_checkable
class FusesRanges(Protocol):
    """A batch estimator that fuses a range to another vehicle, whose position estimate is
    broadcast, into a lane's state (the team env's ``team.range_fusion: ci``, docs/team.md);
    its class says ``fuses_ranges = True``, which the team settings' check reads before any
    estimator is built."""

    def fuse_range(
        self,
        lane: int,
        beacon: FloatArray,
        beacon_cov: FloatArray,
        measured_m: float,
        sigma_m: float,
    ) -> tuple[float, float]:
        """Fuse the range ``measured_m`` m (noise std ``sigma_m`` m) from lane ``lane``'s
        vehicle to another vehicle estimated at ``beacon`` (3,) m, N frame, with covariance
        ``beacon_cov`` (3, 3) m², by covariance intersection (the correlation between the
        two is unknown); returns the CI weight ω (NaN if not fused) and the innovation, m."""


# ---------------------------------------------------------- abilities of one vehicle's
@runtime_checkable
class ChecksMemory(Protocol):
    """A one-vehicle estimator that can tell whether B of it fit in memory (FastSLAM)."""

    def check_memory(self, num_lanes: int, landmark_capacity: int) -> None:
        """Reject ``num_lanes`` instances with ``landmark_capacity`` landmarks each.

        Raises:
            ValueError: The batch would not fit (names the sizes and what would fit).
        """


@runtime_checkable
class LabelsReturns(Protocol):
    """A one-vehicle estimator that takes unlabeled scans (``LidarScan.ids is None``).

    Its class also says ``associates_unlabeled = True``.
    """

    @property
    def last_association(self) -> np.ndarray:
        """(k,) int the landmark id each return of the last unlabeled scan was paired with
        (-1: none)."""


@runtime_checkable
class EstimatesState(Protocol):
    """A one-vehicle estimator whose snapshot can leave the landmark covariances out.

    The env's per-step snapshot of every lane has no landmark covariances
    (:func:`~quadslam_env.estimation.snapshot.stack_lanes`); an estimator for which they cost
    more than the rest of the snapshot (iSAM2 recovers them from its Bayes tree) gives the
    lane loop this cheaper one and computes them only when
    :meth:`Estimator.estimate` is called.
    """

    def state_estimate(self) -> BatchEstimate:
        """:meth:`Estimator.estimate` with ``landmark_covs`` None (the same belief otherwise)."""


@runtime_checkable
class HasParticles(Protocol):
    """A one-vehicle particle filter (FastSLAM)."""

    lineage: np.ndarray
    """(N,) int index of each particle's ancestor among the particles drawn at reset."""

    def particle_positions(self) -> FloatArray:
        """(N, 3) particle positions ρ in N, m (a copy)."""


@runtime_checkable
class UsesVehicle(Protocol):
    """A one-vehicle estimator whose process model uses the vehicle's parameters (FastSLAM)."""

    def set_vehicle(self, vehicle: VehicleParams) -> None:
        """Use ``vehicle`` instead of the one it was built with (every constant taken from the
        vehicle is refreshed); the env calls it just before a reset."""


@runtime_checkable
class ModelsDrag(Protocol):
    """A one-vehicle estimator whose process model has the drag, so a known wind changes it
    (its class says ``models_drag = True``)."""

    def set_wind(self, wind: FloatArray) -> None:
        """The wind (3,) in N, m/s held over the next predictions (copied)."""


@runtime_checkable
class JoinsTeam(Protocol):
    """A one-vehicle estimator whose instances, one per vehicle of the team env, can be one
    estimator of the whole team (``team.fusion: centralised``, docs/team-fusion.md; its class
    says ``joins_team = True``, which the team settings' check reads)."""

    def join(self, team: Sequence[JoinsTeam], index: int) -> None:
        """Be vehicle ``index`` of ``team`` (every vehicle's estimator, this one at ``index``)
        from the next reset on; the team env resets vehicle 0 first, then the others."""

    def range_to(self, other: int, measured_m: float, sigma_m: float) -> bool:
        """Fuse a range (m, std ``sigma_m``) between this vehicle and vehicle ``other``
        measured at the end of the last step; returns whether it was fused."""
