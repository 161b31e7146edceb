"""``quadslam study integrity-task``: does a heading policy that sees its protection levels keep
the solution available more often than the look-at heuristic?

The active-perception study (:mod:`agents.lab.control_studies.active`: fixed, tangent and look-at
headings and residual PPO with the heading channel, on the same held-out seeds) on the
integrity-aware task :data:`TASK`: EKF-SLAM's integrity monitor excluding, an alert limit of 0.5 m,
the protection levels in the observation and a reward term on every alert (docs/integrity.md "An
integrity-aware task"). The table adds to the active-perception study's rows their availability
(the share of steps without an alert; median over the episodes, for the learned row median over
the training seeds of each seed's median, with its IQM and bootstrap CI) and the claim that the
learned row's availability is above the look-at heuristic's, with the training seeds it holds
on. ``--quick`` trains one seed on a small budget (a smoke run, not a result).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float
from agents.evaluation.seed_stats import summary
from agents.lab.control_studies import active

ALERT_LIMIT_M = 0.5
ALERT_WEIGHT = 0.5
TASK: dict[str, Any] = {
    "integrity": {"monitor": "exclude", "alert_limit_m": ALERT_LIMIT_M,
                  "alert_weight": ALERT_WEIGHT},
    "observation": {"protection_levels": True},
}  # fmt: skip
"""The task's settings on top of ``active_perception``'s (training and every flight)."""


def _availability(episodes: list[dict[str, Any]]) -> float:
    """Median availability over ``episodes`` (records of one controller, one training seed)."""
    return float(np.median([e["integrity_availability"] for e in episodes]))


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    jobs: int | None = None,
    first_training_seed: int = 0,
) -> dict[str, Any]:
    """The active-perception study on :data:`TASK` (arguments as
    :func:`agents.lab.control_studies.active.run_study`'s), with each row's availability and the
    claim."""
    result = active.run_study(
        out, quick, training_seeds, episodes, timesteps, jobs,
        first_training_seed=first_training_seed, env_overrides=TASK,
    )  # fmt: skip
    rows = {row["config"]: row for row in result["rows"]}
    n_eps = len(result["settings"]["eval_seeds"])
    for row in rows.values():
        eps = row["episodes"]  # a learned row's: its training seeds' episodes one after another
        per_seed = [_availability(eps[i : i + n_eps]) for i in range(0, len(eps), n_eps)]
        row["availability_by_seed"] = [json_float(v) for v in per_seed]
        row["availability"] = json_float(float(np.median(per_seed)))
    learned = rows["ppo"]
    base = rows["lookat"]["availability"]
    above = [v > base for v in learned["availability_by_seed"] if v is not None and base]
    learned["availability_stats"] = summary(learned["availability_by_seed"])
    learned["availability_above_lookat"] = f"{sum(above)}/{len(above)}"
    result["settings"]["task"] = TASK
    return result


def format_study(result: dict[str, Any]) -> str:
    """The active-perception table, then availability per row."""
    lines = [active.format_study(result), "", "config | availability | per training seed"]
    lines.append("--- | --- | ---")
    for row in result["rows"]:
        seeds = ", ".join(f"{v:.3f}" for v in row["availability_by_seed"] if v is not None)
        lines.append(f"{row['config']} | {row['availability']:.3f} | {seeds}")
    learned = next(r for r in result["rows"] if r["config"] == "ppo")
    lines.append(
        f"learned availability above look-at's on {learned['availability_above_lookat']} "
        "training seeds"
    )
    return "\n".join(lines)


def write_json(result: dict[str, Any], path: Path) -> None:
    """The result as JSON (:func:`agents.lab.control_studies.active.write_json`)."""
    active.write_json(result, path)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """The active-perception figure (:func:`agents.lab.control_studies.active.plot_study`)."""
    return active.plot_study(result, out_dir)
