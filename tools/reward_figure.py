"""The reward's per-step terms and their sum over one DF-LQR episode, as a figure.

Writes ``docs/figures/reward_terms.png``: flies DF-LQR on ``QuadSLAM-EKF-v0`` (the default
``paper_ekf_figure8`` scenario: EKF-SLAM, the vehicle starting at rest 2 m below the figure-8)
with seed 0, reads the signed terms ``reward_<term>`` from each step's ``info`` and plots them
with their sum (the reward) and the running return. Deterministic: the same seed gives the same
figure. Run it from a checkout::

    python tools/reward_figure.py               # writes docs/figures/reward_terms.png
    python tools/reward_figure.py --out fig.png --seed 3 --duration 20
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy

TERMS = ("alive", "pos", "vel", "yaw", "effort", "termination", "pos_std")
DEFAULT_OUT = Path(__file__).resolve().parents[1] / "docs" / "figures" / "reward_terms.png"


def episode_terms(
    env_id: str = "QuadSLAM-EKF-v0", seed: int = 0, duration_s: float | None = None
) -> dict[str, np.ndarray]:
    """One DF-LQR episode's per-step reward terms.

    Args:
        env_id: A registered id (its default scenario).
        seed: The reset seed.
        duration_s: Episode length override (``None``: the scenario's).

    Returns:
        ``{"t": times, "reward": rewards, "<term>": signed term}`` per step, each (T,).
    """
    kwargs: dict[str, Any] = {} if duration_s is None else {"episode": {"duration_s": duration_s}}
    env = gym.make(env_id, **kwargs)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed)
    rows: dict[str, list[float]] = {key: [] for key in ("t", "reward", *TERMS)}
    done = False
    while not done:
        obs, reward, terminated, truncated, info = env.step(policy.predict(obs)[0])
        rows["t"].append(float(info["t"]))
        rows["reward"].append(float(reward))
        for term in TERMS:
            rows[term].append(float(info[f"reward_{term}"]))
        done = terminated or truncated
    env.close()
    return {key: np.asarray(values) for key, values in rows.items()}


def plot(terms: dict[str, np.ndarray], out: Path) -> None:
    """Draw the terms, their sum and the running return into ``out`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    t = terms["t"]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(8.0, 6.0), sharex=True)
    for term in TERMS:
        if np.any(terms[term] != 0.0):  # the termination and P_ρ terms are 0 here
            top.plot(t, terms[term], lw=1.0, label=f"reward_{term}")
    top.plot(t, terms["reward"], "k", lw=1.6, label="reward (their sum)")
    top.axhline(0.0, color="0.6", lw=0.6)
    top.set_ylabel("per step")
    top.set_title("Reward terms, DF-LQR on QuadSLAM-EKF-v0 (paper_ekf_figure8), seed 0")
    top.legend(fontsize=8, ncol=3, loc="lower right")
    bottom.plot(t, np.cumsum(terms["reward"]), "k", lw=1.6)
    bottom.axhline(0.0, color="0.6", lw=0.6)
    bottom.set_ylabel("return so far")
    bottom.set_xlabel("t (s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """Fly the episode, write the figure, print where and the episode's return."""
    parser = argparse.ArgumentParser(description=(__doc__ or "").splitlines()[0])
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="PNG to write")
    parser.add_argument("--seed", type=int, default=0, help="reset seed")
    parser.add_argument("--duration", type=float, default=None, help="episode length, s")
    args = parser.parse_args(argv)
    terms = episode_terms(seed=args.seed, duration_s=args.duration)
    plot(terms, args.out)
    print(f"{args.out}: {terms['t'].size} steps, return {terms['reward'].sum():.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
