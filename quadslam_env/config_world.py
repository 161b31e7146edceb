"""Scenario sections of the world the vehicle flies in: ``landmarks`` (layouts) and
``trajectory`` (the reference); re-exported by :mod:`quadslam_env.config`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from quadslam_env.config_schema import ConfigError, Section
from quadslam_env.config_schema import spec as _spec


@dataclass(frozen=True)
class LandmarksConfig(Section):
    """Landmark layout (docs/design.md §3).

    ``rauniyar2023`` random points, ``poles4``, ``explicit``.
    """

    SECTION: ClassVar[str] = "landmarks"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {
        **dict.fromkeys(
            ("count", "azimuth_deg", "elevation_deg", "range_m", "center"),
            ("layout", ("rauniyar2023",)),
        ),
        **dict.fromkeys(("pole_spacing_m", "pole_altitude_m"), ("layout", ("poles4",))),
        "positions": ("layout", ("explicit",)),
    }
    layout: str = _spec(
        "rauniyar2023",
        kind="str",
        choices=("rauniyar2023", "poles4", "explicit"),
        doc="rauniyar2023: random points about the centre; poles4: four poles; explicit: positions",
    )
    count: int = _spec(
        40, kind="int", lo=1, hi=100000, doc="number of random landmarks (rauniyar2023 layout)"
    )
    azimuth_deg: tuple[float, ...] = _spec(
        [-180.0, 180.0],
        kind="vec",
        length=2,
        lo=-180,
        hi=180,
        doc="[min, max] azimuth of random landmarks about the centre, deg",
    )
    elevation_deg: tuple[float, ...] = _spec(
        [-50.0, 50.0],
        kind="vec",
        length=2,
        lo=-90,
        hi=90,
        doc="[min, max] elevation of random landmarks about the centre, deg",
    )
    range_m: tuple[float, ...] = _spec(
        [8.0, 20.0],
        kind="vec",
        length=2,
        lo=0.0,
        doc="[min, max] distance of random landmarks from the centre, m",
    )
    center: tuple[float, ...] | None = _spec(
        None, kind="vec", length=3, optional=True, doc="NED m; null = trajectory centre"
    )
    pole_spacing_m: float = _spec(
        2.0, lo=0.0, lo_open=True, doc="poles4: the poles stand at (±spacing, ±spacing), m"
    )
    pole_altitude_m: float = _spec(
        1.0, doc="poles4: altitude of each pole's landmark above the origin, m"
    )
    positions: tuple[tuple[float, ...], ...] = _spec(
        [], kind="vecs", doc="explicit: landmark positions [x, y, z] in NED, m"
    )

    def validate(self) -> None:
        for name in ("azimuth_deg", "elevation_deg", "range_m"):
            lo, hi = getattr(self, name)
            if hi < lo:
                raise ConfigError(
                    f"landmarks.{name}: got {[lo, hi]}; allowed: [min, max] with min <= max"
                )
        if self.layout == "explicit" and not self.positions:
            raise ConfigError(
                "landmarks.positions: got []; allowed: a non-empty list of "
                "[x, y, z] when landmarks.layout is 'explicit'"
            )


@dataclass(frozen=True)
class TrajectoryConfig(Section):
    """Reference trajectory (flat outputs). ``center`` is NED, so altitude is ``-center[2]``."""

    SECTION: ClassVar[str] = "trajectory"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {
        **dict.fromkeys(("amplitude_x_m", "amplitude_y_m"), ("kind", ("figure8",))),
        "radius_m": ("kind", ("circle", "helix")),
        "climb_rate_mps": ("kind", ("helix",)),
        "period_s": ("kind", ("figure8", "circle", "helix")),
    }
    kind: str = _spec(
        "figure8",
        kind="str",
        choices=("figure8", "helix", "circle", "hover"),
        doc="reference shape (flat outputs ρ_d, ψ_d)",
    )
    center: tuple[float, ...] = _spec(
        [0.0, 0.0, -2.0],
        kind="vec",
        length=3,
        lo=-1e6,
        hi=1e6,
        doc="centre of the shape in NED, m (altitude is −center[2])",
    )
    amplitude_x_m: float = _spec(
        4.0, lo=0.0, hi=1e4, doc="figure8: x amplitude A in x = A sin ωt, m"
    )
    amplitude_y_m: float = _spec(
        2.0, lo=0.0, hi=1e4, doc="figure8: y amplitude B in y = B sin 2ωt, m"
    )
    radius_m: float = _spec(1.0, lo=0.0, hi=1e4, doc="circle and helix: radius, m")
    period_s: float = _spec(25.0, lo=0.1, doc="time of one lap, s (ω = 2π/period)")
    climb_rate_mps: float = _spec(
        0.0, lo=-10.0, hi=10.0, doc="helix: climb rate (altitude gained per second), m/s"
    )
    yaw_mode: str = _spec(
        "tangent",
        kind="str",
        choices=("tangent", "fixed", "free"),
        doc="tangent: heading along the horizontal velocity; fixed: yaw_deg; free: set by the "
        "action's heading channel (action.heading), starting at yaw_deg",
    )
    yaw_deg: float = _spec(
        0.0, lo=-180.0, hi=180.0, doc="heading of the fixed yaw mode (free: at t = 0), deg"
    )
    start_on_reference: bool = _spec(
        False,
        kind="bool",
        doc="start each episode on the reference (its position, velocity, attitude and yaw "
        "rate at t = 0, the estimate around it) instead of episode.initial_*: no transient",
    )
