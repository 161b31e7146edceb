"""The ``quadslam`` command line: ``run``, ``evaluate``, ``train``, ``convert-run``, ``study``,
``sweep``, ``bench``.

Bad input (unknown scenario, malformed YAML, wrong model file, bad numbers), a file system
that refuses a write and a full disk are reported in one line on stderr with exit status 2
(:func:`main`); a bug (``TypeError``, ``KeyError``, …) keeps its traceback. Ctrl-C ends a
command with status 130 and SIGTERM with 143, after ``train`` and ``sweep`` saved their work
and printed how to resume it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agents.lab.cli.arg_types import positive_float, positive_int
from agents.lab.cli.fly import add_fly_parsers
from agents.lab.cli.study import add_study_parser

# The filters multiply matrices of a few hundred rows: multithreaded BLAS only adds hand-off
# latency there (an EKF update took 7-24 ms with 2 threads vs 1 ms with 1 on 2 cores), and
# vectorised envs already use the cores. Set by main() before numpy is imported (nothing above
# imports it), not at import: importing this module changes no environment; users may override.
BLAS_THREAD_VARS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def cmd_scenarios(args: argparse.Namespace) -> int:
    """List the shipped scenarios with their one-line descriptions."""
    from quadslam_env.config.files import config_dir, scenario_descriptions

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
    from agents.lab.bench.runner import main_bench

    main_bench(args.quick, args.json, args.plots, args.only, started=getattr(args, "started", None))
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    """Train an SB3 agent with ``configs/agents/<algo>.yaml`` and print the run folder."""
    from agents.io.paths import check_output_dir
    from agents.io.signals import Terminated
    from agents.rl.hyperparams import parse_hyperparam_overrides
    from agents.rl.training import resume, train
    from quadslam_env.config.files import check_config_file

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
            backend=args.backend,
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


def cmd_convert_run(args: argparse.Namespace) -> int:
    """Write a run folder's weights and statistics as arrays, from its pickles (trusted)."""
    if not args.trust_pickle:
        raise ValueError(
            f"convert-run reads {args.run}'s SB3 zips and VecNormalize pickles, which run any "
            "code they hold: pass --trust-pickle if you trust who wrote the folder"
        )
    from agents.rl.convert import convert_run

    done = convert_run(args.run)
    for line in done.skipped:
        print(f"skipped {line}", file=sys.stderr)
    names = ", ".join(str(path.relative_to(args.run)) for path in done.written) or "nothing"
    print(f"{args.run}: wrote {names}" + ("; manifest.json rewritten" if done.manifest else ""))
    print(f"evaluate:   quadslam evaluate --policy {args.run}")
    return 0


def _add_convert_parser(sub: Any) -> None:
    """``quadslam convert-run``."""
    conv = sub.add_parser(
        "convert-run",
        help="give a run folder saved before policy.npz its weights and statistics as arrays "
        "(reads its pickles once: --trust-pickle)",
    )
    conv.add_argument("run", type=Path, metavar="RUN", help="the run folder")
    conv.add_argument(
        "--trust-pickle",
        action="store_true",
        help="confirm that you trust who wrote RUN: its model.zip and vecnormalize.pkl are "
        "unpickled, which runs any code they hold (required)",
    )
    conv.set_defaults(func=cmd_convert_run)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser (exposed for tests and docs)."""
    parser = argparse.ArgumentParser(
        prog="quadslam",
        description="Estimation-aware quadcopter control: DF-LQR baseline, RL training, "
        "evaluation and benchmarks on the QuadSLAM Gymnasium environments.",
    )
    parser.add_argument("--version", action=_VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)

    add_fly_parsers(sub)
    _add_train_parser(sub)
    _add_convert_parser(sub)
    add_study_parser(sub, positive_int, positive_float)
    from agents.lab.sweep.driver import add_sweep_parser  # light: Ray is imported when a sweep runs

    add_sweep_parser(sub, positive_int)
    scn = sub.add_parser("scenarios", help="list the shipped scenarios with their descriptions")
    scn.set_defaults(func=cmd_scenarios)
    _add_bench_parser(sub)
    return parser


def _add_train_parser(sub: Any) -> None:
    """``quadslam train``."""
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
    tr.add_argument("--timesteps", type=positive_int, help="override n_timesteps")
    tr.add_argument("--n-envs", type=positive_int, help="override n_envs")
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
        type=positive_int,
        help="torch threads while training (default 1: small networks; see agents.rl.training)",
    )
    tr.add_argument(
        "--backend",
        choices=["sb3", "sbx"],
        help="the learner: sb3 (torch) or sbx (JAX, PPO only; the sbx extra); default the "
        "config entry's backend, else sb3",
    )
    tr.add_argument("--no-progress", action="store_true", help="hide the progress bar")
    tr.add_argument("--verbose", type=int, default=0, choices=[0, 1, 2], help="SB3 verbosity")
    tr.set_defaults(func=cmd_train)


def _add_bench_parser(sub: Any) -> None:
    """``quadslam bench``."""
    from agents.lab.bench.runner import SECTION_NAMES as BENCH_SECTIONS  # light: no numpy

    bench = sub.add_parser("bench", help="measure env and estimator speed and scaling")
    bench.add_argument(
        "--quick",
        action="store_true",
        help="every section on fewer, smaller samples: 81 s measured on a 2-core Intel Xeon "
        "VM (load average 0.6-2), 38-48 s of it the first-use compile (target 20 s); budget "
        "60 s, which needs that compile near its target; ends with its wall times",
    )
    bench.add_argument("--json", type=Path, help="write the measurements as JSON")
    bench.add_argument("--plots", type=Path, help="write scaling plots (PNG) here")
    bench.add_argument(
        "--only",
        nargs="+",
        choices=BENCH_SECTIONS,
        help="run only these sections",
    )
    bench.set_defaults(func=cmd_bench)


#: What a command stopped by Ctrl-C or SIGTERM leaves behind (train and sweep say it
#: themselves, with the folder to resume).
_STOPPED_HINTS = {
    "study": "; finished training runs in its --out folder are reused when it is rerun",
}


def _user_error(exc: BaseException) -> bool:
    """An error of the input or the environment (one line, status 2), not a bug.

    The project's own errors are ``ValueError`` subclasses (``ConfigError``,
    ``OutputPathError``, ``SweepError``, …) or :class:`agents.io.outputs.DiskFullError`; the file
    system's are ``OSError``; Gymnasium's (an unknown or broken env id) derive from
    ``gymnasium.error.Error``. ``TypeError``, ``KeyError`` and the rest are bugs and keep their
    traceback.
    """
    from agents.io.outputs import DiskFullError

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
    started = time.perf_counter()  # wall times count from here (bench)
    for var in BLAS_THREAD_VARS:
        os.environ.setdefault(var, "1")
    from agents.io.signals import Terminated, sigterm_as_interrupt, sigterm_received
    from agents.lab.cli.warning_lines import one_line_warnings

    parser = build_parser()
    args, unknown = parser.parse_known_args(argv)
    if getattr(args, "analysis", None) is not None:
        args.options = unknown  # an analysis parses its own options (quadslam study soak …)
    elif unknown:
        parser.error(f"unrecognized arguments: {' '.join(unknown)}")
    args.started = started
    # A command may build EKF-SLAM envs: on a cold numba cache, compile its update in a second
    # process meanwhile (a library user asks for that explicitly).
    from estimators.ekf import warmup
    from quadslam_env.models.jit import announce_compilation

    warmup.enable()
    announce_compilation()  # a cold cache: one line saying why the first step takes a while
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
