"""Where one training's wall time goes: ``quadslam train`` under cProfile, as a tree.

Runs :func:`agents.rl.training.train` under :mod:`cProfile` and prints the cumulative time of
the parts of a training, nested as they call each other (a child's time is part of its
parent's)::

    train() (the command's own imports of this package come before it)
      startup: config, the throwaway build of check_setup, the lanes' first build
      learn
        collect_rollouts
          vec env step (VecNormalize included)
            lanes: native vector env, residual base included
              simulator + estimator (the env core)
              residual base (DF-LQR / LQI / look-at)
          policy forward (actions while collecting)
          callbacks per step (metrics, evaluation, checkpoints)
        train (gradient steps)

cProfile slows Python-heavy code more than compiled kernels, so the shares are indicative;
the run's own ``timing.json`` (written without the profiler) has the true wall time. Run it
from a checkout, on an idle machine::

    python tools/profile_training.py --timesteps 262144          # the QuadSLAM-EKF-v0 entry
    python tools/profile_training.py --env QuadSLAM-ActivePerception-v0 --prof ap.prof
"""

from __future__ import annotations

import argparse
import cProfile
import pstats
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

# (label, depth, file suffix, function name): the first match of each is reported.
PARTS = (
    ("learn", 1, "common/base_class.py", "learn"),
    ("learn", 1, "on_policy_algorithm.py", "learn"),
    ("learn", 1, "off_policy_algorithm.py", "learn"),
    ("collect_rollouts", 2, "on_policy_algorithm.py", "collect_rollouts"),
    ("collect_rollouts", 2, "off_policy_algorithm.py", "collect_rollouts"),
    ("vec env step (VecNormalize included)", 3, "vec_env/base_vec_env.py", "step"),
    ("lanes: native vector env, residual base included", 4, "agents/rl/lane_share.py", "step"),
    ("simulator + estimator (the env core)", 5, "quadslam_env/core.py", "step"),
    ("residual base (DF-LQR / LQI / look-at)", 5, "agents/rl/wrappers.py", "__call__"),
    ("policy forward (actions while collecting)", 3, "common/policies.py", "forward"),
    ("policy forward (actions while collecting)", 3, "sbx/ppo/policies.py", "predict_all"),
    ("callbacks per step (metrics, evaluation, checkpoints)", 3, "common/callbacks.py", "on_step"),
    ("train (gradient steps)", 2, "ppo/ppo.py", "train"),
    ("train (gradient steps)", 2, "sac/sac.py", "train"),
)


def cumulative(stats: pstats.Stats, suffix: str, name: str) -> tuple[float, int] | None:
    """``(cumulative s, calls)`` of the function ``name`` in a file ending in ``suffix``.

    Of several matches (a recursive or re-entered function) the largest cumulative time.
    """
    found = [
        (ct, nc)
        for (path, _line, func), (_cc, nc, _tt, ct, _callers) in stats.stats.items()  # type: ignore[attr-defined]
        if func == name and path.replace("\\", "/").endswith(suffix)
    ]
    return max(found) if found else None


def report(stats: pstats.Stats, total_s: float) -> list[str]:
    """The tree's lines: label, seconds, share of the total."""
    lines = [f"{'part':<60} {'s':>8} {'share':>7}"]
    lines.append(f"{'train()':<60} {total_s:8.1f} {100.0:6.1f}%")
    seen: set[str] = set()
    learn_s = 0.0
    for label, depth, suffix, name in PARTS:
        if label in seen:
            continue
        hit = cumulative(stats, suffix, name)
        if hit is None:
            continue
        seen.add(label)
        seconds, _calls = hit
        if label == "learn":
            learn_s = seconds
            startup = total_s - seconds
            lines.append(f"{'  startup: config, check_setup, building':<60} {startup:8.1f} "
                         f"{100 * startup / total_s:6.1f}%")  # fmt: skip
        lines.append(f"{'  ' * depth + label:<60} {seconds:8.1f} {100 * seconds / total_s:6.1f}%")
    if not learn_s:
        lines.append("(no learn() call found: is the algorithm an SB3 one?)")
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    """Profile one training; print the tree (and keep the raw profile with ``--prof``)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--algo", default="ppo")
    parser.add_argument("--env", default="QuadSLAM-EKF-v0")
    parser.add_argument("--timesteps", type=int, default=262_144)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--prof", type=Path, default=None, help="also write the raw profile")
    parser.add_argument(
        "--set", nargs="+", default=[], metavar="KEY=VALUE", help="as train --hyperparams"
    )
    args = parser.parse_args(argv)

    from agents.rl.hyperparams import parse_hyperparam_overrides  # the CLI's parsing
    from agents.rl.training import train

    overrides = parse_hyperparam_overrides(args.set) if args.set else None
    profiler = cProfile.Profile()
    with tempfile.TemporaryDirectory(prefix="quadslam-profile-") as out:
        tic = time.perf_counter()
        profiler.enable()
        train(args.algo, args.env, timesteps=args.timesteps, seed=args.seed, out_dir=out,
              progress=False, hyperparams=overrides)  # fmt: skip
        profiler.disable()
        total = time.perf_counter() - tic
    if args.prof is not None:
        profiler.dump_stats(str(args.prof))
    stats = pstats.Stats(profiler)
    print(f"{args.algo} on {args.env}, {args.timesteps:,} env steps, seed {args.seed} (cProfile)")
    print("\n".join(report(stats, total)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
