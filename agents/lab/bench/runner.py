"""``quadslam bench``: speed and scaling of the envs and the estimators.

Every measurement is repeated (after a warm-up) and reported as median / min / max with its
unit, as one JSON entry. The sections (``--only``):

* ``ekf``, ``fastslam`` (:mod:`agents.lab.bench.estimators`): filter cost vs map size and
  particles through the :class:`estimators.Estimator` protocol with synthetic scans;
* ``env`` (:mod:`agents.lab.bench.envs`): scalar env (``gymnasium.make``) steps/s and real-time
  factor, zero action and DF-LQR;
* ``vector``, ``workers`` (:mod:`agents.lab.bench.envs`): native vector env throughput in
  env-steps/s vs lanes B, in one process and split over 2 worker processes;
* ``physics`` (:mod:`agents.lab.bench.paired`): rotors, wind and randomised physics against the
  nominal vector env, timed in alternation;
* ``team`` (:mod:`agents.lab.bench.team`): the team env of 4 vehicles against the vector env of 4
  lanes, timed in alternation;
* ``association`` (:mod:`agents.lab.bench.association`): unknown data association (JCBB, NN)
  against known association, scalar and vector env;
* ``memory``, ``compile`` (:mod:`agents.lab.bench.process`): peak RSS vs B and numba compile time,
  each measured in fresh subprocesses;
* ``render`` (:mod:`agents.lab.bench.render`): ``rgb_array`` frames/s and the time to record a
  video of an episode (``gymnasium.wrappers.RecordVideo``).

Three sections need an extra (:data:`SECTION_EXTRAS`): ``workers`` stable-baselines3
(``[rl]``), ``render`` matplotlib (``[plots]``) and ``team`` pettingzoo (``[team]``). Without
it, a run of all sections skips that one with a line on stderr naming the extra, and ``--only``
naming it stops before anything is measured with that line as its error.

The old ``AsyncVectorEnv``/``SubprocVecEnv`` scaling section (about 2,000 steps/s for 1–4
workers of the scalar env) was dropped: the native vector env does 5,000 steps/s with one lane
and about 100,000 with a few hundred, so it no longer said anything useful.
"""

from __future__ import annotations

import importlib.metadata
import importlib.util
import math
import os
import platform
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from agents.lab.bench.plan import FULL, QUICK, Plan, Results

SECTION_NAMES = (
    "ekf", "fastslam", "env", "vector", "physics", "team", "association", "workers", "memory",
    "compile", "render",
)  # fmt: skip

SECTION_EXTRAS = {
    "workers": ("stable_baselines3", "rl"),
    "render": ("matplotlib", "plots"),
    "team": ("pettingzoo", "team"),
}
"""Section → (the module it needs, the ``quadslam[...]`` extra that brings it)."""

VERSIONED = ("numpy", "numba", "gymnasium", "stable_baselines3", "matplotlib", "gtsam")
"""The packages whose versions :func:`machine_info` records (those installed)."""


def missing_extra(name: str) -> str | None:
    """Why section ``name`` cannot run here (one line naming the extra), or ``None``."""
    if name not in SECTION_EXTRAS:
        return None
    module, extra = SECTION_EXTRAS[name]
    if importlib.util.find_spec(module) is not None:
        return None
    return (
        f"bench section {name} needs {module}, which is not installed; install it with: "
        f"pip install 'quadslam[{extra}]'"
    )


def installed_version(package: str) -> str | None:
    """The installed distribution's version of ``package``, or ``None`` if it is absent."""
    try:
        return importlib.metadata.version(package)
    except importlib.metadata.PackageNotFoundError:
        return None


# ---------------------------------------------------------------- report
def machine_info() -> dict[str, Any]:
    """What the numbers were measured on (CPU model, cores, load, the installed packages'
    versions: those of :data:`VERSIONED` that are installed, no key for the others)."""
    from agents.io.cpus import cpu_model

    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
        **{
            package: version
            for package in VERSIONED
            if (version := installed_version(package)) is not None
        },
        "platform": platform.platform(),
    }


def best_batches(entries: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """The fastest B of each env-steps/s series (``vector`` group).

    Returns:
        ``{series name: {"num_envs", "workers", "median"}}``.
    """
    best: dict[str, dict[str, Any]] = {}
    for e in entries:
        if e["group"] != "vector":
            continue
        if e["name"] not in best or e["median"] > best[e["name"]]["median"]:
            best[e["name"]] = {
                "num_envs": e["params"]["num_envs"],
                "workers": e["params"]["workers"],
                "median": e["median"],
            }
    return best


def _table(rows: Sequence[Sequence[str]]) -> str:
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    return "\n".join(
        "  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows
    )


def format_batch_table(entries: list[dict[str, Any]]) -> str:
    """Medians vs lanes B of the ``vector`` and ``memory`` series (one row each); '' if none."""
    series: dict[tuple[str, str, str], dict[int, float]] = {}
    for e in entries:
        if e["group"] in ("vector", "memory"):
            key = (e["group"], e["name"], e["unit"])
            series.setdefault(key, {})[e["params"]["num_envs"]] = e["median"]
    if not series:
        return ""
    batches = sorted({b for row in series.values() for b in row})
    best = best_batches(entries)
    rows = [("series", *(f"B={b}" for b in batches), "unit", "best B")]
    for (_, name, unit), row in series.items():
        cells = tuple(_fmt(row[b]) if b in row else "-" for b in batches)
        rows.append((name, *cells, unit, str(best[name]["num_envs"]) if name in best else ""))
    return _table(rows)


def format_results(entries: list[dict[str, Any]]) -> str:
    """Plain-text table of all measurements, then the medians vs lanes B."""
    rows = [("group", "measurement", "params", "median", "min", "max", "unit")]
    for e in entries:
        params = ", ".join(
            f"{k}={v}"
            for k, v in e["params"].items()
            if k not in ("env_id", "kind", "policy", "estimator", "scenario")
        )
        rows.append(
            (
                e["group"],
                e["name"],
                params,
                _fmt(e["median"]),
                _fmt(e["min"]),
                _fmt(e["max"]),
                e["unit"],
            )
        )
    text = _table(rows)
    batch = format_batch_table(entries)
    return f"{text}\n\nmedians vs lanes B:\n{batch}" if batch else text


def format_targets(entries: list[dict[str, Any]]) -> str:
    """One line per entry with a ``target_s`` (an upper bound) or a ``target_min`` (a lower
    bound): its median against the target and whether it is met, in plain words; '' if no
    entry has one."""
    lines = []
    for e in entries:
        for key, sign, ok in (("target_s", "<=", e["median"].__le__),
                              ("target_min", ">=", e["median"].__ge__)):  # fmt: skip
            target = e["params"].get(key)
            if target is None:
                continue
            lines.append(
                f"target {e['group']} {e['name']}: {_fmt(e['median'])} {e['unit']} "
                f"(median of {e['n']}) against {sign} {_fmt(target)} {e['unit']}: "
                f"{'met' if ok(target) else 'NOT met'}"
            )
    return "\n".join(lines)


def format_wall_times(doc: dict[str, Any], budget: tuple[str, float] | None = None) -> str:
    """The wall time of each section and of the whole run (from the command's start), and
    whether it is within ``budget`` = (plan name, seconds) when given."""
    total = f"wall time {doc['wall_time_s']:.1f} s from the command's start"
    per_section = doc.get("section_wall_s", {})
    if budget is not None:
        verdict = "within" if doc["wall_time_s"] <= budget[1] else "OVER"
        total += f" ({verdict} the {budget[0]} plan's budget of {budget[1]:g} s"
        if verdict == "OVER" and per_section:
            longest = max(per_section, key=per_section.__getitem__)
            total += f"; the longest section: {longest} {per_section[longest]:.1f} s"
        total += ")"
    if not per_section:
        return total
    sections_s = ", ".join(f"{name} {s:.1f} s" for name, s in per_section.items())
    return f"wall time per section: {sections_s}\n{total}"


def _fmt(value: float) -> str:
    if value == 0 or not math.isfinite(value):
        return str(value)
    return f"{value:.4g}"


def sections() -> dict[str, Callable[[Results, Plan], None]]:
    """Section name → function (imported here, so that importing this module, as ``quadslam
    --help`` does for :data:`SECTION_NAMES`, imports no numpy)."""
    from agents.lab.bench.association import bench_association
    from agents.lab.bench.envs import bench_env, bench_vector, bench_workers
    from agents.lab.bench.estimators import bench_ekf, bench_fastslam
    from agents.lab.bench.paired import bench_physics
    from agents.lab.bench.process import bench_compile, bench_memory
    from agents.lab.bench.render import bench_render
    from agents.lab.bench.team import bench_team

    return {
        "ekf": bench_ekf,
        "fastslam": bench_fastslam,
        "env": bench_env,
        "vector": bench_vector,
        "physics": bench_physics,
        "team": bench_team,
        "association": bench_association,
        "workers": bench_workers,
        "memory": bench_memory,
        "compile": bench_compile,
        "render": bench_render,
    }


def run_bench(
    quick: bool,
    only: list[str] | None = None,
    progress: bool = True,
    plan: Plan | None = None,
    started: float | None = None,
) -> dict[str, Any]:
    """Run the benchmark sections and return the JSON document.

    Args:
        quick: Use the ``quick`` plan (else ``full``) unless ``plan`` is given.
        only: Section names to run (default: all, in :data:`SECTION_NAMES` order).
        progress: Show a progress bar of the sections.
        plan: Explicit plan (e.g. :data:`agents.lab.bench.plan.TINY` for tests).
        started: ``time.perf_counter()`` at the command's start (the CLI passes the entry of
            its ``main``); default: the call of this function. ``wall_time_s`` counts from it,
            so it includes importing the sections' modules (numpy, numba, gymnasium).

    Returns:
        ``{"machine", "plan", "quick", "sections", "skipped", "wall_time_s",
        "section_wall_s", "best_batch", "results"}``: ``sections`` those that ran, ``skipped``
        section → why (a missing extra), ``section_wall_s`` section → its wall time in s (in
        the order they ran).

    Raises:
        quadslam_env.extras.MissingExtraError: A section named in ``only`` needs an extra that
            is not installed (before anything is measured).
    """
    started = time.perf_counter() if started is None else started
    from tqdm import tqdm

    from quadslam_env.extras import MissingExtraError

    plan = plan or (QUICK if quick else FULL)
    table = sections()
    results = Results()
    skipped = {
        name: why for name in only or SECTION_NAMES if (why := missing_extra(name)) is not None
    }
    if only and skipped:
        raise MissingExtraError(next(iter(skipped.values())))
    for why in skipped.values():
        print(f"quadslam bench: skipped: {why}", file=sys.stderr)
    names = [name for name in only or SECTION_NAMES if name not in skipped]
    machine = machine_info()
    section_wall_s: dict[str, float] = {}
    for name in tqdm(names, desc="bench", unit="section", disable=not progress):
        tic = time.perf_counter()
        table[name](results, plan)
        section_wall_s[name] = time.perf_counter() - tic
    return {
        "machine": machine,
        "plan": plan.name,
        "quick": quick,
        "sections": names,
        "skipped": skipped,
        "wall_time_s": time.perf_counter() - started,
        "section_wall_s": section_wall_s,
        "best_batch": best_batches(results.entries),
        "results": results.entries,
    }


def main_bench(
    quick: bool,
    json_path: Path | None,
    plots: Path | None,
    only: list[str] | None = None,
    plan: Plan | None = None,
    started: float | None = None,
) -> dict[str, Any]:
    """CLI body: check the output paths, run, print the table, write JSON and plots.

    After the table it prints each target the results carry (met or not), the machine, the
    load average at the start and the wall times (per section and in all, from ``started``:
    see :func:`run_bench`), against the plan's budget when it has one.

    Raises:
        agents.io.outputs.OutputPathError: ``--json`` or ``--plots`` cannot be written (before
            anything is measured).
        quadslam_env.extras.MissingExtraError: ``--plots`` without matplotlib, or a section of
            ``only`` without its extra (before anything is measured).
        agents.io.outputs.OutputWriteError: A file could not be written at the end; it was saved
            elsewhere and the message says where.
    """
    from agents.io.outputs import Saver
    from agents.io.paths import check_output_dir, check_output_file
    from agents.lab.bench.plots import write_plots
    from quadslam_env.extras import require

    if json_path is not None:
        check_output_file(json_path, "--json")
    if plots is not None:
        check_output_dir(plots, "--plots")
        require("matplotlib", "plots", "--plots")
    doc = run_bench(quick, only, plan=plan, started=started)
    print(format_results(doc["results"]))
    if targets := format_targets(doc["results"]):
        print(targets)
    machine = doc["machine"]
    load = machine.get("load_average")
    print(
        f"machine: {machine['cpu']} ({machine['cores']} cores); load average (1/5/15 min) at "
        "the start " + ("unknown" if load is None else " / ".join(f"{x:.2f}" for x in load))
    )
    chosen = plan or (QUICK if quick else FULL)
    budget = chosen.wall_budget_s  # for a run of all sections
    print(format_wall_times(doc, None if only or budget is None else (chosen.name, budget)))
    saver = Saver()
    if json_path is not None:
        print(f"json: {saver.write_json(json_path, doc, '--json')}")
    if plots is not None:
        files = write_plots(doc["results"], plots, saver)
        print(f"plots: {', '.join(str(f) for f in files)}")
    saver.check()
    return doc
