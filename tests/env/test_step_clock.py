"""``steps_per_s`` of ``quadslam run``/``evaluate`` leaves out the warm-up: the first step and
the steps in which numba compiled or loaded a kernel (read from a fake clock, no timing)."""

from __future__ import annotations

import time
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from numba.core.compiler_lock import global_compiler_lock

import quadslam_env  # noqa: F401  (registers the ids)
from agents.evaluation.episodes import run_episode, run_episodes
from agents.evaluation.step_clock import StepClock

STEP_S = 0.002
"""The fake seconds of every step after the first."""
FIRST_S = 100.0
"""The fake seconds of the first step (a cold cache's compilation)."""


class FakeClock:
    """``time.perf_counter`` that only moves when told."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(time, "perf_counter", fake)
    return fake


class SlowFirstPolicy:
    """Hover (zero action) for every lane; its first call takes :data:`FIRST_S`, each later
    one :data:`STEP_S` of the fake clock."""

    def __init__(self, clock: FakeClock) -> None:
        self.clock, self.calls = clock, 0

    def predict(self, obs: Any, **kwargs: Any) -> tuple[np.ndarray, None]:
        self.clock.now += FIRST_S if self.calls == 0 else STEP_S
        self.calls += 1
        obs = np.asarray(obs)
        shape = (obs.shape[0], 4) if obs.ndim == 2 else (4,)
        return np.zeros(shape, dtype=np.float32), None


def test_clock_leaves_out_the_first_step(clock: FakeClock) -> None:
    steps = StepClock()
    for seconds in (FIRST_S, STEP_S, STEP_S, STEP_S):
        steps.start()
        clock.now += seconds
        steps.stop()
    assert steps.left_out == 1 and steps.steps == 3
    assert steps.rate == pytest.approx(1 / STEP_S)


def test_clock_leaves_out_a_step_that_took_the_compiler_lock(clock: FakeClock) -> None:
    steps = StepClock()
    for i in range(5):
        steps.start()
        if i == 2:  # what compiling or loading a kernel does
            with global_compiler_lock:
                clock.now += 50.0
        else:
            clock.now += STEP_S
        steps.stop()
    assert steps.left_out == 2 and steps.steps == 3
    assert steps.rate == pytest.approx(1 / STEP_S)


def test_clock_without_a_counted_step_has_no_rate(clock: FakeClock) -> None:
    steps = StepClock()
    steps.start()
    clock.now += FIRST_S
    steps.stop()
    assert np.isnan(steps.rate)


@pytest.fixture
def env() -> Any:
    env = gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 0.2})
    yield env
    env.close()


def test_run_episodes_rate_excludes_the_first_step(env: Any, clock: FakeClock) -> None:
    records = run_episodes(env, SlowFirstPolicy(clock), [0, 1])  # lanes of the vector env
    for record in records:
        assert record["steps_per_s"] == pytest.approx(1 / STEP_S)


def test_run_episode_rate_excludes_the_first_step(env: Any, clock: FakeClock) -> None:
    record = run_episode(env, SlowFirstPolicy(clock), 0)  # the scalar env
    assert record["steps_per_s"] == pytest.approx(1 / STEP_S)
