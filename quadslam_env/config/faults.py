"""The ``faults`` section: one fault of the simulated world per episode (docs/integrity.md
"Faults"), re-exported by :mod:`quadslam_env.config`.

A fault is a landmark that moves (``landmark_moves``), a false return that moves with the
vehicle and looks like a landmark (``phantom_landmark``), a bias on the LiDAR's ranges
(``range_bias``) or a step in one IMU axis's constant bias (``imu_bias_step``), active from its
onset for its duration. ``kind: none`` (the default) is no fault: nothing is drawn and every
result is the one without the section. :mod:`quadslam_env.sim.faults` applies it to the lanes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

from quadslam_env.config.hardware import LidarConfig
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec
from quadslam_env.types import DEG

FAULT_KINDS = ("none", "landmark_moves", "phantom_landmark", "range_bias", "imu_bias_step")
"""The values of ``faults.kind``; ``none`` is no fault."""

_FAULTED = FAULT_KINDS[1:]
_SCALED = ("landmark_moves", "range_bias", "imu_bias_step")

MAGNITUDE_MAX = 100.0
"""Largest ``|faults.magnitude|``: 100 m/s, 100 m, 100 m/s² or 100 rad/s."""


@dataclass(frozen=True)
class FaultsConfig(Section):
    """One fault of the world per episode (off by default): a moving landmark, a phantom
    landmark, a LiDAR range bias or an IMU bias step, from its onset for its duration."""

    SECTION: ClassVar[str] = "faults"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {
        **dict.fromkeys(("onset_s", "onset_max_s", "duration_s"), ("kind", _FAULTED)),
        "magnitude": ("kind", _SCALED),
        **dict.fromkeys(("landmark", "direction_deg"), ("kind", ("landmark_moves",))),
        "fraction": ("kind", ("range_bias",)),
        **dict.fromkeys(("sensor", "axis"), ("kind", ("imu_bias_step",))),
        "offset_m": ("kind", ("phantom_landmark",)),
    }
    kind: str = _spec(
        "none",
        kind="str",
        choices=FAULT_KINDS,
        doc="none: no fault; landmark_moves: a true landmark moves; phantom_landmark: a false "
        "return fixed in the body frame; range_bias: a bias on the LiDAR's ranges; "
        "imu_bias_step: a step in one IMU axis's constant bias",
    )
    onset_s: float = _spec(
        0.0,
        lo=0.0,
        hi=1e6,
        doc="episode time the fault starts, s (with onset_max_s: the earliest onset); less "
        "than episode.duration_s",
    )
    onset_max_s: float | None = _spec(
        None,
        lo=0.0,
        hi=1e6,
        optional=True,
        doc="latest onset, s: the onset is drawn per episode uniformly in [onset_s, "
        "onset_max_s]; null = onset_s every episode",
    )
    duration_s: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e6,
        optional=True,
        doc="how long the fault lasts, s (active on the steps with onset <= t < onset + "
        "duration); null = to the episode's end",
    )
    magnitude: float = _spec(
        0.5,
        lo=-MAGNITUDE_MAX,
        hi=MAGNITUDE_MAX,
        doc="landmark_moves: the landmark's speed, m/s (>= 0); range_bias: added to each "
        "affected range, m; imu_bias_step: added to the constant bias, m/s² (accel) or rad/s "
        "(gyro)",
    )
    landmark: int | None = _spec(
        None,
        kind="int",
        lo=0,
        hi=100000,
        optional=True,
        doc="index of the moving landmark; null = drawn per episode among those the "
        "reference trajectory sees while the fault is active (all, if none or with a free "
        "heading)",
    )
    direction_deg: float | None = _spec(
        None,
        lo=-180.0,
        hi=180.0,
        optional=True,
        doc="heading of the landmark's horizontal motion, deg from north towards east; null "
        "= drawn per episode uniformly",
    )
    fraction: float = _spec(
        1.0,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="share of the landmarks whose returns are biased: 1 = every return (false "
        "returns too); less = round(fraction · L) landmarks (at least 1) drawn per episode",
    )
    sensor: str = _spec(
        "accel",
        kind="str",
        choices=("accel", "gyro"),
        doc="the IMU sensor whose bias steps: accelerometer (m/s²) or gyro (rad/s)",
    )
    axis: int = _spec(
        2, kind="int", lo=0, hi=2, doc="the body axis of the step: 0 x (forward), 1 y, 2 z (down)"
    )
    offset_m: tuple[float, ...] = _spec(
        [4.0, 0.0, 0.0],
        kind="vec",
        length=3,
        lo=-1e4,
        hi=1e4,
        doc="the phantom's position in the body frame (FRD), m: a return at its azimuth, "
        "elevation and range, inside the LiDAR's field of view and range",
    )

    @property
    def enabled(self) -> bool:
        """Whether there is a fault (``kind`` is not ``none``)."""
        return self.kind != "none"

    @property
    def extra_landmarks(self) -> int:
        """Landmark ids the fault adds to the scans: 1 for the phantom, else 0."""
        return 1 if self.kind == "phantom_landmark" else 0

    @property
    def latest_onset_s(self) -> float:
        """The latest onset an episode can draw, s."""
        return self.onset_s if self.onset_max_s is None else self.onset_max_s

    def validate(self) -> None:
        if self.onset_max_s is not None and self.onset_max_s < self.onset_s:
            raise ConfigError(
                f"faults.onset_max_s: got {self.onset_max_s} with faults.onset_s = "
                f"{self.onset_s}; allowed: null or a time >= faults.onset_s"
            )
        if self.kind == "landmark_moves" and self.magnitude < 0.0:
            raise ConfigError(
                f"faults.magnitude: got {self.magnitude} with faults.kind 'landmark_moves' (a "
                f"speed, m/s); allowed: a speed from 0 to {MAGNITUDE_MAX} (faults.direction_deg "
                "gives the way)"
            )
        if self.kind == "phantom_landmark" and not any(self.offset_m):
            raise ConfigError(
                "faults.offset_m: got [0.0, 0.0, 0.0]; allowed: a position in the body frame "
                "away from the sensor (a return needs a range > 0)"
            )

    def check_scenario(self, duration_s: float, landmark_count: int, lidar: LidarConfig) -> None:
        """Against the other sections: the onset before the episode's end, a moving
        landmark the layout has, a phantom the LiDAR sees.

        Args:
            duration_s: ``episode.duration_s``.
            landmark_count: Landmarks the ``landmarks`` layout makes.
            lidar: The LiDAR's settings (its field of view and range).

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        if not self.enabled:
            return
        if self.latest_onset_s >= duration_s:
            key = "onset_s" if self.onset_max_s is None else "onset_max_s"
            raise ConfigError(
                f"faults.{key}: got {self.latest_onset_s} with episode.duration_s = "
                f"{duration_s}; allowed: an onset before the episode's end (< {duration_s} s)"
            )
        landmark = self.landmark
        if self.kind == "landmark_moves" and landmark is not None and landmark >= landmark_count:
            raise ConfigError(
                f"faults.landmark: got {landmark} with {landmark_count} landmark(s) in the "
                f"landmarks layout; allowed: null or an index from 0 to {landmark_count - 1}"
            )
        if self.kind == "phantom_landmark":
            self._check_phantom(lidar)

    def _check_phantom(self, lidar: LidarConfig) -> None:
        """The phantom's offset inside the LiDAR's field of view and range (the test of
        :class:`~quadslam_env.sim.lidar.LidarBatch`'s in-view kernel)."""
        x, y, z = self.offset_m
        horiz = math.hypot(x, y)
        az, el, rng = math.atan2(y, x), math.atan2(z, horiz), math.hypot(horiz, z)
        az_max, el_max = lidar.azimuth_fov_deg, lidar.elevation_fov_deg
        in_fov = abs(az) <= az_max * DEG and abs(el) <= el_max * DEG
        if in_fov and lidar.range_min_m <= rng <= lidar.range_max_m:
            return
        raise ConfigError(
            f"faults.offset_m: got {list(self.offset_m)} (azimuth {az / DEG:.4g} deg, "
            f"elevation {el / DEG:.4g} deg, range {rng:.4g} m), which the LiDAR never sees; "
            f"allowed: a body-frame position within lidar.azimuth_fov_deg = {az_max}, "
            f"lidar.elevation_fov_deg = {el_max} and the range [{lidar.range_min_m}, "
            f"{lidar.range_max_m}] m"
        )
