"""tianshou's PPO (torch) on the scalar env, one env per lane of tianshou's own vector env.

tianshou 2.x steps a list of Gymnasium envs through its ``DummyVectorEnv`` (or
``SubprocVectorEnv``) and resets each one itself when its episode ends, so the env ids work
as they are: each lane is a plain ``gymnasium.make`` env. tianshou is not a dependency of
quadslam (``pip install tianshou``). This trains PPO from scratch on thrust and torques: a
demonstration of the integration, not a recipe. Run it::

    python examples/tianshou_ppo.py --steps 4096 --envs 4
"""

from __future__ import annotations

import argparse
from typing import Any

import gymnasium as gym

import quadslam_env  # noqa: F401  (registers the ids)


def make_envs(env_id: str, num_envs: int, duration_s: float, seed: int) -> Any:
    """tianshou's in-process vector env of ``num_envs`` scalar envs, lane i seeded
    ``seed + i`` (tianshou seeds a lane by resetting it with that seed)."""
    from tianshou.env import DummyVectorEnv

    def factory() -> gym.Env:
        return gym.make(env_id, episode={"duration_s": duration_s})

    envs = DummyVectorEnv([factory for _ in range(num_envs)])
    envs.seed(seed)
    return envs


def build(env: gym.Env, hidden: int = 64) -> Any:
    """A PPO algorithm with a Gaussian actor and a critic of two ``hidden``-unit layers."""
    import torch
    from tianshou.algorithm import PPO
    from tianshou.algorithm.modelfree.reinforce import ProbabilisticActorPolicy
    from tianshou.algorithm.optim import AdamOptimizerFactory
    from tianshou.utils.net.common import Net
    from tianshou.utils.net.continuous import ContinuousActorProbabilistic, ContinuousCritic

    obs_shape, act_shape = env.observation_space.shape, env.action_space.shape
    assert obs_shape is not None and act_shape is not None
    sizes = [hidden, hidden]
    actor = ContinuousActorProbabilistic(
        preprocess_net=Net(state_shape=obs_shape, hidden_sizes=sizes, activation=torch.nn.Tanh),
        action_shape=act_shape,
        unbounded=True,
    )
    critic = ContinuousCritic(
        preprocess_net=Net(state_shape=obs_shape, hidden_sizes=sizes, activation=torch.nn.Tanh)
    )

    def dist(loc_scale: tuple[torch.Tensor, torch.Tensor]) -> torch.distributions.Distribution:
        loc, scale = loc_scale
        return torch.distributions.Independent(torch.distributions.Normal(loc, scale), 1)

    policy = ProbabilisticActorPolicy(
        actor=actor,
        dist_fn=dist,
        action_scaling=False,  # the env's action box is already [-1, 1]
        action_bound_method="clip",  # the Gaussian's samples are clipped into it
        action_space=env.action_space,
        deterministic_eval=True,
    )
    return PPO(policy=policy, critic=critic, optim=AdamOptimizerFactory(lr=3e-4))


def train(
    steps: int,
    num_envs: int = 4,
    duration_s: float = 5.0,
    seed: int = 0,
    env_id: str = "QuadSLAM-EKF-v0",
) -> tuple[Any, Any]:
    """Train tianshou's PPO for ``steps`` env steps (one epoch).

    Args:
        steps: Env steps in all (summed over lanes).
        num_envs: Training lanes.
        duration_s: Episode length (``episode.duration_s``).
        seed: Seeds torch (networks) and the lanes (lane i: ``seed + i``).
        env_id: The env id.

    Returns:
        ``(algorithm, training result)``.
    """
    import numpy as np
    import torch
    from tianshou.data import Collector, CollectStats, VectorReplayBuffer
    from tianshou.trainer import OnPolicyTrainerParams

    np.random.seed(seed)  # noqa: NPY002  (tianshou draws its minibatches from numpy's global)
    torch.manual_seed(seed)
    probe = gym.make(env_id)
    algorithm = build(probe)
    probe.close()
    envs = make_envs(env_id, num_envs, duration_s, seed)
    per_update = min(steps, 512)
    collector = Collector[CollectStats](
        algorithm, envs, VectorReplayBuffer(per_update, num_envs), exploration_noise=True
    )
    result = algorithm.run_training(
        OnPolicyTrainerParams(
            training_collector=collector,
            test_collector=None,
            max_epochs=1,
            epoch_num_steps=steps,
            collection_step_num_env_steps=per_update,
            update_step_num_repetitions=2,
            batch_size=64,
            test_in_training=False,
        )
    )
    envs.close()
    return algorithm, result


def evaluate(
    algorithm: Any, episodes: int, duration_s: float, seed: int, env_id: str = "QuadSLAM-EKF-v0"
) -> Any:
    """Fly ``episodes`` episodes with the policy's mean action on lanes seeded from ``seed``;
    tianshou's collect statistics (per-episode returns and lengths in ``returns``, ``lens``)."""
    from tianshou.data import Collector, CollectStats

    envs = make_envs(env_id, episodes, duration_s, seed)
    algorithm.policy.eval()
    collector = Collector[CollectStats](algorithm, envs)
    stats = collector.collect(n_episode=episodes, reset_before_collect=True)
    envs.close()
    return stats


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=4096)
    parser.add_argument("--envs", type=int, default=4)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    algorithm, _ = train(args.steps, args.envs, seed=args.seed)
    stats = evaluate(algorithm, episodes=4, duration_s=5.0, seed=1000)
    print("held-out returns:", [round(float(r), 2) for r in stats.returns])


if __name__ == "__main__":
    main()
