"""One smoother for a team: the vehicles of the team env as lanes of one factor graph
(``team.fusion: centralised``, docs/team-fusion.md "Centralised").

Each vehicle keeps its own :class:`~estimators.isam2.estimator.Isam2Slam` front (its
preintegration, its keyframes, its snapshot), but the vehicles of one world share one
:class:`~estimators.isam2.fixed_lag.FixedLagIsam2` and one map: vehicle ``i``'s states are the
keys ``x``, ``v``, ``b`` with its keyframe index offset by ``i ·`` :data:`VEHICLE_STRIDE`
(vehicle 0's are the single estimator's own), and a landmark id names the same ``l`` key for
every vehicle, so two vehicles' returns of one landmark constrain one variable. The graph so
holds every vehicle's IMU factors (Forster et al. 2017) and LiDAR factors (seed 001 eq.
30–31) over the shared landmarks: the reference a decentralised fusion is measured against
(the third source paper, §6: the measurements in one estimator, no correlation to guess).

The common frame is anchored by the known start poses: each vehicle's first keyframe has the
prior of its own initial belief (:func:`~estimators.isam2.graph.first_keyframe`) in the N frame
the team shares.

Order of the calls: the team env resets vehicle 0 first (its reset builds the smoother), then
the others, which add their first keyframes to it; within a step each vehicle's scan is one
smoother update (in lane order). After an update every other vehicle's map is the new one and
its landmark covariances are recovered afresh when a snapshot asks; its own state is its last
keyframe's, read when it was added (a filter's estimate: later scans of the others refine the
smoother, not the snapshot, until its next keyframe).

With ``team.range_fusion: factor`` a range between two vehicles measured at the instant of
their keyframes is a factor between those keyframes (:meth:`TeamMember.range_to`).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from quadslam_env.estimation.snapshot import BatchEstimate, LaneMap
from quadslam_env.types import FloatArray

VEHICLE_STRIDE = 10**6
"""Keyframe indices per vehicle in the state keys: vehicle i's keyframe k is index
``i · VEHICLE_STRIDE + k`` (10⁶ keyframes: 27 h of 10 Hz scans). Decimal, and the keys below
10⁸ (:data:`MAX_VEHICLES`), because the fixed-lag window tells the Bayes tree's variables by
GTSAM's printed key names (``ISAM2.dot``), and the Python key formatter prints 8 digits."""

MAX_VEHICLES = 99
"""Vehicles a team's smoother holds (their keys stay below 10⁸)."""


class TeamMember:
    """Mixin of :class:`~estimators.isam2.estimator.Isam2Slam`: a vehicle of a team that shares
    one smoother and one map (module docstring); alone (the default) it is the single
    estimator, bit for bit."""

    # The team env's check reads it (quadslam_env.estimation.registry.joins_team).
    joins_team = True

    _team: list[TeamMember]
    _vehicle: int
    _smoother: Any
    _lm_means: dict[int, FloatArray]
    _lm_covs: dict[int, FloatArray] | None
    _lm_map: LaneMap | None
    _cache: BatchEstimate | None
    _state_cache: BatchEstimate | None

    def join(self, team: Sequence[Any], index: int) -> None:
        """Make this estimator vehicle ``index`` of ``team``, the estimators of every vehicle
        (``team[index]`` is this one), from its next reset on.

        Raises:
            ValueError: ``team[index]`` is not this estimator, a member cannot join, or the
                team has more than :data:`MAX_VEHICLES` vehicles.
        """
        members = list(team)
        if len(members) > MAX_VEHICLES:
            raise ValueError(f"join: {len(members)} vehicles; allowed: at most {MAX_VEHICLES}")
        if not 0 <= index < len(members) or members[index] is not self:
            raise ValueError(f"join: team[{index}] must be this estimator")
        for member in members:
            if not isinstance(member, TeamMember):
                raise ValueError(f"join: {type(member).__name__} cannot share a smoother")
        self._team = members
        self._vehicle = index

    def _team_smoother(self) -> Any | None:
        """The team's smoother for a vehicle after the first (``None``: build one — alone, or
        vehicle 0, whose reset starts the team's episode).

        Raises:
            ValueError: Vehicle 0 has not been reset.
        """
        if self._vehicle == 0:
            return None
        smoother = self._team[0]._smoother
        if smoother is None:
            raise ValueError(
                "reset: vehicle 0 of the team must be reset first (it builds the graph)"
            )
        return smoother

    def _check_keyframe(self, k: int) -> None:
        """Refuse keyframe ``k`` of a team's vehicle where its keys would reach the next
        vehicle's.

        Raises:
            OverflowError: ``k`` ≥ :data:`VEHICLE_STRIDE` in a team.
        """
        if k >= VEHICLE_STRIDE and len(self._team) > 1:
            raise OverflowError(
                f"isam2: keyframe {k} of vehicle {self._vehicle}; a team's vehicle holds at most "
                f"{VEHICLE_STRIDE} keyframes (its keys would reach the next vehicle's)"
            )

    def range_to(self, other: int, measured_m: float, sigma_m: float) -> bool:
        """Add the range ``measured_m`` (m, std ``sigma_m``) between this vehicle's position and
        vehicle ``other``'s as a factor between their latest keyframes, when both are at the
        range's instant (no IMU sample since them: the team env delivers a range at the start
        of the step after its epoch, and a scan on the epoch's step put the keyframes there),
        and read both keyframes again.

        The factor is GTSAM's ``RangeFactorPose3``, ``r = ‖t_i − t_j‖ + n``, n ~ N(0, σ²), on
        the poses' translations (the vehicles' centres, N frame).

        Returns:
            Whether the range was added (False: a keyframe not at the range's instant, a
            vehicle diverged, or a GTSAM failure, which sets this vehicle diverged).
        """
        peer = self._team[other]
        if peer is self or not isinstance(peer, TeamMember):
            raise ValueError(f"range_to: vehicle {other} is not another vehicle of the team")
        me: Any = self
        them: Any = peer
        if me._diverged or them._diverged or me._kept or them._kept:
            return False
        if abs(me._kf_t - them._kf_t) > 1e-9:
            return False
        g = me._g
        graph = g.NonlinearFactorGraph()
        noise = g.noiseModel.Isotropic.Sigma(1, sigma_m)
        xi, xj = me._key("x", me._k), them._key("x", them._k)
        graph.add(g.RangeFactorPose3(xi, xj, float(measured_m), noise))
        try:
            me._solve(graph, g.Values(), {})
            me._read_keyframe(me._k)
            them._read_keyframe(them._k)
        except Exception as exc:  # a GTSAM failure (C++ exceptions arrive as RuntimeError)
            me._diverge(exc)
            return False
        finally:
            me._cache = me._state_cache = them._cache = them._state_cache = None
        return True

    def _share_map(self, means: dict[int, FloatArray]) -> None:
        """The map ``means`` (id → (3,) m, N) read after this vehicle's keyframe, given to every
        vehicle of the team; the others' maps and landmark covariances are read afresh."""
        self._lm_means = means
        for member in self._team:
            if member is not self:
                member._lm_means = means
                member._lm_map = None
                member._lm_covs = None  # recovered on request, from the smoother as it is
                member._cache = member._state_cache = None
