"""The team env's settings: how many vehicles, how the vehicles' estimates are fused, where
each vehicle flies and when two collide (docs/team.md).

The ``team`` mapping of :func:`quadslam_env.team.parallel_env` is validated by the settings
system (:class:`~quadslam_env.config_schema.Section`), so a bad value is a
:class:`~quadslam_env.config_schema.ConfigError` naming ``team.<key>``, the value and what is
allowed; the checks that need the number of vehicles or the scenario follow in
:meth:`TeamConfig.check`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from quadslam_env.config import ScenarioConfig
from quadslam_env.config_schema import ConfigError, Section
from quadslam_env.config_schema import spec as _spec
from quadslam_env.types import FloatArray

FUSION_MODES = ("independent",)
"""The fusion modes there are: ``independent``, each vehicle its own estimator and nothing
shared (the baseline; ``ci``, ``naive`` and ``centralised`` are planned, docs/team.md)."""

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
    fusion: str = _spec(
        "independent",
        kind="str",
        choices=FUSION_MODES,
        doc="independent: each vehicle runs its own estimator and nothing is shared",
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
        if scenario.faults.kind == "landmark_moves":
            raise ConfigError(
                "faults.kind: got 'landmark_moves'; allowed in the team env: any other kind "
                "(a landmark moved in one vehicle's lane would split the shared field)"
            )

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


def _plain(value: Any) -> Any:
    """A canonical tuple back to a list, as the user wrote it."""
    return list(value) if isinstance(value, tuple) else value
