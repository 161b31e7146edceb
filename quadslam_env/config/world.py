"""Scenario sections of the world the vehicle flies in: ``landmarks`` (layouts),
``trajectory`` (the reference) and ``wind``; re-exported by :mod:`quadslam_env.config`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from quadslam_env.models.wind import W20_MPS, dryden_low_altitude
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec

MIN_AIRSPEED_MPS = 0.1
"""Slowest speed V at which Dryden turbulence may pass the vehicle, m/s: its time scales L/V
grow without bound as V → 0 (the frozen field stands still), and below ~1e-100 m/s their
powers leave the floating-point range."""

DRAG_STEP_MAX = 1.0
"""Largest product of the drag's relaxation rate and the RK4 substep (``vehicle.physics_dt_s``)
in the steady wind and 3σ gusts; RK4 itself turns unstable at 2.79, and at 1 it follows the
decay e^{−λ dt} to 2% per substep."""


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
        hi=1e6,
        doc="[min, max] distance of random landmarks from the centre, m (at most 1000 km)",
    )
    center: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        length=3,
        lo=-1e6,
        hi=1e6,
        optional=True,
        doc="NED m, within 1000 km of the origin; null = trajectory centre",
    )
    pole_spacing_m: float = _spec(
        2.0,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        doc="poles4: the poles stand at (±spacing, ±spacing), m",
    )
    pole_altitude_m: float = _spec(
        1.0, lo=-1e4, hi=1e4, doc="poles4: altitude of each pole's landmark above the origin, m"
    )
    positions: tuple[tuple[float, ...], ...] = _spec(
        [],
        kind="vecs",
        lo=-1e6,
        hi=1e6,
        doc="explicit: landmark positions [x, y, z] in NED, m, each within 1000 km of the origin",
    )

    @property
    def size(self) -> int:
        """Number of landmarks the layout makes (the map's size bound Lmax)."""
        if self.layout == "rauniyar2023":
            return self.count
        if self.layout == "poles4":
            return 4
        return len(self.positions)

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
    period_s: float = _spec(25.0, lo=0.1, hi=1e6, doc="time of one lap, s (ω = 2π/period)")
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


@dataclass(frozen=True)
class WindConfig(Section):
    """Wind (docs/physics.md "Wind"): a steady wind plus optional Dryden turbulence.

    The Dryden gust is the MIL-F-8785C low-altitude model (:mod:`quadslam_env.models.wind`):
    intensities and scale lengths from ``w20_mps`` and ``altitude_m``, a frozen field carried
    past the vehicle at ``airspeed_mps``. A ``preset`` (the standard's light, moderate or severe
    turbulence) sets ``turbulence: dryden`` and ``w20_mps``. The estimators do not see the wind
    unless ``inform_estimator`` (then those whose model has the drag take it as a known input).
    """

    SECTION: ClassVar[str] = "wind"
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        name: {"turbulence": "dryden", "w20_mps": w20} for name, w20 in W20_MPS.items()
    }
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = dict.fromkeys(
        ("w20_mps", "altitude_m", "airspeed_mps"), ("turbulence", ("dryden",))
    )
    preset: str | None = _spec(
        None,
        kind="str",
        choices=tuple(W20_MPS),
        optional=True,
        doc="Dryden turbulence of the standard's intensity (W20 = 15, 30, 45 kt); null = none",
    )
    steady_mps: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-100.0,
        hi=100.0,
        doc="steady wind velocity in NED (the air's velocity, not where it blows from), m/s",
    )
    turbulence: str = _spec(
        "none",
        kind="str",
        choices=("none", "dryden"),
        doc="none, or Dryden gusts (MIL-F-8785C low-altitude model) on top of the steady wind",
    )
    w20_mps: float = _spec(
        W20_MPS["light"],
        lo=0.0,
        hi=100.0,
        doc="wind speed at 20 ft (6.1 m), m/s: σ_w = 0.1 W20 (light 7.72, moderate 15.4, "
        "severe 23.2)",
    )
    altitude_m: float = _spec(
        2.0,
        lo=0.0,
        lo_open=True,
        hi=304.8,
        doc="height above ground for the scale lengths and intensities, m (the model's range "
        "is 10–1000 ft; below 3.05 m the 10 ft values)",
    )
    airspeed_mps: float | None = _spec(
        None,
        lo=MIN_AIRSPEED_MPS,
        hi=200.0,
        optional=True,
        doc="speed V at which the frozen turbulence passes the vehicle (time scales L/V), "
        "m/s; null = the steady wind's speed (which must then be at least the same 0.1 m/s)",
    )

    inform_estimator: bool = _spec(
        False,
        kind="bool",
        doc="give the estimator the wind of every step (steady part and gust) as a known "
        "disturbance input, so its drag acts on the air-relative velocity; only for an "
        "estimator whose process model has the drag (fastslam)",
    )

    @property
    def enabled(self) -> bool:
        """Whether there is any wind (a non-zero steady wind or turbulence)."""
        return self.turbulence != "none" or any(w != 0.0 for w in self.steady_mps)

    @property
    def speed_mps(self) -> float:
        """V in m/s: ``airspeed_mps``, or the steady wind's speed when that is null."""
        if self.airspeed_mps is not None:
            return self.airspeed_mps
        return math.sqrt(sum(w * w for w in self.steady_mps))

    def validate(self) -> None:
        if self.turbulence == "dryden" and self.speed_mps < MIN_AIRSPEED_MPS:
            raise ConfigError(
                f"wind.airspeed_mps: got null with wind.steady_mps = {list(self.steady_mps)} "
                f"(speed {self.speed_mps:g} m/s); allowed: a speed >= {MIN_AIRSPEED_MPS} m/s, "
                f"or a wind.steady_mps of at least {MIN_AIRSPEED_MPS} m/s (Dryden turbulence "
                "is a frozen field carried past the vehicle at that speed)"
            )

    def check_drag(
        self,
        drag_per_s: float,
        drag_quadratic_per_m: tuple[float, ...],
        physics_dt_s: float,
        wind_scale: float,
    ) -> None:
        """A wind acts through the drag: with none (``vehicle.drag_per_s`` and
        ``vehicle.drag_quadratic_per_m`` zero) it would be silently ignored; and the drag must
        relax slower than the RK4 substep resolves (:data:`DRAG_STEP_MAX`).

        The relaxation rate on the air-relative velocity v_a is ``λ = d + 2 max(c_q) ‖v_a‖``
        (the largest eigenvalue of the drag's Jacobian), taken at the vehicle at rest in the
        steady wind plus 3σ of its gusts, both scaled by the largest ``randomize.wind_scale``.

        Args:
            drag_per_s: d, 1/s. drag_quadratic_per_m: (3,) c_q, 1/m.
            physics_dt_s: The RK4 substep, s. wind_scale: The largest scale on the wind.

        Raises:
            ConfigError: Naming the keys, their values and what is allowed.
        """
        if not self.enabled:
            return
        if drag_per_s == 0.0 and not any(drag_quadratic_per_m):
            raise ConfigError(
                f"wind.steady_mps: got {list(self.steady_mps)} with wind.turbulence "
                f"{self.turbulence!r}, vehicle.drag_per_s = 0 and "
                f"vehicle.drag_quadratic_per_m = {list(drag_quadratic_per_m)}, so the wind "
                "would push on nothing; allowed: a drag with a wind (vehicle.drag_per_s > 0 "
                "or a vehicle.drag_quadratic_per_m > 0), or no wind"
            )
        speed = math.sqrt(sum(w * w for w in self.steady_mps))
        if self.turbulence == "dryden":
            speed += 3.0 * float(max(dryden_low_altitude(self.altitude_m, self.w20_mps)[0]))
        rate = drag_per_s + 2.0 * max(drag_quadratic_per_m) * wind_scale * speed
        if rate * physics_dt_s > DRAG_STEP_MAX:
            raise ConfigError(
                f"vehicle.drag_quadratic_per_m: got {list(drag_quadratic_per_m)} with "
                f"vehicle.drag_per_s = {drag_per_s:g} in a wind of up to "
                f"{wind_scale * speed:.4g} m/s, so the drag relaxes at {rate:.4g} /s and "
                f"vehicle.physics_dt_s = {physics_dt_s:g} s cannot resolve it (rate × substep "
                f"{rate * physics_dt_s:.3g}); allowed: rate × substep <= {DRAG_STEP_MAX:g} "
                "(a smaller drag, a weaker wind or a shorter vehicle.physics_dt_s)"
            )

    def check_inform(self, estimator: str, steps_per_imu: int, scan_delay_steps: int) -> None:
        """``inform_estimator`` needs an estimator whose model has the drag
        (:func:`quadslam_env.estimation.models_drag`) that runs at the control rate: an IMU
        slower than the control or a delayed LiDAR replays past steps on a copy of the
        estimator, which is not told those steps' wind.

        Args:
            estimator: ``estimator.name``. steps_per_imu: Control steps per IMU sample.
            scan_delay_steps: ``lidar.delay_steps``.

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        if not self.inform_estimator:
            return
        from quadslam_env.estimation.registry import estimator_flag, models_drag

        if not estimator_flag(estimator, models_drag):
            raise ConfigError(
                f"wind.inform_estimator: got true with estimator.name = {estimator!r}, whose "
                "process model has no drag for a wind to act on (it is driven by the IMU's "
                "specific force, which already holds the drag); allowed: false, or an "
                "estimator that models the drag (fastslam, or a plug-in with models_drag = True)"
            )
        if steps_per_imu > 1 or scan_delay_steps > 0:
            got = (
                f"an IMU {steps_per_imu} times slower than the control (imu.rate_hz)"
                if steps_per_imu > 1
                else f"lidar.delay_steps = {scan_delay_steps}"
            )
            raise ConfigError(
                f"wind.inform_estimator: got true with {got}, which replays past steps on a "
                "copy of the estimator that is not told their wind; allowed: false, or an IMU "
                "at or above the control rate and lidar.delay_steps: 0"
            )
