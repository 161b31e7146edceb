"""``quadslam study …``: the studies' subcommands (cost of estimation, active perception,
robustness, data association, integrity, Cramér–Rao bound, the estimators against the bound) and
the
writing of their ``--json``/``--plots`` outputs."""

from __future__ import annotations

import argparse
import itertools
import os
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any


def cmd_study_cost(args: argparse.Namespace) -> int:
    """Train and evaluate the cost-of-estimation configurations; print the table."""
    from agents.lab.control_studies import cost as study_cost

    return _training_study(args, study_cost, "study_cost", "cost_of_estimation.png")


def cmd_study_active(args: argparse.Namespace) -> int:
    """Fixed, tangent and look-at headings and residual PPO with the heading channel."""
    from agents.lab.control_studies import active as study_active

    return _training_study(args, study_active, "study_active", "active_perception.png")


def cmd_study_integrity_task(args: argparse.Namespace) -> int:
    """The active-perception study on the integrity-aware task: availability per heading."""
    from agents.lab.control_studies import integrity_task

    return _training_study(args, integrity_task, "study_integrity_task", "integrity_task.png")


def cmd_study_robustness(args: argparse.Namespace) -> int:
    """DF-LQR, LQI, SE(3) and residual PPO on the LQI, each on the Oracle and every
    estimator, under nominal, randomised and windy physics."""
    from agents.lab.control_studies import robustness as study_robustness

    return _training_study(
        args,
        study_robustness,
        "study_robustness",
        "robustness.png",
        rows=args.rows,
        estimators=args.estimators,
    )


def _training_study(
    args: argparse.Namespace, study: Any, folder: str, png: str, **extra: Any
) -> int:
    """Run a study that trains agents (its module's ``run_study``, given ``extra`` keyword
    arguments, ``format_study``, ``write_json``, ``plot_study``): check every output path
    before the first training, print the table and the wall clock, write ``--json`` and
    ``--plots`` (``png``)."""
    from agents.io.paths import check_output_dir, check_output_file

    out = args.out or Path("runs") / f"{folder}{'_quick' if args.quick else ''}"
    check_output_dir(out, "--out")
    if args.json is not None:
        check_output_file(args.json, "--json")
    if args.plots is not None:
        check_output_dir(args.plots, "--plots")
    result = study.run_study(
        out,
        args.quick,
        args.training_seeds,
        args.episodes,
        args.timesteps,
        jobs=args.jobs,
        first_training_seed=args.first_training_seed,
        **extra,
    )
    print(study.format_study(result))
    settings = result["settings"]
    print(
        f"wall clock: {settings['wall_s'] / 60:.1f} min ({settings['jobs']} training job(s) at "
        f"a time); training runs in {out}"
    )
    return _save_study(args, result, study.write_json, study.plot_study, png)


def _save_study(
    args: argparse.Namespace, result: dict[str, Any], write_json: Any, plot: Any, png: str
) -> int:
    """Write a study's ``--json`` and ``--plots`` outputs (a failed write is saved elsewhere
    and reported by :meth:`Saver.check`)."""
    from agents.io.outputs import Saver

    saver = Saver()
    if args.json is not None:
        where = saver.produce(args.json, "--json", lambda target: write_json(result, target))
        print(f"wrote {where}")
    if args.plots is not None:
        where = saver.produce(
            args.plots / png, "--plots", lambda target: _plot_to(plot, result, target)
        )
        print(f"wrote {where}")
    saver.check()
    return 0


def _flown_study(
    args: argparse.Namespace, study: Any, png: str, run: Callable[[int], dict[str, Any]]
) -> int:
    """Run a study that flies episodes without training (``run(seeds)``, its module's
    ``format_study``, ``write_json``, ``plot_study``): check the output paths first, print the
    table and the wall clock, write ``--json`` and ``--plots`` (``png``)."""
    from agents.io.paths import check_output_dir, check_output_file

    if args.json is not None:
        check_output_file(args.json, "--json")
    if args.plots is not None:
        check_output_dir(args.plots, "--plots")
    tic = time.perf_counter()
    result = run(args.seeds or (3 if args.quick else 20))
    result["settings"]["wall_s"] = round(time.perf_counter() - tic, 1)
    print(study.format_study(result))
    print(f"wall clock: {result['settings']['wall_s'] / 60:.1f} min")
    return _save_study(args, result, study.write_json, study.plot_study, png)


def cmd_study_association(args: argparse.Namespace) -> int:
    """Known vs NN vs JCBB (EKF) and known vs ML (FastSLAM), and the clutter sweep."""
    from agents.lab.estimator_studies import association

    def run(seeds: int) -> dict[str, Any]:
        return association.run_study(seeds, args.quick)

    return _flown_study(args, association, "association_clutter.png", run)


def cmd_study_integrity(args: argparse.Namespace) -> int:
    """The integrity monitor against each fault kind: detection, protection levels, errors."""
    from agents.io.cpus import available_cpus
    from agents.lab.estimator_studies import integrity

    def run(seeds: int) -> dict[str, Any]:
        jobs = args.jobs or available_cpus()
        return integrity.run_study(seeds, args.seed, args.quick, args.free_seeds, jobs)

    return _flown_study(args, integrity, "integrity_stanford.png", run)


def cmd_study_cooperative(args: argparse.Namespace) -> int:
    """Teams of 1, 2 and 4 vehicles: map fusion modes, team map RMSE and consistency."""
    from agents.io.cpus import available_cpus
    from agents.lab.estimator_studies import cooperative

    def run(seeds: int) -> dict[str, Any]:
        return cooperative.run_study(seeds, args.seed, args.quick, args.jobs or available_cpus())

    return _flown_study(args, cooperative, "cooperative_map.png", run)


ANALYSES = {
    "degradation": ("degradation", "how EKF-SLAM's error grows and recovers over long gaps "
                    "without landmarks (the 600 s out-of-view scenarios)"),
    "imu-instants": ("imu_instants", "a slow IMU: the filter at its own instants against the "
                     "control rate's output"),
    "particle-nees": ("particle_nees", "FastSLAM's NEES against its particle count"),
    "soak": ("soak", "a long flight (an hour by default): finite, symmetric, bounded, healthy"),
}  # fmt: skip
"""The analyses of ``quadslam study``: CLI name → (module of :mod:`agents.lab.estimator_studies`,
help); each parses its own options (``quadslam study NAME --help``)."""


def cmd_study_analysis(args: argparse.Namespace) -> int:
    """Run the analysis ``args.analysis`` with the options after its name."""
    import importlib

    module = importlib.import_module(f"agents.lab.estimator_studies.{ANALYSES[args.analysis][0]}")
    return int(module.main(args.options))


def cmd_study_bound(args: argparse.Namespace) -> int:
    """The posterior Cramér–Rao bound of a scenario next to its estimator's errors."""
    from agents.lab.estimator_studies.bound_report import cli_bound

    return cli_bound(args)


def cmd_study_estimators(args: argparse.Namespace) -> int:
    """EKF-SLAM, FastSLAM and iSAM2 against the Cramér–Rao bound on the paper scenarios."""
    from agents.lab.estimator_studies.estimators import cli_estimators

    return cli_estimators(args)


def _plot_to(plot: Any, result: dict[str, Any], target: Path) -> None:
    """Call ``plot(result, folder)`` (which writes one PNG into ``folder``) so that the PNG
    ends up at ``target`` (a temporary folder beside it holds the PNG until it is moved)."""
    import shutil
    import tempfile

    folder = Path(tempfile.mkdtemp(prefix=".plot-", dir=target.parent))
    try:
        os.replace(plot(result, folder), target)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def _subset(text: str, allowed: Sequence[str]) -> list[str]:
    """Comma-separated names from ``allowed``."""
    names = [name.strip() for name in text.split(",") if name.strip()]
    if not names or any(name not in allowed for name in names):
        raise argparse.ArgumentTypeError(
            f"got {text!r}; allowed: a comma-separated subset of {','.join(allowed)}"
        )
    return names


def _robustness_rows(text: str) -> list[str]:
    """``--rows`` of the robustness study: comma-separated names from its ``ROWS``."""
    from agents.lab.control_studies.robustness import ROWS

    return _subset(text, ROWS)


def _robustness_estimators(text: str) -> list[str]:
    """``--estimators`` of the robustness study: names from its ``ESTIMATORS``."""
    from agents.lab.control_studies.robustness import ESTIMATORS

    return _subset(text, ESTIMATORS)


def _first_seed(text: str) -> int:
    """``--first-training-seed``: an integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        value = -1
    if value < 0:
        raise argparse.ArgumentTypeError(f"got {text!r}; allowed: an integer >= 0")
    return value


def _flown_study_args(
    parser: argparse.ArgumentParser,
    positive_int: Callable[[str], int],
    quick_help: str,
    plots_help: str,
    seeds_help: str = "episodes per row (default 20)",
) -> None:
    """The options :func:`_flown_study` reads: ``--quick``, ``--seeds``, ``--json``, ``--plots``."""
    parser.add_argument("--quick", action="store_true", help=quick_help)
    parser.add_argument("--seeds", type=positive_int, help=seeds_help)
    parser.add_argument("--json", type=Path, help="write the table and episodes as JSON")
    parser.add_argument("--plots", type=Path, help=plots_help)


def _training_study_args(
    parser: argparse.ArgumentParser,
    positive_int: Callable[[str], int],
    default_seeds: int,
    plots_help: str,
) -> None:
    """The options of a study that trains agents: budget, seeds, episodes, parallel trainings
    and outputs."""
    parser.add_argument("--quick", action="store_true", help="1 training seed, small budget")
    parser.add_argument(
        "--training-seeds", type=positive_int, help=f"default {default_seeds} (quick: 1)"
    )
    parser.add_argument(
        "--first-training-seed",
        type=_first_seed,
        default=0,
        help="the training seeds are this one on (default 0): for the final table, seeds no "
        "design choice was made on",
    )
    parser.add_argument("--episodes", type=positive_int, help="held-out episodes (20; quick 5)")
    parser.add_argument(
        "--timesteps",
        type=positive_int,
        help="training budget per run (default: the ppo.yaml entry's; quick: a small one); "
        "finished runs in --out are reused whatever their budget: give another --out for "
        "another budget",
    )
    parser.add_argument(
        "--jobs",
        type=positive_int,
        help="trainings at a time, each in its own process (default: the CPU cores available; "
        "1: one after the other in this process); the results do not depend on it",
    )
    parser.add_argument("--out", type=Path, help="training runs folder (reused when rerun)")
    parser.add_argument("--json", type=Path, help="write the table and episodes as JSON")
    parser.add_argument("--plots", type=Path, help=plots_help)


def add_study_parser(
    sub: Any, positive_int: Callable[[str], int], positive_float: Callable[[str], float]
) -> None:
    """Add ``quadslam study`` and its subcommands to the CLI's subparsers ``sub``."""
    study = sub.add_parser("study", help="studies that train and evaluate several agents")
    studies = study.add_subparsers(dest="study", required=True)
    cost = studies.add_parser(
        "cost-of-estimation",
        help="DF-LQR and residual PPO on truth vs EKF-SLAM vs FastSLAM, privileged critic, "
        "uncertainty-aware observation (held-out seeds)",
    )
    _training_study_args(cost, positive_int, 5, "write the box plot (PNG) here")
    cost.set_defaults(func=cmd_study_cost)
    active = studies.add_parser(
        "active-perception",
        help="where to look: DF-LQR with a fixed or tangent heading, the look-at heuristic "
        "and residual PPO with a heading channel (held-out seeds)",
    )
    _training_study_args(active, positive_int, 5, "write the where-it-looks figure (PNG) here")
    active.set_defaults(func=cmd_study_active)
    robust = studies.add_parser(
        "robustness",
        help="DF-LQR, LQI, SE(3) and residual PPO on the LQI, on the Oracle and on each "
        "estimator, under nominal, randomised and windy physics (held-out seeds)",
    )
    _training_study_args(robust, positive_int, 5, "write the figure (PNG) here")
    robust.add_argument(
        "--rows",
        type=_robustness_rows,
        help="comma-separated rows to fly (default all: dflqr,lqi,lqi_adapt,se3,ppo_lqi); "
        "ppo_lqi is trained only when listed",
    )
    robust.add_argument(
        "--estimators",
        type=_robustness_estimators,
        help="comma-separated estimators to fly on (default all that can run here: oracle,"
        "ekf_thrust_axis,ekf_full,ekf_wind,isam2; ekf_wind flies the windy conditions only, "
        "isam2 needs the gtsam extra)",
    )
    robust.set_defaults(func=cmd_study_robustness)
    assoc = studies.add_parser(
        "association",
        help="unknown data association: known vs NN vs JCBB (EKF-SLAM), known vs ML "
        "(FastSLAM), a held-out closely spaced map, and RMSE/wrong rate against clutter",
    )
    _flown_study_args(assoc, positive_int, "3 seeds of 10 s, 3 clutter rates",
                      "write the clutter figure (PNG) here")  # fmt: skip
    assoc.set_defaults(func=cmd_study_association)
    _add_integrity_parser(studies, positive_int)
    bound = studies.add_parser(
        "bound",
        help="posterior Cramér–Rao bound along each seed's true trajectory vs the "
        "scenario's estimator (position, velocity, attitude)",
    )
    bound.add_argument("--scenario", default="paper_ekf_figure8", help="scenario name or path")
    bound.add_argument("--seeds", type=positive_int, default=10, help="number of seeds (10)")
    bound.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    bound.add_argument("--duration", type=positive_float, help="episode length in s")
    bound.add_argument("--estimator", metavar="NAME", help="replace the scenario's estimator")
    bound.add_argument(
        "--set",
        action="append",
        default=[],
        metavar="SECTION.KEY=VALUE",
        help="override a scenario setting (repeatable)",
    )
    bound.add_argument("--json", type=Path, help="write the per-seed values and summary as JSON")
    bound.add_argument("--plots", type=Path, help="write the error-vs-bound figure (PNG) here")
    bound.add_argument(
        "--phases",
        type=_phase_edges,
        metavar="T0,T1,...",
        help="also print (and write) RMSE / bound per phase between these times in s",
    )
    bound.set_defaults(func=cmd_study_bound)
    _add_estimators_parser(studies, positive_int, positive_float)
    _add_analysis_parsers(studies)


def _add_analysis_parsers(studies: Any) -> None:
    """The parsers of the analyses (:data:`ANALYSES`): each parses its own options."""
    for name, (_, help_text) in ANALYSES.items():
        analysis = studies.add_parser(name, help=help_text, add_help=False)
        analysis.set_defaults(func=cmd_study_analysis, analysis=name)


def _add_integrity_parser(studies: Any, positive_int: Callable[[str], int]) -> None:
    """The parsers of ``quadslam study integrity`` and ``integrity-task``."""
    integ = studies.add_parser(
        "integrity",
        help="EKF-SLAM's and iSAM2's integrity monitors, detecting and excluding, fault-free and "
        "with each fault kind: false alarms, protection levels, detection, errors, Stanford "
        "diagrams",
    )
    _flown_study_args(integ, positive_int, "3 seeds of 20 s", "write the Stanford diagrams "
                      "(PNG) here", seeds_help="episodes per fault row (default 20)")  # fmt: skip
    integ.add_argument(
        "--free-seeds", type=positive_int, help="fault-free episodes (default 50; quick 3)"
    )
    integ.add_argument("--seed", type=int, default=1000, help="first held-out seed (1000)")
    integ.add_argument(
        "--jobs",
        type=positive_int,
        help="rows at a time, each in its own process (default: the CPU cores available; "
        "1: in this process); the results do not depend on it",
    )
    integ.set_defaults(func=cmd_study_integrity)
    task = studies.add_parser(
        "integrity-task",
        help="the active-perception study with the integrity monitor, the protection levels "
        "in the observation and a reward on alerts: availability of each heading policy",
    )
    _training_study_args(task, positive_int, 5, "write the active-perception figure here")
    task.set_defaults(func=cmd_study_integrity_task)
    coop = studies.add_parser(
        "cooperative",
        help="teams of 1, 2 and 4 vehicles sharing maps: independent, covariance intersection "
        "and naive fusion; team map RMSE, landmark ANEES, bytes sent; the map figure",
    )
    _flown_study_args(coop, positive_int, "3 seeds of 20 s", "write the team map figure (PNG) here")
    coop.add_argument("--seed", type=int, default=1000, help="first held-out seed (1000)")
    coop.add_argument(
        "--jobs",
        type=positive_int,
        help="episodes at a time, each in its own process (default: the CPU cores available; "
        "1: in this process); the results do not depend on it",
    )
    coop.set_defaults(func=cmd_study_cooperative)


def _phase_edges(text: str) -> list[float]:
    """``--phases``: two or more increasing times in s, from 0 on."""
    try:
        edges = [float(t) for t in text.split(",") if t.strip()]
    except ValueError:
        edges = []
    if len(edges) < 2 or edges[0] < 0.0 or any(b <= a for a, b in itertools.pairwise(edges)):
        raise argparse.ArgumentTypeError(
            f"got {text!r}; allowed: two or more increasing times in s from 0, e.g. 0,2,5,10,50"
        )
    return edges


def _add_estimators_parser(
    studies: Any, positive_int: Callable[[str], int], positive_float: Callable[[str], float]
) -> None:
    """``quadslam study estimators``."""
    from agents.lab.estimator_studies.estimator_cells import ROWS, SCENARIOS

    def names(allowed: list[str]) -> Callable[[str], list[str]]:
        def parse(text: str) -> list[str]:
            got = [t.strip() for t in text.split(",") if t.strip()]
            bad = [g for g in got if g not in allowed]
            if bad or not got:
                raise argparse.ArgumentTypeError(
                    f"got {text!r}; allowed: a comma-separated list of {allowed}"
                )
            return got

        return parse

    est = studies.add_parser(
        "estimators",
        help="EKF-SLAM, FastSLAM, iSAM2 fixed lag and full against the posterior Cramér–Rao "
        "bound on the paper scenarios: RMSE / bound, block ANEES, time per step",
    )
    est.add_argument("--seeds", type=positive_int, default=10, help="seeds per cell (10)")
    est.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    est.add_argument(
        "--scenarios", type=names(list(SCENARIOS)), help=f"subset of {','.join(SCENARIOS)}"
    )
    keys = [r.key for r in ROWS]
    est.add_argument("--rows", type=names(keys), help=f"subset of {','.join(keys)}")
    est.add_argument(
        "--duration", type=positive_float, help="episode length in s (default: each scenario's)"
    )
    est.add_argument("--json", type=Path, help="write the cells, per-seed values and ANEES")
    est.set_defaults(func=cmd_study_estimators)
