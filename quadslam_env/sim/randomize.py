"""Domain randomisation: per-lane, per-episode scales of the true vehicle, sensors and wind.

docs/physics.md "Domain randomisation". The ``randomize`` section
(:class:`~quadslam_env.config.randomize.RandomizeConfig`) gives a range ``[lo, hi]`` per scale;
at every reset of a lane (autoresets included) each scale of :data:`SCALE_KEYS` is drawn
uniformly on its range, or pinned by ``reset(options={"randomized": {...}})``. The scales act on
the truth only: the vehicle kernels, the IMU, the LiDAR and the wind take per-lane parameter
arrays (the nominal case is the same kernels with the nominal rows). The estimators, the action
map and the controllers keep the scenario's nominal parameters: the mismatch is the point.
With ``randomize.inform_estimator`` the simulator gives each reset lane's estimator the vehicle
of its draw (:meth:`Randomizer.vehicles`, :func:`scaled_vehicle`) instead.

Random stream per lane (the contract with the single env): at each reset, with randomisation
on, one generator is spawned from the lane's initial-error child (the fifth child the simulator
spawns from the lane's generator, :class:`~quadslam_env.core.SimCore`; nothing else spawns from
it, and spawning draws nothing from its stream, so the landmarks, the sensors' noise, the
estimator and the initial error draw exactly what they draw without randomisation), and from it
one ``random(8)``: the uniforms of :data:`SCALE_KEYS` in that order, all eight whatever the
ranges. With every range ``[1, 1]`` (the default) nothing is spawned or drawn. With
``inertia_scale_per_axis`` the body x axis takes the ``inertia_scale`` uniform of the eight and
one more ``random(2)`` from the same generator gives the y and z axes: the eight scales, and so
every other stream, are those of the same seed without it.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np

from quadslam_env.config.randomize import (
    AXIS_KEYS,
    SCALE_KEYS,
    RandomizeConfig,
    check_thrust_to_weight,
)
from quadslam_env.estimation.protocol import TakesVehicle
from quadslam_env.models.params import VehicleParams
from quadslam_env.schema import ConfigError
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.lidar import LidarBatch
from quadslam_env.sim.vehicle import VehicleBatch, inertia_factor
from quadslam_env.sim.wind import WindBatch
from quadslam_env.types import FloatArray

RANDOMIZED_KEYS = tuple(f"rand_{key}" for key in SCALE_KEYS)
"""``info`` terms of the episode's scales (where randomisation applies), in :data:`SCALE_KEYS`
order: ``rand_mass_scale``, ``rand_inertia_scale``, …"""

AXIS_INFO_KEYS = tuple(f"rand_{key}" for key in AXIS_KEYS)
"""``info`` terms of the body axes' inertia scales with ``inertia_scale_per_axis`` (in place of
``rand_inertia_scale``): ``rand_inertia_scale_x``, ``_y``, ``_z``."""

_COLUMN = {key: j for j, key in enumerate(SCALE_KEYS)}
_INERTIA = _COLUMN["inertia_scale"]


class Randomizer:
    """The scales of B lanes and their draws (module docstring).

    Args:
        cfg: The ``randomize`` section.
        vehicle: The nominal vehicle (for the thrust-to-weight check of pinned scales).
        num_lanes: B.

    Attributes:
        values: (B, 8) each lane's current scales, columns :data:`SCALE_KEYS` (1 = nominal;
            with ``inertia_scale_per_axis`` the inertia column is the x axis's).
        axes: (B, 3) each lane's inertia scales of the body axes x, y, z (all equal to the
            inertia column unless ``inertia_scale_per_axis``).
        enabled: Whether the section draws (some range is not ``[1, 1]``).
    """

    def __init__(self, cfg: RandomizeConfig, vehicle: VehicleParams, num_lanes: int) -> None:
        b = int(num_lanes)
        self.cfg = cfg
        self.vehicle = vehicle
        self.enabled = cfg.enabled
        self.values = np.ones((b, len(SCALE_KEYS)))
        self.axes = np.ones((b, 3))
        self.per_axis = cfg.inertia_scale_per_axis
        self._keys = RANDOMIZED_KEYS
        if self.per_axis:  # the axes' terms in the place of the common scale's
            self._keys = (
                *RANDOMIZED_KEYS[:_INERTIA],
                *AXIS_INFO_KEYS,
                *RANDOMIZED_KEYS[_INERTIA + 1 :],
            )
        ranges = np.array([getattr(cfg, key) for key in SCALE_KEYS], dtype=float)
        self._lo, self._span = ranges[:, 0], ranges[:, 1] - ranges[:, 0]
        self._reported = np.zeros(b, dtype=bool)  # lanes whose episode was randomised or pinned
        self._pending: np.ndarray | None = None
        # (K, B) the info rows of the current episodes, rebuilt only when a reset changes them
        self._shown: FloatArray | None = None

    def check_pins(self, pins: Mapping[str, float] | None) -> None:
        """Pinned scales must hover against the worst corner of the ranges left to draw, and
        the body axes' inertia scales are pinned only with ``inertia_scale_per_axis`` and not
        together with ``inertia_scale`` (which pins every axis).

        Raises:
            ConfigError: Thrust-to-weight ≤ 1 possible, or an axis pin not allowed (names the
                option and the values).
        """
        pins = pins or {}
        axes = sorted(set(AXIS_KEYS) & set(pins))
        if axes and not self.per_axis:
            raise ConfigError(
                f"reset options.randomized.{axes[0]}: got {pins[axes[0]]!r} with "
                "randomize.inertia_scale_per_axis false; allowed: inertia_scale (every axis), "
                "or set randomize.inertia_scale_per_axis: true to pin an axis"
            )
        if axes and "inertia_scale" in pins:
            raise ConfigError(
                f"reset options.randomized.{axes[0]}: got {pins[axes[0]]!r} with "
                f"inertia_scale = {pins['inertia_scale']!r}; allowed: inertia_scale (every "
                "axis) or some of the axes' scales, not both"
            )
        if not ({"mass_scale", "thrust_scale"} & set(pins)):
            return
        pin = "reset options.randomized"
        thrust = (
            (f"{pin}.thrust_scale", pins["thrust_scale"])
            if "thrust_scale" in pins
            else ("randomize.thrust_scale[0]", self.cfg.thrust_scale[0])
        )
        mass = (
            (f"{pin}.mass_scale", pins["mass_scale"])
            if "mass_scale" in pins
            else ("randomize.mass_scale[1]", self.cfg.mass_scale[1])
        )
        blame = "thrust_scale" if "thrust_scale" in pins else "mass_scale"  # a pinned one
        check_thrust_to_weight(self.vehicle, thrust, mass, blame)

    def begin(
        self,
        lanes: np.ndarray,
        parents: Sequence[np.random.Generator],
        pins: Mapping[str, float] | None,
        vehicle: VehicleBatch,
    ) -> None:
        """Draw (or pin) the scales of ``lanes`` (k,) and set the vehicle's; call before the
        vehicle's reset (its actuators start at the lane's own hover).

        Args:
            lanes: (k,) lane indices.
            parents: (k,) the lanes' initial-error children (module docstring).
            pins: Scales fixed for every lane reset (``reset`` options), or ``None``.
            vehicle: The true vehicles.
        """
        self._pending = None
        moved = (self.values[lanes] != 1.0).any() or (self.axes[lanes] != 1.0).any()
        if not (self.enabled or pins or moved):
            return  # nominal lanes stay nominal: nothing drawn, nothing set
        k = lanes.shape[0]
        out = np.ones((k, len(SCALE_KEYS)))
        axes = np.ones((k, 2))  # the y and z axes' inertia scales (per axis)
        if self.enabled:
            lo, span = self._lo[_INERTIA], self._span[_INERTIA]
            for j, parent in enumerate(parents):
                draws = parent.spawn(1)[0]
                out[j] = self._lo + self._span * draws.random(len(SCALE_KEYS))
                if self.per_axis:  # only then: the stream of the eight is the same either way
                    axes[j] = lo + span * draws.random(2)
        pinned = dict(pins or {})
        for key, value in pinned.items():
            if key in _COLUMN:
                out[:, _COLUMN[key]] = value
        if self.per_axis:
            if "inertia_scale" in pinned:
                axes[:] = pinned["inertia_scale"]
            out[:, _INERTIA] = pinned.get("inertia_scale_x", out[:, _INERTIA])
            for i, key in enumerate(AXIS_KEYS[1:]):
                axes[:, i] = pinned.get(key, axes[:, i])
            self.axes[lanes] = np.column_stack((out[:, _INERTIA], axes))
        else:
            self.axes[lanes] = out[:, [_INERTIA]]
        self.values[lanes] = out
        self._reported[lanes] = self.enabled or bool(pins)
        reported = self._reported[:, None]
        self._shown = (
            np.where(reported, self._rows(), math.nan).T.copy() if reported.any() else None
        )
        c = _COLUMN
        inertia = self.axes[lanes] if self.per_axis else out[:, _INERTIA]
        vehicle.set_scales(
            lanes, out[:, c["mass_scale"]], inertia, out[:, c["thrust_scale"]],
            out[:, c["lag_scale"]],
        )  # fmt: skip
        self._pending = lanes

    def _rows(self) -> FloatArray:
        """(B, K) every lane's scales in the order of its ``info`` terms."""
        if not self.per_axis:
            return self.values
        v = self.values
        return np.hstack((v[:, :_INERTIA], self.axes, v[:, _INERTIA + 1 :]))

    def finish(self, imu: ImuBatch, lidar: LidarBatch, wind: WindBatch) -> None:
        """Scale the sensors and the wind of the lanes of the last :meth:`begin`; call after
        their resets (the IMU's drawn biases and the wind's first gust are scaled here)."""
        lanes = self._pending
        if lanes is None:
            return
        v, c = self.values[lanes], _COLUMN
        imu.set_scales(
            lanes, v[:, c["mass_scale"]], v[:, c["imu_bias_scale"]], v[:, c["imu_noise_scale"]]
        )
        lidar.set_scales(lanes, v[:, c["lidar_noise_scale"]])
        wind.set_scales(lanes, v[:, c["wind_scale"]])
        self._pending = None

    def vehicles(self, lanes: np.ndarray) -> list[VehicleParams]:
        """The vehicle of each of ``lanes`` (k,) this episode: the nominal one scaled by the
        lane's current draw (:func:`scaled_vehicle`; the nominal object where nothing moved)."""
        c = _COLUMN
        out = []
        for lane in np.asarray(lanes, dtype=np.int64).tolist():
            row = self.values[lane]
            inertia = self.axes[lane] if self.per_axis else row[_INERTIA]
            mass, thrust, lag = row[c["mass_scale"]], row[c["thrust_scale"]], row[c["lag_scale"]]
            out.append(scaled_vehicle(self.vehicle, mass, inertia, thrust, lag))
        return out

    def inform(self, lanes: np.ndarray, estimators: Sequence[object]) -> None:
        """With ``randomize.inform_estimator``, give each estimator that
        :class:`~quadslam_env.estimation.protocol.TakesVehicle` the vehicles of ``lanes`` (k,)
        (:meth:`vehicles`; call after :meth:`begin`, before their reset). Nominal lanes get the
        nominal vehicle back, so a lane never keeps an earlier episode's draw."""
        if not self.cfg.inform_estimator:
            return
        vehicles = self.vehicles(lanes)
        for est in estimators:
            if isinstance(est, TakesVehicle):
                est.set_vehicle(lanes, vehicles)

    def info(self) -> dict[str, FloatArray]:
        """The ``info`` terms :data:`RANDOMIZED_KEYS` (with ``inertia_scale_per_axis`` the
        :data:`AXIS_INFO_KEYS` in the place of ``rand_inertia_scale``), (B,) copies each, NaN in
        lanes whose episode is nominal; none when no lane is randomised."""
        shown = self._shown
        if shown is None:
            return {}
        return {key: shown[j].copy() for j, key in enumerate(self._keys)}


def scaled_vehicle(
    vehicle: VehicleParams, mass: float, inertia: float | FloatArray, thrust: float, lag: float
) -> VehicleParams:
    """The parameters of the vehicle :meth:`VehicleBatch.set_scales` simulates with these scales.

    The mass and the inertia are scaled (the inertia by one scale or per body axis,
    :func:`~quadslam_env.sim.vehicle.inertia_factor`); the thrust scale is a gain on the saturated
    command, so the thrust and torque limits scale with it (and, with rotors, ``k_f`` and
    ``k_m``); the lag scale multiplies ``actuator_tau`` (rotors: ``motor_tau``). All ones give
    ``vehicle``.

    Args:
        vehicle: The nominal vehicle. mass, thrust, lag: The scales (dimensionless).
        inertia: The scale of J, or (3,) the scales of its body axes x, y, z.

    Returns:
        A :class:`VehicleParams` (the same object when every scale is 1).
    """
    axes = np.asarray(inertia, dtype=float)
    if mass == 1.0 and np.all(axes == 1.0) and thrust == 1.0 and lag == 1.0:
        return vehicle
    factor = inertia_factor(axes.reshape(1, -1) if axes.ndim else axes.reshape(1))
    rotors = vehicle.rotors
    if rotors is not None:
        rotors = dataclasses.replace(
            rotors, k_f=rotors.k_f * thrust, k_m=rotors.k_m * thrust,
            motor_tau=rotors.motor_tau * lag,
        )  # fmt: skip
    return dataclasses.replace(
        vehicle, mass=vehicle.mass * mass,
        inertia=(np.asarray(vehicle.inertia).reshape(1, 9) * factor).reshape(3, 3),
        max_thrust=vehicle.max_thrust * thrust, max_torque=np.asarray(vehicle.max_torque) * thrust,
        actuator_tau=vehicle.actuator_tau * lag, rotors=rotors,
    )  # fmt: skip
