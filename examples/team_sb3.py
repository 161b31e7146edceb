"""PPO (stable-baselines3) with one policy shared by every vehicle of the team env.

Parameter sharing: each vehicle of ``quadslam_env.team.parallel_env`` is one slot of an SB3
``VecEnv`` (the vehicles have the single env's observation and action spaces), so one PPO
policy acts for all of them and learns from every vehicle's transitions. This is what
SuperSuit's ``pettingzoo_env_to_vec_env_v1`` + ``concat_vec_envs_v1(...,
base_class="stable_baselines3")`` are meant to do, but SuperSuit 3.11.0 (the newest release,
which installs next to pettingzoo 1.27.0, gymnasium 1.4 and stable-baselines3 2.9) does not run
this env, so the small :class:`TeamVecEnv` below does the same:

- **a vehicle that ends early** (a crash, a tilt or bounds limit, a diverged filter: the
  vehicle leaves ``env.agents``) stops SuperSuit's vector env with an ``AssertionError``
  ("MarkovVectorEnv does not support environments with varying numbers of active agents");
  its ``black_death_v3`` wrapper, which is meant to fill the ended vehicles' slots, never ends
  the episode (it combines terminations and truncations with ``and``), so the next step finds
  no live vehicle and the team env raises ``ResetNeeded``;
- ``PPO(..., seed=...)`` raises ``AttributeError: 'ConcatVecEnv' object has no attribute
  'seed'`` (Gymnasium 1.0 removed ``VectorEnv.seed``), and without a seed its SB3 wrapper
  never seeds the env;
- its SB3 wrapper sets no ``TimeLimit.truncated``, so PPO would treat the time limit as a
  terminal state instead of bootstrapping from the last observation.

**When one vehicle ends, the team's episode ends** in :class:`TeamVecEnv`: the vehicles still
flying are cut and reported as truncated (``TimeLimit.truncated``, with their
``terminal_observation``, so PPO bootstraps their value), and the team is reset. Every sample
in PPO's buffer is then a real transition of a vehicle, at the price of team episodes as long
as their shortest vehicle's; filling an ended vehicle's slot with made-up zero observations
and rewards until the others end (SuperSuit's "black death") would put those in the buffer.

This trains PPO from scratch on thrust and torques for a few thousand steps: a demonstration
of the integration, not a recipe (the vehicles crash after a second or so). The evaluation
flies one team episode on the team env itself, with the trained policy deterministic, and
prints each vehicle's tracking RMSE. Run it::

    pip install "quadslam[rl,team]"
    python examples/team_sb3.py --timesteps 20000 --vehicles 3
    python examples/team_sb3.py --timesteps 2048 --vehicles 2 --duration 2
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

import gymnasium as gym
import numpy as np
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import VecEnv
from stable_baselines3.common.vec_env.base_vec_env import (
    VecEnvIndices,
    VecEnvObs,
    VecEnvStepReturn,
)

from quadslam_env.team import TeamParallelEnv, parallel_env


class TeamVecEnv(VecEnv):
    """The team env as an SB3 ``VecEnv``: slot i is ``vehicle_i`` (module docstring).

    Args:
        env: The team env; its ``possible_agents`` are the slots, in order.
        seed: Seed of the first ``reset`` (``None``: random); later resets continue the
            vehicles' streams.

    Attributes:
        env: The team env.
        samples: (N,) transitions of each vehicle handed to the learner.
        episodes_ended: Vehicle episodes that ended by the vehicle's own termination or
            time limit.
        episodes_cut: Vehicle episodes cut because a teammate's had ended.
    """

    def __init__(self, env: TeamParallelEnv, seed: int | None = 0) -> None:
        self.env = env
        first = env.possible_agents[0]
        box = env.action_space(first)
        super().__init__(len(env.possible_agents), env.observation_space(first), box)
        self.samples = np.zeros(self.num_envs, dtype=np.int64)
        self.episodes_ended = 0
        self.episodes_cut = 0
        self._actions = np.zeros((self.num_envs, *box.shape), np.float32)
        self.seed(seed)

    def _rows(self, values: dict[str, Any]) -> np.ndarray:
        return np.stack([values[agent] for agent in self.env.possible_agents])

    def reset(self) -> VecEnvObs:
        """Reset the team (with the seed set by ``seed``, if any); the slots' observations."""
        return self._reset()

    def _reset(self) -> np.ndarray:
        seed = self._seeds[0] if self._seeds else None
        obs, infos = self.env.reset(seed=seed)
        self._reset_seeds()
        self.reset_infos = [infos[agent] for agent in self.env.possible_agents]
        return self._rows(obs)

    def seed(self, seed: int | None = None) -> Sequence[int | None]:
        """Seed the next ``reset`` of the team (one seed: the team env seeds its vehicles)."""
        self._seeds = [] if seed is None else [int(seed)] * self.num_envs
        return list(self._seeds)

    def step_async(self, actions: np.ndarray) -> None:
        """Store the (N, 4) actions, row i for ``vehicle_i``."""
        self._actions = np.asarray(actions, dtype=np.float32)

    def step_wait(self) -> VecEnvStepReturn:
        """Step every vehicle; if any ends, end the team's episode and reset it."""
        acts = {agent: self._actions[i] for i, agent in enumerate(self.env.possible_agents)}
        obs, rewards, terms, truncs, infos = self.env.step(acts)
        self.samples += 1
        agents = self.env.possible_agents
        own_end = [terms[a] or truncs[a] for a in agents]
        done = any(own_end)
        out = []
        for agent, ended in zip(agents, own_end, strict=True):
            info = dict(infos[agent])
            info["TimeLimit.truncated"] = done and not terms[agent]  # time limit or cut
            if done:
                info["terminal_observation"] = obs[agent]
                self.episodes_ended += int(ended)
                self.episodes_cut += int(not ended)
            out.append(info)
        rows = self._rows(obs)
        if done:
            rows = self._reset()  # SB3's autoreset: the next episode's first observations
        reward = np.array([rewards[a] for a in agents], dtype=np.float32)
        return rows, reward, np.full(self.num_envs, done), out

    def close(self) -> None:
        """Close the team env."""
        self.env.close()

    def get_attr(self, attr_name: str, indices: VecEnvIndices = None) -> list[Any]:
        """The team env's attribute, once per slot of ``indices``."""
        return [getattr(self.env, attr_name) for _ in self._get_indices(indices)]

    def set_attr(self, attr_name: str, value: Any, indices: VecEnvIndices = None) -> None:
        """Set an attribute of the team env (every slot shares it)."""
        setattr(self.env, attr_name, value)

    def env_method(
        self, method_name: str, *args: Any, indices: VecEnvIndices = None, **kwargs: Any
    ) -> list[Any]:
        """Call a method of the team env once; its result repeated per slot of ``indices``."""
        result = getattr(self.env, method_name)(*args, **kwargs)
        return [result for _ in self._get_indices(indices)]

    def env_is_wrapped(
        self, wrapper_class: type[gym.Wrapper], indices: VecEnvIndices = None
    ) -> list[bool]:
        """False: the vehicles are not Gymnasium envs, so nothing wraps them."""
        return [False for _ in self._get_indices(indices)]


def evaluate(model: PPO, env: TeamParallelEnv, seed: int) -> dict[str, dict[str, Any]]:
    """Fly one team episode with the deterministic policy; each vehicle's last ``info``."""
    obs, _ = env.reset(seed=seed)
    last: dict[str, dict[str, Any]] = {}
    while env.agents:
        live = list(env.agents)
        actions, _ = model.predict(np.stack([obs[a] for a in live]), deterministic=True)
        obs, _, terms, truncs, infos = env.step(dict(zip(live, actions, strict=True)))
        last |= {a: infos[a] for a in live if terms[a] or truncs[a]}
    return last


def main(argv: Sequence[str] | None = None) -> int:
    """Train the shared policy, then print each vehicle's tracking RMSE in one team episode."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--timesteps", type=int, default=20_000, help="env steps, all vehicles")
    parser.add_argument("--vehicles", type=int, default=3, help="vehicles in the team")
    parser.add_argument("--duration", type=float, default=10.0, help="episode length, s")
    parser.add_argument("--n-steps", type=int, default=256, help="PPO rollout steps per vehicle")
    parser.add_argument("--hidden", type=int, nargs="+", default=[32, 32], help="layer sizes")
    parser.add_argument("--seed", type=int, default=0, help="seeds PPO and the team env")
    args = parser.parse_args(argv)

    env = parallel_env(n_vehicles=args.vehicles, episode={"duration_s": args.duration})
    venv = TeamVecEnv(env, seed=args.seed)
    batch = args.n_steps * args.vehicles
    model = PPO("MlpPolicy", venv, n_steps=args.n_steps, batch_size=min(64, batch), n_epochs=4,
                policy_kwargs={"net_arch": list(args.hidden)}, seed=args.seed)  # fmt: skip
    model.learn(total_timesteps=args.timesteps)
    samples = " ".join(f"{a}={n}" for a, n in zip(env.possible_agents, venv.samples, strict=True))
    print(f"trained: {model.num_timesteps} steps; samples per vehicle: {samples}")
    print(f"vehicle episodes: {venv.episodes_ended} ended, {venv.episodes_cut} cut by a teammate's")
    last = evaluate(model, env, seed=args.seed + 1000)
    for agent in env.possible_agents:
        info = last[agent]
        reason = info.get("termination_reason") or "time limit"
        print(f"{agent}: tracking RMSE {info['episode_track_pos_rmse_m']:.3f} m, "
              f"{int(info['episode_steps'])} steps, ended by {reason}")  # fmt: skip
    venv.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
