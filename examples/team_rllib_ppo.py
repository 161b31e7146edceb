"""RLlib's multi-agent PPO (new API stack) on the team env, one policy shared by every vehicle.

The team env (``quadslam_env.team.parallel_env``, a PettingZoo ``ParallelEnv``) is wrapped in
RLlib's ``ParallelPettingZooEnv``, a ``MultiAgentEnv``, and registered as ``quadslam_team``;
``env_config`` holds the ``parallel_env`` arguments (``n_vehicles``, ``scenario``, ``team``,
section overrides). Every vehicle maps to one RLModule, ``"shared"`` (``policy_mapping_fn``), so
the policy learns from all the vehicles' samples (parameter sharing). The vehicles end their
episodes one by one (a crash leaves ``env.agents`` while the others fly on), which RLlib's
multi-agent episodes follow agent by agent.

RLlib's wrapper (ray 2.60) sets ``__all__`` to ``all(...)`` of the step's terminations and,
apart, of its truncations, so a step on which the last vehicles end, one crashing and another
reaching the time limit, ends neither, and the next step finds no vehicle.
:class:`TeamMultiAgentEnv` ends the episode when no vehicle is left.

This trains PPO from scratch on thrust and torques: a demonstration of the integration, not a
recipe. After training, one team episode is flown with the shared module's deterministic
actions and each vehicle's tracking RMSE printed. Run it::

    pip install "quadslam[rllib]"
    python examples/team_rllib_ppo.py --iterations 5 --vehicles 3 --env-runners 1
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import Any

# The filters' small matrices: one BLAS thread (set before NumPy loads its BLAS).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np
from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv
from ray.tune.registry import register_env

from quadslam_env.team import TeamParallelEnv, parallel_env

ENV_NAME = "quadslam_team"
SHARED = "shared"


class TeamMultiAgentEnv(ParallelPettingZooEnv):
    """RLlib's PettingZoo wrapper whose episode ends when no vehicle is left (module docstring).

    Args:
        env: The team env.
    """

    def __init__(self, env: TeamParallelEnv) -> None:
        super().__init__(env)
        self.observation_spaces = {a: env.observation_space(a) for a in env.possible_agents}
        self.action_spaces = {a: env.action_space(a) for a in env.possible_agents}

    def step(self, action_dict: dict[str, Any]) -> tuple[dict[str, Any], ...]:
        """Step the live vehicles; ``__all__`` once every vehicle has ended."""
        obs, rewards, terms, truncs, infos = self.par_env.step(action_dict)
        ended = not self.par_env.agents
        all_terminated = ended and all(terms.values())
        terms["__all__"] = all_terminated
        truncs["__all__"] = ended and not all_terminated
        self.agents = list(self.par_env.agents)
        return obs, rewards, terms, truncs, infos


def make_team_env(env_config: dict[str, Any]) -> TeamMultiAgentEnv:
    """The env creator registered as :data:`ENV_NAME`: ``parallel_env(**env_config)``."""
    return TeamMultiAgentEnv(parallel_env(**dict(env_config)))


def policy_mapping_fn(agent_id: str, episode: Any, **kwargs: Any) -> str:
    """Every vehicle acts with the shared module."""
    return SHARED


def build_config(
    env_config: dict[str, Any] | None = None,
    *,
    env_runners: int = 0,
    rollout_length: int = 128,
    minibatch_size: int = 128,
    epochs: int = 4,
    hidden: Sequence[int] = (64, 64),
    seed: int = 0,
) -> Any:
    """A multi-agent ``PPOConfig`` of the team env, one module ``"shared"`` for every vehicle.

    Args:
        env_config: ``parallel_env`` keyword arguments, e.g. ``{"n_vehicles": 3, "episode":
            {"duration_s": 10.0}}``.
        env_runners: Remote env runners (0: sample in this process), one team env each.
        rollout_length: Env steps per sample (each of them one step of every live vehicle).
        minibatch_size: SGD minibatch in agent steps.
        epochs: Passes over each train batch.
        hidden: Hidden layer sizes of the policy and value networks.
        seed: Seeds RLlib (networks, env runners' env seeds).

    Returns:
        The config; ``config.build_algo()`` makes the algorithm.
    """
    from ray.rllib.algorithms.ppo import PPOConfig

    register_env(ENV_NAME, make_team_env)
    batch = rollout_length * max(env_runners, 1)
    return (
        PPOConfig()
        .environment(ENV_NAME, env_config=dict(env_config or {}))
        .env_runners(num_env_runners=env_runners, rollout_fragment_length=rollout_length)
        .multi_agent(policies={SHARED}, policy_mapping_fn=policy_mapping_fn)
        .training(
            train_batch_size_per_learner=batch,
            minibatch_size=min(minibatch_size, batch),
            num_epochs=epochs,
        )
        .rl_module(model_config={"fcnet_hiddens": list(hidden)})
        .debugging(seed=seed)
    )


def fly_team(algo: Any, env_config: dict[str, Any], seed: int) -> dict[str, dict[str, Any]]:
    """One team episode with the shared module's deterministic actions; each vehicle's last
    ``info``."""
    import torch

    module = algo.get_module(SHARED)
    dist_cls = module.get_inference_action_dist_cls()
    env = parallel_env(**dict(env_config))
    obs, _ = env.reset(seed=seed)
    last: dict[str, dict[str, Any]] = {}
    while env.agents:
        live = list(env.agents)
        batch = torch.from_numpy(np.stack([obs[a] for a in live]))
        with torch.no_grad():
            out = module.forward_inference({"obs": batch})
        actions = dist_cls.from_logits(out["action_dist_inputs"]).to_deterministic().sample()
        actions = np.clip(actions.numpy(), -1.0, 1.0)
        obs, _, terms, truncs, infos = env.step(dict(zip(live, actions, strict=True)))
        last |= {a: infos[a] for a in live if terms[a] or truncs[a]}
    return last


def main(argv: Sequence[str] | None = None) -> int:
    """Train for ``--iterations``, then print each vehicle's tracking RMSE in one episode."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=3, help="vehicles in the team")
    parser.add_argument("--duration", type=float, default=10.0, help="episode length, s")
    parser.add_argument("--iterations", type=int, default=5, help="training iterations")
    parser.add_argument("--env-runners", type=int, default=1, help="remote env runners")
    parser.add_argument("--rollout", type=int, default=512, help="env steps per sample")
    parser.add_argument("--address", help="Ray cluster to join (auto, HOST:PORT, ray://...)")
    args = parser.parse_args(argv)

    import ray

    if args.address is None:
        ray.init(num_cpus=max(args.env_runners, 1) + 1, include_dashboard=False)
    else:
        ray.init(address=args.address)
    env_config = {"n_vehicles": args.vehicles, "episode": {"duration_s": args.duration}}
    config = build_config(env_config, env_runners=args.env_runners, rollout_length=args.rollout)
    algo = config.build_algo()
    try:
        for _ in range(args.iterations):
            result = algo.train()
            runners = result["env_runners"]
            steps = runners["num_agent_steps_sampled_lifetime"]
            per_agent = " ".join(f"{a}={steps[a]:.0f}" for a in sorted(steps))
            print(
                f"iteration {result['training_iteration']}: agent steps {per_agent}, "
                f"team return {runners.get('episode_return_mean', float('nan')):.1f}"
            )
        for agent, info in fly_team(algo, env_config, seed=1000).items():
            reason = info.get("termination_reason") or "time limit"
            print(f"{agent}: tracking RMSE {info['episode_track_pos_rmse_m']:.3f} m, "
                  f"{int(info['episode_steps'])} steps, ended by {reason}")  # fmt: skip
    finally:
        algo.stop()
        ray.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
