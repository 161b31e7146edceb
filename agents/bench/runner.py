"""``quadslam bench``: speed and scaling of the envs and the estimators.

Every measurement is repeated (after a warm-up) and reported as median / min / max with its
unit, as one JSON entry. The sections (``--only``):

* ``ekf``, ``fastslam`` (:mod:`agents.bench.estimators`): filter cost vs map size and
  particles through the :class:`estimators.Estimator` protocol with synthetic scans;
* ``env`` (:mod:`agents.bench.envs`): scalar env (``gymnasium.make``) steps/s and real-time
  factor, zero action and DF-LQR;
* ``vector``, ``workers`` (:mod:`agents.bench.envs`): native vector env throughput in
  env-steps/s vs lanes B, in one process and split over 2 worker processes;
* ``association`` (:mod:`agents.bench.association`): unknown data association (JCBB, NN)
  against known association, scalar and vector env;
* ``memory``, ``compile`` (:mod:`agents.bench.process`): peak RSS vs B and numba compile time,
  each measured in fresh subprocesses;
* ``render`` (:mod:`agents.bench.render`): ``rgb_array`` frames/s and the time to record a
  video of an episode (``gymnasium.wrappers.RecordVideo``).

The old ``AsyncVectorEnv``/``SubprocVecEnv`` scaling section (about 2,000 steps/s for 1–4
workers of the scalar env) was dropped: the native vector env does 5,000 steps/s with one lane
and about 100,000 with a few hundred, so it no longer said anything useful.
"""

from __future__ import annotations

import math
import os
import platform
import statistics
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

SECTION_NAMES = (
    "ekf", "fastslam", "env", "vector", "association", "workers", "memory", "compile", "render"
)  # fmt: skip


@dataclass(frozen=True)
class Plan:
    """Sizes and repeats of one benchmark run (``tiny``, ``quick`` or ``full``).

    Attributes:
        name: Plan name, written to the JSON document.
        env_steps: Steps per sample of the scalar env (a tenth for FastSLAM).
        repeats: Samples per measurement.
        ekf_sizes: Mapped landmarks of the EKF-SLAM predict/update measurements.
        ekf_observed: Observed (and newly registered) landmarks per scan.
        fast_particles: FastSLAM particle counts.
        fast_landmarks: FastSLAM map sizes.
        fast_env_particles: Particle counts of the scalar FastSLAM env.
        vec_batches: Lanes B of the single-process vector env.
        worker_batches: Lanes B split over the worker processes.
        n_workers: Worker processes of the ``workers`` section.
        vec_lane_steps: Env-steps per sample: ``max(vec_min_steps, vec_lane_steps // B)``
            vector steps.
        vec_min_steps: Fewest vector steps per sample.
        vec_warmup: Vector steps before timing (the EKF's map fills in the first ~10 s).
        memory_batches: Lanes B of the peak-RSS measurement.
        memory_steps: Vector steps of the peak-RSS measurement.
        process_repeats: Samples (fresh subprocesses) of the memory and compile measurements.
    """

    name: str
    env_steps: int
    repeats: int
    ekf_sizes: tuple[int, ...]
    ekf_observed: tuple[int, ...]
    fast_particles: tuple[int, ...]
    fast_landmarks: tuple[int, ...]
    fast_env_particles: tuple[int, ...]
    vec_batches: tuple[int, ...]
    worker_batches: tuple[int, ...]
    n_workers: int
    vec_lane_steps: int
    vec_min_steps: int
    vec_warmup: int
    memory_batches: tuple[int, ...]
    memory_steps: int
    process_repeats: int


QUICK = Plan(
    name="quick",
    env_steps=300,
    repeats=3,
    ekf_sizes=(5, 50, 200),
    ekf_observed=(1, 10),
    fast_particles=(100, 1000),
    fast_landmarks=(40,),
    fast_env_particles=(500,),
    vec_batches=(1, 64, 256),
    worker_batches=(256,),
    n_workers=2,
    vec_lane_steps=5000,
    vec_min_steps=100,
    vec_warmup=200,
    memory_batches=(1, 256),
    memory_steps=1000,
    process_repeats=1,
)
FULL = Plan(
    name="full",
    env_steps=3000,
    repeats=5,
    ekf_sizes=(5, 10, 20, 50, 100, 200, 300, 500),
    ekf_observed=(1, 2, 5, 10, 20, 40),
    fast_particles=(100, 500, 1000, 2000, 5000),
    fast_landmarks=(10, 40, 100, 200),
    fast_env_particles=(100, 500, 1000),
    vec_batches=(1, 4, 16, 64, 256, 1024),
    worker_batches=(256, 1024),
    n_workers=2,
    vec_lane_steps=50000,
    vec_min_steps=200,
    vec_warmup=1000,
    memory_batches=(1, 64, 256, 1024),
    memory_steps=1000,
    process_repeats=3,
)
TINY = Plan(  # for the tests: every section on the smallest sizes
    name="tiny",
    env_steps=20,
    repeats=2,
    ekf_sizes=(5, 20),
    ekf_observed=(1, 5),
    fast_particles=(50,),
    fast_landmarks=(10,),
    fast_env_particles=(50,),
    vec_batches=(1, 4),
    worker_batches=(4,),
    n_workers=2,
    vec_lane_steps=20,
    vec_min_steps=5,
    vec_warmup=5,
    memory_batches=(1, 4),
    memory_steps=10,
    process_repeats=1,
)
PLANS = {plan.name: plan for plan in (TINY, QUICK, FULL)}


class Results:
    """Collects measurements as JSON-ready entries."""

    def __init__(self) -> None:
        self.entries: list[dict[str, Any]] = []

    def add(
        self,
        group: str,
        name: str,
        samples: list[float],
        unit: str,
        note: str | None = None,
        **params: Any,
    ) -> dict[str, Any]:
        """Append one measurement.

        Args:
            group: Section-level group (``ekf_slam``, ``env``, ``vector``, ...).
            name: Measurement name, unique within the group for given ``params``.
            samples: Repeated samples (≥ 1).
            unit: Unit of the samples.
            note: How it was measured, when that is not obvious from the name.
            **params: Sizes and settings of the measurement.

        Returns:
            The entry (``group, name, params, unit, median, min, max, n`` and ``note``).
        """
        entry = {
            "group": group,
            "name": name,
            "params": params,
            "unit": unit,
            "median": statistics.median(samples),
            "min": min(samples),
            "max": max(samples),
            "n": len(samples),
        }
        if note:
            entry["note"] = note
        self.entries.append(entry)
        return entry


# ---------------------------------------------------------------- report
def machine_info() -> dict[str, Any]:
    """What the numbers were measured on (CPU model, cores, load, versions)."""
    import gymnasium
    import numba
    import numpy as np
    import stable_baselines3

    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
        "python": platform.python_version(),
        "numpy": np.__version__,
        "numba": numba.__version__,
        "gymnasium": gymnasium.__version__,
        "stable_baselines3": stable_baselines3.__version__,
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


def _fmt(value: float) -> str:
    if value == 0 or not math.isfinite(value):
        return str(value)
    return f"{value:.4g}"


def sections() -> dict[str, Callable[[Results, Plan], None]]:
    """Section name → function (imported here: the section modules import this one)."""
    from agents.bench.association import bench_association
    from agents.bench.envs import bench_env, bench_vector, bench_workers
    from agents.bench.estimators import bench_ekf, bench_fastslam
    from agents.bench.process import bench_compile, bench_memory
    from agents.bench.render import bench_render

    return {
        "ekf": bench_ekf,
        "fastslam": bench_fastslam,
        "env": bench_env,
        "vector": bench_vector,
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
) -> dict[str, Any]:
    """Run the benchmark sections and return the JSON document.

    Args:
        quick: Use the ``quick`` plan (else ``full``) unless ``plan`` is given.
        only: Section names to run (default: all, in :data:`SECTION_NAMES` order).
        progress: Show a progress bar of the sections.
        plan: Explicit plan (e.g. :data:`TINY` for tests).

    Returns:
        ``{"machine", "plan", "quick", "sections", "wall_time_s", "best_batch", "results"}``.
    """
    from tqdm import tqdm

    plan = plan or (QUICK if quick else FULL)
    table = sections()
    results = Results()
    names = only or list(SECTION_NAMES)
    machine = machine_info()
    tic = time.perf_counter()
    for name in tqdm(names, desc="bench", unit="section", disable=not progress):
        table[name](results, plan)
    return {
        "machine": machine,
        "plan": plan.name,
        "quick": quick,
        "sections": names,
        "wall_time_s": time.perf_counter() - tic,
        "best_batch": best_batches(results.entries),
        "results": results.entries,
    }


def main_bench(
    quick: bool,
    json_path: Path | None,
    plots: Path | None,
    only: list[str] | None = None,
    plan: Plan | None = None,
) -> dict[str, Any]:
    """CLI body: check the output paths, run, print the table, write JSON and plots.

    Raises:
        agents.io.outputs.OutputPathError: ``--json`` or ``--plots`` cannot be written (before
            anything is measured).
        agents.io.outputs.OutputWriteError: A file could not be written at the end; it was saved
            elsewhere and the message says where.
    """
    from agents.bench.plots import write_plots
    from agents.io.outputs import Saver, check_output_dir, check_output_file

    if json_path is not None:
        check_output_file(json_path, "--json")
    if plots is not None:
        check_output_dir(plots, "--plots")
    doc = run_bench(quick, only, plan=plan)
    print(format_results(doc["results"]))
    print(
        f"machine: {doc['machine']['cpu']} ({doc['machine']['cores']} cores); "
        f"wall time {doc['wall_time_s']:.1f} s"
    )
    saver = Saver()
    if json_path is not None:
        print(f"json: {saver.write_json(json_path, doc, '--json')}")
    if plots is not None:
        files = write_plots(doc["results"], plots, saver)
        print(f"plots: {', '.join(str(f) for f in files)}")
    saver.check()
    return doc
