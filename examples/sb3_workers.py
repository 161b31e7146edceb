"""Residual PPO (stable-baselines3) on DF-LQR, the lanes split over two worker processes.

``QuadSLAMVecEnv`` is an SB3 ``VecEnv`` over the batched simulation; ``n_workers=2`` simulates
half of the lanes in each of two processes, and ``stagger=True`` cuts each lane's first episode
at a different step so the lanes do not fly the reference in lockstep (their episodes end on
different steps, in both workers). ``VecMonitor`` counts the finished episodes. The workers
re-import this module, hence the ``if __name__ == "__main__":`` guard. Run it::

    pip install "quadslam[rl]"
    python examples/sb3_workers.py --timesteps 100000
    python examples/sb3_workers.py --timesteps 512 --lanes 4 --n-steps 64 --duration 0.5
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence

# --8<-- [start:train]
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecMonitor

from agents.rl.vec_adapter import QuadSLAMVecEnv


def train(timesteps: int, lanes: int = 32, n_steps: int = 128, duration_s: float = 20.0) -> int:
    """Train residual PPO, save it to ``ppo_residual_ekf.zip``; the episodes VecMonitor counted."""
    venv = QuadSLAMVecEnv(
        "QuadSLAM-EKF-v0",
        lanes,
        seed=0,
        n_workers=2,  # lanes 0..lanes/2-1 in one process, the rest in the other
        stagger=True,  # lane i's first episode is cut after (i + 1)/lanes of its length
        wrapper="residual_dflqr",  # the action is a residual on DF-LQR's
        episode={"duration_s": duration_s},  # any gymnasium.make override
    )
    monitor = VecMonitor(venv)
    model = PPO("MlpPolicy", monitor, n_steps=n_steps, batch_size=64, seed=0)
    model.learn(total_timesteps=timesteps)
    model.save("ppo_residual_ekf")
    monitor.close()  # stops the workers
    return monitor.episode_count


# --8<-- [end:train]


def main(argv: Sequence[str] | None = None) -> int:
    """Parse the budget, train, print the number of finished episodes."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=100_000, help="env steps to train")
    parser.add_argument("--lanes", type=int, default=32, help="lanes (at least 2)")
    parser.add_argument("--n-steps", type=int, default=128, help="PPO rollout steps per lane")
    parser.add_argument("--duration", type=float, default=20.0, help="episode length, s")
    args = parser.parse_args(argv)
    episodes = train(args.timesteps, args.lanes, args.n_steps, args.duration)
    print(f"finished episodes: {episodes}")
    return 0


if __name__ == "__main__":  # n_workers=2 starts processes that re-import this module
    raise SystemExit(main())
