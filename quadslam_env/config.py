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

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

from quadslam_env.config_files import (
    available_scenarios,
    check_description,
    config_dir,
    deep_merge,
    load_yaml,
    parse_yaml,
    scenario_descriptions,
)
from quadslam_env.config_schema import ConfigError, FieldRow, Section, field_rows
from quadslam_env.config_schema import spec as _spec
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams
from quadslam_env.types import DEG, GRAVITY

__all__ = [
    "SECTIONS",
    "ActionConfig",
    "ConfigError",
    "EpisodeConfig",
    "EstimatorConfig",
    "FieldRow",
    "ImuConfig",
    "LandmarksConfig",
    "LidarConfig",
    "ObservationConfig",
    "RewardConfig",
    "ScenarioConfig",
    "TrajectoryConfig",
    "VehicleConfig",
    "available_scenarios",
    "config_dir",
    "deep_merge",
    "field_rows",
    "load_scenario",
    "load_yaml",
    "parse_yaml",
    "scenario_descriptions",
]


_MICRO_G = 1e-6 * GRAVITY


@dataclass(frozen=True)
class VehicleConfig(Section):
    """Vehicle preset and overrides. ``None`` means "take the preset's value"."""

    SECTION: ClassVar[str] = "vehicle"
    preset: str = _spec(
        "rauniyar2023",
        kind="str",
        choices=tuple(VEHICLE_PRESETS),
        doc="vehicle parameters to start from (mass, inertia, limits); see the presets table",
    )
    mass_kg: float | None = _spec(
        None, lo=0.0, lo_open=True, optional=True, doc="mass m in kg; null = the preset's"
    )
    inertia_diag: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        optional=True,
        doc="principal moments of inertia (J_xx, J_yy, J_zz) in kg·m²; null = the preset's",
    )
    max_thrust_n: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        optional=True,
        doc="collective thrust limit in N (must exceed m g); null = the preset's",
    )
    max_torque_nm: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        optional=True,
        doc="body torque limits (τ_x, τ_y, τ_z) in N·m; null = the preset's",
    )
    drag_per_s: float = _spec(
        0.0,
        lo=0.0,
        hi=10.0,
        doc="linear drag coefficient in 1/s (specific force −drag·v); 0 = none, as in the papers",
    )
    actuator_tau_s: float = _spec(
        0.0, lo=0.0, hi=1.0, doc="first-order lag of thrust and torques in s; 0 = instantaneous"
    )
    physics_dt_s: float = _spec(
        0.002,
        lo=1e-5,
        hi=0.02,
        doc="RK4 substep of the rigid body in s (the control period must be a multiple)",
    )

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
            max_torque=base.max_torque if self.max_torque_nm is None else _vec(self.max_torque_nm),
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


def _vec(values: tuple[float, ...]) -> Any:
    import numpy as np

    return np.array(values, dtype=float)


@dataclass(frozen=True)
class ImuConfig(Section):
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
        # MEMS IMUs with their full-scale ranges (datasheet noise densities; no bias).
        "mpu6000": {
            "accel_noise_density": 400 * _MICRO_G,
            "gyro_noise_density": 0.005 * DEG,
            "accel_bias": [0.0] * 3,
            "gyro_bias": [0.0] * 3,
            "accel_drift_sigma": 0.0,
            "gyro_drift_sigma": 0.0,
            "accel_range_g": 16.0,
            "gyro_range_dps": 2000.0,
        },
        "icm42688": {
            "accel_noise_density": 70 * _MICRO_G,
            "gyro_noise_density": 0.0028 * DEG,
            "accel_bias": [0.0] * 3,
            "gyro_bias": [0.0] * 3,
            "accel_drift_sigma": 0.0,
            "gyro_drift_sigma": 0.0,
            "accel_range_g": 16.0,
            "gyro_range_dps": 2000.0,
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
        None,
        kind="str",
        choices=("rauniyar2023", "sadeghzadeh2021", "mpu6000", "icm42688", "ideal"),
        optional=True,
        doc="IMU error model to start from; null = the values below",
    )
    accel_noise_density: float = _spec(300 * _MICRO_G, lo=0.0, hi=1.0, doc="m/s²/√Hz")
    gyro_noise_density: float = _spec(0.01 * DEG, lo=0.0, hi=1.0, doc="rad/s/√Hz")
    accel_bias: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-5.0,
        hi=5.0,
        doc="constant accelerometer bias b0_a per axis, m/s²",
    )
    gyro_bias: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-1.0,
        hi=1.0,
        doc="constant gyro bias b0_ω per axis, rad/s",
    )
    random_bias_sign: bool = _spec(
        False, kind="bool", doc="flip each bias component's sign at random per episode"
    )
    drift_tau_s: float = _spec(
        100.0, lo=0.0, lo_open=True, doc="correlation time τ of the Gauss–Markov drift b1, s"
    )
    accel_drift_sigma: float = _spec(0.0, lo=0.0, hi=1.0, doc="stationary std of b1_a, m/s²")
    gyro_drift_sigma: float = _spec(0.0, lo=0.0, hi=1.0, doc="stationary std of b1_ω, rad/s")
    accel_range_g: float | None = _spec(
        None,
        lo=0.5,
        hi=1000.0,
        optional=True,
        doc="accelerometer full scale ±range per axis in g (9.81 m/s²), readings saturate "
        "there; null = unlimited",
    )
    gyro_range_dps: float | None = _spec(
        None,
        lo=1.0,
        hi=100000.0,
        optional=True,
        doc="gyro full scale ±range per axis in deg/s, readings saturate there; null = unlimited",
    )


@dataclass(frozen=True)
class LidarConfig(Section):
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
    preset: str | None = _spec(
        None,
        kind="str",
        choices=("rauniyar2023", "vlp16"),
        optional=True,
        doc="sensor to start from; null = the values below",
    )
    azimuth_fov_deg: float = _spec(
        45.0,
        lo=0.0,
        hi=180.0,
        lo_open=True,
        doc="half-width of the azimuth field of view, deg (180 = all round)",
    )
    elevation_fov_deg: float = _spec(
        30.0, lo=0.0, hi=90.0, lo_open=True, doc="half-width of the elevation field of view, deg"
    )
    range_min_m: float = _spec(0.0, lo=0.0, doc="minimum range of a return, m")
    range_max_m: float = _spec(100.0, lo=0.0, lo_open=True, doc="maximum range of a return, m")
    sigma_azimuth_deg: float = _spec(
        0.33, lo=0.0, hi=30.0, doc="azimuth noise standard deviation, deg"
    )
    sigma_elevation_deg: float = _spec(
        0.30, lo=0.0, hi=30.0, doc="elevation noise standard deviation, deg"
    )
    sigma_range_m: float = _spec(0.1, lo=0.0, hi=10.0, doc="range noise standard deviation, m")
    rate_hz: float = _spec(
        10.0,
        lo=0.0,
        lo_open=True,
        hi=1000.0,
        doc="scan rate in Hz (must divide episode.control_hz)",
    )

    def validate(self) -> None:
        if self.range_max_m <= self.range_min_m:
            raise ConfigError(
                f"lidar.range_max_m: got {self.range_max_m}; allowed: > "
                f"lidar.range_min_m = {self.range_min_m}"
            )


@dataclass(frozen=True)
class LandmarksConfig(Section):
    """Landmark layout (DESIGN.md §3): ``rauniyar2023`` random points, ``poles4``, ``explicit``."""

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
        choices=("tangent", "fixed"),
        doc="tangent: heading along the horizontal velocity; fixed: yaw_deg",
    )
    yaw_deg: float = _spec(0.0, lo=-180.0, hi=180.0, doc="heading of the fixed yaw mode, deg")


@dataclass(frozen=True)
class EstimatorConfig(Section):
    """Estimator choice, its own settings, and the initial uncertainty P0."""

    SECTION: ClassVar[str] = "estimator"
    name: str = _spec(
        "ekf_slam",
        kind="str",
        doc="a registered estimator: built in ekf_slam, fastslam, fastslam_kinematic, oracle; "
        "more through estimators.register or a 'quadslam.estimators' entry point",
    )
    params: dict[str, Any] = _spec(  # noqa: RUF009 (validated field spec)
        {}, kind="dict", doc="the estimator's own settings (see the estimators page)"
    )
    # Seed 001 Table 7 for (ρ, v, Λ) followed by the body rates (rad²/s²).
    initial_cov_diag: tuple[float, ...] = _spec(
        [0.001, 0.001, 0.001, 0.1, 0.1, 0.1, 0.0, 0.0, 0.0, 1e-6, 1e-6, 1e-6],
        kind="vec",
        length=12,
        lo=0.0,
        hi=100.0,
        doc="diagonal of P0 over (ρ m², v m²/s², Λ rad², ω rad²/s²)",
    )
    sample_initial_error: bool = _spec(
        True, kind="bool", doc="start the estimate at the truth plus an error drawn from P0"
    )
    known_map: bool = _spec(
        False, kind="bool", doc="hand the true landmarks to the estimator at reset"
    )

    def validate(self) -> None:
        # The names come from the estimator registry (layer 3). Only its name table is read
        # here (estimators.base imports no estimator); plug-ins listed by entry points are not
        # imported until the env builds them.
        from estimators.base import available

        names = available()
        if self.name not in names:
            raise ConfigError(
                f"estimator.name: got {self.name!r}; allowed: one of {names} (more through "
                "estimators.register or a 'quadslam.estimators' entry point)"
            )


@dataclass(frozen=True)
class RewardConfig(Section):
    """Reward weights; reward = alive - Σ w·term (+ termination penalty on failure)."""

    SECTION: ClassVar[str] = "reward"
    alive: float = _spec(1.0, doc="reward per step for staying in the air")
    pos_weight: float = _spec(1.0, lo=0.0, doc="w_p on the true position error ‖ρ − ρ_d‖ (m)")
    vel_weight: float = _spec(0.1, lo=0.0, doc="w_v on the true velocity error ‖ρ̇ − ρ̇_d‖ (m/s)")
    yaw_weight: float = _spec(0.1, lo=0.0, doc="w_ψ on the true yaw error |wrap(ψ − ψ_d)| (rad)")
    effort_weight: float = _spec(
        0.01, lo=0.0, doc="w_u on the effort ‖a − a_hover‖²/4 (normalised action)"
    )
    termination_penalty: float = _spec(
        100.0, lo=0.0, doc="subtracted on the step that terminates the episode"
    )


@dataclass(frozen=True)
class ObservationConfig(Section):
    """Optional observation features on top of the base 16 (see ``QuadSLAMEnv``)."""

    SECTION: ClassVar[str] = "observation"
    pos_uncertainty: bool = _spec(
        False, kind="bool", doc="append √diag of the position covariance (3 values, m)"
    )
    landmark_counts: bool = _spec(
        False, kind="bool", doc="append landmarks visible in the last scan and mapped (2 values)"
    )
    lookahead_s: tuple[float, ...] = _spec(
        [],
        kind="vec",
        lo=0.0,
        hi=10.0,
        doc="append the reference displacement Δ seconds ahead (3 values each, m)",
    )
    clip: float = _spec(
        100.0, lo=1e-6, hi=1e30, doc="observations are clipped to ±clip (the Box bounds)"
    )


@dataclass(frozen=True)
class ActionConfig(Section):
    """Action interpretation: ``thrust_torque`` or ``thrust_rates`` (inner body-rate loop)."""

    SECTION: ClassVar[str] = "action"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = dict.fromkeys(
        ("max_rate_dps", "rate_gain_per_s"), ("mode", ("thrust_rates",))
    )
    mode: str = _spec(
        "thrust_torque",
        kind="str",
        choices=("thrust_torque", "thrust_rates"),
        doc="thrust_torque: a1..a3 are torques; thrust_rates: a1..a3 are body-rate commands",
    )
    max_rate_dps: tuple[float, ...] = _spec(
        [180.0, 180.0, 90.0],
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        doc="thrust_rates: body-rate command at |a| = 1 per axis, deg/s",
    )
    rate_gain_per_s: tuple[float, ...] = _spec(
        [20.0, 20.0, 10.0],
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        doc="thrust_rates: inner-loop gain K in τ = J K (ω_cmd − ω̂), 1/s",
    )


@dataclass(frozen=True)
class EpisodeConfig(Section):
    """Timing, initial state and termination limits."""

    SECTION: ClassVar[str] = "episode"
    duration_s: float = _spec(
        50.0, lo=0.0, lo_open=True, hi=1e6, doc="episode length in s (truncated after it)"
    )
    control_hz: float = _spec(
        100.0,
        lo=0.0,
        lo_open=True,
        hi=10000.0,
        doc="agent steps per second (env.unwrapped.dt = 1/control_hz)",
    )
    initial_position: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0], kind="vec", length=3, lo=-1e6, hi=1e6, doc="true start position in NED, m"
    )
    initial_velocity: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-1e3,
        hi=1e3,
        doc="true start velocity in the body frame, m/s",
    )
    initial_euler_deg: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-180.0,
        hi=180.0,
        doc="true start attitude (φ, θ, ψ), deg",
    )
    max_tilt_deg: float = _spec(
        80.0, lo=0.0, hi=89.0, lo_open=True, doc="terminate when the tilt exceeds this, deg"
    )
    max_pos_err_m: float = _spec(
        10.0, lo=0.0, lo_open=True, doc="terminate when the true tracking error exceeds this, m"
    )
    ground_z_m: float | None = _spec(None, optional=True, doc="NED z of the ground; null = none")
    nees_threshold: float | None = _spec(
        1000.0, lo=0.0, lo_open=True, optional=True, doc="null disables the NEES divergence check"
    )
    nees_window_s: float = _spec(
        2.0, lo=0.0, doc="terminate when the pose NEES stays above nees_threshold this long, s"
    )
    max_cov_trace: float | None = _spec(
        1e6,
        lo=0.0,
        lo_open=True,
        optional=True,
        doc="terminate (estimator divergence) when the trace of the 9×9 pose covariance "
        "(ρ m², v m²/s², Λ rad²) exceeds this; null disables the check",
    )
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
class RenderConfig(Section):
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


SECTIONS: dict[str, type[Section]] = {
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
    """A complete, validated scenario.

    Besides the sections, a scenario mapping may hold ``name`` and ``description`` (one line,
    listed by ``quadslam scenarios``).
    """

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
    description: str = ""

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
            if key not in SECTIONS and key not in ("name", "description"):
                allowed = sorted([*SECTIONS, "description", "name"])
                raise ConfigError(f"{key}: unknown section; allowed: {allowed}")
        text = data.get("description")
        description = "" if text is None else check_description(text)
        sections = {key: sec.from_dict(data.get(key)) for key, sec in SECTIONS.items()}
        scenario = cls(
            name=str(data.get("name", name)),
            description=description,
            **sections,
        )
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
        if self.description:
            out["description"] = self.description
        for key in SECTIONS:
            sec = getattr(self, key)
            out[key] = {f.name: _plain(getattr(sec, f.name)) for f in fields(sec)}
        return out


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


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
    if not isinstance(scenario, str | Path | dict) or scenario == "":
        raise ConfigError(
            f"scenario: got {scenario!r}; allowed: a scenario name (one of "
            f"{available_scenarios()}), a path to a YAML file or a mapping of sections"
        )
    if estimator_name is not None and not isinstance(estimator_name, str):
        raise ConfigError(
            f"estimator_name: got {estimator_name!r}; allowed: an estimator name (a string)"
        )
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
