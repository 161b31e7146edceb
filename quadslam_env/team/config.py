"""The team env's settings: how many vehicles, how the vehicles' estimates are fused, where
each vehicle flies, when two collide and the ranges between them (docs/team.md).

The ``team`` mapping of :func:`quadslam_env.team.parallel_env` is validated by the settings
system (:class:`~quadslam_env.schema.Section`), so a bad value is a
:class:`~quadslam_env.schema.ConfigError` naming ``team.<key>``, the value and what is
allowed; the checks that need the number of vehicles or the scenario follow in
:meth:`TeamConfig.check`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.estimation.registry import (
    estimator_flag,
    fuses_landmarks,
    fuses_ranges,
    joins_team,
)
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec
from quadslam_env.types import FloatArray

FUSION_MODES = ("independent", "ci", "naive", "centralised")
"""The fusion modes there are: ``independent``, each vehicle its own estimator and nothing
shared (the baseline); ``ci``, the vehicles' landmark estimates fused by covariance
intersection; ``naive``, the same messages fused as if independent; ``centralised``, one
estimator of every vehicle and the map, every vehicle's measurements in one factor graph
(docs/team-fusion.md)."""

SHARING = ("ci", "naive")
"""The fusion modes that send messages (the communication settings apply to them only)."""

COMMS_KEYS = (
    "message_every_scans",
    "message_rate_hz",
    "latency_steps",
    "drop_probability",
    "comm_range_m",
    "landmarks_per_message",
    "message_covariance",
)
"""The communication settings, read only with a fusion mode of :data:`SHARING`."""

RANGE_KEYS = ("range_sigma_m", "range_rate_hz", "range_dropout", "range_max_m", "range_fusion")
"""The settings of the ranges between vehicles, read only with ``team.ranges``."""

RANGE_FUSIONS = ("none", "ci", "factor")
"""What a vehicle does with the ranges it measures: ``none``, nothing (they are only in its
``info``); ``ci``, each fused into its estimate by covariance intersection with the other's
broadcast position estimate (docs/team-fusion.md "Ranges between vehicles"); ``factor``, with
``fusion: centralised``, each a factor between the two vehicles' keyframes in the team's one
graph."""

BEACON_FLOATS = 3 + 6
"""The floats of a position broadcast for the ranges: the mean (3) and the upper triangle of
its 3×3 covariance (6)."""

COVARIANCES = ("joint", "blocks")
"""What a message carries of its landmarks' covariance: ``joint``, the sender's joint (3k, 3k)
covariance of its k landmarks; ``blocks``, only their 3×3 blocks (docs/team.md "Fusion")."""

FLOAT_BYTES = 8
"""Bytes per float of a message (:func:`message_floats`)."""
IMU_SAMPLE_FLOATS = 7
"""An IMU sample as a vehicle sends it to a centralised estimator: its time, specific force (3)
and rate (3)."""
RETURN_FLOATS = 4
"""A LiDAR return as a vehicle sends it to a centralised estimator: its landmark id and
(α, β, δ); a scan adds its time (1)."""
RANGE_FLOATS = 3
"""A range between two vehicles sent to a centralised estimator: the two vehicles and the
range."""


def message_floats(k: int, covariance: str) -> int:
    """The floats of a message of ``k`` landmarks: per landmark its id and mean (4), and the
    upper triangle of the joint (3k, 3k) covariance (``joint``) or of each 3×3 block (6 per
    landmark, ``blocks``)."""
    if covariance == "joint":
        return 4 * k + 3 * k * (3 * k + 1) // 2
    return 10 * k


OFFSET_MAX_M = 1e3
"""Largest |coordinate| of a vehicle's position offset, m."""


def parse_vehicles(value: Any) -> int:
    """The number of vehicles N as an ``int``.

    Raises:
        ConfigError: Not an integer (a bool is not), or below 1.
    """
    if isinstance(value, bool | np.bool_) or not isinstance(value, int | np.integer) or value < 1:
        raise ConfigError(f"n_vehicles: got {value!r}; allowed: an integer >= 1")
    return int(value)


@dataclass(frozen=True)
class TeamConfig(Section):
    """The team of N vehicles in one world: fusion, per-vehicle references, collisions."""

    SECTION: ClassVar[str] = "team"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[Any, ...]]]] = {
        **dict.fromkeys(COMMS_KEYS, ("fusion", SHARING)),
        **dict.fromkeys(RANGE_KEYS, ("ranges", (True,))),
    }
    fusion: str = _spec(
        "independent",
        kind="str",
        choices=FUSION_MODES,
        doc="independent: each vehicle runs its own estimator and nothing is shared; ci: the "
        "vehicles send their landmark estimates and each fuses them by covariance "
        "intersection; naive: the same fused as if independent (double counting); "
        "centralised: one smoother of every vehicle and the map (estimator isam2)",
    )
    message_every_scans: int | None = _spec(
        None,
        kind="int",
        optional=True,
        lo=1,
        hi=100000,
        doc="with message_rate_hz null: a vehicle sends a message after every m-th of its "
        "scans; null = every scan",
    )
    message_rate_hz: float | None = _spec(
        0.2,
        optional=True,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        doc="messages per second of each vehicle, Hz, at most episode.control_hz (sent at the "
        "end of the step on which floor(t · rate) grows); null = by scans "
        "(message_every_scans)",
    )
    latency_steps: int = _spec(
        0,
        kind="int",
        lo=0,
        hi=100000,
        doc="control steps between a message's sending (end of a step) and its fusion (start of "
        "the step after this many more)",
    )
    drop_probability: float = _spec(
        0.0,
        lo=0.0,
        hi=1.0,
        doc="probability that a message does not reach one receiver (drawn per receiver from "
        "the sender's own generator)",
    )
    comm_range_m: float | None = _spec(
        None,
        optional=True,
        lo=0.0,
        lo_open=True,
        hi=1e6,
        doc="a receiver farther than this from the sender when it sends (true positions), m, "
        "does not hear the message (counted in team_messages_out_of_range, after its drop "
        "draw); null = every vehicle hears every other",
    )
    landmarks_per_message: int | None = _spec(
        None,
        kind="int",
        optional=True,
        lo=1,
        hi=100000,
        doc="the k landmarks a message carries: the sender's best known (smallest covariance "
        "trace, then smallest id); null = every landmark it has mapped",
    )
    message_covariance: str = _spec(
        "joint",
        kind="str",
        choices=COVARIANCES,
        doc="joint: a message carries the sender's joint covariance of its k landmarks (4k + "
        "3k(3k + 1)/2 floats); blocks: only their 3×3 blocks (10 floats per landmark), which "
        "ci then bounds by k times their block diagonal",
    )
    time_offsets_s: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        optional=True,
        lo=-1e6,
        hi=1e6,
        doc="τ_i per vehicle, s: vehicle i flies the trajectory at t + τ_i (N entries, the "
        "first 0); null = i · trajectory.period_s / N",
    )
    position_offsets_m: tuple[tuple[float, ...], ...] | None = _spec(
        None,
        kind="vecs",
        optional=True,
        lo=-OFFSET_MAX_M,
        hi=OFFSET_MAX_M,
        doc="p_i per vehicle, N frame m: added to vehicle i's reference and start (N entries, "
        "the first [0, 0, 0]); null = no offsets",
    )
    collision_radius_m: float | None = _spec(
        None,
        optional=True,
        lo=0.0,
        lo_open=True,
        hi=100.0,
        doc="two vehicles whose true positions come closer than this, m, both terminate "
        "(vehicle_collision); null = no collision check",
    )
    ranges: bool = _spec(
        False,
        kind="bool",
        doc="every pair of live vehicles within range_max_m measures its distance at "
        "range_rate_hz (inter-vehicle ranging); false = no ranges",
    )
    range_sigma_m: float = _spec(
        0.1,
        lo=0.0,
        lo_open=True,
        hi=100.0,
        doc="std of a range's additive Gaussian noise, m",
    )
    range_rate_hz: float = _spec(
        10.0,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        doc="range epochs per second, Hz, at most episode.control_hz (at the end of the step "
        "on which floor(t · rate) grows)",
    )
    range_dropout: float = _spec(
        0.0,
        lo=0.0,
        hi=1.0,
        doc="probability that a pair's range of an epoch is lost (drawn from the "
        "lower-numbered vehicle's own generator)",
    )
    range_max_m: float = _spec(
        50.0,
        lo=0.0,
        lo_open=True,
        hi=1e6,
        doc="pairs whose true distance exceeds this, m, get no range",
    )
    range_fusion: str = _spec(
        "none",
        kind="str",
        choices=RANGE_FUSIONS,
        doc="none: the ranges are only in info; ci: each vehicle fuses the ranges it measures "
        "with the other's broadcast position estimate (3 + 6 floats) by covariance "
        "intersection; factor (fusion centralised): each range a factor between the two "
        "vehicles' keyframes in the team's graph",
    )

    def validate(self) -> None:
        """One way of timing the messages at most.

        Raises:
            ConfigError: Both ``message_every_scans`` and ``message_rate_hz`` set.
        """
        if self.message_every_scans is not None and self.message_rate_hz is not None:
            raise ConfigError(
                f"team.message_every_scans: got {self.message_every_scans!r} with "
                f"team.message_rate_hz = {self.message_rate_hz!r} (its default is 0.2); allowed: "
                "message_rate_hz null, to time the messages by scans, or message_every_scans "
                "null"
            )

    def check(self, n_vehicles: int, scenario: ScenarioConfig) -> None:
        """The checks that need N and the scenario: one offset per vehicle, none for vehicle 0
        (it flies the scenario's own reference, the single env's), and a world the vehicles can
        share.

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        for key, value, zero in (
            ("time_offsets_s", self.time_offsets_s, "0"),
            ("position_offsets_m", self.position_offsets_m, "[0, 0, 0]"),
        ):
            if value is None:
                continue
            if len(value) != n_vehicles:
                raise ConfigError(
                    f"team.{key}: got {len(value)} entries; allowed: one per vehicle "
                    f"(n_vehicles = {n_vehicles})"
                )
            if np.any(np.asarray(value[0]) != 0.0):
                raise ConfigError(
                    f"team.{key}[0]: got {_plain(value[0])}; allowed: {zero} (vehicle 0 flies "
                    "the scenario's own reference)"
                )
        if self.fusion in SHARING:
            self._check_sharing(scenario)
        if self.fusion == "centralised":
            self._check_centralised(scenario)
        if self.ranges:
            self._check_ranges(scenario)
        if scenario.faults.kind == "landmark_moves":
            raise ConfigError(
                "faults.kind: got 'landmark_moves'; allowed in the team env: any other kind "
                "(a landmark moved in one vehicle's lane would split the shared field)"
            )

    def _check_sharing(self, scenario: ScenarioConfig) -> None:
        """What map fusion needs of the scenario: an estimator that fuses landmarks, the
        landmark ids common to the vehicles (known association), a map to fuse (no known
        map), one run of the estimator (no copies) and a message rate the steps can hold.

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        got = f"team.fusion: got {self.fusion!r}"
        _needs_ability(got, "'independent'", scenario, fuses_landmarks, "fuse landmark estimates")
        _needs_known_association(
            got,
            "'independent'",
            scenario,
            "the fusion pairs the vehicles' landmarks by id; unknown association would need map "
            "matching first",
        )
        if scenario.estimator.known_map:
            raise ConfigError(
                f"{got} with estimator.known_map = true (no map to fuse); allowed: "
                "'independent', or estimator.known_map false"
            )
        _needs_one_run(got, "'independent'", scenario, "message")
        if self.message_rate_hz is not None:
            _at_most_one_per_step("message_rate_hz", self.message_rate_hz, scenario, "message")

    def _check_centralised(self, scenario: ScenarioConfig) -> None:
        """What one estimator of the team needs of the scenario: an estimator whose vehicles
        can share one (``joins_team``) and landmark ids common to the vehicles (known
        association).

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        got = f"team.fusion: got {self.fusion!r}"
        _needs_ability(
            got,
            "another fusion mode",
            scenario,
            joins_team,
            "be one estimator of the team",
            "isam2, one factor graph of every vehicle, needs the gtsam extra",
        )
        _needs_known_association(
            got,
            "another fusion mode",
            scenario,
            "the vehicles' returns of a landmark name one variable by its id",
        )

    def _check_ranges(self, scenario: ScenarioConfig) -> None:
        """What the ranges need of the scenario: epochs the steps can hold and, to fuse them,
        an estimator that fuses ranges and one run of it (no copies).

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        _at_most_one_per_step("range_rate_hz", self.range_rate_hz, scenario, "range epoch")
        if self.range_fusion == "none":
            return
        got = f"team.range_fusion: got {self.range_fusion!r}"
        if self.range_fusion == "factor":
            if self.fusion != "centralised":
                raise ConfigError(
                    f"{got} with team.fusion = {self.fusion!r}; allowed: 'none' or 'ci', or "
                    "team.fusion 'centralised' (a factor needs the team's one graph)"
                )
            return
        _needs_ability(got, "'none'", scenario, fuses_ranges, "fuse ranges")
        _needs_one_run(got, "'none'", scenario, "range")

    def offsets(self, n_vehicles: int, period_s: float) -> tuple[FloatArray, FloatArray]:
        """The vehicles' time offsets (N,) s and position offsets (N, 3) N frame m, the
        defaults filled in (``i · period_s / N`` and zeros)."""
        if self.time_offsets_s is None:
            times: FloatArray = np.arange(n_vehicles, dtype=float) * (period_s / n_vehicles)
        else:
            times = np.array(self.time_offsets_s, dtype=float)
        if self.position_offsets_m is None:
            positions = np.zeros((n_vehicles, 3))
        else:
            positions = np.array(self.position_offsets_m, dtype=float)
        return times, positions


def _needs_ability(
    got: str,
    off: str,
    scenario: ScenarioConfig,
    flag: Callable[[str], bool],
    what: str,
    having: str = "ekf_slam",
) -> None:
    """Refuse a team setting (``got``, turned off by ``off``) with an estimator whose class
    lacks ``flag`` (``fuses_landmarks``, ``fuses_ranges``, ``joins_team``), the ability to
    ``what``; ``having`` names the built-in estimators that have it.

    Raises:
        ConfigError: Naming the setting, the estimator and what is allowed.
    """
    name = scenario.estimator.name
    if not estimator_flag(name, flag):
        raise ConfigError(
            f"{got} with estimator.name = {name!r}, which cannot {what}; allowed: {off}, or "
            f"an estimator that can ({having}, or a plug-in with {flag.__name__} = True)"
        )


def _needs_known_association(got: str, off: str, scenario: ScenarioConfig, why: str) -> None:
    """Refuse a team setting (``got``, turned off by ``off``) without the landmark ids common
    to the vehicles (``lidar.association: known``), for the reason ``why``.

    Raises:
        ConfigError: Naming the setting, the association and what is allowed.
    """
    association = scenario.lidar.association
    if association != "known":
        raise ConfigError(
            f"{got} with lidar.association = {association!r}; allowed: {off}, or "
            f"lidar.association 'known' ({why})"
        )


def _needs_one_run(got: str, off: str, scenario: ScenarioConfig, item: str) -> None:
    """Refuse a fusion setting (``got``, turned off by ``off``) when the estimator runs from
    copies (:attr:`ScenarioConfig.second_run`), which a fused ``item`` would miss.

    Raises:
        ConfigError: Naming the setting, the one that makes the copies and what is allowed.
    """
    second = scenario.second_run
    if second is not None:
        raise ConfigError(
            f"{got} with {second} set (the estimator runs from copies, which a fused {item} "
            f"would miss); allowed: {off}, or {second} at its default"
        )


def _at_most_one_per_step(key: str, rate: float, scenario: ScenarioConfig, item: str) -> None:
    """Refuse ``team.<key>`` = ``rate`` Hz above the control rate (one ``item`` per step).

    Raises:
        ConfigError: Naming the key, the value and the control rate.
    """
    control = scenario.episode.control_hz
    if rate > control:
        raise ConfigError(
            f"team.{key}: got {rate!r}; allowed: at most episode.control_hz = {control!r} (one "
            f"{item} per step)"
        )


def _plain(value: Any) -> Any:
    """A canonical tuple back to a list, as the user wrote it."""
    return list(value) if isinstance(value, tuple) else value
