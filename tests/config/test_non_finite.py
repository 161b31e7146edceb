"""Settings and reset options that used to overflow or divide by ~0 are refused in one line, and
the last line of defence (``termination.OutputGuard``) ends a lane whose outputs are not finite
with a finite observation and reward, in the scalar env and in every lane of the vector env
(docs/design.md §7, docs/env.md "Termination and truncation")."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.reference import estimator_settings
from quadslam_env.config.scenario import load_scenario
from quadslam_env.core import SimCore
from quadslam_env.schema import ConfigError
from quadslam_env.vector_env import QuadSLAMVectorEnv

ORACLE = "QuadSLAM-Oracle-v0"
SHORT = {"episode": {"duration_s": 0.3}}
PENALTY = 100.0  # reward.termination_penalty's default


# ============================================================================ the last defence
def _inject(core: SimCore, key: str, value: float, lanes: np.ndarray, step: int) -> None:
    """From now on ``core``'s step term ``key`` is ``value`` in ``lanes`` (B,) bool at ``step``."""
    metrics = core._metrics

    def patched(est: Any, ref: Any) -> tuple[np.ndarray, dict[str, Any]]:
        values, info = metrics(est, ref)
        info[key][lanes & (core.steps == step)] = value  # a row of ``values``
        return values, info

    core._metrics = patched  # type: ignore[method-assign]


def _reward_terms(info: dict[str, Any]) -> dict[str, float]:
    return {k: v for k, v in info.items() if k.startswith("reward_")}


def _run(env: gym.Env, steps: int) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
    env.reset(seed=3)
    for _ in range(steps):
        out = env.step(env.unwrapped.hover_action)
        if out[2] or out[3]:
            return out
    raise AssertionError("the episode did not end")


def test_an_infinite_info_term_ends_the_episode_with_the_penalty() -> None:
    env = gym.make(ORACLE, **SHORT)
    _inject(env.unwrapped.core, "est_pos_err_m", math.inf, np.ones(1, bool), 4)
    obs, reward, terminated, truncated, info = _run(env, 10)
    assert terminated and not truncated and env.unwrapped.steps == 4
    assert info["termination_reason"] == "non_finite_output: est_pos_err_m"
    assert np.isfinite(obs).all() and env.observation_space.contains(obs)
    terms = _reward_terms(info)
    assert reward == -PENALTY == terms["reward_termination"]
    assert sum(terms.values()) == reward  # the terms still sum to the reward
    assert info["episode_steps"] == 4  # the episode's summaries come with its end
    with pytest.raises(gym.error.ResetNeeded):  # the episode is over
        env.step(env.unwrapped.hover_action)


def test_a_nan_reward_ends_the_episode(monkeypatch: pytest.MonkeyPatch) -> None:
    env = gym.make(ORACLE, **SHORT)
    reward = env.unwrapped.core.reward
    terms = reward.terms

    def nan_at_step_2(*args: Any) -> np.ndarray:
        out = terms(*args)
        if env.unwrapped.steps == 2:
            out[1] = out[-1] = math.nan  # reward_pos and the reward, their sum
        return out

    monkeypatch.setattr(reward, "terms", nan_at_step_2)
    _, r, terminated, _, info = _run(env, 10)
    assert terminated and info["termination_reason"] == "non_finite_output: reward"
    assert r == -PENALTY and info["reward_pos"] == 0.0


def test_a_nan_observation_ends_the_episode_with_those_entries_zero(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    env = gym.make(ORACLE, **SHORT)
    observer = env.unwrapped.core.observer
    build = observer.build

    def nan_at_step_3(*args: Any) -> np.ndarray:
        obs = build(*args)
        if env.unwrapped.steps == 3:
            obs[:, 0] = math.nan
        return obs

    monkeypatch.setattr(observer, "build", nan_at_step_3)
    obs, r, terminated, _, info = _run(env, 10)
    assert terminated and info["termination_reason"] == "non_finite_output: observation"
    assert obs[0] == 0.0 and np.isfinite(obs).all() and r == -PENALTY


def test_a_non_finite_true_state_keeps_its_reason_and_gets_the_penalty() -> None:
    """A NaN state makes every tracking term NaN: the reason is the state's, the reward finite."""
    env = gym.make(ORACLE, **SHORT)
    env.reset(seed=0)
    env.unwrapped.core.vehicle.state[0, 3] = math.nan
    obs, reward, terminated, _, info = env.step(env.unwrapped.hover_action)
    assert terminated and info["termination_reason"] == "vehicle_state_non_finite"
    assert reward == -PENALTY and np.isfinite(obs).all()


def test_an_earlier_reason_and_its_finite_reward_stand() -> None:
    """An infinite pose NEES is the NEES check's divergence; the guard leaves its reward."""
    env = gym.make(ORACLE, **SHORT)
    _inject(env.unwrapped.core, "est_nees_pose", math.inf, np.ones(1, bool), 2)
    _, reward, terminated, _, info = _run(env, 10)
    reason = "estimator_diverged: pose covariance not positive semi-definite"
    assert terminated and info["termination_reason"] == reason
    terms = _reward_terms(info)
    assert terms["reward_alive"] == 1.0 and terms["reward_pos"] < 0.0  # computed, not zeroed
    assert reward == pytest.approx(sum(terms.values()))


def _vector_and_scalars(
    b: int, patch: Callable[[SimCore, np.ndarray], None], seed: int, steps: int
) -> None:
    """Lane i of a vector env with ``patch`` equals the scalar env seeded ``seed + i`` with the
    same patch on its one lane, step by step through the lane's end and its reset."""
    vec = QuadSLAMVectorEnv(b, estimator_name="oracle", **SHORT)
    patch(vec.core, np.arange(b) == 1)
    hover = np.tile(vec.hover_action, (b, 1)).astype(np.float32)
    v_obs, _ = vec.reset(seed=seed)
    scalars = []
    for lane in range(b):
        env = gym.make(ORACLE, **SHORT)
        patch(env.unwrapped.core, np.full(1, lane == 1))
        scalars.append([env, *env.reset(seed=seed + lane), False])
    ended_lane1 = False
    for _ in range(steps):
        v_obs, v_rew, v_term, v_trunc, v_info = vec.step(hover)
        for lane, entry in enumerate(scalars):
            env, _, _, done = entry
            if done:  # NEXT_STEP: the vector env resets the lane on this step
                s_obs, _ = env.reset()
                s_rew, s_term, s_trunc, reason = 0.0, False, False, ""
            else:
                s_obs, s_rew, s_term, s_trunc, info = env.step(hover[lane])
                reason = info["termination_reason"]
            np.testing.assert_array_equal(v_obs[lane], s_obs)
            assert (v_rew[lane], v_term[lane], v_trunc[lane]) == (s_rew, s_term, s_trunc)
            got = v_info["termination_reason"][lane] if "termination_reason" in v_info else ""
            assert got == reason
            ended_lane1 |= lane == 1 and reason.startswith("non_finite_output")
            entry[1:] = [s_obs, None, s_term or s_trunc]
    assert ended_lane1


def test_a_vector_lane_ended_by_the_guard_equals_the_scalar_env() -> None:
    _vector_and_scalars(3, lambda core, lanes: _inject(core, "t", -math.inf, lanes, 5), 11, 12)


# ============================================================================ refused settings
@pytest.mark.parametrize(
    ("overrides", "key", "value"),
    [
        # Dryden turbulence passing at ~0 m/s: its time scales L/V overflow.
        (
            {
                "wind": {"turbulence": "dryden", "airspeed_mps": 1e-110},
                "vehicle": {"drag_per_s": 0.3},
            },
            "wind.airspeed_mps",
            "1e-110",
        ),
        (
            {
                "wind": {"turbulence": "dryden", "steady_mps": [1e-110, 0.0, 0.0]},
                "vehicle": {"drag_per_s": 0.3},
            },
            "wind.airspeed_mps",
            "1e-110",
        ),
        # Every value in range, but the quadratic drag in a 173 m/s wind relaxes at 3474 /s,
        # which a 2 ms RK4 substep cannot follow.
        (
            {
                "wind": {"steady_mps": [100.0, 100.0, 100.0]},
                "vehicle": {"drag_per_s": 10.0, "drag_quadratic_per_m": [10.0, 10.0, 10.0]},
            },
            "vehicle.drag_quadratic_per_m",
            "[10.0, 10.0, 10.0]",
        ),
        ({"vehicle": {"mass_kg": 1e-300}}, "vehicle.mass_kg", "1e-300"),
        ({"vehicle": {"max_torque_nm": [1e300, 1.0, 1.0]}}, "vehicle.max_torque_nm[0]", "1e+300"),
        ({"vehicle": {"inertia_diag": [1e-300, 0.1, 0.1]}}, "vehicle.inertia_diag[0]", "1e-300"),
        (
            {"vehicle": {"preset": "crazyflie2", "rotor_omega_max_rad_s": 1e200}},
            "vehicle.rotor_omega_max_rad_s",
            "1e+200",
        ),
        ({"randomize": {"mass_scale": [1e-300, 1.0]}}, "randomize.mass_scale", "1e-300"),
        ({"randomize": {"inertia_scale": [1e-300, 1.0]}}, "randomize.inertia_scale", "1e-300"),
        ({"episode": {"nees_window_s": 1e300}}, "episode.nees_window_s", "1e+300"),
        ({"reward": {"pos_weight": 1e308}}, "reward.pos_weight", "1e+308"),
        (
            {"landmarks": {"layout": "explicit", "positions": [[1e300, 0.0, 0.0]]}},
            "landmarks.positions[0][0]",
            "1e+300",
        ),
    ],
)
def test_settings_that_would_overflow_are_refused_naming_key_value_and_range(
    overrides: dict[str, Any], key: str, value: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario("paper_ekf_figure8", overrides)
    message = str(err.value)
    assert message.startswith(f"{key}: got ") and value in message and "allowed: " in message
    assert "\n" not in message


@pytest.mark.parametrize(
    ("name", "key"),
    [
        ("isam2", "integration_sigma"),
        ("ekf_slam", "accel_bias_walk"),
        ("ekf_slam", "gyro_bias_sigma0"),
        ("isam2", "accel_bias_walk"),
        ("fastslam", "accel_drift_sigma"),
        ("fastslam", "gyro_bias_sigma"),
    ],
)
def test_estimator_sigmas_that_would_overflow_are_refused(name: str, key: str) -> None:
    # Each is squared into a covariance: 1e300² is beyond the floating-point range.
    assert not math.isfinite(1e300 * 1e300)
    with pytest.raises(ConfigError) as err:
        estimator_settings()[name].from_dict({key: 1e300})
    message = str(err.value)
    assert message.startswith(f"estimator.params.{key}: got 1e+300; allowed: ")


@pytest.mark.parametrize(
    ("options", "key"),
    [
        ({"initial_state": [0.0, 0.0, -1e300] + [0.0] * 9}, "initial_state[2]"),
        ({"initial_state": [0.0] * 3 + [1e300] + [0.0] * 8}, "initial_state[3]"),
        ({"initial_state": [0.0] * 6 + [1e300] + [0.0] * 5}, "initial_state[6]"),
        ({"initial_state": [0.0] * 8 + [-7.0] + [0.0] * 3}, "initial_state[8]"),
        ({"initial_state": [0.0] * 9 + [1e300, 0.0, 0.0]}, "initial_state[9]"),
        ({"initial_state": [0.0] * 11 + [1e3]}, "initial_state[11]"),
        ({"landmarks": [[0.0, 0.0, 1e300]]}, "landmarks"),
        ({"randomized": {"mass_scale": 1e-300}}, "randomized.mass_scale"),
        ({"randomized": {"inertia_scale": 1e-300}}, "randomized.inertia_scale"),
    ],
)
def test_reset_options_out_of_range_are_refused_and_change_nothing(
    options: dict[str, Any], key: str
) -> None:
    env = gym.make(ORACLE, randomize={"mass_scale": [0.9, 1.1]}, **SHORT)
    env.reset(seed=0)
    state = env.unwrapped.true_state
    with pytest.raises(ConfigError) as err:
        env.reset(seed=1, options=options)
    message = str(err.value)
    assert message.startswith(f"reset options.{key}") and "allowed: " in message
    np.testing.assert_array_equal(env.unwrapped.true_state, state)


def test_the_bounds_admit_the_states_a_flight_reaches() -> None:
    """Any state the vehicle flies through (roll and yaw wrapped to ±π) is a valid start."""
    env = gym.make(ORACLE, **SHORT)
    env.reset(seed=0)
    for _ in range(10):
        env.step(env.unwrapped.hover_action)
    x0 = env.unwrapped.true_state
    x0[8] = math.pi  # the wrap's edge
    env.reset(seed=0, options={"initial_state": x0})
    np.testing.assert_array_equal(env.unwrapped.true_state, x0)
