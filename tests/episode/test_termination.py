"""How an episode ends (tilt, ground contact, position error) and what ``step`` and ``reset``
accept around it: no step after the end or before the first reset, seeds checked."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from quadslam_env.schema import ConfigError


def oracle(**kwargs: Any) -> gym.Env:
    """The Oracle env (the truth as the estimate) with 2 s episodes unless given."""
    return gym.make("QuadSLAM-Oracle-v0", **{"episode": {"duration_s": 2.0}, **kwargs})


def _first_step(env: gym.Env, action, options=None):
    env.reset(seed=0, options=options)
    return env.step(np.asarray(action, dtype=np.float32))


def test_terminates_on_tilt():
    env = oracle()
    x0 = np.zeros(12)
    x0[6] = math.radians(85.0)
    _, reward, term, trunc, info = _first_step(
        env, env.unwrapped.hover_action, {"initial_state": x0}
    )
    assert term and not trunc
    assert info["termination_reason"] == "tilt_limit"
    assert info["reward_termination"] < 0.0
    assert reward == pytest.approx(sum(v for k, v in info.items() if k.startswith("reward_")))
    assert "episode_est_pos_rmse_m" in info


def test_terminates_on_ground_contact():
    env = oracle(episode={"duration_s": 2.0, "ground_z_m": 0.0})
    _, _, term, _, info = _first_step(env, [-1.0, 0.0, 0.0, 0.0])  # zero thrust: falls
    assert term
    assert info["termination_reason"] == "ground_contact"
    assert env.unwrapped.true_state[2] > 0.0


def test_no_ground_contact_while_climbing():
    env = oracle(episode={"duration_s": 2.0, "ground_z_m": 0.0})
    _, _, term, _, info = _first_step(env, [1.0, 0.0, 0.0, 0.0])  # full thrust: climbs
    assert not term and info["termination_reason"] == ""


def test_terminates_on_position_error():
    # The default scenario starts at the origin, 2 m below the reference.
    env = oracle(episode={"duration_s": 2.0, "max_pos_err_m": 1.0})
    _, _, term, _, info = _first_step(env, env.unwrapped.hover_action)
    assert term
    assert info["termination_reason"] == "position_error_limit"
    assert info["track_pos_err_m"] > 1.0


@pytest.mark.parametrize("end", ["terminated", "truncated"])
def test_step_after_the_episode_ended_raises_until_reset(end):
    env = oracle(episode={"duration_s": 0.05})  # 5 steps
    hover = env.unwrapped.hover_action.astype(np.float32)
    x0 = np.zeros(12)
    x0[6] = math.radians(85.0)  # tilted beyond the limit: ends on the first step
    options = {"initial_state": x0} if end == "terminated" else None
    env.reset(seed=0, options=options)
    for _ in range(5):
        _, _, term, trunc, _ = env.step(hover)
        if term or trunc:
            break
    assert (term, trunc) == (end == "terminated", end == "truncated")
    state, steps = env.unwrapped.true_state, env.unwrapped.steps
    for stepped in (env, env.unwrapped):  # wrapped by gymnasium.make, and bare
        with pytest.raises(gym.error.ResetNeeded, match=r"episode ended.*call reset\(\)"):
            stepped.step(hover)
    np.testing.assert_array_equal(env.unwrapped.true_state, state)  # it did not move
    assert env.unwrapped.steps == steps
    env.reset()
    assert not any(env.step(hover)[2:4])


def test_step_before_the_first_reset_raises():
    env = oracle().unwrapped
    with pytest.raises(gym.error.ResetNeeded, match=r"no episode was started; call reset\(\)"):
        env.step(env.hover_action)


@pytest.mark.parametrize("seed", [1.5, "3", True, np.True_, -1, [3]])
def test_bad_seed_names_the_key_the_value_and_what_is_allowed(seed):
    env = oracle()
    with pytest.raises(ConfigError) as err:
        env.reset(seed=seed)
    assert str(err.value) == f"seed: got {seed!r}; allowed: None or an integer >= 0"


def test_numpy_integer_seed_equals_the_python_int():
    env = oracle()
    want, _ = env.reset(seed=7)
    for seed in (np.int64(7), np.uint16(7)):
        np.testing.assert_array_equal(env.reset(seed=seed)[0], want)
