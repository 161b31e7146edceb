"""RLlib's PPO (new API stack) on a QuadSLAM env id, through ``gymnasium.make``.

RLlib builds each env runner's envs with ``gymnasium.make_vec(id, num_envs, vectorization_mode,
**env_config)``. The id is given as ``"quadslam_env:QuadSLAM-EKF-v0"``: Gymnasium imports the
module before looking the id up, so the ids are registered in every env runner process, local
or on another node, without a ``tune.register_env`` creator. ``env_config`` holds the usual
``gymnasium.make`` keyword arguments (``scenario``, section overrides). ``--vectorize sync``
(RLlib's default) steps ``gymnasium.make`` envs one after another; ``--vectorize
vector_entry_point`` gives each env runner the package's native vector env (its envs as lanes
of one batched simulation), which is faster with many envs per runner.

This trains PPO from scratch on thrust and torques: a demonstration of the integration, not a
recipe (``quadslam train`` has the tuned residual-on-DF-LQR setups). Run it::

    pip install "quadslam[rllib]"
    python examples/rllib_ppo.py --iterations 5 --env-runners 1
    python examples/rllib_ppo.py --address auto   # on a running Ray cluster
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import Any

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")  # the filters' small matrices: one BLAS thread


def build_config(
    env_id: str = "QuadSLAM-EKF-v0",
    env_config: dict[str, Any] | None = None,
    *,
    env_runners: int = 0,
    envs_per_runner: int = 4,
    vectorize: str = "sync",
    rollout_length: int = 128,
    minibatch_size: int = 128,
    epochs: int = 4,
    hidden: Sequence[int] = (64, 64),
    seed: int = 0,
) -> Any:
    """A ``PPOConfig`` for ``env_id`` on RLlib's new API stack.

    Args:
        env_id: A registered QuadSLAM id (``QuadSLAM-v0``, ``-EKF-v0``, ``-FastSLAM-v0``,
            ``-Oracle-v0``).
        env_config: ``gymnasium.make`` keyword arguments, e.g. ``{"episode": {"duration_s":
            10.0}}``.
        env_runners: Remote env runners (0: sample in this process).
        envs_per_runner: Envs per runner (one vector env).
        vectorize: ``sync``, ``async`` or ``vector_entry_point`` (the native vector env).
        rollout_length: Steps per env per sample; the train batch per learner is
            ``rollout_length × envs_per_runner × max(env_runners, 1)`` steps.
        minibatch_size: SGD minibatch in steps.
        epochs: Passes over each train batch.
        hidden: Hidden layer sizes of the policy and value networks.
        seed: Seeds RLlib (networks, env runners' env seeds).

    Returns:
        The config; ``config.build_algo()`` makes the algorithm.
    """
    from ray.rllib.algorithms.ppo import PPOConfig

    batch = rollout_length * envs_per_runner * max(env_runners, 1)
    return (
        PPOConfig()
        .environment(f"quadslam_env:{env_id}", env_config=dict(env_config or {}))
        .env_runners(
            num_env_runners=env_runners,
            num_envs_per_env_runner=envs_per_runner,
            rollout_fragment_length=rollout_length,
            gym_env_vectorize_mode=vectorize,
        )
        .training(
            train_batch_size_per_learner=batch,
            minibatch_size=min(minibatch_size, batch),
            num_epochs=epochs,
        )
        .rl_module(model_config={"fcnet_hiddens": list(hidden)})
        .debugging(seed=seed)
    )


def main(argv: Sequence[str] | None = None) -> int:
    """Train for ``--iterations`` and print each iteration's returns."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--env", default="QuadSLAM-EKF-v0", help="env id")
    parser.add_argument("--duration", type=float, default=10.0, help="episode length, s")
    parser.add_argument("--iterations", type=int, default=5, help="training iterations")
    parser.add_argument("--env-runners", type=int, default=1, help="remote env runners")
    parser.add_argument("--envs-per-runner", type=int, default=4, help="envs per runner")
    parser.add_argument(
        "--vectorize", default="sync", choices=["sync", "async", "vector_entry_point"]
    )
    parser.add_argument("--address", help="Ray cluster to join (auto, HOST:PORT, ray://...)")
    args = parser.parse_args(argv)

    import ray

    if args.address is None:
        ray.init(num_cpus=max(args.env_runners, 1) + 1, include_dashboard=False)
    else:
        ray.init(address=args.address)
    config = build_config(
        args.env,
        {"episode": {"duration_s": args.duration}},
        env_runners=args.env_runners,
        envs_per_runner=args.envs_per_runner,
        vectorize=args.vectorize,
    )
    algo = config.build_algo()
    try:
        for _ in range(args.iterations):
            result = algo.train()
            runners = result["env_runners"]
            print(
                f"iteration {result['training_iteration']}: "
                f"{runners['num_env_steps_sampled_lifetime']:.0f} env steps, "
                f"episode return {runners.get('episode_return_mean', float('nan')):.1f}, "
                f"length {runners.get('episode_len_mean', float('nan')):.0f} steps"
            )
    finally:
        algo.stop()
        ray.shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
