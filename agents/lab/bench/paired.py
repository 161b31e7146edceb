"""``quadslam bench --only physics``: a relative target measured in alternation.

The full-physics target (rotors, Dryden wind and randomised physics at ≥ 80% of the nominal
EKF-SLAM vector env's env-steps/s) is a ratio of two speeds, and a shared machine's speed
drifts within minutes (docs/performance.md). Measured one after the other, as
the ``vector`` section does, the two sides see different machines. Here both vector envs live
in one process and are timed in short alternating samples, the order swapped every round, so
each round's ratio compares the two on the same machine state; the median over the rounds is
the figure.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import numpy as np

from agents.lab.bench.envs import VECTOR_SCENARIOS, make_vector, steps_per_sample
from agents.lab.bench.plan import Plan, Results

NOMINAL, FULL_PHYSICS = "ekf_unknown_map", "ekf_rotors_wind_randomized"
ROUNDS_PER_REPEAT = 4
"""Alternating rounds per repeat of the plan: more, shorter samples than the other sections,
so that the ratio's median is not one slow minute's."""


def _lanes(plan: Plan) -> int:
    """B: 256 (the target's batch) when the plan has it, else its largest batch."""
    return 256 if 256 in plan.vec_batches else max(plan.vec_batches)


def alternate(
    runs: dict[str, Callable[[int], Any]], steps: int, rounds: int
) -> dict[str, list[float]]:
    """Time ``runs`` (label → a function flying that many steps) in alternating rounds of
    ``steps`` steps each, the order reversed every round.

    Returns:
        label → the wall time of each round, s.
    """
    times: dict[str, list[float]] = {label: [] for label in runs}
    labels = list(runs)
    for r in range(rounds):
        for label in labels if r % 2 == 0 else labels[::-1]:
            tic = time.perf_counter()
            runs[label](steps)
            times[label].append(time.perf_counter() - tic)
    return times


def bench_physics(results: Results, plan: Plan) -> None:
    """Env-steps/s of the nominal and the full-physics EKF-SLAM vector env, timed in
    alternation in one process, and their ratio per round (full over nominal)."""
    from agents.control.dflqr import DFLQRPolicy

    scenarios = {label: (env_id, kw) for label, env_id, kw in VECTOR_SCENARIOS}
    b = _lanes(plan)
    steps = steps_per_sample(plan, b)
    vecs = []
    try:
        runs = {}
        for label in (NOMINAL, FULL_PHYSICS):
            env_id, kwargs = scenarios[label]
            vec = make_vector(env_id, b, **kwargs)
            vecs.append(vec)
            runs[label] = vector_flight(vec, DFLQRPolicy.from_env(vec))
            runs[label](plan.vec_warmup)  # the EKF maps its landmarks first
        times = alternate(runs, steps, plan.repeats * ROUNDS_PER_REPEAT)
    finally:
        for vec in vecs:
            vec.close()
    rates = {label: [b * steps / t for t in samples] for label, samples in times.items()}
    note = (
        f"the two vector envs timed in alternation in one process ({len(rates[NOMINAL])} "
        f"rounds of {steps} steps each, the order swapped every round) after "
        f"{plan.vec_warmup} warm-up steps; batched DF-LQR; autoresets included"
    )
    for label, samples in rates.items():
        results.add("physics", f"env_steps_per_s/{label}", samples, "env-steps/s", note=note,
                    num_envs=b, steps=steps, warmup_steps=plan.vec_warmup)  # fmt: skip
    ratio = [f / n for f, n in zip(rates[FULL_PHYSICS], rates[NOMINAL], strict=True)]
    results.add("physics", "full_over_nominal", ratio, "ratio", note=note, num_envs=b,
                steps=steps)  # fmt: skip


def vector_flight(vec: Any, policy: Any) -> Callable[[int], None]:
    """A function that steps the vector env ``vec`` that many times with ``policy`` (from its
    reset with seed 0), keeping its observations between calls."""
    obs = [vec.reset(seed=0)[0]]

    def fly(steps: int) -> None:
        for _ in range(steps):
            obs[0] = np.asarray(vec.step(policy.predict(obs[0])[0])[0])

    return fly
