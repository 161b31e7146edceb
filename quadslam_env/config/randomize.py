"""The ``randomize`` section: per-episode domain randomisation of the physics and sensors.

docs/physics.md "Domain randomisation". Each setting is a range ``[lo, hi]`` of a multiplicative
scale on a nominal parameter, drawn uniformly per lane and episode
(:mod:`quadslam_env.sim.randomize`); ``[1, 1]`` (every default) leaves the parameter nominal, and a
section whose ranges are all ``[1, 1]`` is off (no draw at all).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from quadslam_env.models.params import VehicleParams
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec
from quadslam_env.types import GRAVITY

SCALE_KEYS = (
    "mass_scale",
    "inertia_scale",
    "thrust_scale",
    "lag_scale",
    "imu_bias_scale",
    "imu_noise_scale",
    "lidar_noise_scale",
    "wind_scale",
)
"""The randomised scales, in draw order (one uniform each, always all of them)."""

AXIS_KEYS = ("inertia_scale_x", "inertia_scale_y", "inertia_scale_z")
"""The inertia scales of the body axes x, y, z with ``inertia_scale_per_axis`` (each drawn on
``inertia_scale``'s range; pinnable on their own, ``info`` terms ``rand_inertia_scale_x`` …)."""

SCALE_MAX = 10.0
"""Largest scale a range or a pinned value may reach."""

BODY_SCALE_MIN = 0.1
"""Smallest scale on the mass or the inertia (a range's lower bound or a pinned value): a
tenth of the nominal body, still inside ``vehicle.mass_kg`` and ``vehicle.inertia_diag``'s
ranges for every preset; a scale near 0 would divide the dynamics by ~0."""


def _range(doc: str) -> Any:
    return _spec([1.0, 1.0], kind="vec", length=2, lo=0.0, hi=SCALE_MAX, doc=doc)


@dataclass(frozen=True)
class RandomizeConfig(Section):
    """Per-episode scales of the true vehicle, sensors and wind (the estimators keep the
    nominal model unless ``inform_estimator``). Each ``*_scale`` is ``[lo, hi]``: a uniform
    draw on that interval multiplies the nominal parameter; ``lo == hi`` fixes it."""

    SECTION: ClassVar[str] = "randomize"
    mass_scale: tuple[float, ...] = _range(
        "range of the scale on the vehicle's mass (from 0.1: a body needs a mass)"
    )
    inertia_scale: tuple[float, ...] = _range(
        "range of the scale on the inertia matrix (all axes together, or each body axis on "
        "its own with inertia_scale_per_axis; from 0.1: a body needs an inertia)"
    )
    thrust_scale: tuple[float, ...] = _range(
        "range of the scale on the actuators' effect: thrust and torque produced for a command "
        "(collective models: max thrust and max torque; rotors: k_f and k_m together)"
    )
    lag_scale: tuple[float, ...] = _range(
        "range of the scale on the actuator time constant (vehicle.actuator_tau_s or the "
        "rotors' motor lag)"
    )
    imu_bias_scale: tuple[float, ...] = _range(
        "range of the scale on the IMU's constant biases and drift std"
    )
    imu_noise_scale: tuple[float, ...] = _range(
        "range of the scale on the IMU's white-noise std (accelerometer and gyro)"
    )
    lidar_noise_scale: tuple[float, ...] = _range(
        "range of the scale on the LiDAR's noise std (all three channels)"
    )
    wind_scale: tuple[float, ...] = _range(
        "range of the scale on the wind (steady part and gusts; no effect in still air)"
    )
    inertia_scale_per_axis: bool = _spec(
        False,
        kind="bool",
        doc="draw the inertia scale of each body axis (x, y, z) on its own, uniform on "
        "inertia_scale's range: J_ij scales by sqrt(s_i s_j), so J_xx, J_yy, J_zz by s_x, s_y, "
        "s_z and J stays symmetric positive definite; info reports rand_inertia_scale_x/_y/_z "
        "instead of rand_inertia_scale",
    )
    inform_estimator: bool = _spec(
        False,
        kind="bool",
        doc="give each lane's estimator the vehicle of its draw (mass, inertia, thrust and "
        "torque scale, lag) at every reset instead of the nominal one; only estimators whose "
        "process model uses the vehicle (fastslam) change, the others have nothing to be told",
    )

    @property
    def enabled(self) -> bool:
        """Whether any range differs from ``[1, 1]`` (otherwise nothing is drawn)."""
        return any(getattr(self, key) != (1.0, 1.0) for key in SCALE_KEYS)

    def validate(self) -> None:
        """Inverted ranges and mass or inertia scales below :data:`BODY_SCALE_MIN` are errors.

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        for key in SCALE_KEYS:
            lo, hi = getattr(self, key)
            if lo > hi:
                raise ConfigError(
                    f"randomize.{key}: got {[lo, hi]}; allowed: [lo, hi] with 0 <= lo <= hi <= "
                    f"{SCALE_MAX} (a range of scales, lower bound first)"
                )
        for key in ("mass_scale", "inertia_scale"):
            if getattr(self, key)[0] < BODY_SCALE_MIN:
                raise ConfigError(
                    f"randomize.{key}: got {list(getattr(self, key))}; allowed: [lo, hi] with "
                    f"{BODY_SCALE_MIN} <= lo <= hi <= {SCALE_MAX} (a body needs a mass and an "
                    "inertia)"
                )

    def check_feasible(self, vehicle: VehicleParams) -> None:
        """The worst corner of the ranges (least thrust, most mass) must still hover.

        The message leads with ``mass_scale`` when the thrust range does not go below the
        nominal thrust (only the mass can be at fault), else with ``thrust_scale``.

        Raises:
            ConfigError: ``thrust_scale`` lo × max thrust ≤ ``mass_scale`` hi × m g.
        """
        thrust = ("randomize.thrust_scale[0]", self.thrust_scale[0])
        mass = ("randomize.mass_scale[1]", self.mass_scale[1])
        blame = "mass_scale" if self.thrust_scale[0] >= 1.0 else "thrust_scale"
        check_thrust_to_weight(vehicle, thrust, mass, blame)


def check_thrust_to_weight(
    vehicle: VehicleParams,
    thrust: tuple[str, float],
    mass: tuple[str, float],
    blame: str = "thrust_scale",
) -> None:
    """Thrust-to-weight ``thrust_scale f_max / (mass_scale m g)`` must exceed 1.

    Args:
        vehicle: The nominal vehicle.
        thrust: ``(key, scale)``: the thrust scale and the key it comes from, as the message
            names it (``randomize.thrust_scale[0]``, a range's lower bound, or
            ``reset options.randomized.thrust_scale``, a pin).
        mass: ``(key, scale)`` of the mass scale, the same way.
        blame: The scale the message leads with, as the one at fault: ``"thrust_scale"``
            or ``"mass_scale"`` (the one the user set; both are named).

    Raises:
        ConfigError: Naming both keys, their values and what either would need.
    """
    (thrust_key, thrust_scale), (mass_key, mass_scale) = thrust, mass
    weight = vehicle.mass * GRAVITY
    ratio = thrust_scale * vehicle.max_thrust / (mass_scale * weight)
    if math.isfinite(ratio) and ratio > 1.0:
        return
    least_thrust = mass_scale * weight / vehicle.max_thrust
    most_mass = thrust_scale * vehicle.max_thrust / weight
    more_thrust = f"a thrust scale > {least_thrust:.4g} at that mass scale"
    less_mass = f"a mass scale < {most_mass:.4g} at that thrust scale"
    if blame == "mass_scale":
        got = f"{mass_key}: got {mass_scale:g} with {thrust_key} {thrust_scale:g}"
        allowed = f"{less_mass}, or {more_thrust}"
    else:
        got = f"{thrust_key}: got {thrust_scale:g} with {mass_key} {mass_scale:g}"
        allowed = f"{more_thrust}, or {less_mass}"
    raise ConfigError(
        f"{got}: thrust-to-weight {ratio:.3g} (max thrust {vehicle.max_thrust:.4g} N, mass "
        f"{vehicle.mass:.4g} kg); allowed: {allowed} (thrust-to-weight > 1, so the vehicle "
        "can hover)"
    )


def parse_pins(value: Any) -> dict[str, float]:
    """Validate the reset option ``randomized``: a mapping of some :data:`SCALE_KEYS` (or of the
    :data:`AXIS_KEYS`, checked against the section by ``Randomizer.check_pins``) to scales.

    Returns:
        ``{key: scale}`` as floats.

    Raises:
        ConfigError: Not a mapping, an unknown key, or a value that is not a finite number in
            [0, 10] (mass and inertia scales in [0.1, 10], :data:`BODY_SCALE_MIN`).
    """
    allowed = [*SCALE_KEYS, *AXIS_KEYS]
    if not isinstance(value, dict):
        raise ConfigError(
            f"reset options.randomized: got {value!r}; allowed: a mapping of some of "
            f"{allowed} to scales"
        )
    out: dict[str, float] = {}
    for key, v in value.items():
        if key not in allowed:
            raise ConfigError(f"reset options.randomized.{key}: unknown key; allowed: {allowed}")
        body = key.startswith(("mass_scale", "inertia_scale"))
        ok = isinstance(v, int | float | np.floating | np.integer) and not isinstance(v, bool)
        num = float(v) if ok else math.nan
        least = BODY_SCALE_MIN if body else 0.0
        if not (math.isfinite(num) and num >= least) or num > SCALE_MAX:
            low = f">= {least:g}"
            raise ConfigError(
                f"reset options.randomized.{key}: got {v!r}; allowed: a number {low} and "
                f"<= {SCALE_MAX} (a scale on the nominal parameter)"
            )
        out[key] = num
    return out
