"""``quadslam run`` and ``quadslam evaluate``: fly a policy on seeded episodes and report them.

Both go through one path (:func:`fly`): the env from the command's options
(:func:`make_env`), the output paths checked before anything flies, the episodes, the table,
``--json``, ``--plots`` and ``--video``.
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from tqdm import tqdm

from agents.control.named import CONTROLLERS, OPTIONS
from agents.io.overrides import parse_overrides
from agents.lab.cli.arg_types import positive_float, positive_int

RESULTS_FILE = "results.txt"
"""The results table, written into the figures' folder with the figures."""


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
    from quadslam_env.config.files import deep_merge

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
        agents.io.outputs.OutputPathError: One-line message naming the option and the path.
    """
    from agents.evaluation.video import check_video_path
    from agents.io.paths import check_output_dir, check_output_file
    from quadslam_env.extras import require

    if json_path is not None:
        check_output_file(json_path, "--json")
    if video is not None:
        check_video_path(video)  # what its file type needs, in one line
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
    """Fly ``policy`` for each seed with a progress bar, print the table, write JSON and the
    figures and video of the first seed's episode (the figures' line names that seed); with
    the figures, the table goes into their folder too (:data:`RESULTS_FILE`).

    The output paths are checked before the flight (:func:`check_outputs`); the files are
    written atomically, and one that cannot be written at the end is saved elsewhere
    (:class:`agents.io.outputs.Saver`).

    Raises:
        agents.io.outputs.OutputPathError: An output path cannot be written (before flying).
        agents.io.outputs.OutputWriteError: After every result was written somewhere, when a
            file could not be written where asked (the message says where it went).
    """
    from agents.evaluation.episodes import Trace, format_table, run_episodes, summarize
    from agents.evaluation.video import LaneVideo
    from agents.io.outputs import Saver

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
    table = format_table(episodes, summary)
    print(table)
    saver = Saver()
    if json_path is not None:  # the smallest and most precious file first
        print(f"json: {saver.write_json(json_path, result, '--json')}")
    if plots is not None and trace is not None:
        from agents.evaluation.plots import write_figures

        span = f"seed {seeds[0]}" if len(seeds) == 1 else f"seeds {seeds[0]}-{seeds[-1]}"
        head = f"{base.scenario.name} / {base.scenario.estimator.name} / {policy_name}, {span}"
        text = "\n".join((head, table, ""))
        print(f"table: {saver.write_text(plots / RESULTS_FILE, text, '--plots')}")
        files = write_figures(
            trace,
            plots,
            f"{base.scenario.name} / {base.scenario.estimator.name} / seed {seeds[0]}",
            saver,
        )
        of = f"seed {seeds[0]}" + (f" only, of {len(seeds)} seeds" if len(seeds) > 1 else "")
        print(f"figures: {files[0].parent if files else plots} ({len(files)} PNG, {of})")
    if recorder is not None:
        where = recorder.close(saver)
        print(f"video: {where} (seed {seeds[0]}, {recorder.frames} frames)")
    saver.check()
    return result


def cmd_run(args: argparse.Namespace) -> int:
    """Baseline-controller episodes (DF-LQR by default) on a scenario: the package's main job."""
    from agents.control.dflqr import DFLQRPolicy
    from agents.control.named import build_controller
    from agents.evaluation.episodes import check_episodes_memory
    from agents.io.paths import safe_name

    env = make_env("QuadSLAM-v0", args.scenario, args.estimator, args.duration, args.set)
    check_episodes_memory(env.unwrapped.scenario, args.seeds, "--seeds")  # before the seeds
    plots = args.plots
    if plots is None and not args.no_plots and importlib.util.find_spec("matplotlib") is not None:
        stamp = time.strftime("%Y%m%d-%H%M%S")
        # The scenario's name comes from its file: one safe folder name inside runs/.
        plots = Path("runs") / f"run-{stamp}-{safe_name(env.unwrapped.scenario.name)}"
    check_outputs(plots, args.json, args.video)
    if plots is None and not args.no_plots:  # after the checks: a refused output is one line
        print("quadslam run: no figures (matplotlib is not installed: pip install "
              "'quadslam[plots]')", file=sys.stderr)  # fmt: skip
    seeds = list(range(args.seed, args.seed + args.seeds))
    if args.integral_gain and args.policy != "dflqr":
        raise SystemExit(
            f"quadslam run: error: --integral-gain: only with --policy dflqr (got --policy "
            f"{args.policy}, whose integral action is its own)"
        )
    options = controller_options(args, "run")
    if args.policy == "dflqr":
        policy = DFLQRPolicy.from_env(env, integral_gain=args.integral_gain or 0.0)
    else:
        policy = build_controller(args.policy, env, **options)
    fly(env, policy, args.policy, seeds, plots, args.json, args.video)
    return 0


def cmd_evaluate(args: argparse.Namespace) -> int:
    """Any policy (a controller by name or a trained model) through the same code path as
    ``run``."""
    from agents.rl.policies import load_policy
    from agents.rl.saved.run_folder import run_config

    options = controller_options(args, "evaluate")  # before anything is read or built
    # A trained model is evaluated on its training env id and scenario unless told otherwise.
    named = args.policy in CONTROLLERS
    cfg = run_config(args.policy) if not named and Path(args.policy).exists() else None
    if cfg is not None and Path(args.policy).is_dir():
        _warn_unfinished(Path(args.policy))
    env_id = args.env or (cfg["env_id"] if cfg else "QuadSLAM-v0")
    # The run's resolved scenario (every section, env_kwargs overrides included) rebuilds the
    # training env without the scenario files; --scenario replaces it.
    scenario = args.scenario or (cfg.get("scenario") if cfg else None)
    if cfg and args.env and args.env != cfg["env_id"] and not args.scenario:
        # Another env id switches the estimator, whose settings the training scenario may not
        # hold (a run trained on the truth has none): they fall back to that estimator's
        # defaults, which can differ from the ones its own scenarios use (e.g. IMU-bias states).
        print(
            f"quadslam evaluate: note: flying the run's scenario with {args.env}'s estimator at "
            "the settings that scenario gives it (its defaults if none); pass --scenario or "
            "--set estimator.params.<key>=... to choose them",
            file=sys.stderr,
        )
    env = make_env(env_id, scenario, args.estimator, args.duration, args.set)
    if hasattr(env.unwrapped, "scenario"):  # a QuadSLAM env (another id has no scenario)
        from agents.evaluation.episodes import check_episodes_memory

        check_episodes_memory(env.unwrapped.scenario, args.episodes, "--episodes")
    check_outputs(args.plots, args.json, args.video)  # before loading and flying
    policy, name = load_policy(args.policy, env, trust_pickle=args.trust_pickle, options=options)
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


def add_fly_parsers(sub: Any) -> None:
    """The ``run`` and ``evaluate`` subcommands on the ``quadslam`` parser's ``sub``."""

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--scenario", help="scenario name in configs/scenarios or a YAML path")
        p.add_argument(
            "--estimator",
            metavar="NAME",
            help="replace the scenario's estimator: ekf_slam, fastslam, fastslam_kinematic, "
            "isam2 (extra gtsam), oracle or a registered plug-in",
        )
        p.add_argument("--duration", type=positive_float, help="episode length in s")
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
    run.add_argument(
        "--seeds",
        type=positive_int,
        default=1,
        help="number of seeds (the figures and --video show the first seed's episode)",
    )
    run.add_argument(
        "--policy",
        default="dflqr",
        choices=sorted(CONTROLLERS),
        help="the baseline controller: dflqr (the paper's DF-LQR, default), lqi (DF-LQR "
        "with integral action in the Riccati design) or se3 (geometric SE(3) tracking with "
        "integral action)",
    )
    run.add_argument("--plots", type=Path, help="figure folder (default: a new runs/ folder)")
    run.add_argument("--no-plots", action="store_true", help="skip the figures")
    _controller_options(run)
    run.set_defaults(func=cmd_run)

    ev = sub.add_parser("evaluate", help="evaluate dflqr or a trained model on an env id")
    common(ev)
    ev.add_argument(
        "--policy",
        required=True,
        help=f"a controller ({', '.join(sorted(CONTROLLERS))}), or a run folder / model .zip",
    )
    ev.add_argument(
        "--env", help="env id (default: the model's training env, or QuadSLAM-v0 for a controller)"
    )
    ev.add_argument("--episodes", type=positive_int, default=10, help="number of episodes")
    ev.add_argument("--plots", type=Path, help="write figures of the first episode here")
    ev.add_argument(
        "--trust-pickle",
        action="store_true",
        help="read SB3's model.zip and vecnormalize.pkl when the run has no policy.npz (a run "
        "saved before it, or a bare .zip): unpickling runs any code the files hold, so only "
        "for files you trust (quadslam convert-run converts a run once)",
    )
    add_controller_flags(ev)
    ev.set_defaults(func=cmd_evaluate)


def _controller_options(run: argparse.ArgumentParser) -> None:
    """``quadslam run``'s options of the named controllers."""
    run.add_argument(
        "--integral-gain",
        type=positive_float,
        metavar="K_I",
        help="DF-LQR integral action on the position error, k_i in s^-3 (default off; "
        "e.g. 0.02; must stay below the loop's stability bound, 0.11 with the shipped weights)",
    )
    add_controller_flags(run)


def add_controller_flags(parser: argparse.ArgumentParser) -> None:
    """``--drag-feedforward`` and ``--thrust-adaptation`` on ``parser``: the controller options
    of :data:`agents.control.named.OPTIONS`, read back by :func:`controller_options`."""
    parser.add_argument(
        "--drag-feedforward",
        action="store_true",
        help="lqi and se3: add the drag the vehicle's model predicts on the estimated "
        "air-relative velocity to the commanded acceleration (default off); needs --set "
        "observation.air_velocity=true and an estimator that estimates the wind (ekf_slam "
        "with estimator.params.wind: estimate, as in ekf_figure8_wind_states)",
    )
    parser.add_argument(
        "--thrust-adaptation",
        action="store_true",
        help="lqi and se3: scale the reference acceleration (the feed-forward) by the thrust "
        "ratio (true over nominal mass, per unit thrust) that the vertical integral measures "
        "(default off)",
    )


def controller_options(args: argparse.Namespace, command: str) -> dict[str, Any]:
    """The keyword arguments of the controller options that ``args`` turns on
    (:func:`add_controller_flags`), for
    :func:`agents.control.named.build_controller` (``drag_feedforward=True``, …).

    Args:
        args: The parsed options of ``quadslam run`` or ``quadslam evaluate`` (``policy``
            and the flags).
        command: The command's name, for the error.

    Raises:
        SystemExit: A flag given with a ``--policy`` that does not take it (a controller
            without the option, or a trained model), one line naming the flag.
    """
    options: dict[str, Any] = {}
    for option, (names, _) in OPTIONS.items():
        if getattr(args, option):
            if args.policy not in names:
                raise SystemExit(
                    f"quadslam {command}: error: --{option.replace('_', '-')}: only with "
                    f"--policy {' or '.join(names)} (got --policy {args.policy})"
                )
            options[option] = True
    return options
