"""Scenario sections of the vehicle and its sensors: ``vehicle``, ``imu``, ``lidar`` (presets of
the papers' hardware and of common MEMS IMUs); re-exported by :mod:`quadslam_env.config`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams, rotor_vehicle
from quadslam_env.models.rotors import LAYOUTS, RotorParams
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec
from quadslam_env.types import DEG, GRAVITY

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
        None, lo=1e-3, hi=1e3, optional=True, doc="mass m in kg (1 g to 1 t); null = the preset's"
    )
    inertia_diag: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        length=3,
        lo=1e-8,
        hi=1e3,
        optional=True,
        doc="principal moments of inertia (J_xx, J_yy, J_zz) in kg·m², the range of the masses' "
        "bodies (a 1 g body of 1 cm to a 1 t one of 1 m); null = the preset's",
    )
    max_thrust_n: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e5,
        optional=True,
        doc="collective thrust limit in N (must exceed m g; up to ten times the weight of the "
        "heaviest mass); null = the preset's",
    )
    max_torque_nm: tuple[float, ...] | None = _spec(
        None,
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        optional=True,
        doc="body torque limits (τ_x, τ_y, τ_z) in N·m (at most the largest thrust on a 0.1 m "
        "arm); null = the preset's",
    )
    drag_per_s: float = _spec(
        0.0,
        lo=0.0,
        hi=10.0,
        doc="linear drag coefficient in 1/s (specific force −drag·v_a on the velocity relative "
        "to the air); 0 = none, as in the papers",
    )
    drag_quadratic_per_m: tuple[float, ...] = _spec(
        [0.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=0.0,
        hi=10.0,
        doc="quadratic drag c_q per body axis in 1/m (specific force −c_q ∘ (‖v_a‖ v_a) on "
        "the velocity relative to the air); simulator only, the estimators' models leave it out",
    )
    actuator_tau_s: float = _spec(
        0.0, lo=0.0, hi=1.0, doc="first-order lag of thrust and torques in s; 0 = instantaneous"
    )
    rotor_layout: str | None = _spec(
        None,
        kind="str",
        choices=("none", *LAYOUTS),
        optional=True,
        doc="rotor model: none (thrust and torque act directly), x or plus (four rotors, the "
        'mixer and motor lag of docs/physics.md "Rotors"); null = the preset\'s (crazyflie2: x)',
    )
    rotor_arm_m: float | None = _spec(
        None, lo=0.0, lo_open=True, hi=10.0, optional=True, doc="rotors: centre-to-rotor arm L, m"
    )
    rotor_k_f: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e-3,
        optional=True,
        doc="rotors: thrust k_f in T = k_f ω², N/(rad/s)² (the Crazyflie's 2.9e-8; large "
        "rotors 1e-5)",
    )
    rotor_k_m: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e-4,
        optional=True,
        doc="rotors: drag torque k_m in |τ| = k_m ω², N·m/(rad/s)² (the Crazyflie's 7.2e-10)",
    )
    rotor_motor_tau_s: float | None = _spec(
        None,
        lo=0.0,
        hi=1.0,
        optional=True,
        doc="rotors: motor time constant of the rotor speed, s (0 = instantaneous)",
    )
    rotor_omega_min_rad_s: float | None = _spec(
        None, lo=0.0, hi=1e4, optional=True, doc="rotors: lowest rotor speed, rad/s"
    )
    rotor_omega_max_rad_s: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        optional=True,
        doc="rotors: highest rotor speed, rad/s (4 k_f ω_max² must exceed m g; the "
        "Crazyflie's 2274, 1e4 ≈ 95,000 rpm at most)",
    )
    physics_dt_s: float = _spec(
        0.002,
        lo=1e-5,
        hi=0.02,
        doc="RK4 substep of the rigid body in s (the control period must be a multiple)",
    )

    def rotors(self) -> RotorParams | None:
        """The rotor model: the preset's with this section's ``rotor_*`` overrides, or ``None``.

        Raises:
            ConfigError: A rotor layout on a preset without rotors with a missing ``rotor_*``
                setting, or inconsistent speeds.
        """
        base = VEHICLE_PRESETS[self.preset].rotors
        layout = self.rotor_layout or (base.layout if base else "none")
        if layout == "none":
            return None
        values = {}
        for key, attr, fallback in _ROTOR_KEYS:
            value = getattr(self, key)
            if value is None:
                value = getattr(base, attr) if base is not None else fallback
            if value is None:
                raise ConfigError(
                    f"vehicle.{key}: got null with vehicle.rotor_layout = {layout!r} on preset "
                    f"{self.preset!r}, which has no rotors; allowed: a number (see docs/physics.md "
                    '"Rotors")'
                )
            values[attr] = float(value)
        if values["omega_max"] <= values["omega_min"]:
            raise ConfigError(
                f"vehicle.rotor_omega_max_rad_s: got {values['omega_max']}; allowed: > "
                f"vehicle.rotor_omega_min_rad_s = {values['omega_min']}"
            )
        return RotorParams(layout=layout, **values)

    def params(self) -> VehicleParams:
        """The :class:`VehicleParams` of the preset with this section's overrides applied."""
        base = VEHICLE_PRESETS[self.preset]
        mass = base.mass if self.mass_kg is None else self.mass_kg
        inertia = base.inertia if self.inertia_diag is None else _diag(self.inertia_diag)
        rotors = self.rotors()
        if rotors is not None:
            return rotor_vehicle(
                self.preset,
                mass,
                inertia,
                rotors,
                drag=self.drag_per_s,
                drag_quadratic=_vec(self.drag_quadratic_per_m),
            )
        return VehicleParams(
            name=self.preset,
            mass=mass,
            inertia=inertia,
            max_thrust=base.max_thrust if self.max_thrust_n is None else self.max_thrust_n,
            max_torque=base.max_torque if self.max_torque_nm is None else _vec(self.max_torque_nm),
            drag=self.drag_per_s,
            actuator_tau=self.actuator_tau_s,
            drag_quadratic=_vec(self.drag_quadratic_per_m),
        )

    def validate(self) -> None:
        params = self.params()
        if params.rotors is not None:
            self._check_rotors(params)
            return
        for key, _, _ in _ROTOR_KEYS:
            if getattr(self, key) is not None:
                raise ConfigError(
                    f"vehicle.{key}: got {getattr(self, key)!r} on a vehicle without rotors, "
                    "which ignores it; allowed: null, or vehicle.rotor_layout: x or plus"
                )
        if params.max_thrust <= params.mass * GRAVITY:
            raise ConfigError(
                f"vehicle.max_thrust_n: got {float(params.max_thrust)!r}; allowed: > m g = "
                f"{params.mass * GRAVITY:.6g} N (the vehicle must be able to hover)"
            )

    def _check_rotors(self, params: VehicleParams) -> None:
        """Rotors: the limits and the lag are the rotors', and they must lift the vehicle."""
        for key, default in (
            ("max_thrust_n", None),
            ("max_torque_nm", None),
            ("actuator_tau_s", 0.0),
        ):
            value = getattr(self, key)
            if value != default:
                raise ConfigError(
                    f"vehicle.{key}: got {_plain(value)!r} on a vehicle with rotors, whose "
                    f"limits and lag are the rotors'; allowed: {_plain(default)!r} (set the "
                    "vehicle.rotor_* settings instead)"
                )
        rotors = params.rotors
        assert rotors is not None
        weight = params.mass * GRAVITY
        if rotors.max_collective_thrust <= weight:
            raise ConfigError(
                f"vehicle.rotor_omega_max_rad_s: got {rotors.omega_max:g}, so the rotors lift "
                f"4 k_f ω_max² = {rotors.max_collective_thrust:.4g} N (thrust-to-weight "
                f"{rotors.max_collective_thrust / weight:.3g}); allowed: thrust-to-weight > 1, "
                f"ω_max > {rotors.hover_speed(weight):.5g} rad/s with k_f = {rotors.k_f:g} and "
                f"m g = {weight:.4g} N"
            )


_ROTOR_KEYS = (
    ("rotor_arm_m", "arm", None),
    ("rotor_k_f", "k_f", None),
    ("rotor_k_m", "k_m", None),
    ("rotor_motor_tau_s", "motor_tau", 0.0),
    ("rotor_omega_min_rad_s", "omega_min", 0.0),
    ("rotor_omega_max_rad_s", "omega_max", None),
)
"""``(setting, RotorParams attribute, value when neither the setting nor the preset gives one)``."""


def check_rotor_action(mode: str, vehicle: VehicleConfig) -> None:
    """``action.mode: rotor_thrust`` needs a vehicle with rotors.

    Raises:
        ConfigError: Naming the key, the value and what is allowed.
    """
    if mode == "rotor_thrust" and vehicle.rotors() is None:
        raise ConfigError(
            f"action.mode: got 'rotor_thrust' on vehicle preset {vehicle.preset!r} without "
            "rotors; allowed: 'thrust_torque' or 'thrust_rates', or a vehicle with rotors "
            "(vehicle.preset: crazyflie2, or vehicle.rotor_layout: x or plus)"
        )


def _plain(value: Any) -> Any:
    return list(value) if isinstance(value, tuple) else value


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
        100.0, lo=1e-3, hi=1e6, doc="correlation time τ of the Gauss–Markov drift b1, s"
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
    rate_hz: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=100000.0,
        optional=True,
        doc="IMU sample rate in Hz; null = episode.control_hz. Either rate must be an integer "
        "multiple of the other (Rauniyar et al. 2023, Table 5: 10 Hz under a 100 Hz "
        "controller). The estimator predicts once per sample of a faster IMU; with a slower "
        "one it runs at the IMU instants and its output is carried forward at the control "
        "rate (docs/timing.md, IMU rate)",
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
    range_min_m: float = _spec(0.0, lo=0.0, hi=1e4, doc="minimum range of a return, m")
    range_max_m: float = _spec(
        100.0, lo=0.0, lo_open=True, hi=1e4, doc="maximum range of a return, m (at most 10 km)"
    )
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
    association: str = _spec(
        "known",
        kind="str",
        choices=("known", "unknown"),
        doc="known: each return carries its landmark id (the papers); unknown: returns are "
        "unlabeled and shuffled, the estimator associates them (the truth pairing reaches "
        "only the metrics)",
    )
    detection_prob: float = _spec(
        1.0, lo=0.0, hi=1.0, doc="probability that a landmark in the FOV and range is returned"
    )
    clutter_rate: float = _spec(
        0.0,
        lo=0.0,
        hi=1000.0,
        doc="mean number of false returns per scan (Poisson), uniform over the FOV volume "
        "within range; needs association: unknown",
    )
    delay_steps: int = _spec(
        0,
        kind="int",
        lo=0,
        doc="control steps between a scan's measurement and its arrival at the estimator, "
        "which updates the belief of the scan's own time and re-propagates (less than the "
        "episode's steps)",
    )

    def validate(self) -> None:
        if self.range_max_m <= self.range_min_m:
            raise ConfigError(
                f"lidar.range_max_m: got {self.range_max_m}; allowed: > "
                f"lidar.range_min_m = {self.range_min_m}"
            )
        if self.clutter_rate > 0.0 and self.association == "known":
            raise ConfigError(
                f"lidar.clutter_rate: got {self.clutter_rate}; allowed: 0 with association: "
                "known (a false return has no landmark id), or set lidar.association: unknown"
            )
