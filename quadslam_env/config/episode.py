"""The scenario sections of an episode: its timing, start and limits, the reward, the optional
observation features, and the rendered frames (docs/design.md §4).

Each is a frozen :class:`~quadslam_env.schema.Section`; :mod:`quadslam_env.config`
assembles them with the others into a scenario.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, ClassVar

from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec

SUBSTEP_TOLERANCE = 1e-9
"""Relative rounding allowed in ``control period / vehicle.physics_dt_s`` being whole."""

MAX_LOOKAHEAD = 64
"""Most entries of ``observation.lookahead_s``: 64 look-ahead times, 192 observation values
(the nearest-landmark block holds at most 256)."""

_WEIGHT_MAX = 1e6
"""Largest magnitude of a reward weight: a term stays inside the floating-point range for any
error below 1e300."""


def _weight(default: float, doc: str) -> Any:
    """A reward weight's field: a number in [0, :data:`_WEIGHT_MAX`]."""
    return _spec(default, lo=0.0, hi=_WEIGHT_MAX, doc=doc)


@dataclass(frozen=True)
class RewardConfig(Section):
    """Reward weights; reward = alive - Σ w·term (+ termination penalty on failure)."""

    SECTION: ClassVar[str] = "reward"
    alive: float = _spec(
        1.0, lo=-_WEIGHT_MAX, hi=_WEIGHT_MAX, doc="reward per step for staying in the air"
    )
    pos_weight: float = _weight(1.0, "w_p on the true position error ‖ρ − ρ_d‖ (m)")
    vel_weight: float = _weight(0.1, "w_v on the true velocity error ‖ρ̇ − ρ̇_d‖ (m/s)")
    yaw_weight: float = _weight(0.1, "w_ψ on the true yaw error |wrap(ψ − ψ_d)| (rad)")
    effort_weight: float = _weight(0.01, "w_u on the effort ‖a − a_hover‖²/4 (normalised action)")
    termination_penalty: float = _weight(
        100.0,
        "subtracted on the step that terminates the episode; a step whose outputs are not "
        "finite gets −termination_penalty alone (docs/env.md, Termination and truncation)",
    )
    pos_std_weight: float = _weight(
        0.0,
        "w_σ on the estimator's own position uncertainty √trace(P_ρ) (m; 0 without a "
        "covariance): rewards looking where the filter learns",
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
        max_length=MAX_LOOKAHEAD,
        doc="append the reference displacement Δ seconds ahead (3 values each, m)",
    )
    landmarks_nearest: int = _spec(
        0,
        kind="int",
        lo=0,
        hi=64,
        doc="append the K nearest mapped landmarks as the estimate sees them: LiDAR azimuth, "
        "elevation (rad) and range (m) from the estimated pose, and 1 (0 and zeros: padding), "
        "nearest first (4 values each)",
    )
    estimated_wind: bool = _spec(
        False,
        kind="bool",
        doc="append the estimated horizontal wind (ŵ_N, ŵ_E), world frame (2 values, m/s); "
        "needs an estimator that estimates it (ekf_slam with wind: estimate)",
    )
    air_velocity: bool = _spec(
        False,
        kind="bool",
        doc="append the estimated velocity relative to the estimated wind, C_NBᵀ(C_NB v̂ − ŵ), "
        "body frame (3 values, m/s; what the drag feed-forward of lqi and se3 reads); needs "
        "an estimator that estimates the wind",
    )
    protection_levels: bool = _spec(
        False,
        kind="bool",
        doc="append the horizontal and vertical protection levels (2 values, m); needs "
        "integrity.monitor",
    )
    clip: float = _spec(
        100.0, lo=1e-6, hi=1e30, doc="observations are clipped to ±clip (the Box bounds)"
    )

    def check_estimator(self, name: str, params: dict[str, Any]) -> None:
        """The wind blocks need an estimator that reports the wind
        (:func:`quadslam_env.estimation.estimates_wind`). The oracle is refused: the truth it
        is fed has no wind (docs/env.md "Observation").

        Args:
            name: ``estimator.name``. params: ``estimator.params``.

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        wanted = [key for key in ("estimated_wind", "air_velocity") if getattr(self, key)]
        if not wanted:
            return
        from quadslam_env.estimation.registry import estimates_wind, estimator_flag

        if not estimator_flag(name, lambda n: estimates_wind(n, params)):
            wind = f" and estimator.params.wind = {params.get('wind', 'none')!r}"
            raise ConfigError(
                f"{self.SECTION}.{wanted[0]}: got true with estimator.name = {name!r}"
                f"{wind if name == 'ekf_slam' else ''}, which estimates no wind; allowed: "
                "false, or an estimator that estimates it (ekf_slam with "
                "estimator.params.wind: estimate, or a plug-in whose class method "
                "estimates_wind(params) is true)"
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
        2.0,
        lo=0.0,
        hi=1e6,
        doc="terminate when the pose NEES stays above nees_threshold this long, s",
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
    settle_s: float | None = _spec(
        None,
        lo=0.0,
        hi=1e6,
        optional=True,
        doc="end of the transient, s: the *_steady metrics cover t > settle_s, the "
        "*_transient ones the rest; null = 10 s, or 0 when the vehicle starts on the reference",
    )

    def validate(self) -> None:
        if abs(self.initial_euler_deg[1]) >= 89.0:
            raise ConfigError(
                f"episode.initial_euler_deg[1]: got {self.initial_euler_deg[1]}; "
                "allowed: |pitch| < 89 deg"
            )
        if self.settle_s is not None and self.settle_s >= self.duration_s:
            raise ConfigError(
                f"episode.settle_s: got {self.settle_s}; allowed: null or 0 <= settle_s < "
                f"episode.duration_s = {self.duration_s} (a steady phase must remain)"
            )

    def check_imu_rate(self, rate_hz: float | None) -> None:
        """``imu.rate_hz`` must be null, an integer multiple of ``control_hz`` or an integer
        fraction of it (the IMU samples on a grid that the control grid refines or is refined
        by: docs/design.md §3, docs/timing.md "IMU rate").

        Raises:
            ConfigError: Naming the key, the value and what is allowed.
        """
        if rate_hz is None:
            return
        control_hz = self.control_hz
        ratio = rate_hz / control_hz
        whole = ratio if ratio >= 1.0 else 1.0 / ratio
        if abs(whole - round(whole)) > 1e-9 * whole:
            raise ConfigError(
                f"imu.rate_hz: got {rate_hz}; allowed: null (= episode.control_hz), or a rate "
                f"that is an integer multiple or an integer fraction of episode.control_hz = "
                f"{control_hz} (e.g. {control_hz / 10:g} or {control_hz * 10:g})"
            )

    def check_substep(self, physics_dt_s: float) -> None:
        """The control period ``1 / control_hz`` must be a whole multiple n ≥ 1 of the RK4
        substep ``vehicle.physics_dt_s``, so that the vehicle is integrated in substeps of
        exactly that length; the ratio may differ from n by float rounding (a relative
        :data:`SUBSTEP_TOLERANCE`: 0.01 / 0.002 is 5.000000000000001).

        Raises:
            ConfigError: Naming ``vehicle.physics_dt_s``, both values and the nearest shorter
                substep that would do.
        """
        period = 1.0 / self.control_hz
        ratio = period / physics_dt_s
        n = round(ratio)
        if n >= 1 and abs(ratio - n) <= SUBSTEP_TOLERANCE * ratio:
            return
        shorter = period / max(1, math.ceil(ratio))  # the longest that divides the period
        raise ConfigError(
            f"vehicle.physics_dt_s: got {physics_dt_s:g} with episode.control_hz = "
            f"{self.control_hz:g}, whose control period {period:g} s is {ratio:.6g} substeps; "
            f"allowed: a substep the control period is a whole multiple of, period / n for a "
            f"whole n >= 1 (e.g. {shorter!r} s)"
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
