"""Smoke test of ``pip install quadslam`` with no extras, run from a folder outside the checkout.

Every env id makes, resets and steps; the native vector env steps; DF-LQR flies; ``quadslam run``
works without figures; nothing imports torch, stable-baselines3, tensorboard or matplotlib; and
the commands that need an extra say in one line which one.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np

import quadslam_env
from agents.control.dflqr import DFLQRPolicy

HEAVY = ("torch", "stable_baselines3", "tensorboard", "matplotlib")
BIN = Path(sys.executable).parent


def main() -> None:
    installed = [m for m in HEAVY if importlib.util.find_spec(m) is not None]
    assert not installed, f"the env-only install brought {installed}"
    for env_id in quadslam_env.ENV_IDS:
        kwargs = {"estimator": {"params": {"n_particles": 20}}} if "FastSLAM" in env_id else {}
        env = gym.make(env_id, episode={"duration_s": 1.0}, **kwargs)
        policy = DFLQRPolicy.from_env(env)
        obs, _ = env.reset(seed=0)
        for _ in range(50):
            obs, reward, _, _, info = env.step(policy.predict(obs)[0])
            assert np.isfinite(obs).all() and np.isfinite(reward), env_id
        env.close()
        print(f"{env_id}: 50 DF-LQR steps, est_pos_err_m {info['est_pos_err_m']:.3f}")
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=4, vectorization_mode="vector_entry_point")
    policy = DFLQRPolicy.from_env(vec)
    obs, _ = vec.reset(seed=0)
    for _ in range(50):
        obs, reward, *_ = vec.step(policy.predict(obs)[0])
    assert obs.shape[0] == 4 and np.isfinite(reward).all()
    vec.close()
    print("vector env: 4 lanes x 50 DF-LQR steps")
    loaded = [m for m in HEAVY if m in sys.modules]
    assert not loaded, loaded

    run = subprocess.run(
        [str(BIN / "quadslam"), "run", "--duration", "1", "--no-plots"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr
    for args, extra in ((["train", "--algo", "ppo"], "rl"), (["run", "--plots", "figs"], "plots")):
        done = subprocess.run(
            [str(BIN / "quadslam"), *args, "--duration", "1"] if args[0] == "run"
            else [str(BIN / "quadslam"), *args],
            capture_output=True, text=True, check=False,
        )  # fmt: skip
        lines = done.stderr.strip().splitlines()
        assert done.returncode == 2 and len(lines) == 1, (args, done.returncode, done.stderr)
        assert f"pip install 'quadslam[{extra}]'" in lines[0], lines
        print(f"quadslam {' '.join(args)} without [{extra}]: {lines[0]}")
    env = None
    try:
        env = gym.make("QuadSLAM-v0", render_mode="rgb_array")
    except ValueError as exc:
        assert "pip install 'quadslam[plots]'" in str(exc), exc
        print(f"render without [plots]: {exc}")
    else:
        sys.exit("render_mode='rgb_array' made an env without matplotlib")
    print("env-only install: all checks passed")


if __name__ == "__main__":
    main()
