"""skrl's PPO (torch) on the native vector env with same-step autoreset.

skrl's Gymnasium wrapper treats a vector env as autoresetting in the same step (the observation
returned with ``terminated``/``truncated`` is the next episode's first), so the env is made with
``autoreset_mode=AutoresetMode.SAME_STEP``; with the default next-step mode skrl would store one
transition per episode from the reset step. skrl is not a dependency of quadslam
(``pip install skrl``). This trains PPO from scratch on thrust and torques: a demonstration of
the integration, not a recipe. skrl writes its checkpoints into a run folder under ``--out``
(``runs/`` in the working directory by default). Run it::

    python examples/skrl_ppo.py --timesteps 2000 --envs 8
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
from gymnasium.vector import AutoresetMode

import quadslam_env  # noqa: F401  (registers the ids)


def train(
    timesteps: int,
    num_envs: int = 8,
    duration_s: float = 5.0,
    rollouts: int = 64,
    seed: int = 0,
    directory: str | Path = "runs",
) -> Any:
    """Train skrl's PPO for ``timesteps`` vector steps; the trained agent.

    Args:
        timesteps: Vector steps (``num_envs`` env steps each).
        num_envs: Lanes.
        duration_s: Episode length (``episode.duration_s``).
        rollouts: Vector steps per PPO update.
        seed: Seeds skrl (networks) and the env (lane i: ``seed + i``).
        directory: Where skrl makes the run folder of its checkpoints.

    Returns:
        The :class:`skrl.agents.torch.ppo.PPO` agent.
    """
    from skrl.agents.torch.ppo import PPO
    from skrl.envs.wrappers.torch import wrap_env
    from skrl.memories.torch import RandomMemory
    from skrl.trainers.torch import SequentialTrainer
    from skrl.utils import set_seed
    from skrl.utils.model_instantiators.torch import deterministic_model, gaussian_model

    set_seed(seed)
    vec = gym.make_vec(
        "QuadSLAM-EKF-v0",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
        episode={"duration_s": duration_s},
    )
    env = wrap_env(vec, wrapper="gymnasium")
    spaces = {"observation_space": env.observation_space, "action_space": env.action_space}
    net = [{"name": "net", "input": "OBSERVATIONS", "layers": [64, 64], "activations": "tanh"}]
    models = {
        "policy": gaussian_model(**spaces, device=env.device, network=net, output="ACTIONS"),
        "value": deterministic_model(**spaces, device=env.device, network=net, output="ONE"),
    }
    agent = PPO(
        models=models,
        memory=RandomMemory(memory_size=rollouts, num_envs=env.num_envs, device=env.device),
        **spaces,
        device=env.device,
        cfg={
            "rollouts": rollouts,
            "learning_epochs": 4,
            "mini_batches": 2,
            "experiment": {"directory": str(directory)},
        },
    )
    trainer = SequentialTrainer(
        env=env,
        agents=agent,
        # The env is closed below: no second close (and log line) when the interpreter exits.
        cfg={
            "timesteps": timesteps,
            "headless": True,
            "disable_progressbar": True,
            "close_environment_at_exit": False,
        },
    )
    trainer.train()
    env.close()
    return agent


def main(argv: Sequence[str] | None = None) -> int:
    """Train with the given budget."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=2000, help="vector steps")
    parser.add_argument("--envs", type=int, default=8, help="lanes")
    parser.add_argument("--duration", type=float, default=5.0, help="episode length, s")
    parser.add_argument("--out", type=Path, default=Path("runs"), help="skrl's run folders")
    args = parser.parse_args(argv)
    train(args.timesteps, args.envs, args.duration, directory=args.out)
    print("trained")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
