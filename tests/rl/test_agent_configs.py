"""The hyperparameter files: every shipped entry complete and valid, bad entries refused naming
the problem, numeric strings and linear schedules converted."""

from __future__ import annotations

from pathlib import Path

import gymnasium as gym
import pytest
from training_cases import (
    REQUIRED_KEYS,
    config_entries,
)

import quadslam_env  # noqa: F401  (registers the ids)
from agents.rl.hyperparams import (
    RESERVED_KEYS,
    load_hyperparams,
    resolve_settings,
)
from agents.rl.training import train


@pytest.mark.parametrize(("algo", "env_id"), config_entries())
def test_shipped_config_entries_are_complete_and_valid(algo: str, env_id: str) -> None:
    entry = load_hyperparams(algo, env_id)
    for key in (*REQUIRED_KEYS, "normalize"):
        assert key in entry, f"{algo}.yaml[{env_id}] lacks {key}"
    assert env_id in gym.registry
    settings = resolve_settings(algo, entry)
    assert settings["n_timesteps"] >= 100_000
    assert settings["policy_kwargs"]  # parsed from a string or a mapping
    if env_id == "QuadSLAM-EKF-v0":
        assert entry["env_kwargs"]["scenario"] == "ekf_figure8_biased_imu"
        assert settings["wrapper"] is not None and settings["wrapper"][0] == "residual_dflqr"
    assert set(settings["algo_kwargs"]).isdisjoint(RESERVED_KEYS)


def test_bad_configs_raise_value_errors_naming_the_problem(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="no entry for env 'QuadSLAM-Nope-v0'"):
        load_hyperparams("ppo", "QuadSLAM-Nope-v0")
    entry = load_hyperparams("ppo", "QuadSLAM-EKF-v0")
    with pytest.raises(ValueError, match="learning_rat: unknown hyperparameter for PPO"):
        resolve_settings("ppo", {**entry, "learning_rat": 1e-3})
    with pytest.raises(ValueError, match="wrapper: got 'residual'"):
        resolve_settings("ppo", {**entry, "wrapper": "residual"})
    with pytest.raises(ValueError, match="scale"):
        resolve_settings("ppo", {**entry, "wrapper": {"name": "residual_dflqr", "scale": -1}})
    with pytest.raises(ValueError, match=r"normalize\.norm_obz"):
        resolve_settings("ppo", {**entry, "normalize": {"norm_obz": True}})
    bad_yaml = tmp_path / "bad.yaml"
    bad_yaml.write_text("QuadSLAM-EKF-v0: [unclosed\n")
    with pytest.raises(ValueError, match="malformed YAML"):
        load_hyperparams("ppo", "QuadSLAM-EKF-v0", bad_yaml)
    with pytest.raises(ValueError, match="env: got 'NoSuchEnv-v0'"):
        train("ppo", "NoSuchEnv-v0", out_dir=tmp_path)
    assert not list(tmp_path.glob("ppo_*")), "no run folder for a rejected config"


def test_numeric_strings_and_linear_schedules_are_converted() -> None:
    entry = {"n_timesteps": "1e4", "learning_rate": "lin_1e-3", "n_steps": "2e2", "gamma": "0.98"}
    settings = resolve_settings("ppo", entry)
    kw = settings["algo_kwargs"]
    assert settings["n_timesteps"] == 10_000
    assert kw["n_steps"] == 200 and isinstance(kw["n_steps"], int)
    assert kw["gamma"] == pytest.approx(0.98)
    assert kw["learning_rate"](1.0) == pytest.approx(1e-3)
    assert kw["learning_rate"](0.5) == pytest.approx(5e-4)
    sac = resolve_settings("sac", {"n_timesteps": 10, "ent_coef": "auto", "buffer_size": 1e4})
    assert sac["algo_kwargs"] == {"ent_coef": "auto", "buffer_size": 10_000}
