"""A CleanRL-style rollout loop on the native vector env with same-step autoreset.

CleanRL's PPO scripts (and skrl) expect Gymnasium's ``SyncVectorEnv`` in ``SAME_STEP`` mode: when
a lane ends, the step that ends it already returns the lane's *reset* observation, and the
ending step's observation and info are in ``info["final_obs"]`` and ``info["final_info"]``
(masked by ``info["_final_obs"]``/``info["_final_info"]``). The loop below records each
episode's return and length on the step that ends it, bootstraps from the true last
observation as CleanRL does (``real_next_obs``), and takes DF-LQR's actions (a learning agent
would sample its own). Run it::

    python examples/cleanrl_loop.py --envs 4 --steps 300 --duration 1.0
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import dataclass

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy


@dataclass(frozen=True)
class Episode:
    """One finished episode of one lane."""

    lane: int
    ret: float  # the sum of the episode's rewards
    length: int  # steps counted by the loop
    reported_steps: int  # the env's own count, info["final_info"]["episode_steps"]
    reason: str  # info["final_info"]["termination_reason"] ("" for a time limit)


def rollout(
    env_id: str = "QuadSLAM-EKF-v0",
    num_envs: int = 4,
    steps: int = 300,
    duration_s: float = 1.0,
    seed: int = 0,
) -> list[Episode]:
    """Step ``num_envs`` lanes ``steps`` times with DF-LQR; the episodes that finished.

    Args:
        env_id: A registered QuadSLAM id.
        num_envs: Lanes B.
        steps: Vector steps (B env steps each).
        duration_s: Episode length (``episode.duration_s``).
        seed: Lane i is the scalar env seeded ``seed + i``.

    Returns:
        The finished episodes in the order they ended (lane order within a step).
    """
    envs = gym.make_vec(
        env_id,
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        autoreset_mode=AutoresetMode.SAME_STEP,
        episode={"duration_s": duration_s},
    )
    policy = DFLQRPolicy.from_env(envs)
    obs, _ = envs.reset(seed=seed)
    returns = np.zeros(num_envs)
    lengths = np.zeros(num_envs, dtype=int)
    episodes: list[Episode] = []
    for _ in range(steps):
        action, _ = policy.predict(obs)
        next_obs, reward, terminated, truncated, info = envs.step(action)
        returns += reward
        lengths += 1
        done = np.logical_or(terminated, truncated)
        # CleanRL: the value target bootstraps from the ending step's observation, not the reset.
        real_next_obs = next_obs.copy()
        for lane in np.flatnonzero(done):
            real_next_obs[lane] = info["final_obs"][lane]
            final = info["final_info"]  # the vector env's keys: present where they apply
            reasons = final.get("termination_reason")  # absent when no lane was terminated
            episodes.append(
                Episode(
                    lane=int(lane),
                    ret=float(returns[lane]),
                    length=int(lengths[lane]),
                    reported_steps=int(final["episode_steps"][lane]),
                    reason="" if reasons is None else str(reasons[lane] or ""),
                )
            )
            returns[lane], lengths[lane] = 0.0, 0
        # (a learner would store (obs, action, reward, real_next_obs, terminated) here)
        obs = next_obs
    envs.close()
    return episodes


def main(argv: Sequence[str] | None = None) -> int:
    """Run :func:`rollout` and print each finished episode."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--env", default="QuadSLAM-EKF-v0", help="env id")
    parser.add_argument("--envs", type=int, default=4, help="lanes")
    parser.add_argument("--steps", type=int, default=300, help="vector steps")
    parser.add_argument("--duration", type=float, default=1.0, help="episode length, s")
    args = parser.parse_args(argv)
    episodes = rollout(args.env, args.envs, args.steps, args.duration)
    for ep in episodes:
        print(f"lane {ep.lane}: return {ep.ret:.2f}, {ep.length} steps {ep.reason}".rstrip())
    print(f"{len(episodes)} episodes")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
