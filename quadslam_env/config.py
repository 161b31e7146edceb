"""Typed, frozen, validated scenario settings (DESIGN.md §4 "Config flow").

A scenario is a YAML file in ``configs/scenarios/`` (or any path) with the sections ``vehicle``,
``imu``, ``lidar``, ``landmarks``, ``trajectory``, ``estimator``, ``reward``, ``observation``,
``action``, ``episode`` and ``render``. Per-call overrides (``gymnasium.make(id,
episode={...})``) are merged into it key by key. Sections with a ``preset`` key start from that
preset's values; keys given explicitly win over the preset.

Every unknown key, wrong type or out-of-range value raises :class:`ConfigError` (a
``ValueError``) whose message names the dotted key, the bad value and what is allowed.
"""

from __future__ import annotations

import copy
import math
import os
import re
from dataclasses import dataclass, field, fields
from importlib import resources
from pathlib import Path
from typing import Any, ClassVar

import yaml

from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams
from quadslam_env.types import DEG, GRAVITY


class ConfigError(ValueError):
    """Invalid configuration: the message names the key, the value and what is allowed."""


def _spec(
    default: Any = None,
    *,
    kind: str = "float",
    lo: float | None = None,
    hi: float | None = None,
    lo_open: bool = False,
    length: int | None = None,
    choices: tuple[str, ...] | None = None,
    optional: bool = False,
    doc: str = "",
) -> Any:
    """Declare a validated field: ``kind`` is float|int|bool|str|vec|vecs|dict."""
    meta = {
        "kind": kind,
        "lo": lo,
        "hi": hi,
        "lo_open": lo_open,
        "length": length,
        "choices": choices,
        "optional": optional,
        "doc": doc,
    }
    if isinstance(default, list | dict):
        return field(default_factory=lambda d=default: copy.deepcopy(d), metadata=meta)
    return field(default=default, metadata=meta)


def _describe(meta: dict[str, Any]) -> str:
    if meta["choices"]:
        return f"one of {list(meta['choices'])}"
    kind = meta["kind"]
    base = {
        "float": "a number",
        "int": "an integer",
        "bool": "true or false",
        "str": "a string",
        "vec": f"a list of {meta['length']} numbers",
        "vecs": "a list of [x, y, z] lists",
        "dict": "a mapping",
    }[kind]
    rng = []
    if meta["lo"] is not None:
        rng.append(f"{'>' if meta['lo_open'] else '>='} {meta['lo']}")
    if meta["hi"] is not None:
        rng.append(f"<= {meta['hi']}")
    text = base + (f" {' and '.join(rng)}" if rng else "")
    return text + (" or null" if meta["optional"] else "")


def _check_number(key: str, value: Any, meta: dict[str, Any]) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
    num = float(value)
    lo, hi = meta["lo"], meta["hi"]
    bad = not math.isfinite(num) or (
        lo is not None and (num <= lo if meta["lo_open"] else num < lo)
    )
    if bad or (hi is not None and num > hi):
        raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
    return num


def _coerce(key: str, value: Any, meta: dict[str, Any]) -> Any:
    """Validate one value against its field spec and return it in canonical (immutable) form."""
    if value is None:
        if meta["optional"]:
            return None
        raise ConfigError(f"{key}: got null; allowed: {_describe(meta)}")
    kind = meta["kind"]
    if kind == "float":
        return _check_number(key, value, meta)
    if kind == "int":
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        return int(_check_number(key, value, meta))
    if kind == "bool":
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        return value
    if kind == "str":
        if not isinstance(value, str) or (meta["choices"] and value not in meta["choices"]):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        return value
    if kind == "vec":
        if not isinstance(value, list | tuple) or (
            meta["length"] is not None and len(value) != meta["length"]
        ):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        return tuple(_check_number(f"{key}[{i}]", v, meta) for i, v in enumerate(value))
    if kind == "vecs":
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        point_meta = {**meta, "length": 3, "lo": None, "hi": None}
        return tuple(
            _coerce(f"{key}[{i}]", p, {**point_meta, "kind": "vec"}) for i, p in enumerate(value)
        )
    if kind == "dict":
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: got {value!r}; allowed: {_describe(meta)}")
        return copy.deepcopy(value)
    raise AssertionError(f"unhandled field kind {kind}")  # pragma: no cover - programming error


class _Section:
    """Mixin: build a frozen section dataclass from a plain mapping with validation."""

    SECTION: ClassVar[str] = ""
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {}

    @classmethod
    def from_dict(cls, data: Any) -> Any:
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(f"{cls.SECTION}: got {data!r}; allowed: a mapping of settings")
        known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
        for key in data:
            if key not in known:
                raise ConfigError(f"{cls.SECTION}.{key}: unknown key; allowed: {sorted(known)}")
        merged = dict(data)
        preset = data.get("preset")
        if cls.PRESETS and preset is not None:
            if not isinstance(preset, str) or preset not in cls.PRESETS:
                raise ConfigError(
                    f"{cls.SECTION}.preset: got {preset!r}; allowed: one of {sorted(cls.PRESETS)}"
                )
            merged = {**cls.PRESETS[preset], **data}
        kwargs = {}
        for name, spec in known.items():
            # Defaults go through the same coercion so every stored value is immutable.
            value = (
                merged[name]
                if name in merged
                else (spec.default_factory() if callable(spec.default_factory) else spec.default)
            )
            kwargs[name] = _coerce(f"{cls.SECTION}.{name}", value, dict(spec.metadata))
        obj = cls(**kwargs)
        obj.validate()
        return obj

    def validate(self) -> None:
        """Cross-field checks; overridden where needed."""


_MICRO_G = 1e-6 * GRAVITY


@dataclass(frozen=True)
class VehicleConfig(_Section):
    """Vehicle preset and overrides. ``None`` means "take the preset's value"."""

    SECTION: ClassVar[str] = "vehicle"
    preset: str = _spec("rauniyar2023", kind="str", choices=tuple(VEHICLE_PRESETS))
    mass_kg: float | None = _spec(None, lo=0.0, lo_open=True, optional=True)
    inertia_diag: tuple[float, ...] | None = _spec(
        None, kind="vec", length=3, lo=0.0, lo_open=True, optional=True
    )
    max_thrust_n: float | None = _spec(None, lo=0.0, lo_open=True, optional=True)
    max_torque_nm: tuple[float, ...] | None = _spec(
        None, kind="vec", length=3, lo=0.0, lo_open=True, optional=True
    )
    drag_per_s: float = _spec(0.0, lo=0.0, hi=10.0)
    actuator_tau_s: float = _spec(0.0, lo=0.0, hi=1.0)
    physics_dt_s: float = _spec(0.002, lo=1e-5, hi=0.02)

    def params(self) -> VehicleParams:
        """The :class:`VehicleParams` of the preset with this section's overrides applied."""
        base = VEHICLE_PRESETS[self.preset]
        mass = base.mass if self.mass_kg is None else self.mass_kg
        inertia = base.inertia if self.inertia_diag is None else _diag(self.inertia_diag)
        return VehicleParams(
            name=self.preset,
            mass=mass,
            inertia=inertia,
            max_thrust=base.max_thrust if self.max_thrust_n is None else self.max_thrust_n,
            max_torque=base.max_torque if self.max_torque_nm is None else self.max_torque_nm,
            drag=self.drag_per_s,
            actuator_tau=self.actuator_tau_s,
        )

    def validate(self) -> None:
        params = self.params()
        if params.max_thrust <= params.mass * GRAVITY:
            raise ConfigError(
                f"vehicle.max_thrust_n: got {params.max_thrust:.3f}; allowed: > m g = "
                f"{params.mass * GRAVITY:.3f} N (the vehicle must be able to hover)"
            )


def _diag(values: tuple[float, ...]) -> Any:
    import numpy as np

    return np.diag(values)


@dataclass(frozen=True)
class ImuConfig(_Section):
    """IMU error model (seed 000 eq. 5–11; seed 001 Table 5). Noise densities per √Hz."""

    SECTION: ClassVar[str] = "imu"
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        # Seed 001 Table 5: 300 µg/√Hz and 0.01 °/s/√Hz, no bias.
        "rauniyar2023": {
            "accel_noise_density": 300 * _MICRO_G,
            "gyro_noise_density": 0.01 * DEG,
            "accel_bias": [0.0] * 3,
            "gyro_bias": [0.0] * 3,
            "accel_drift_sigma": 0.0,
            "gyro_drift_sigma": 0.0,
        },
        # Seed 000 §IV: 0.005 m/s² and 0.005 rad/s per axis; τ and σ_b1 are not given there,
        # we use τ = 100 s and a stationary drift std of 20% of the bias.
        "sadeghzadeh2021": {
            "accel_noise_density": 300 * _MICRO_G,
            "gyro_noise_density": 0.01 * DEG,
            "accel_bias": [0.005] * 3,
            "gyro_bias": [0.005] * 3,
            "drift_tau_s": 100.0,
            "accel_drift_sigma": 0.001,
            "gyro_drift_sigma": 0.001,
        },
        "ideal": {
            "accel_noise_density": 0.0,
            "gyro_noise_density": 0.0,
            "accel_bias": [0.0] * 3,
            "gyro_bias": [0.0] * 3,
            "accel_drift_sigma": 0.0,
            "gyro_drift_sigma": 0.0,
        },
    }
    preset: str | None = _spec(
        None, kind="str", choices=("rauniyar2023", "sadeghzadeh2021", "ideal"), optional=True
    )
    accel_noise_density: float = _spec(300 * _MICRO_G, lo=0.0, hi=1.0, doc="m/s²/√Hz")
    gyro_noise_density: float = _spec(0.01 * DEG, lo=0.0, hi=1.0, doc="rad/s/√Hz")
    accel_bias: tuple[float, ...] = _spec([0.0, 0.0, 0.0], kind="vec", length=3, lo=-5.0, hi=5.0)
    gyro_bias: tuple[float, ...] = _spec([0.0, 0.0, 0.0], kind="vec", length=3, lo=-1.0, hi=1.0)
    random_bias_sign: bool = _spec(
        False, kind="bool", doc="flip each bias component's sign at random per episode"
    )
    drift_tau_s: float = _spec(100.0, lo=0.0, lo_open=True)
    accel_drift_sigma: float = _spec(0.0, lo=0.0, hi=1.0, doc="stationary std of b1_a, m/s²")
    gyro_drift_sigma: float = _spec(0.0, lo=0.0, hi=1.0, doc="stationary std of b1_ω, rad/s")


@dataclass(frozen=True)
class LidarConfig(_Section):
    """FOV-limited 3D LiDAR (seed 001 Tables 3–4). FOVs are half-widths in degrees."""

    SECTION: ClassVar[str] = "lidar"
    PRESETS: ClassVar[dict[str, dict[str, Any]]] = {
        "rauniyar2023": {
            "azimuth_fov_deg": 45.0,
            "elevation_fov_deg": 30.0,
            "range_min_m": 0.0,
            "range_max_m": 100.0,
            "sigma_azimuth_deg": 0.33,
            "sigma_elevation_deg": 0.30,
            "sigma_range_m": 0.1,
            "rate_hz": 10.0,
        },
        # Velodyne VLP-16: 360° azimuth, ±15° elevation, 100 m, ~3 cm range noise.
        "vlp16": {
            "azimuth_fov_deg": 180.0,
            "elevation_fov_deg": 15.0,
            "range_min_m": 0.5,
            "range_max_m": 100.0,
            "sigma_azimuth_deg": 0.1,
            "sigma_elevation_deg": 0.1,
            "sigma_range_m": 0.03,
            "rate_hz": 10.0,
        },
    }
    preset: str | None = _spec(None, kind="str", choices=("rauniyar2023", "vlp16"), optional=True)
    azimuth_fov_deg: float = _spec(45.0, lo=0.0, hi=180.0, lo_open=True)
    elevation_fov_deg: float = _spec(30.0, lo=0.0, hi=90.0, lo_open=True)
    range_min_m: float = _spec(0.0, lo=0.0)
    range_max_m: float = _spec(100.0, lo=0.0, lo_open=True)
    sigma_azimuth_deg: float = _spec(0.33, lo=0.0, hi=30.0)
    sigma_elevation_deg: float = _spec(0.30, lo=0.0, hi=30.0)
    sigma_range_m: float = _spec(0.1, lo=0.0, hi=10.0)
    rate_hz: float = _spec(10.0, lo=0.0, lo_open=True, hi=1000.0)

    def validate(self) -> None:
        if self.range_max_m <= self.range_min_m:
            raise ConfigError(
                f"lidar.range_max_m: got {self.range_max_m}; allowed: > "
                f"lidar.range_min_m = {self.range_min_m}"
            )


@dataclass(frozen=True)
class LandmarksConfig(_Section):
    """Landmark layout (DESIGN.md §3): ``rauniyar2023`` random points, ``poles4``, ``explicit``."""

    SECTION: ClassVar[str] = "landmarks"
    layout: str = _spec("rauniyar2023", kind="str", choices=("rauniyar2023", "poles4", "explicit"))
    count: int = _spec(40, kind="int", lo=1, hi=100000)
    azimuth_deg: tuple[float, ...] = _spec([-180.0, 180.0], kind="vec", length=2, lo=-180, hi=180)
    elevation_deg: tuple[float, ...] = _spec([-50.0, 50.0], kind="vec", length=2, lo=-90, hi=90)
    range_m: tuple[float, ...] = _spec([8.0, 20.0], kind="vec", length=2, lo=0.0)
    center: tuple[float, ...] | None = _spec(
        None, kind="vec", length=3, optional=True, doc="NED m; null = trajectory centre"
    )
    pole_spacing_m: float = _spec(2.0, lo=0.0, lo_open=True)
    pole_altitude_m: float = _spec(1.0)
    positions: tuple[tuple[float, ...], ...] = _spec([], kind="vecs")

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
class TrajectoryConfig(_Section):
    """Reference trajectory (flat outputs). ``center`` is NED, so altitude is ``-center[2]``."""

    SECTION: ClassVar[str] = "trajectory"
    kind: str = _spec("figure8", kind="str", choices=("figure8", "helix", "circle", "hover"))
    center: tuple[float, ...] = _spec([0.0, 0.0, -2.0], kind="vec", length=3, lo=-1e6, hi=1e6)
    amplitude_x_m: float = _spec(4.0, lo=0.0, hi=1e4)
    amplitude_y_m: float = _spec(2.0, lo=0.0, hi=1e4)
    radius_m: float = _spec(1.0, lo=0.0, hi=1e4)
    period_s: float = _spec(25.0, lo=0.1)
    climb_rate_mps: float = _spec(0.0, lo=-10.0, hi=10.0)
    yaw_mode: str = _spec("tangent", kind="str", choices=("tangent", "fixed"))
    yaw_deg: float = _spec(0.0, lo=-180.0, hi=180.0)


@dataclass(frozen=True)
class EstimatorConfig(_Section):
    """Estimator choice, its own settings, and the initial uncertainty P0."""

    SECTION: ClassVar[str] = "estimator"
    name: str = _spec(
        "ekf_slam", kind="str", choices=("ekf_slam", "fastslam", "fastslam_kinematic", "oracle")
    )
    params: dict[str, Any] = _spec({}, kind="dict")  # noqa: RUF009 (validated field spec)
    # Seed 001 Table 7 for (ρ, v, Λ) followed by the body rates (rad²/s²).
    initial_cov_diag: tuple[float, ...] = _spec(
        [0.001, 0.001, 0.001, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0, 1e-6, 1e-6, 1e-6],
        kind="vec",
        length=12,
        lo=0.0,
        hi=100.0,
    )
    sample_initial_error: bool = _spec(True, kind="bool")
    known_map: bool = _spec(
        False, kind="bool", doc="hand the true landmarks to the estimator at reset"
    )


@dataclass(frozen=True)
class RewardConfig(_Section):
    """Reward weights; reward = alive - Σ w·term (+ termination penalty on failure)."""

    SECTION: ClassVar[str] = "reward"
    alive: float = _spec(1.0)
    pos_weight: float = _spec(1.0, lo=0.0)
    vel_weight: float = _spec(0.1, lo=0.0)
    yaw_weight: float = _spec(0.1, lo=0.0)
    effort_weight: float = _spec(0.01, lo=0.0)
    termination_penalty: float = _spec(100.0, lo=0.0)


@dataclass(frozen=True)
class ObservationConfig(_Section):
    """Optional observation features on top of the base 16 (see ``QuadSLAMEnv``)."""

    SECTION: ClassVar[str] = "observation"
    pos_uncertainty: bool = _spec(False, kind="bool")
    landmark_counts: bool = _spec(False, kind="bool")
    lookahead_s: tuple[float, ...] = _spec([], kind="vec", lo=0.0, hi=10.0)
    clip: float = _spec(100.0, lo=1e-6, hi=1e30)


@dataclass(frozen=True)
class ActionConfig(_Section):
    """Action interpretation: ``thrust_torque`` or ``thrust_rates`` (inner body-rate loop)."""

    SECTION: ClassVar[str] = "action"
    mode: str = _spec("thrust_torque", kind="str", choices=("thrust_torque", "thrust_rates"))
    max_rate_dps: tuple[float, ...] = _spec(
        [180.0, 180.0, 90.0], kind="vec", length=3, lo=0.0, lo_open=True
    )
    rate_gain_per_s: tuple[float, ...] = _spec(
        [20.0, 20.0, 10.0], kind="vec", length=3, lo=0.0, lo_open=True
    )


@dataclass(frozen=True)
class EpisodeConfig(_Section):
    """Timing, initial state and termination limits."""

    SECTION: ClassVar[str] = "episode"
    duration_s: float = _spec(50.0, lo=0.0, lo_open=True, hi=1e6)
    control_hz: float = _spec(100.0, lo=0.0, lo_open=True, hi=10000.0)
    initial_position: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0], kind="vec", length=3, lo=-1e6, hi=1e6
    )
    initial_velocity: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0], kind="vec", length=3, lo=-1e3, hi=1e3
    )
    initial_euler_deg: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0], kind="vec", length=3, lo=-180.0, hi=180.0
    )
    max_tilt_deg: float = _spec(80.0, lo=0.0, hi=89.0, lo_open=True)
    max_pos_err_m: float = _spec(10.0, lo=0.0, lo_open=True)
    ground_z_m: float | None = _spec(None, optional=True, doc="NED z of the ground; null = none")
    nees_threshold: float | None = _spec(
        1000.0, lo=0.0, lo_open=True, optional=True, doc="null disables the NEES divergence check"
    )
    nees_window_s: float = _spec(2.0, lo=0.0)
    report_step_time: bool = _spec(
        False, kind="bool", doc="put the estimator's wall-clock time in info['est_step_time_ms']"
    )

    def validate(self) -> None:
        if abs(self.initial_euler_deg[1]) >= 89.0:
            raise ConfigError(
                f"episode.initial_euler_deg[1]: got {self.initial_euler_deg[1]}; "
                "allowed: |pitch| < 89 deg"
            )


@dataclass(frozen=True)
class RenderConfig(_Section):
    """``rgb_array`` frames (:mod:`quadslam_env.render`): size, frame rate and view extents.

    Only read when the env has ``render_mode="rgb_array"``; a make() kwarg
    ``render={"width_px": 800}`` overrides it like any section.
    """

    SECTION: ClassVar[str] = "render"
    width_px: int = _spec(640, kind="int", lo=320, hi=3840, doc="frame width in pixels")
    height_px: int = _spec(480, kind="int", lo=240, hi=2160, doc="frame height in pixels")
    fps: float | None = _spec(
        10.0,
        lo=0.0,
        lo_open=True,
        hi=1000.0,
        optional=True,
        doc="frames drawn per simulated second; a render() call sooner than 1/fps after the "
        "last drawn frame returns that frame again; null draws on every call",
    )
    view_radius_m: float = _spec(
        8.0, lo=0.5, hi=1e4, doc="half-width of the top-down view around the vehicle, m"
    )
    trail_s: float = _spec(25.0, lo=0.0, hi=3600.0, doc="length of the drawn paths, s")
    history_s: float = _spec(10.0, lo=0.5, hi=3600.0, doc="time span of the strip charts, s")
    max_particles: int = _spec(
        200, kind="int", lo=0, hi=100000, doc="particles drawn (an evenly strided subsample)"
    )


SECTIONS: dict[str, type[_Section]] = {
    "vehicle": VehicleConfig,
    "imu": ImuConfig,
    "lidar": LidarConfig,
    "landmarks": LandmarksConfig,
    "trajectory": TrajectoryConfig,
    "estimator": EstimatorConfig,
    "reward": RewardConfig,
    "observation": ObservationConfig,
    "action": ActionConfig,
    "episode": EpisodeConfig,
    "render": RenderConfig,
}


@dataclass(frozen=True)
class ScenarioConfig:
    """A complete, validated scenario."""

    name: str
    vehicle: VehicleConfig
    imu: ImuConfig
    lidar: LidarConfig
    landmarks: LandmarksConfig
    trajectory: TrajectoryConfig
    estimator: EstimatorConfig
    reward: RewardConfig
    observation: ObservationConfig
    action: ActionConfig
    episode: EpisodeConfig
    render: RenderConfig

    @property
    def lidar_every(self) -> int:
        """Control steps between LiDAR scans."""
        return round(self.episode.control_hz / self.lidar.rate_hz)

    @property
    def max_steps(self) -> int:
        """Control steps in one episode."""
        return math.ceil(self.episode.duration_s * self.episode.control_hz - 1e-9)

    @classmethod
    def from_dict(cls, data: dict[str, Any], name: str = "custom") -> ScenarioConfig:
        """Validate a full scenario mapping (missing sections take their defaults)."""
        if not isinstance(data, dict):
            raise ConfigError(
                f"scenario {name!r}: got {type(data).__name__}; allowed: a mapping "
                f"with sections {sorted(SECTIONS)}"
            )
        for key in data:
            if key not in SECTIONS and key != "name":
                raise ConfigError(f"{key}: unknown section; allowed: {sorted(SECTIONS)}")
        sections = {key: sec.from_dict(data.get(key)) for key, sec in SECTIONS.items()}
        scenario = cls(name=str(data.get("name", name)), **sections)  # type: ignore[arg-type]
        ratio = scenario.episode.control_hz / scenario.lidar.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(
                f"lidar.rate_hz: got {scenario.lidar.rate_hz}; allowed: a rate that divides "
                f"episode.control_hz = {scenario.episode.control_hz} (integer ratio >= 1)"
            )
        return scenario

    def to_dict(self) -> dict[str, Any]:
        """Plain-data form (YAML/JSON serialisable), e.g. for run folders."""
        out: dict[str, Any] = {"name": self.name}
        for key in SECTIONS:
            sec = getattr(self, key)
            out[key] = {f.name: _plain(getattr(sec, f.name)) for f in fields(sec)}
        return out


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def config_dir() -> Path:
    """Package data ``quadslam_env/configs`` (``QUADSLAM_CONFIG_DIR`` overrides)."""
    env = os.environ.get("QUADSLAM_CONFIG_DIR")
    if env:
        return Path(env)
    # Package data (pyproject's package-data), so a wheel install finds it from any folder.
    return Path(str(resources.files("quadslam_env") / "configs"))


def available_scenarios() -> list[str]:
    """Names of the scenario files shipped in ``configs/scenarios``."""
    return sorted(p.stem for p in (config_dir() / "scenarios").glob("*.yaml"))


def deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """Recursively merge ``override`` into a copy of ``base`` (mappings merge, others replace)."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


class _YamlLoader(yaml.SafeLoader):
    """PyYAML's safe loader that also reads ``1e-4`` as a float.

    PyYAML follows YAML 1.1, where a float needs a dot (``1.0e-4``) and ``1e-4`` is the string
    ``"1e-4"``; config values would then fail validation with a confusing message.
    """


_YamlLoader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"^[-+]?(?:[0-9][0-9_]*)(?:\.[0-9_]*)?[eE][-+]?[0-9]+$"),
    list("-+0123456789"),
)


def parse_yaml(text: str) -> Any:
    """``yaml.safe_load`` that also reads exponent floats without a dot (``1e-4``)."""
    return yaml.load(text, Loader=_YamlLoader)  # a SafeLoader subclass: no arbitrary objects


def load_yaml(path: Path) -> dict[str, Any]:
    """Read a YAML mapping, with errors that name the file."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: cannot be read ({exc.strerror})") from exc
    try:
        data = parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"scenario file {str(path)!r}: malformed YAML ({exc})") from exc
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise ConfigError(
            f"scenario file {str(path)!r}: got {type(data).__name__}; "
            "allowed: a YAML mapping of sections"
        )
    return data


def load_scenario(
    scenario: str | Path | dict[str, Any] | None = None,
    overrides: dict[str, Any] | None = None,
    estimator_name: str | None = None,
) -> ScenarioConfig:
    """Load a scenario by name, path or mapping and apply overrides.

    Args:
        scenario: A name from ``configs/scenarios`` (e.g. ``"paper_ekf_figure8"``), a path to
            a YAML file, a mapping, or ``None`` for the default ``paper_ekf_figure8``.
        overrides: Section mappings merged into the scenario, e.g.
            ``{"episode": {"duration_s": 10.0}}``.
        estimator_name: Swap the scenario's estimator for this one before the overrides; the
            scenario's estimator ``params`` are dropped when the name changes, since they
            belong to the other estimator.

    Raises:
        ConfigError: Unknown scenario name, unreadable/malformed file, or invalid settings.
    """
    if scenario is None:
        scenario = "paper_ekf_figure8"
    if isinstance(scenario, dict):
        data, name = scenario, str(scenario.get("name", "custom"))
    else:
        path = Path(scenario)
        if path.suffix in (".yaml", ".yml") or path.exists():
            name = path.stem
        else:
            name = str(scenario)
            path = config_dir() / "scenarios" / f"{name}.yaml"
            if not path.exists():
                raise ConfigError(
                    f"scenario: got {name!r}; allowed: one of "
                    f"{available_scenarios()} or a path to a YAML file"
                )
        data = load_yaml(path)
    if estimator_name is not None:
        est = dict(data.get("estimator") or {})
        if est.get("name") != estimator_name:
            est = {**est, "name": estimator_name, "params": {}}
        data = {**data, "estimator": est}
    if overrides:
        if not isinstance(overrides, dict):
            raise ConfigError(f"overrides: got {overrides!r}; allowed: a mapping of sections")
        data = deep_merge(data, overrides)
    return ScenarioConfig.from_dict(data, name=name)
