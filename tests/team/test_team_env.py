"""The team env (quadslam_env.team): PettingZoo's parallel API, vehicle 0 against the single
env bit for bit, the other vehicles' own streams, references and starts, collisions and bad
input."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from quadslam_env.episode.actions import ActionError
from quadslam_env.estimation.memory import MemoryLimitError
from quadslam_env.schema import ConfigError

pytest.importorskip("pettingzoo")
from pettingzoo.test import parallel_api_test

from quadslam_env.team.config import TeamConfig
from quadslam_env.team.env import parallel_env

SHORT = {"duration_s": 2.0}
"""Short episodes: 200 steps at 100 Hz."""


def _actions(env: Any, rng: np.random.Generator, hover: np.ndarray) -> dict[str, np.ndarray]:
    """Hover plus small noise for every live agent (each its own draw, in agent order)."""
    return {
        agent: np.clip(hover + 0.02 * rng.standard_normal(hover.shape), -1, 1).astype(np.float32)
        for agent in env.agents
    }


def _rollout(env: Any, seed: int, steps: int) -> list[dict[str, np.ndarray]]:
    """Every agent's observations from a reset with ``seed`` over ``steps`` steps."""
    obs, _ = env.reset(seed=seed)
    hover = env.core.action_map.hover_action
    rng = np.random.default_rng(1)
    out = [obs]
    for _ in range(steps):
        obs, *_ = env.step(_actions(env, rng, hover))
        out.append(obs)
    return out


def test_parallel_api_test_passes() -> None:
    env = parallel_env(n_vehicles=3, episode={"duration_s": 1.0})
    # The API test resets with options={"options": 1}, a key the team env does not read.
    with pytest.warns(UserWarning, match=r"options \['options'\] are not read"):
        parallel_api_test(env, num_cycles=120)
    assert env.possible_agents == ["vehicle_0", "vehicle_1", "vehicle_2"]
    single = gym.make("QuadSLAM-v0")
    for agent in env.possible_agents:
        assert env.observation_space(agent) == single.observation_space
        assert env.action_space(agent) == single.action_space


@pytest.mark.parametrize("n", [1, 3])
def test_vehicle_0_is_the_single_env_bit_for_bit(n: int) -> None:
    """``vehicle_0`` of a team of n is ``gymnasium.make("QuadSLAM-v0")`` with the same seed:
    observations, rewards and the single env's info terms, every step to the episode's end."""
    env = parallel_env(n_vehicles=n, episode=SHORT)
    single = gym.make("QuadSLAM-v0", episode=SHORT)
    obs, infos = env.reset(seed=11)
    s_obs, s_info = single.reset(seed=11)
    np.testing.assert_array_equal(obs["vehicle_0"], s_obs)
    assert {k: infos["vehicle_0"][k] for k in s_info} == s_info
    np.testing.assert_array_equal(env.core.landmarks[0], single.unwrapped.landmarks)
    hover, rng, steps, done = single.unwrapped.hover_action, np.random.default_rng(3), 0, False
    while not done:
        actions = _actions(env, rng, hover)
        obs, rewards, terms, truncs, infos = env.step(actions)
        s_obs, s_reward, s_term, s_trunc, s_info = single.step(actions["vehicle_0"])
        np.testing.assert_array_equal(obs["vehicle_0"], s_obs, err_msg=f"step {steps}")
        assert rewards["vehicle_0"] == s_reward
        assert (terms["vehicle_0"], truncs["vehicle_0"]) == (s_term, s_trunc)
        assert {k: infos["vehicle_0"][k] for k in s_info} == s_info, f"step {steps}"
        done, steps = s_term or s_trunc, steps + 1
    assert steps == 200 and s_trunc
    assert "vehicle_0" not in env.agents


def test_other_vehicles_draw_their_own_streams_and_repeat_with_the_seed() -> None:
    env = parallel_env(n_vehicles=3, episode=SHORT)
    first = _rollout(env, seed=5, steps=30)
    again = _rollout(parallel_env(n_vehicles=3, episode=SHORT), seed=5, steps=30)
    for step, (a, b) in enumerate(zip(first, again, strict=True)):
        for agent in a:
            np.testing.assert_array_equal(a[agent], b[agent], err_msg=f"{agent} step {step}")
    for step in (0, 30):
        obs = first[step]
        assert not np.array_equal(obs["vehicle_1"], obs["vehicle_0"])
        assert not np.array_equal(obs["vehicle_2"], obs["vehicle_1"])
    other = _rollout(env, seed=6, steps=0)[0]
    assert not np.array_equal(other["vehicle_1"], first[0]["vehicle_1"])


def test_same_reference_and_start_still_differ_by_stream() -> None:
    """With no offsets the vehicles fly the same reference from the same start: only their
    streams (initial error, IMU and LiDAR noise) differ, and they share the landmark field."""
    team = {"time_offsets_s": [0.0, 0.0], "position_offsets_m": [[0, 0, 0], [0, 0, 0]]}
    env = parallel_env(n_vehicles=2, team=team, episode=SHORT)
    obs, _ = env.reset(seed=2)
    core = env.core
    np.testing.assert_array_equal(core.landmarks[1], core.landmarks[0])
    np.testing.assert_array_equal(core.vehicle.state[1], core.vehicle.state[0])
    assert not np.array_equal(obs["vehicle_1"], obs["vehicle_0"])


def test_references_and_starts_are_shifted_per_vehicle() -> None:
    """Vehicle i flies ρ_d(t + τ_i) + p_i, and starts where vehicle 0 does relative to its own
    reference (2 m below the figure-8's first point in the default scenario)."""
    offsets = [[0.0, 0.0, 0.0], [1.0, -2.0, 0.5], [0.0, 3.0, 0.0]]
    env = parallel_env(n_vehicles=3, team={"position_offsets_m": offsets}, episode=SHORT)
    env.reset(seed=0)
    core, period = env.core, env.scenario.trajectory.period_s
    tau = np.arange(3) * period / 3
    for _ in range(7):
        env.step({agent: core.action_map.hover_action for agent in env.agents})
    ref = core.reference()
    for i in range(3):
        want = core.trajectory(float(core.t[i]) + tau[i]).pos + np.array(offsets[i])
        np.testing.assert_allclose(ref.pos[i], want, rtol=0, atol=1e-12)
    env.reset(seed=0)
    start = env.core.vehicle.state[:, :3]
    first = np.array([core.trajectory(tau[i]).pos + offsets[i] for i in range(3)])
    np.testing.assert_allclose(start - first, np.tile(start[0] - first[0], (3, 1)), atol=1e-12)


def _trio(radius: float) -> Any:
    """Three vehicles on one reference: vehicle 1 placed 0.1 m north of vehicle 0, vehicle 2
    5 m east."""
    team = {
        "time_offsets_s": [0.0, 0.0, 0.0],
        "position_offsets_m": [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 5.0, 0.0]],
        "collision_radius_m": radius,
    }
    return parallel_env(n_vehicles=3, team=team, episode=SHORT)


def test_two_vehicles_within_the_radius_collide_on_the_first_step() -> None:
    env = _trio(0.5)
    _, infos = env.reset(seed=0)
    assert infos["vehicle_0"]["team_min_separation_m"] == pytest.approx(0.1, abs=1e-12)
    hover = env.core.action_map.hover_action
    _, rewards, terms, truncs, infos = env.step({a: hover for a in env.agents})
    assert terms == {"vehicle_0": True, "vehicle_1": True, "vehicle_2": False}
    assert not any(truncs.values())
    assert infos["vehicle_0"]["termination_reason"] == "vehicle_collision: vehicle_1"
    assert infos["vehicle_1"]["termination_reason"] == "vehicle_collision: vehicle_0"
    penalty = env.scenario.reward.termination_penalty
    for agent in ("vehicle_0", "vehicle_1"):
        info = infos[agent]
        assert info["reward_termination"] == -penalty
        assert rewards[agent] == pytest.approx(
            sum(v for k, v in info.items() if k[:7] == "reward_")
        )
        assert "episode_est_pos_rmse_m" in info  # the core's summaries of an ended episode
    assert "episode_est_pos_rmse_m" not in infos["vehicle_2"]
    assert env.agents == ["vehicle_2"]
    with pytest.raises(ActionError, match=r"actions\['vehicle_0'\]: 'vehicle_0' is done"):
        env.step({"vehicle_0": hover, "vehicle_2": hover})
    obs, _, terms, _, infos = env.step({"vehicle_2": hover})
    assert list(obs) == ["vehicle_2"] and not terms["vehicle_2"]
    assert "team_min_separation_m" not in infos["vehicle_2"]  # one vehicle left
    assert env.core.steps.tolist() == [1, 1, 2]  # the ended vehicles' lanes are not stepped


def test_vehicles_outside_the_radius_fly_on() -> None:
    """The same vehicles with a radius below their 0.1 m: the same hover action moves every
    vehicle alike (no wind), so the closest two stay 0.1 m apart and none ends."""
    env = _trio(0.05)
    env.reset(seed=0)
    hover = env.core.action_map.hover_action
    for _ in range(20):
        _, _, terms, _, infos = env.step({a: hover for a in env.agents})
        assert not any(terms.values())
    assert infos["vehicle_1"]["team_min_separation_m"] == pytest.approx(0.1, abs=1e-9)
    assert "termination_reason" in infos["vehicle_1"]
    assert infos["vehicle_1"]["termination_reason"] == ""


def test_team_position_rmse_is_over_the_vehicles_and_the_episode() -> None:
    env = parallel_env(n_vehicles=3, episode={"duration_s": 0.3})
    env.reset(seed=4)
    hover, errors = env.core.action_map.hover_action, []
    while env.agents:
        _, _, _, _, infos = env.step({a: hover for a in env.agents})
        err = np.array([infos[a]["est_pos_err_m"] for a in env.possible_agents])
        errors.append(err)
        want = math.sqrt(float(np.mean(err**2)))
        assert infos["vehicle_2"]["team_est_pos_rmse_m"] == pytest.approx(want, rel=1e-12)
    total = math.sqrt(float(np.mean(np.square(errors))))
    assert infos["vehicle_0"]["team_episode_est_pos_rmse_m"] == pytest.approx(total, rel=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        ({"n_vehicles": 0}, "n_vehicles: got 0; allowed: an integer >= 1"),
        ({"n_vehicles": True}, "n_vehicles: got True"),
        ({"n_vehicles": 2.0}, "n_vehicles: got 2.0"),
        (
            {"team": {"fusion": "pooled"}},
            "team.fusion: got 'pooled'; allowed: one of ['independent'",
        ),
        ({"team": {"links": True}}, "team.links: unknown key"),
        ({"team": {"time_offsets_s": [0.0, 1.0]}}, "team.time_offsets_s: got 2 entries"),
        ({"team": {"time_offsets_s": [1.0, 2.0, 3.0]}}, "team.time_offsets_s[0]: got 1.0"),
        (
            {"team": {"position_offsets_m": [[0, 0, 1], [0, 0, 0], [0, 0, 0]]}},
            "team.position_offsets_m[0]: got [0.0, 0.0, 1.0]; allowed: [0, 0, 0]",
        ),
        ({"team": {"collision_radius_m": -1.0}}, "team.collision_radius_m: got -1.0"),
        ({"faults": {"kind": "landmark_moves"}}, "faults.kind: got 'landmark_moves'"),
        ({"render_mode": "rgb_array"}, "render_mode: got 'rgb_array'; allowed: None"),
    ],
)
def test_bad_settings_name_the_key_the_value_and_what_is_allowed(
    kwargs: dict[str, Any], fragment: str
) -> None:
    with pytest.raises(ConfigError) as err:
        parallel_env(**kwargs)
    assert fragment in str(err.value)


def test_too_many_vehicles_are_refused_before_anything_is_allocated() -> None:
    with pytest.raises(MemoryLimitError, match="lane"):
        parallel_env(n_vehicles=10**9)


def test_team_settings_are_documented() -> None:
    page = (Path(__file__).resolve().parents[2] / "docs" / "team.md").read_text()
    for name in TeamConfig.defaults():
        assert f"`team.{name}`" in page, name


@pytest.mark.parametrize(
    ("actions", "fragment"),
    [
        ([np.zeros(4)] * 2, "actions: got list; allowed: a dict with one action per live agent"),
        ({"vehicle_0": np.zeros(4)}, "actions: no action for ['vehicle_1']"),
        ({"vehicle_0": np.zeros(4), "vehicle_1": np.zeros(3)}, "actions['vehicle_1']: got shape"),
        (
            {"vehicle_0": np.zeros(4), "vehicle_1": [math.nan] * 4},
            "actions['vehicle_1']: got non-finite values",
        ),
        (
            {"vehicle_0": np.zeros(4), "vehicle_1": np.zeros(4), "vehicle_9": np.zeros(4)},
            "actions['vehicle_9']: 'vehicle_9' is not an agent of this env",
        ),
    ],
)
def test_bad_actions_name_the_agent_and_change_nothing(actions: Any, fragment: str) -> None:
    env = parallel_env(n_vehicles=2, episode=SHORT)
    env.reset(seed=0)
    before = env.core.vehicle.state.copy()
    with pytest.raises(ActionError) as err:
        env.step(actions)
    assert fragment in str(err.value)
    np.testing.assert_array_equal(env.core.vehicle.state, before)
    assert env.core.steps.tolist() == [0, 0]


def test_bad_agents_seeds_and_options() -> None:
    env = parallel_env(n_vehicles=2, episode=SHORT)
    with pytest.raises(ConfigError, match=r"agent: got 'vehicle_2'; allowed: one of"):
        env.observation_space("vehicle_2")
    with pytest.raises(ConfigError, match="seed: got -1"):
        env.reset(seed=-1)
    with pytest.raises(ConfigError, match=r"reset options\.initial_state: not taken"):
        env.reset(options={"initial_state": np.zeros(12)})
    with pytest.raises(ConfigError, match="reset options: got 3"):
        env.reset(options=3)  # type: ignore[arg-type]
    with pytest.raises(gym.error.ResetNeeded, match="no live agent"):
        env.step({})


def test_without_pettingzoo_the_import_names_the_extra(monkeypatch: pytest.MonkeyPatch) -> None:
    import importlib
    import sys

    from quadslam_env.extras import MissingExtraError

    for name in [m for m in sys.modules if m.startswith("quadslam_env.team")]:
        monkeypatch.delitem(sys.modules, name)
    monkeypatch.setitem(sys.modules, "pettingzoo", None)  # an import of it fails
    with pytest.raises(MissingExtraError, match=r"pip install 'quadslam\[team\]'"):
        importlib.import_module("quadslam_env.team")
