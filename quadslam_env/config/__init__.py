"""Typed, frozen, validated scenario settings (docs/design.md §4 "Config flow").

A scenario is a YAML file in ``configs/scenarios/`` (or any path) with the sections ``vehicle``,
``imu``, ``lidar``, ``landmarks``, ``trajectory``, ``estimator``, ``reward``, ``observation``,
``action``, ``episode``, ``render``, ``wind``, ``randomize``, ``faults`` and ``integrity``.
Per-call overrides (``gymnasium.make(id, episode={...})``) are merged into it key by key.
Sections with a ``preset`` key start from that preset's values; keys given explicitly win.

This module is the settings' public face for users (``from quadslam_env.config import
load_scenario``); the project's own code imports each name from the module that defines it
(docs/design.md §1). The modules of the package, one per concept:
:mod:`~quadslam_env.config.scenario` (the whole scenario, the estimator and action sections, the
loader), :mod:`~quadslam_env.config.hardware` (vehicle, IMU, LiDAR),
:mod:`~quadslam_env.config.world` (landmarks, trajectory, wind), :mod:`~quadslam_env.config.episode`
(episode, reward, observation, render), :mod:`~quadslam_env.config.randomize`,
:mod:`~quadslam_env.config.faults`, :mod:`~quadslam_env.config.integrity`, and
:mod:`~quadslam_env.config.files` (the YAML files and the shipped scenarios). The schema every
section is written in (:class:`ConfigError`, ``Section``, ``spec``) is :mod:`quadslam_env.schema`,
below the estimators, which declare their own settings in it.
"""

from __future__ import annotations

from quadslam_env.config.episode import EpisodeConfig, ObservationConfig, RenderConfig, RewardConfig
from quadslam_env.config.faults import FaultsConfig
from quadslam_env.config.files import (
    available_scenarios,
    config_dir,
    deep_merge,
    load_yaml,
    parse_yaml,
    scenario_descriptions,
)
from quadslam_env.config.hardware import ImuConfig, LidarConfig, VehicleConfig
from quadslam_env.config.integrity import IntegrityConfig
from quadslam_env.config.randomize import RandomizeConfig
from quadslam_env.config.scenario import (
    SECTIONS,
    ActionConfig,
    EstimatorConfig,
    ScenarioConfig,
    load_scenario,
)
from quadslam_env.config.world import LandmarksConfig, TrajectoryConfig, WindConfig
from quadslam_env.schema import ConfigError, FieldRow, field_rows

__all__ = [
    "SECTIONS",
    "ActionConfig",
    "ConfigError",
    "EpisodeConfig",
    "EstimatorConfig",
    "FaultsConfig",
    "FieldRow",
    "ImuConfig",
    "IntegrityConfig",
    "LandmarksConfig",
    "LidarConfig",
    "ObservationConfig",
    "RandomizeConfig",
    "RenderConfig",
    "RewardConfig",
    "ScenarioConfig",
    "TrajectoryConfig",
    "VehicleConfig",
    "WindConfig",
    "available_scenarios",
    "config_dir",
    "deep_merge",
    "field_rows",
    "load_scenario",
    "load_yaml",
    "parse_yaml",
    "scenario_descriptions",
]
