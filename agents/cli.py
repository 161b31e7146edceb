"""The ``quadslam`` command line: ``run``, ``evaluate``, ``train``, ``study``, ``sweep``, ``bench``.

Bad input (unknown scenario, malformed YAML, wrong model file, bad numbers), a file system
that refuses a write and a full disk are reported in one line on stderr with exit status 2
(:func:`main`); a bug (``TypeError``, ``KeyError``, …) keeps its traceback. Ctrl-C ends a
command with status 130 and SIGTERM with 143, after ``train`` and ``sweep`` saved their work
and printed how to resume it.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from agents.cli_study import add_study_parser

# The filters multiply matrices of a few hundred rows: multithreaded BLAS only adds hand-off
# latency there (an EKF update took 7-24 ms with 2 threads vs 1 ms with 1 on 2 cores), and
# vectorised envs already use the cores. Set by main() before numpy is imported (nothing above
# imports it), not at import: importing this module changes no environment; users may override.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


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


def parse_overrides(items: Sequence[str]) -> dict[str, Any]:
    """Turn ``["episode.duration_s=20", "imu.preset=ideal"]`` into nested override mappings.

    Values are parsed as YAML (numbers, booleans, lists); keys are ``section.key[.key...]``.
    A key given twice (or a YAML value that repeats a key) is an error, not "last one wins".
    """
    import yaml

    from quadslam_env.config import parse_yaml

    out: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        parts = key.split(".")
        if not sep or len(parts) < 2 or not all(parts):
            raise ValueError(
                f"--set: got {item!r}; allowed: section.key=value, e.g. episode.duration_s=20"
            )
        try:
            value = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"--set {key}: value {text!r} is not valid YAML ({exc})") from exc
        node = out
        for part in parts[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"--set: {key!r} conflicts with another --set")
        if parts[-1] in node:
            raise ValueError(f"--set {key}: given twice; allowed: each key once")
        node[parts[-1]] = value
    return out


def make_env(
    env_id: str,
    scenario: str | dict[str, Any] | None,
    estimator: str | None,
    duration: float | None,
    overrides: Sequence[str] = (),
) -> Any:
    """``gymnasium.make`` with the CLI's scenario / estimator / duration / ``--set`` choices."""
    import gymnasium as gym

    import quadslam_env  # registers the ids
    from quadslam_env.config import deep_merge

    kwargs: dict[str, Any] = parse_overrides(overrides)
    if scenario is not None:
        kwargs["scenario"] = scenario
    if estimator is not None:
        kwargs["estimator_name"] = estimator
    if duration is not None:
        kwargs = deep_merge(kwargs, {"episode": {"duration_s": duration}})
    if env_id not in gym.registry:
        raise ValueError(
            f"--env: got {env_id!r}; allowed: one of {list(quadslam_env.ENV_IDS)} "
            "or another registered Gymnasium id"
        )
    return gym.make(env_id, **kwargs)


def check_outputs(plots: Path | None, json_path: Path | None, video: Path | None) -> None:
    """Check every output path of ``run``/``evaluate`` before anything is flown.

    Raises:
        agents.outputs.OutputPathError: One-line message naming the option and the path.
    """
    from agents.outputs import check_output_dir, check_output_file
    from agents.video import check_video_path
    from quadslam_env.extras import require

    if json_path is not None:
        check_output_file(json_path, "--json")
    if video is not None:
        require("matplotlib", "plots", "--video")
        check_video_path(video)
    if plots is not None:
        require("matplotlib", "plots", "--plots")
        check_output_dir(plots, "--plots")


def fly(
    env: Any,
    policy: Any,
    policy_name: str,
    seeds: Sequence[int],
    plots: Path | None,
    json_path: Path | None,
    video: Path | None = None,
) -> dict[str, Any]:
    """Fly ``policy`` for each seed with a progress bar, print the table, write JSON/plots
    (and a video of the first seed's episode).

    The output paths are checked before the flight (:func:`check_outputs`); the files are
    written atomically, and one that cannot be written at the end is saved elsewhere
    (:class:`agents.outputs.Saver`).

    Raises:
        agents.outputs.OutputPathError: An output path cannot be written (before flying).
        agents.outputs.OutputWriteError: After every result was written somewhere, when a
            file could not be written where asked (the message says where it went).
    """
    from agents.evaluation import Trace, format_table, run_episodes, summarize
    from agents.outputs import Saver
    from agents.video import LaneVideo

    check_outputs(plots, json_path, video)
    recorder = None if video is None else LaneVideo(video)
    base = env.unwrapped
    total = base.max_steps * len(seeds)
    trace = Trace() if plots is not None else None
    with tqdm(
        total=total,
        unit="step",
        desc=f"{base.scenario.name} × {len(seeds)} seed(s)",
        file=sys.stderr,
        mininterval=0.5,
    ) as bar:
        # The episodes run as lanes of the native vector env (same numbers as one by one).
        episodes = run_episodes(env, policy, seeds, trace=trace, on_step=bar.update, video=recorder)
    summary = summarize(episodes)
    result = {
        "scenario": base.scenario.name,
        "estimator": base.scenario.estimator.name,
        "policy": policy_name,
        "episodes": episodes,
        "summary": summary,
    }
    print(format_table(episodes, summary))
    saver = Saver()
    if json_path is not None:  # the smallest and most precious file first
        print(f"json: {saver.write_json(json_path, result, '--json')}")
    if plots is not None and trace is not None:
        from agents.plots import write_figures

        files = write_figures(
            trace,
            plots,
            f"{base.scenario.name} / {base.scenario.estimator.name} / seed {seeds[0]}",
            saver,
        )
        print(f"figures: {files[0].parent if files else plots} ({len(files)} PNG)")
    if recorder is not None:
        where = recorder.close(saver)
        print(f"video: {where} (seed {seeds[0]}, {recorder.frames} frames)")
    saver.check()
    return result


def cmd_run(args: argparse.Namespace) -> int:
    """DF-LQR episodes on a scenario: the package's main job."""
    from agents.dflqr import DFLQRPolicy
    from agents.outputs import safe_name

    env = make_env("QuadSLAM-v0", args.scenario, args.estimator, args.duration, args.set)
    plots = args.plots
    if plots is None and not args.no_plots and importlib.util.find_spec("matplotlib") is None:
        print("quadslam run: no figures (matplotlib is not installed: pip install "
              "'quadslam[plots]')", file=sys.stderr)  # fmt: skip
    elif plots is None and not args.no_plots:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        # The scenario's name comes from its file: one safe folder name inside runs/.
        plots = Path("runs") / f"run-{stamp}-{safe_name(env.unwrapped.scenario.name)}"
    check_outputs(plots, args.json, args.video)
    seeds = list(range(args.seed, args.seed + args.seeds))
    fly(env, DFLQRPolicy.from_env(env), "dflqr", seeds, plots, args.json, args.video)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Any policy (``dflqr`` or a trained model) through the same code path as ``run``."""
    from agents.policies import load_policy
    from agents.run_folder import run_config

    # A trained model is evaluated on its training env id and scenario unless told otherwise.
    cfg = run_config(args.policy) if args.policy != "dflqr" and Path(args.policy).exists() else None
    if cfg is not None and Path(args.policy).is_dir():
        _warn_unfinished(Path(args.policy))
    env_id = args.env or (cfg["env_id"] if cfg else "QuadSLAM-v0")
    # The run's resolved scenario (every section, env_kwargs overrides included) rebuilds the
    # training env without the scenario files; --scenario replaces it.
    scenario = args.scenario or (cfg.get("scenario") if cfg else None)
    env = make_env(env_id, scenario, args.estimator, args.duration, args.set)
    check_outputs(args.plots, args.json, args.video)  # before loading and flying
    policy, name = load_policy(args.policy, env)
    seeds = list(range(args.seed, args.seed + args.episodes))
    fly(env, policy, name, seeds, args.plots, args.json, args.video)
    return 0


def _warn_unfinished(run_dir: Path) -> None:
    """One warning line when a run folder's training did not finish (its model is partial)."""
    marker = run_dir / "INTERRUPTED"
    if marker.is_file() or not (run_dir / "timing.json").is_file():
        at = marker.read_text().strip() if marker.is_file() else ""
        where = f" at {at} steps" if at.isdigit() else ""
        print(
            f"quadslam evaluate: warning: {run_dir} did not finish training{where}; "
            f"resume it with: quadslam train --resume {run_dir}",
            file=sys.stderr,
        )


def cmd_scenarios(args: argparse.Namespace) -> int:
    """List the shipped scenarios with their one-line descriptions."""
    from quadslam_env.config_files import config_dir, scenario_descriptions

    rows = scenario_descriptions()
    width = max((len(name) for name in rows), default=0)
    for name, text in rows.items():
        print(f"{name:<{width}}  {text}".rstrip())
    print(f"({len(rows)} scenarios in {config_dir() / 'scenarios'})")
    return 0


class _VersionAction(argparse.Action):
    """``--version``: print the package version (imported only when asked for)."""

    def __init__(self, option_strings: Sequence[str], dest: str, **kwargs: Any) -> None:
        super().__init__(option_strings, dest, nargs=0, help="print the version and exit")

    def __call__(self, parser: argparse.ArgumentParser, *args: Any, **kwargs: Any) -> None:
        from quadslam_env._version import __version__

        print(f"quadslam {__version__}")
        parser.exit()


def cmd_bench(args: argparse.Namespace) -> int:
    """Speed and scaling benchmark (the figures of docs/performance.md)."""
    from agents.bench import main_bench

    main_bench(args.quick, args.json, args.plots, args.only)
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train an SB3 agent with ``configs/agents/<algo>.yaml`` and print the run folder."""
    from agents.hyperparams import parse_hyperparam_overrides
    from agents.outputs import Terminated, check_output_dir
    from agents.training import resume, train
    from quadslam_env.config_files import check_config_file

    try:
        if args.resume is not None:
            run_dir = resume(
                args.resume,
                progress=not args.no_progress,
                verbose=args.verbose,
                torch_threads=args.torch_threads,
            )
            return _report_run(run_dir)
        if args.algo is None:
            raise ValueError("--algo: required (one of ppo, sac, td3, a2c) unless --resume RUN")
        if args.config is not None:
            check_config_file(args.config, "--config")  # before an unbounded read
        check_output_dir(args.out or Path("runs"), "--out")
        run_dir = train(
            args.algo,
            args.env,
            config_path=args.config,
            timesteps=args.timesteps,
            n_envs=args.n_envs,
            seed=args.seed,
            out_dir=args.out,
            progress=not args.no_progress,
            hyperparams=parse_hyperparam_overrides(args.hyperparams),
            verbose=args.verbose,
            torch_threads=args.torch_threads,
        )
    except Terminated as exc:  # SIGTERM: the run folder was saved first
        if exc.run_dir is None:
            raise
        return _report_run(exc.run_dir, status=143)
    return _report_run(run_dir)


def _report_run(run_dir: Path, status: int = 130) -> int:
    """Print a finished run folder with its wall clock (status 0), or an interrupted one with
    how to resume it (``status``: 130 after Ctrl-C, 143 after SIGTERM)."""
    import json

    marker = run_dir / "INTERRUPTED"
    if marker.exists():
        at = marker.read_text().strip()
        steps = f" at {int(at):,} steps" if at.isdigit() else ""
        print(
            f"run folder: {run_dir} (partial: interrupted{steps}, model saved); resume with: "
            f"quadslam train --resume {run_dir}",
            file=sys.stderr,
        )
        return status  # the shell's status for the signal, so scripts see it did not finish
    timing = json.loads((run_dir / "timing.json").read_text())
    print(f"run folder: {run_dir}")
    print(
        f"wall clock: {timing['wall_s']:.1f} s ({timing['timesteps']:,} env steps, "
        f"{timing['steps_per_s']:,.0f} steps/s while learning)"
    )
    print(f"evaluate:   quadslam evaluate --policy {run_dir} --episodes 20 --seed 1000")
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for tests and docs)."""
    parser = argparse.ArgumentParser(
        prog="quadslam",
        description="Estimation-aware quadcopter control: DF-LQR baseline, RL training, "
        "evaluation and benchmarks on the QuadSLAM Gymnasium environments.",
    )
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--scenario", help="scenario name in configs/scenarios or a YAML path")
        p.add_argument(
            "--estimator",
            metavar="NAME",
            help="replace the scenario's estimator: ekf_slam, fastslam, fastslam_kinematic, "
            "isam2 (extra gtsam), oracle or a registered plug-in",
        )
        p.add_argument("--duration", type=_positive_float, help="episode length in s")
        p.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
        p.add_argument("--json", type=Path, help="write results as JSON to this file")
        p.add_argument(
            "--video",
            type=Path,
            metavar="FILE",
            help="record the first seed's episode (.mp4 or .gif)",
        )
        p.add_argument(
            "--set",
            action="append",
            default=[],
            metavar="SECTION.KEY=VALUE",
            help="override a scenario setting (repeatable), e.g. "
            "--set estimator.sample_initial_error=false",
        )

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
    ev.add_argument(
        "--env", help="env id (default: the model's training env, or QuadSLAM-v0 for dflqr)"
    )
    ev.add_argument("--episodes", type=_positive_int, default=10, help="number of episodes")
    ev.add_argument("--plots", type=Path, help="write figures of the first episode here")
    ev.set_defaults(func=cmd_evaluate)

    tr = sub.add_parser(
        "train",
        help="train a stable-baselines3 agent (hyperparameters from configs/agents/<algo>.yaml)",
    )
    tr.add_argument("--algo", choices=["ppo", "sac", "td3", "a2c"])
    tr.add_argument(
        "--resume",
        type=Path,
        metavar="RUN",
        help="continue a run folder from its latest checkpoint (or interrupted model) to its "
        "n_timesteps; other options are taken from the run",
    )
    tr.add_argument(
        "--env", default="QuadSLAM-EKF-v0", help="env id and config key (default QuadSLAM-EKF-v0)"
    )
    tr.add_argument(
        "--config",
        type=Path,
        help="hyperparameter YAML (default configs/agents/<algo>.yaml) or a run's config.yaml",
    )
    tr.add_argument("--timesteps", type=_positive_int, help="override n_timesteps")
    tr.add_argument("--n-envs", type=_positive_int, help="override n_envs")
    tr.add_argument("--seed", type=int, default=0, help="seed (default 0)")
    tr.add_argument("--out", type=Path, help="parent folder of the run folder (default runs/)")
    tr.add_argument(
        "--hyperparams",
        nargs="+",
        metavar="KEY=VALUE",
        help="override config entries, e.g. learning_rate=1e-4 env_kwargs.episode.duration_s=10",
    )
    tr.add_argument(
        "--torch-threads",
        type=_positive_int,
        help="torch threads while training (default 1: small networks; see agents.training)",
    )
    tr.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    tr.add_argument("--verbose", type=int, default=0, choices=[0, 1, 2], help="SB3 verbosity")
    tr.set_defaults(func=cmd_train)
    add_study_parser(sub, _positive_int, _positive_float)
    from agents.sweep import add_sweep_parser  # light: Ray is imported when a sweep runs

    add_sweep_parser(sub, _positive_int)
    scn = sub.add_parser("scenarios", help="list the shipped scenarios with their descriptions")
    scn.set_defaults(func=cmd_scenarios)
    from agents.bench import SECTION_NAMES as BENCH_SECTIONS  # light: no numpy

    bench = sub.add_parser("bench", help="measure env and estimator speed and scaling")
    bench.add_argument("--quick", action="store_true", help="small sizes, about a minute")
    bench.add_argument("--json", type=Path, help="write the measurements as JSON")
    bench.add_argument("--plots", type=Path, help="write scaling plots (PNG) here")
    bench.add_argument(
        "--only",
        nargs="+",
        choices=BENCH_SECTIONS,
        help="run only these sections",
    )
    bench.set_defaults(func=cmd_bench)
    return parser


#: What a command stopped by Ctrl-C or SIGTERM leaves behind (train and sweep say it
#: themselves, with the folder to resume).
_STOPPED_HINTS = {
    "study": "; finished training runs in its --out folder are reused when it is rerun",
}


def _user_error(exc: BaseException) -> bool:
    """An error of the input or the environment (one line, status 2), not a bug.

    The project's own errors are ``ValueError`` subclasses (``ConfigError``,
    ``OutputPathError``, ``SweepError``, …) or :class:`agents.outputs.DiskFullError`; the file
    system's are ``OSError``; Gymnasium's (an unknown or broken env id) derive from
    ``gymnasium.error.Error``. ``TypeError``, ``KeyError`` and the rest are bugs and keep their
    traceback.
    """
    from agents.outputs import DiskFullError

    if isinstance(exc, ValueError | OSError | DiskFullError):
        return True
    gym_error = sys.modules.get("gymnasium.error")  # not imported: cannot be one of its errors
    return gym_error is not None and isinstance(exc, gym_error.Error)


def _message(exc: BaseException) -> str:
    """The error on one line; an ``OSError`` as its reason and file, without ``[Errno N]``."""
    if isinstance(exc, OSError) and exc.strerror:
        text = exc.strerror
        if exc.filename is not None:
            text += f": {str(exc.filename)!r}"
        if exc.filename2 is not None:
            text += f" -> {str(exc.filename2)!r}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())  # one line, even for multi-line YAML errors


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``quadslam`` console script.

    Returns:
        The command's status; 2 after a one-line error (see :func:`_user_error`), 130 after
        Ctrl-C and 143 after SIGTERM (``train`` and ``sweep`` save their work first).
    """
    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")
    from agents.cli_warnings import one_line_warnings
    from agents.outputs import Terminated, sigterm_as_interrupt, sigterm_received

    parser = build_parser()
    args = parser.parse_args(argv)
    # A command may build EKF-SLAM envs: on a cold numba cache, compile its update in a second
    # process meanwhile (a library user asks for that explicitly).
    from estimators.ekf import warmup

    warmup.enable()
    try:
        with sigterm_as_interrupt(), one_line_warnings(args.command):
            code = int(args.func(args))
    except KeyboardInterrupt as exc:
        terminated = isinstance(exc, Terminated)
        what = "terminated (SIGTERM)" if terminated else "interrupted"
        # Only the studies that keep training runs (they have --out) reuse anything.
        hint = _STOPPED_HINTS.get(args.command, "") if hasattr(args, "out") else ""
        print(f"quadslam {args.command}: {what}{hint}", file=sys.stderr)
        return 143 if terminated else 130
    except Exception as exc:
        if not _user_error(exc):
            raise
        print(f"quadslam {args.command}: error: {_message(exc)}", file=sys.stderr)
        return 2
    # A command that saved its work after SIGTERM returns Ctrl-C's 130: the shell's status
    # for SIGTERM is 143.
    return 143 if code == 130 and sigterm_received() else code


if __name__ == "__main__":
    sys.exit(main())
