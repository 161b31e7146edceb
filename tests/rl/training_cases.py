"""What the training tests share (tests/rl/test_training.py, test_agent_configs.py, test_resume.py):
tiny settings that exercise every part in about a second, the env they train on, the shipped
config entries, and one torch thread per test module."""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
import yaml

import quadslam_env  # noqa: F401  (registers the ids)
from agents.rl.hyperparams import default_config_path

ALGOS = ("ppo", "sac")
SHORT = {"episode": {"duration_s": 1.0}}
# Tiny networks, short episodes, frequent eval/checkpoints: exercises every part in ~1 s.
TINY: dict[str, dict[str, Any]] = {
    "ppo": {"n_steps": 64, "batch_size": 32, "n_epochs": 2},
    "sac": {"learning_starts": 32, "batch_size": 32, "buffer_size": 2000},
}
TINY_COMMON = {
    "policy_kwargs": {"net_arch": [8]},
    "env_kwargs": SHORT,
    "eval_freq": 128,
    "n_eval_episodes": 1,
    "checkpoint_freq": 128,
}
REQUIRED_KEYS = ("n_envs", "n_timesteps", "policy", "policy_kwargs", "env_kwargs", "wrapper")


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread() -> Any:
    """Tiny networks gain nothing from threads, and on a busy machine torch's spinning OpenMP
    threads can make SAC updates 5x slower; one thread keeps the test time predictable."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@functools.cache
def env_problem(env_id: str, scenario: str | None = None) -> str | None:
    """``None`` if the env builds and steps, else why not (e.g. an estimator still missing)."""
    kwargs: dict[str, Any] = {"episode": {"duration_s": 0.2}}
    if scenario is not None:
        kwargs["scenario"] = scenario
    try:
        env = gym.make(env_id, **kwargs)
        env.reset(seed=0)
        env.step(env.unwrapped.hover_action)
        env.close()
    except Exception as exc:  # any failure means "not available yet"
        return f"{env_id} unavailable: {type(exc).__name__}: {exc}"
    return None


def main_env() -> str:
    """The EKF env if EKF-SLAM works, else the oracle env."""
    return "QuadSLAM-EKF-v0" if env_problem("QuadSLAM-EKF-v0") is None else "QuadSLAM-Oracle-v0"


def tiny(algo: str, **extra: Any) -> dict[str, Any]:
    return {**TINY_COMMON, **TINY[algo], **extra}


def config_entries() -> list[Any]:
    params = []
    for algo in ALGOS:
        data = yaml.safe_load(default_config_path(algo).read_text())
        for env_id in data:
            params.append(pytest.param(algo, env_id, id=f"{algo}-{env_id}"))
    return params


def skip_unless_available(env_id: str, env_kwargs: dict[str, Any]) -> None:
    problem = env_problem(env_id, env_kwargs.get("scenario"))
    if problem is not None:
        pytest.skip(problem)


def read_monitor(run_dir: Path) -> list[list[str]]:
    lines = (run_dir / "monitor" / "lanes.monitor.csv").read_text().splitlines()[2:]
    return [line.split(",")[:2] for line in lines]  # return, length (not wall time)
