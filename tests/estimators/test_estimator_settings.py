"""Every estimator's ``estimator.params`` go through the one validator of the scenario sections
(:class:`~quadslam_env.schema.Section`): bad settings raise a ``ConfigError`` naming the
key, the value and what is allowed when the env is built, before any episode starts."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.lab.cli.reference import estimator_settings
from estimators.ekf.settings import EkfSlamSettings
from estimators.fastslam.settings import DynamicFastSlamSettings, KinematicFastSlamSettings
from estimators.isam2.graph import GTSAM_INSTALL
from estimators.isam2.settings import Isam2Settings
from quadslam_env.schema import ConfigError
from quadslam_env.types import STATE_DIM

# (estimator, key, bad value, a fragment of what the message says is allowed)
CASES: list[tuple[str, str, Any, str]] = [
    # unknown keys: the message lists the accepted ones
    ("ekf_slam", "n_particles", 10, "allowed: ['accel_bias_sigma0'"),
    ("fastslam", "relinearise_tolerance", 2.0, "allowed: ['accel_bias_sigma'"),
    ("fastslam_kinematic", "inertia_scale", 2.5, "'imu_noise_scale'"),
    ("isam2", "max_iterations", 3, "'window_s'"),
    ("oracle", "process_noise", [0.0] * 9, "allowed: []"),
    # wrong types
    ("ekf_slam", "estimate_imu_bias", 1, "true or false"),
    ("ekf_slam", "process_noise", "big", "a list of 9 numbers >= 0.0"),
    ("fastslam", "n_particles", 10.0, "an integer >= 1"),
    ("fastslam", "stage2", "yes", "true or false"),
    ("fastslam_kinematic", "integrator", 4, "one of ['rk4', 'euler']"),
    ("isam2", "window_s", "3", "a number > 0.0 or null"),
    ("isam2", "association", 1, "one of ['nn', 'jcbb']"),
    # out-of-range values
    ("ekf_slam", "max_iterations", 0, "an integer >= 1 and <= 100"),
    ("ekf_slam", "gate_probability", 1.5, "a number > 0.0 and <= 1.0"),
    ("ekf_slam", "relinearise_tolerance", 0.0, "a number > 0.0 (or .inf)"),
    ("fastslam", "likelihood_inflation", 0.5, "a number >= 1.0"),
    ("fastslam", "process_noise", [0.1, 0.2], "a number or a list of 4 or 12 numbers >= 0.0"),
    ("fastslam", "gyro_bias_sigma", float("nan"), "a number > 0.0"),
    ("fastslam_kinematic", "imu_noise_scale", -1.0, "a number >= 0.0"),
    ("fastslam_kinematic", "resample_threshold", 1.5, "a number >= 0.0 and <= 1.0"),
    ("isam2", "iterations", 21, "an integer >= 1 and <= 20"),
    ("isam2", "gyro_bias_walk", -1e-3, "a number >= 0.0"),
]


@pytest.mark.parametrize(("name", "key", "value", "allowed"), CASES)
def test_bad_params_name_the_key_the_value_and_what_is_allowed(
    name: str, key: str, value: Any, allowed: str
) -> None:
    with pytest.raises(ConfigError) as err:
        estimator_settings()[name].from_dict({key: value})
    message = str(err.value)
    assert message.startswith(f"estimator.params.{key}: "), message
    assert allowed in message, message
    if "unknown key" not in message:
        assert f"got {value!r}" in message or f"got {value}" in message, message


@pytest.mark.parametrize("name", ["ekf_slam", "fastslam", "fastslam_kinematic", "oracle"])
def test_the_env_rejects_bad_params_before_the_first_reset(name: str) -> None:
    # Each estimator's own rejection (an unknown key), raised by gymnasium.make.
    with pytest.raises(ConfigError, match=r"estimator\.params\.no_such_key: unknown key"):
        gym.make("QuadSLAM-v0", estimator={"name": name, "params": {"no_such_key": 1}})


def test_isam2_rejects_bad_params_before_the_first_reset() -> None:
    pytest.importorskip("gtsam", reason=GTSAM_INSTALL)
    with pytest.raises(ConfigError, match=r"estimator\.params\.factorization: got 'lu'"):
        gym.make("QuadSLAM-v0", estimator={"name": "isam2", "params": {"factorization": "lu"}})


@pytest.mark.parametrize("estimator", ["oracle", "fastslam"])
def test_switching_the_estimator_by_a_kwarg_starts_from_its_defaults(estimator: str) -> None:
    # ekf_figure8_biased_imu sets EKF-only params (process_noise of 9 values, which FastSLAM
    # would read as neither 4 nor 12 groups, estimate_imu_bias); they must not reach the other
    # estimator.
    env = gym.make("QuadSLAM-v0", scenario="ekf_figure8_biased_imu", estimator={"name": estimator})
    try:
        scenario: Any = env.unwrapped.scenario  # type: ignore[attr-defined]
        assert scenario.estimator.name == estimator and scenario.estimator.params == {}
        env.reset(seed=0)
    finally:
        env.close()


def test_a_setting_the_chosen_mode_ignores_is_rejected() -> None:
    with pytest.raises(ConfigError) as err:
        DynamicFastSlamSettings.from_dict({"stage2_position": False})
    message = str(err.value)
    assert message.startswith("estimator.params.stage2_position: got False")
    assert "estimator.params.stage2 False ignores" in message and "['true']" in message
    assert not DynamicFastSlamSettings.from_dict(
        {"stage2": True, "stage2_position": False}
    ).stage2_position


def test_cross_field_rules() -> None:
    with pytest.raises(ConfigError, match=r"confirm_window: got 3; allowed: .*confirm_hits = 4"):
        Isam2Settings.from_dict({"confirm_hits": 4, "confirm_window": 3})
    with pytest.raises(ConfigError, match=r"new_landmark_probability: got 0\.95"):
        EkfSlamSettings.from_dict({"gate_probability": 0.99, "new_landmark_probability": 0.95})
    # The new-landmark gate defaults to 0.9999, or to the association gate when that is wider,
    # and to 0.9999 when there is no association gate.
    assert EkfSlamSettings.from_dict({}).new_landmark_probability == 0.9999
    wide = EkfSlamSettings.from_dict({"gate_probability": 0.99999})
    assert wide.new_landmark_probability == 0.99999
    assert EkfSlamSettings.from_dict({"gate_probability": 1.0}).new_landmark_probability == 0.9999


def test_numbers_in_numpy_and_infinite_tolerances_are_accepted() -> None:
    s = EkfSlamSettings.from_dict({"process_noise": np.full(9, 0.5), "max_iterations": np.int64(3)})
    assert s.process_noise == (0.5,) * 9 and type(s.max_iterations) is int
    assert (
        EkfSlamSettings.from_dict({"relinearise_tolerance": np.inf}).relinearise_tolerance == np.inf
    )
    with pytest.raises(ConfigError, match="max_iterations: got inf"):
        EkfSlamSettings.from_dict({"max_iterations": float("inf")})


def test_fastslam_process_noise_expands_a_value_or_four_groups_to_every_state() -> None:
    one = KinematicFastSlamSettings.from_dict({"process_noise": 0.3}).noise_density()
    np.testing.assert_array_equal(one, np.full(STATE_DIM, 0.3))
    groups = DynamicFastSlamSettings.from_dict({"process_noise": [1, 2, 3, 4]}).noise_density()
    np.testing.assert_array_equal(groups, [1, 1, 1, 2, 2, 2, 3, 3, 3, 4, 4, 4])
    every = np.arange(STATE_DIM, dtype=float)
    full = DynamicFastSlamSettings.from_dict({"process_noise": every}).noise_density()
    np.testing.assert_array_equal(full, every)


def test_a_bool_is_not_a_one_number_process_noise() -> None:
    """``true`` is an int in Python, not a density: refused under its own key."""
    with pytest.raises(ConfigError, match=r"^estimator\.params\.process_noise: got True"):
        DynamicFastSlamSettings.from_dict({"process_noise": True})


def test_every_gated_filter_gates_at_the_chi2_quantile() -> None:
    """χ²₃ at 0.99 is 11.345 (tables), and p = 1 turns the gate off."""
    for cls in (EkfSlamSettings, DynamicFastSlamSettings, Isam2Settings):
        assert cls.from_dict({}).gate == pytest.approx(11.345, abs=1e-3)
        assert cls.from_dict({"gate_probability": 1.0}).gate == np.inf
