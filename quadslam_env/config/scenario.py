"""The scenario: the estimator and action sections, the whole settings of one env
(:class:`ScenarioConfig`), the checks across sections, and :func:`load_scenario`, which reads a
scenario file, applies the presets and the per-call overrides and validates every section
(docs/design.md §4 "Config flow").

Every unknown key, wrong type or out-of-range value raises :class:`ConfigError` (a
``ValueError``) whose message names the dotted key, the bad value and what is allowed.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, ClassVar

from quadslam_env.config.episode import EpisodeConfig, ObservationConfig, RenderConfig, RewardConfig
from quadslam_env.config.faults import FaultsConfig
from quadslam_env.config.files import (
    available_scenarios,
    check_description,
    config_dir,
    deep_merge,
    load_yaml,
)
from quadslam_env.config.hardware import (
    ImuConfig,
    LidarConfig,
    VehicleConfig,
    check_rotor_action,
)
from quadslam_env.config.integrity import IntegrityConfig
from quadslam_env.config.randomize import RandomizeConfig
from quadslam_env.config.world import LandmarksConfig, TrajectoryConfig, WindConfig
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec


@dataclass(frozen=True)
class EstimatorConfig(Section):
    """Estimator choice, its own settings, and the initial uncertainty P0."""

    SECTION: ClassVar[str] = "estimator"
    name: str = _spec(
        "ekf_slam",
        kind="str",
        doc="a registered estimator: built in ekf_slam, fastslam, fastslam_kinematic, isam2, "
        "oracle; "
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
        # The names come from the estimator registry, which imports no estimator; plug-ins
        # listed by entry points are not imported until the env builds them.
        from quadslam_env.estimation.registry import available

        names = available()
        if self.name not in names:
            raise ConfigError(
                f"estimator.name: got {self.name!r}; allowed: one of {names} (more through "
                "estimators.register or a 'quadslam.estimators' entry point)"
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
        choices=("thrust_torque", "thrust_rates", "rotor_thrust"),
        doc="thrust_torque: a1..a3 are torques; thrust_rates: a1..a3 are body-rate commands; "
        "rotor_thrust: a0..a3 are the four rotors' thrusts (a vehicle with rotors)",
    )
    max_rate_dps: tuple[float, ...] = _spec(
        [180.0, 180.0, 90.0],
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        hi=1e5,
        doc="thrust_rates: body-rate command at |a| = 1 per axis, deg/s (at most the widest "
        "gyro range, imu.gyro_range_dps)",
    )
    rate_gain_per_s: tuple[float, ...] = _spec(
        [20.0, 20.0, 10.0],
        kind="vec",
        length=3,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        doc="thrust_rates: inner-loop gain K in τ = J K (ω_cmd − ω̂), 1/s (at most 1e4: faster "
        "than any control rate)",
    )
    heading: bool = _spec(
        False,
        kind="bool",
        doc="a fifth action a4: the rate a4·max_heading_rate_dps of the reference heading ψ_d "
        "(with trajectory.yaw_mode: free), which a controller then tracks",
    )
    max_heading_rate_dps: float = _spec(
        90.0, lo=0.0, lo_open=True, hi=3600.0, doc="heading: ψ̇_d at |a4| = 1, deg/s"
    )
    delay_steps: int = _spec(
        0,
        kind="int",
        lo=0,
        doc="control steps between an action and its application (the hover action over "
        "an episode's first steps; less than the episode's steps)",
    )

    @property
    def dim(self) -> int:
        """Components of one action: 4, plus 1 with the heading channel."""
        return 5 if self.heading else 4


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
    "wind": WindConfig,
    "randomize": RandomizeConfig,
    "faults": FaultsConfig,
    "integrity": IntegrityConfig,
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
    wind: WindConfig
    randomize: RandomizeConfig
    faults: FaultsConfig
    integrity: IntegrityConfig
    description: str = ""

    @property
    def lidar_every(self) -> int:
        """Control steps between LiDAR scans."""
        return round(self.episode.control_hz / self.lidar.rate_hz)

    @property
    def imu_rate_hz(self) -> float:
        """IMU sample rate f_IMU in Hz (``imu.rate_hz``, or the control rate when null)."""
        rate = self.imu.rate_hz
        return self.episode.control_hz if rate is None else rate

    @property
    def imu_per_step(self) -> int:
        """IMU samples per control step (≥ 1; > 1 when the IMU is faster than the control)."""
        return max(1, round(self.imu_rate_hz / self.episode.control_hz))

    @property
    def steps_per_imu(self) -> int:
        """Control steps per IMU sample (≥ 1; > 1 when the IMU is slower than the control)."""
        return max(1, round(self.episode.control_hz / self.imu_rate_hz))

    @property
    def second_run(self) -> str | None:
        """The setting that runs a copy of the estimator beside it, or ``None``."""
        if self.steps_per_imu > 1:
            return "imu.rate_hz"
        return "lidar.delay_steps" if self.lidar.delay_steps else None

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
        if scenario.lidar.association == "unknown":
            from quadslam_env.estimation.registry import associates_unlabeled, estimator_flag

            if not estimator_flag(scenario.estimator.name, associates_unlabeled):
                raise ConfigError(
                    f"lidar.association: got 'unknown' with estimator.name = "
                    f"{scenario.estimator.name!r}, which cannot associate unlabeled returns; "
                    "allowed: 'known', or an estimator that associates (ekf_slam, fastslam, isam2, "
                    "fastslam_kinematic, oracle, or a plug-in with associates_unlabeled = True)"
                )
        ratio = scenario.episode.control_hz / scenario.lidar.rate_hz
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise ConfigError(
                f"lidar.rate_hz: got {scenario.lidar.rate_hz}; allowed: a rate that divides "
                f"episode.control_hz = {scenario.episode.control_hz} (integer ratio >= 1)"
            )
        scenario.episode.check_imu_rate(scenario.imu.rate_hz)
        scenario.episode.check_substep(scenario.vehicle.physics_dt_s)
        check_delays(scenario)
        check_copyable(scenario)
        check_heading(scenario)
        check_rotor_action(scenario.action.mode, scenario.vehicle)
        vehicle = scenario.vehicle
        scenario.wind.check_drag(
            vehicle.drag_per_s, vehicle.drag_quadratic_per_m, vehicle.physics_dt_s,
            scenario.randomize.wind_scale[1],
        )  # fmt: skip
        scenario.wind.check_inform(
            scenario.estimator.name, scenario.steps_per_imu, scenario.lidar.delay_steps
        )
        scenario.observation.check_estimator(scenario.estimator.name, scenario.estimator.params)
        scenario.randomize.check_feasible(scenario.vehicle.params())
        faults, size = scenario.faults, scenario.landmarks.size
        faults.check_scenario(scenario.episode.duration_s, size, scenario.lidar)
        scenario.integrity.check_scenario(scenario)
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


def check_delays(scenario: ScenarioConfig) -> None:
    """``action.delay_steps`` and ``lidar.delay_steps`` must be shorter than an episode, and a
    delayed LiDAR does not go with an IMU slower than the control (docs/timing.md "Latency"; its
    estimator is checked by :func:`check_copyable`). Either association is fine: the lagging
    filter applies each scan, labeled or not, at its own time
    (:mod:`quadslam_env.runtime.scan_delay`).

    Raises:
        ConfigError: Naming the key, the value and what is allowed.
    """
    steps = scenario.max_steps
    for key, value in (
        ("action.delay_steps", scenario.action.delay_steps),
        ("lidar.delay_steps", scenario.lidar.delay_steps),
    ):
        if value >= steps:
            raise ConfigError(
                f"{key}: got {value}; allowed: an integer from 0 to {steps - 1} (an episode "
                f"has episode.duration_s × episode.control_hz = {steps} steps)"
            )
    delay = scenario.lidar.delay_steps
    if delay == 0:
        return
    if scenario.steps_per_imu > 1:
        raise ConfigError(
            f"lidar.delay_steps: got {delay} with imu.rate_hz = {scenario.imu.rate_hz} < "
            f"episode.control_hz = {scenario.episode.control_hz}; allowed: lidar.delay_steps: "
            "0 with an IMU slower than the control, or imu.rate_hz null or >= "
            "episode.control_hz with a delayed LiDAR"
        )


def check_copyable(scenario: ScenarioConfig) -> None:
    """A second run (:attr:`ScenarioConfig.second_run`, ``period_log.EstimatorCopies``) needs
    an estimator that can be copied (:func:`quadslam_env.estimation.copyable`), or, for a
    delayed LiDAR, one that takes late scans (:func:`quadslam_env.estimation.takes_late_scans`:
    each scan at its own time without a copy, :class:`~quadslam_env.runtime.scan_delay.LateScans`).

    Raises:
        ConfigError: Naming the key, the value and what is allowed.
    """
    name, second = scenario.estimator.name, scenario.second_run
    if second == "imu.rate_hz":
        control_hz = scenario.episode.control_hz
        got = f"imu.rate_hz: got {scenario.imu.rate_hz} < episode.control_hz = {control_hz}"
        why = "an IMU slower than the control runs a copy of the estimator at its instants"
        allowed = f"imu.rate_hz null or >= episode.control_hz with {name!r}"
    elif second is not None:
        got = f"lidar.delay_steps: got {scenario.lidar.delay_steps}"
        why = "a delayed scan is applied to a copy of the estimator at the scan's time"
        allowed = f"lidar.delay_steps: 0 with {name!r}"
    else:
        return
    from quadslam_env.estimation.registry import copyable, estimator_flag, takes_late_scans

    if estimator_flag(name, copyable):
        return
    late = scenario.steps_per_imu == 1  # a delayed LiDAR only
    if late and estimator_flag(name, takes_late_scans):
        return
    also = " or takes late scans (takes_late_scans = True)" if late else ""
    raise ConfigError(
        f"{got} with estimator.name = {name!r}, which cannot be copied ({why}); allowed: "
        f"{allowed}, or an estimator that can be copied (whose class does not say "
        f"copyable = False){also}"
    )


def check_heading(scenario: ScenarioConfig) -> None:
    """The heading channel goes with the free heading; the landmark observation, a real map.

    Raises:
        ConfigError: Naming the key, the value and what is allowed.
    """
    yaw_mode, heading = scenario.trajectory.yaw_mode, scenario.action.heading
    if heading and yaw_mode != "free":
        raise ConfigError(
            f"action.heading: got true with trajectory.yaw_mode = {yaw_mode!r}, which "
            "prescribes the heading; allowed: false, or trajectory.yaw_mode: free"
        )
    if yaw_mode == "free" and not heading:
        raise ConfigError(
            "trajectory.yaw_mode: got 'free' with action.heading = false (nothing would set "
            "the heading); allowed: 'tangent' or 'fixed', or action.heading: true"
        )
    if scenario.observation.landmarks_nearest and scenario.estimator.name == "oracle":
        raise ConfigError(
            f"observation.landmarks_nearest: got {scenario.observation.landmarks_nearest} with "
            "estimator.name = 'oracle', whose map is the truth; allowed: 0, or an estimator "
            "that maps the landmarks"
        )


def _plain(value: Any) -> Any:
    if isinstance(value, tuple):
        return [_plain(v) for v in value]
    return value


def _drop_other_params(data: dict[str, Any], override: Any) -> dict[str, Any]:
    """The scenario without its estimator ``params`` when ``override`` (the ``estimator``
    override) names another estimator: those settings belong to the scenario's estimator, and
    the new one starts from its own defaults (plus any ``params`` the override gives)."""
    if not isinstance(override, dict) or not isinstance(data.get("estimator"), dict):
        return data
    name = override.get("name")
    if name is None or name == data["estimator"].get("name", "ekf_slam"):
        return data
    return {**data, "estimator": {**data["estimator"], "params": {}}}


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
        data = deep_merge(_drop_other_params(data, overrides.get("estimator")), overrides)
    return ScenarioConfig.from_dict(data, name=name)
