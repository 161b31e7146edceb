"""Smoke test of an installed quadslam wheel, run from a folder outside the checkout.

Checks what the README promises a user of ``pip install quadslam[rl,plots]``: the env ids
make, reset and step; ``quadslam --version``, ``scenarios``, ``run``, ``train`` and
``evaluate`` work; a run folder evaluates from its own ``config.yaml`` without any scenario
file; the sweep specs ship and ``quadslam sweep`` without the ``ray`` extra says how to get it.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import gymnasium as gym
import numpy as np

import quadslam_env
from agents.control.dflqr import DFLQRPolicy

BIN = Path(sys.executable).parent


def quadslam(*args: str, env: dict[str, str] | None = None) -> str:
    """Run the installed console script and return its stdout (fails loudly)."""
    tic = time.perf_counter()
    done = subprocess.run(
        [str(BIN / "quadslam"), *args],
        capture_output=True,
        text=True,
        env={**os.environ, **(env or {})},
        check=False,
    )
    took = time.perf_counter() - tic
    print(f"quadslam {' '.join(args[:3])} ... -> exit {done.returncode} ({took:.1f} s)")
    if done.returncode != 0:
        sys.exit(f"failed:\n{done.stdout}\n{done.stderr}")
    return done.stdout


def main() -> None:
    here = Path.cwd()
    installed = Path(quadslam_env.__file__).resolve()
    assert "site-packages" in installed.parts, f"not the installed package: {installed}"

    env = gym.make("QuadSLAM-EKF-v0")
    policy = DFLQRPolicy.from_env(env)
    obs, info = env.reset(seed=0)
    for _ in range(100):
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        assert not (terminated or truncated), info.get("termination_reason")
        assert np.isfinite(obs).all() and np.isfinite(reward)
    print(f"gymnasium.make + 100 DF-LQR steps: est_pos_err_m {info['est_pos_err_m']:.3f}")

    version = quadslam("--version").strip()
    assert version == f"quadslam {quadslam_env.__version__}", version
    listing = quadslam("scenarios")
    assert "paper_ekf_figure8 " in listing and "Rauniyar" in listing, listing

    quadslam("run", "--duration", "2", "--json", "run.json")
    result = json.loads((here / "run.json").read_text())
    assert result["episodes"][0]["duration_s"] >= 1.99, result["episodes"][0]
    assert list((here / "runs").glob("run-*/*.png")), "quadslam run wrote no figures"

    # Training reads configs/agents/ppo.yaml from the package data.
    hp = ["n_steps=32", "batch_size=32", "n_epochs=1", "policy_kwargs={net_arch: [8]}"]
    hp += ["env_kwargs.episode.duration_s=0.5", "eval_freq=0", "checkpoint_freq=0"]
    quadslam(
        "train", "--algo", "ppo", "--timesteps", "64", "--n-envs", "1", "--no-progress",
        "--out", "runs", "--hyperparams", *hp,
    )  # fmt: skip
    (run_dir,) = (here / "runs").glob("ppo_*")
    # The run folder alone defines the evaluation env: no scenario files are reachable.
    empty = here / "no_configs"
    empty.mkdir()
    quadslam(
        "evaluate", "--policy", str(run_dir), "--episodes", "1", "--json", "eval.json",
        env={"QUADSLAM_CONFIG_DIR": str(empty)},
    )  # fmt: skip
    evaluated = json.loads((here / "eval.json").read_text())
    assert evaluated["scenario"] == "ekf_figure8_biased_imu", evaluated["scenario"]
    assert abs(evaluated["episodes"][0]["duration_s"] - 0.5) < 1e-6, evaluated["episodes"]
    # The example sweep specs are package data; without the `ray` extra, `quadslam sweep`
    # checks the spec and then says in one line how to get Ray.
    from agents.lab.sweep.spec import load_spec

    assert len(load_spec("rauniyar2023_table")) == 20
    done = subprocess.run(
        [str(BIN / "quadslam"), "sweep", "rauniyar2023_table", "--out", "sweep"],
        capture_output=True,
        text=True,
        check=False,
    )
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, done.stderr)
    assert "pip install 'quadslam[ray]'" in lines[0], lines
    print(f"quadslam sweep without ray: {lines[0]}")
    print("installed wheel: all checks passed")


if __name__ == "__main__":
    main()
