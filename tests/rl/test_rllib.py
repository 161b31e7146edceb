"""RLlib's PPO (new API stack) trains on the env ids through ``gymnasium.make``, and its
multi-agent PPO on the team env with one module shared by the vehicles.

Needs the ``rllib`` extra (``ray[rllib]`` pins gymnasium 1.2.2, so CI runs this file in its
own venv: ``make test-rllib``); skipped without it.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

import pytest

pytest.importorskip("ray.rllib.algorithms.ppo", exc_type=ImportError)
import ray

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "rllib_ppo.py"


def _example() -> object:
    spec = importlib.util.spec_from_file_location("rllib_ppo_example", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


@pytest.mark.parametrize(
    ("env_id", "runners", "vectorize"),
    [
        # RLlib's default: gymnasium.make per env, in a remote env runner (a fresh process,
        # where only the "quadslam_env:" prefix of the id registers the envs).
        ("QuadSLAM-EKF-v0", 1, "sync"),
        # The native vector env as RLlib's vector env, sampled in this process.
        ("QuadSLAM-Oracle-v0", 0, "vector_entry_point"),
    ],
)
def test_ppo_one_iteration(local_ray, env_id, runners, vectorize):
    example: object = _example()
    config = example.build_config(  # type: ignore[attr-defined]
        env_id,
        {"episode": {"duration_s": 1.0}},
        env_runners=runners,
        envs_per_runner=2,
        vectorize=vectorize,
        rollout_length=100,
        minibatch_size=100,
        epochs=1,
        hidden=(16,),
    )
    algo = config.build_algo()
    try:
        result = algo.train()
    finally:
        algo.stop()
    assert result["training_iteration"] == 1
    runners_res = result["env_runners"]
    assert runners_res["num_env_steps_sampled_lifetime"] >= 200
    assert runners_res["num_episodes"] >= 1  # 1 s episodes: 100 steps at most
    assert runners_res["episode_len_mean"] <= 100
    learner = result["learners"]["default_policy"]
    assert all(v == v for v in (learner["total_loss"], learner["policy_loss"]))  # not NaN


def test_readme_rllib_block_trains_one_iteration(local_ray):
    text = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    section = text.split("## Other RL libraries", 1)[1]
    block = section.split("```python\n", 1)[1].split("```", 1)[0]
    scope: dict[str, object] = {}
    exec(compile(block, "README.md", "exec"), scope)  # the README's own code
    result = scope["result"]
    assert isinstance(result, dict)
    assert result["training_iteration"] == 1
    # 2 envs x 100-step fragments: 200 steps, and the 1 s episodes (100 steps) end within them.
    runners = result["env_runners"]
    assert runners["num_env_steps_sampled_lifetime"] >= 200
    assert runners["episode_len_mean"] <= 100


TEAM_EXAMPLE = EXAMPLE.with_name("team_rllib_ppo.py")


def _team_example() -> object:
    pytest.importorskip("pettingzoo")
    spec = importlib.util.spec_from_file_location("team_rllib_ppo_example", TEAM_EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def test_team_ppo_trains_the_shared_module_on_every_vehicle(local_ray):
    example: object = _team_example()
    env_config = {"n_vehicles": 2, "episode": {"duration_s": 0.5}}
    config = example.build_config(  # type: ignore[attr-defined]
        env_config, env_runners=0, rollout_length=100, minibatch_size=100, epochs=1, hidden=(16,)
    )
    algo = config.build_algo()
    try:
        result = algo.train()
        flown = example.fly_team(algo, env_config, seed=3)  # type: ignore[attr-defined]
    finally:
        algo.stop()
    assert result["training_iteration"] == 1
    vehicles = {"vehicle_0", "vehicle_1"}
    runners = result["env_runners"]
    # 100 env steps of 0.5 s (50-step) episodes: every vehicle sampled, at least one episode
    # ended, and every agent step went to the one module.
    per_agent = runners["num_agent_steps_sampled_lifetime"]
    assert set(per_agent) == vehicles and all(n > 0 for n in per_agent.values())
    assert runners["num_module_steps_sampled_lifetime"] == {"shared": sum(per_agent.values())}
    assert set(runners["agent_episode_returns_mean"]) == vehicles
    assert runners["num_episodes"] >= 1 and runners["episode_len_mean"] <= 50
    learners = result["learners"]
    assert set(learners) == {"shared", "__all_modules__"}  # one module learns for both
    assert learners["shared"]["num_module_steps_trained"] >= sum(per_agent.values())
    losses = (learners["shared"]["total_loss"], learners["shared"]["policy_loss"])
    assert all(v == v for v in losses)  # not NaN
    assert set(flown) == vehicles
    for info in flown.values():
        assert 1 <= info["episode_steps"] <= 50
        assert info["episode_track_pos_rmse_m"] == info["episode_track_pos_rmse_m"] > 0.0


def test_team_episode_ends_when_a_crash_and_the_time_limit_end_the_last_vehicles():
    from gymnasium import spaces
    from pettingzoo import ParallelEnv

    class TwoVehicles(ParallelEnv):
        """Two agents that both end on the first step: one terminated, one truncated."""

        def __init__(self, terms: dict[str, bool]) -> None:
            self.possible_agents = ["vehicle_0", "vehicle_1"]
            self.agents: list[str] = []
            self._terms = terms

        def observation_space(self, agent: str) -> spaces.Box:
            return spaces.Box(-1.0, 1.0, (2,))

        def action_space(self, agent: str) -> spaces.Box:
            return spaces.Box(-1.0, 1.0, (1,))

        def reset(self, seed=None, options=None):
            self.agents = list(self.possible_agents)
            return {a: [0.0, 0.0] for a in self.agents}, {a: {} for a in self.agents}

        def step(self, actions):
            live, self.agents = self.agents, []
            truncs = {a: not self._terms[a] for a in live}
            return ({a: [0.0, 0.0] for a in live}, {a: 0.0 for a in live}, dict(self._terms),
                    truncs, {a: {} for a in live})  # fmt: skip

    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    example: object = _team_example()
    wrapper = example.TeamMultiAgentEnv  # type: ignore[attr-defined]
    actions = {"vehicle_0": [0.0], "vehicle_1": [0.0]}
    one_each = {"vehicle_0": True, "vehicle_1": False}
    _, _, terms, truncs, _ = wrapper(TwoVehicles(one_each)).step(actions)
    assert (terms["__all__"], truncs["__all__"]) == (False, True)  # ended: no vehicle left
    # RLlib's own wrapper ends neither here (all(...) of each alone), so its next step would
    # find no vehicle.
    _, _, terms, truncs, _ = ParallelPettingZooEnv(TwoVehicles(one_each)).step(actions)
    assert (terms["__all__"], truncs["__all__"]) == (False, False)
    both = {"vehicle_0": True, "vehicle_1": True}
    _, _, terms, truncs, _ = wrapper(TwoVehicles(both)).step(actions)
    assert (terms["__all__"], truncs["__all__"]) == (True, False)
