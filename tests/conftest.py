"""Fixtures and helpers shared by the test modules (helpers imported as ``from conftest import
...``)."""

from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from agents.control.dflqr import DFLQRPolicy


def fly_dflqr(
    env: gym.Env, seed: int, steps: int | None = None
) -> tuple[list[dict[str, Any]], bool]:
    """DF-LQR on the env's observation from ``reset(seed=seed)``, until the episode ends or
    after ``steps`` steps; every observation and reward must be finite.

    Returns:
        The per-step ``info`` dicts and whether the episode terminated (not truncated).
    """
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed)
    infos: list[dict[str, Any]] = []
    terminated = truncated = False
    while not (terminated or truncated) and (steps is None or len(infos) < steps):
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        assert np.isfinite(obs).all() and np.isfinite(reward)
        infos.append(info)
    return infos, bool(terminated)


@pytest.fixture
def temp_root(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """The temporary folder (a failed write's last fallback) inside the test's folder."""
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root
