"""What every section of ``quadslam bench`` is given and fills: the :class:`Plan` (sizes and
repeats: ``tiny``, ``quick``, ``full``) and the :class:`Results` (JSON entries).

The runner (:mod:`agents.lab.bench.runner`) and the section modules import this module; it imports
none of them.
"""

from __future__ import annotations

import statistics
from dataclasses import dataclass
from typing import Any


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
        wall_budget_s: Wall-time budget of a run of all sections on 2 cores with nothing else
            computing, when the plan has one (``quick``); the CLI prints whether a run stayed
            within it. It leaves the first-use compile (``compile``, the same in every plan)
            about its own 20 s target: where that compile takes longer, so does the run
            (docs/performance.md).
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
    wall_budget_s: float | None = None


QUICK = Plan(  # every section of FULL on fewer, shorter samples (docs/performance.md)
    name="quick",
    env_steps=100,
    repeats=3,
    ekf_sizes=(5, 50, 200),
    ekf_observed=(1, 10),
    fast_particles=(100, 1000),
    fast_landmarks=(40,),
    fast_env_particles=(500,),
    vec_batches=(1, 64, 256),
    worker_batches=(256,),
    n_workers=2,
    vec_lane_steps=300,
    vec_min_steps=20,
    vec_warmup=30,
    memory_batches=(1, 256),
    memory_steps=100,
    process_repeats=1,
    wall_budget_s=60.0,
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
