"""The ``quadslam`` command line: ``run``, ``evaluate``, ``train``, ``bench``.

Bad input (unknown scenario, malformed YAML, wrong model file, bad numbers) is reported in one
line on stderr with a non-zero exit status.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}") from None
    if not value > 0:
        raise argparse.ArgumentTypeError(f"expected a positive number, got {text!r}")
    return value


def make_env(
    env_id: str,
    scenario: str | None,
    estimator: str | None,
    duration: float | None,
    render_mode: str | None = None,
) -> Any:
    """``gymnasium.make`` with the CLI's scenario / estimator / duration choices."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)

    kwargs: dict[str, Any] = {}
    if scenario is not None:
        kwargs["scenario"] = scenario
    if estimator is not None:
        kwargs["estimator_name"] = estimator
    if duration is not None:
        kwargs["episode"] = {"duration_s": duration}
    if render_mode is not None:
        kwargs["render_mode"] = render_mode
    return gym.make(env_id, **kwargs)


def fly(
    env: Any,
    policy: Any,
    policy_name: str,
    seeds: Sequence[int],
    plots: Path | None,
    json_path: Path | None,
) -> dict[str, Any]:
    """Fly ``policy`` for each seed with a progress bar, print the table, write JSON/plots."""
    from agents.evaluation import Trace, format_table, run_episode, summarize

    base = env.unwrapped
    total = base.max_steps * len(seeds)
    episodes = []
    trace = Trace() if plots is not None else None
    with tqdm(
        total=total,
        unit="step",
        desc=f"{base.scenario.name} × {len(seeds)} seed(s)",
        file=sys.stderr,
        mininterval=0.5,
    ) as bar:
        for i, seed in enumerate(seeds):
            ep = run_episode(
                env, policy, seed, trace=trace if i == 0 else None, on_step=lambda: bar.update(1)
            )
            bar.update(base.max_steps - round(ep["duration_s"] / base.dt))
            episodes.append(ep)
    summary = summarize(episodes)
    result = {
        "scenario": base.scenario.name,
        "estimator": base.scenario.estimator.name,
        "policy": policy_name,
        "episodes": episodes,
        "summary": summary,
    }
    print(format_table(episodes, summary))
    if plots is not None and trace is not None:
        from agents.plots import write_figures

        files = write_figures(
            trace, plots, f"{base.scenario.name} / {base.scenario.estimator.name} / seed {seeds[0]}"
        )
        print(f"figures: {plots} ({len(files)} PNG)")
    if json_path is not None:
        json_path.parent.mkdir(parents=True, exist_ok=True)
        json_path.write_text(json.dumps(result, indent=2))
        print(f"json: {json_path}")
    return result


def cmd_run(args: argparse.Namespace) -> int:
    """DF-LQR episodes on a scenario: the package's main job."""
    from agents.dflqr import DFLQRPolicy

    env = make_env("QuadSLAM-v0", args.scenario, args.estimator, args.duration)
    plots = args.plots
    if plots is None and not args.no_plots:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        plots = Path("runs") / f"run-{stamp}-{env.unwrapped.scenario.name}"
    seeds = list(range(args.seed, args.seed + args.seeds))
    fly(env, DFLQRPolicy.from_env(env), "dflqr", seeds, plots, args.json)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Any policy (``dflqr`` or a trained model) through the same code path as ``run``."""
    from agents.policies import load_policy

    env = make_env(args.env, args.scenario, args.estimator, args.duration)
    policy, name = load_policy(args.policy, env)
    seeds = list(range(args.seed, args.seed + args.episodes))
    fly(env, policy, name, seeds, args.plots, args.json)
    return 0


def cmd_bench(args: argparse.Namespace) -> int:
    """Speed and scaling benchmark (figures for the README's Performance section)."""
    from agents.bench import main_bench

    main_bench(args.quick, args.json, args.plots, args.only)
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for tests and docs)."""
    parser = argparse.ArgumentParser(
        prog="quadslam",
        description="Estimation-aware quadcopter control: DF-LQR baseline, RL training, "
        "evaluation and benchmarks on the QuadSLAM Gymnasium environments.",
    )
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--scenario", help="scenario name in configs/scenarios or a YAML path")
        p.add_argument(
            "--estimator",
            choices=["ekf_slam", "fastslam", "fastslam_kinematic", "oracle"],
            help="replace the scenario's estimator",
        )
        p.add_argument("--duration", type=_positive_float, help="episode length in s")
        p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
        p.add_argument("--json", type=Path, help="write results as JSON to this file")

    run = sub.add_parser(
        "run",
        help="fly the DF-LQR baseline (default: seed-001 figure-8, "
        "EKF-SLAM) and write paper-style figures",
    )
    common(run)
    run.add_argument("--seeds", type=_positive_int, default=1, help="number of seeds")
    run.add_argument("--plots", type=Path, help="figure folder (default: a new runs/ folder)")
    run.add_argument("--no-plots", action="store_true", help="skip the figures")
    run.set_defaults(func=cmd_run)

    ev = sub.add_parser("evaluate", help="evaluate dflqr or a trained model on an env id")
    common(ev)
    ev.add_argument("--policy", required=True, help="'dflqr', or a run folder / model .zip")
    ev.add_argument("--env", default="QuadSLAM-v0", help="env id (default QuadSLAM-v0)")
    ev.add_argument("--episodes", type=_positive_int, default=10, help="number of episodes")
    ev.add_argument("--plots", type=Path, help="write figures of the first episode here")
    ev.set_defaults(func=cmd_evaluate)
    bench = sub.add_parser("bench", help="measure env and estimator speed and scaling")
    bench.add_argument("--quick", action="store_true", help="small sizes, under a minute")
    bench.add_argument("--json", type=Path, help="write the measurements as JSON")
    bench.add_argument("--plots", type=Path, help="write scaling plots (PNG) here")
    bench.add_argument(
        "--only",
        nargs="+",
        choices=["ekf", "fastslam", "env", "vector"],
        help="run only these sections",
    )
    bench.set_defaults(func=cmd_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``quadslam`` console script."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (ValueError, TypeError, FileNotFoundError, KeyError) as exc:
        print(f"quadslam {args.command}: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
