"""Hashes of seeded rollouts of every shipped scenario, in the scalar env and in each lane of the
vector env, to show that a change leaves every result bit for bit where it was.

Each scenario is flown by DF-LQR on what its estimator reports for ``--duration`` seconds on
seeds 0 and 1 (scalar env) and in a vector env of two lanes seeded 0 (lanes 0 and 1); the hash
covers every observation, reward, termination flag and numeric ``info`` value. Run it before
and after a change and compare the two files::

    python tools/rollout_hashes.py --out /tmp/before.json   # on the old tree
    python tools/rollout_hashes.py --out /tmp/after.json    # on the new one
    cmp /tmp/before.json /tmp/after.json
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from quadslam_env.config.files import available_scenarios


def _feed(digest: Any, value: Any) -> None:
    """Add a value (array, number, bool, dict of them) to the hash, in a fixed order."""
    if isinstance(value, dict):
        for key in sorted(value):
            if not key.startswith("_"):
                digest.update(key.encode())
                _feed(digest, value[key])
        return
    array = np.asarray(value)
    if array.dtype.kind in "fiub":
        digest.update(np.ascontiguousarray(array, dtype=np.float64).tobytes())


def scalar_hash(scenario: str, seed: int, duration_s: float) -> str:
    """Hash of one scalar-env rollout of ``scenario`` on ``seed``."""
    env = gym.make("QuadSLAM-v0", scenario=scenario, episode={"duration_s": duration_s})
    policy = DFLQRPolicy.from_env(env)
    digest = hashlib.sha256()
    obs, info = env.reset(seed=seed)
    _feed(digest, obs)
    _feed(digest, info)
    done = False
    while not done:
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        for value in (obs, reward, terminated, truncated, info):
            _feed(digest, value)
        done = terminated or truncated
    env.close()
    return digest.hexdigest()


def lane_hashes(scenario: str, duration_s: float, lanes: int = 2) -> list[str]:
    """Hashes of each lane of a vector env of ``lanes`` lanes of ``scenario`` seeded 0, over
    the steps of the first episode of lane 0."""
    env = gym.make_vec(
        "QuadSLAM-v0",
        num_envs=lanes,
        vectorization_mode="vector_entry_point",
        scenario=scenario,
        episode={"duration_s": duration_s},
    )
    policy = DFLQRPolicy.from_env(env)
    digests = [hashlib.sha256() for _ in range(lanes)]
    obs, info = env.reset(seed=0)
    alive = np.ones(lanes, dtype=bool)
    while alive.any():
        for lane in np.flatnonzero(alive):
            _feed(digests[lane], obs[lane])
        action, _ = policy.predict(obs, deterministic=True)
        obs, reward, terminated, truncated, info = env.step(action)
        for lane in np.flatnonzero(alive):
            _feed(digests[lane], reward[lane])
            lane_info = {
                k: v[lane] for k, v in info.items() if isinstance(v, np.ndarray) and len(v) == lanes
            }
            _feed(digests[lane], lane_info)
        alive &= ~(terminated | truncated)
    env.close()
    return [d.hexdigest() for d in digests]


def main() -> None:
    """Write the hashes of every shipped scenario as JSON."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--duration", type=float, default=3.0, help="seconds per rollout")
    parser.add_argument("--scenarios", help="comma-separated (default: every shipped one)")
    args = parser.parse_args()
    names = args.scenarios.split(",") if args.scenarios else available_scenarios()
    result: dict[str, Any] = {}
    for name in names:
        result[name] = {
            "scalar": [scalar_hash(name, seed, args.duration) for seed in (0, 1)],
            "lanes": lane_hashes(name, args.duration),
        }
        print(name, result[name]["scalar"][0][:12], result[name]["lanes"][0][:12], flush=True)
    args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")


if __name__ == "__main__":
    main()
