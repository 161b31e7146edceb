"""``quadslam study association``: what unknown data association costs the estimators.

DF-LQR flies on the estimate, on the same seeds, in three scenarios with unlabeled LiDAR
returns (``lidar.association: unknown``), 10% missed detections and 2 false returns per scan:

- ``paper_ekf_figure8_unknown``: EKF-SLAM with known association (the same misses, no
  clutter: the baseline), nearest neighbour and JCBB, and the same three for the iSAM2
  smoother (fixed lag, its defaults: the scenario's JCBB and 3-of-5 rule; skipped without
  GTSAM);
- ``fastslam_helix_unknown``: FastSLAM with known association and per-particle maximum
  likelihood (when the FastSLAM estimator associates unlabeled returns);
- ``ekf_close_pairs_unknown`` (held out: 20 landmark pairs 0.6 m apart, a 5 Hz LiDAR): known,
  NN and JCBB, where joint compatibility must beat nearest neighbour;

and tabulates position and map RMSE, pose ANEES, the wrong and missed association rates,
spurious landmarks (medians over the seeds) and the divergences (episodes ended early). A
clutter sweep (0 to 10 false returns per scan on both EKF scenarios, NN and JCBB) gives the
figure of position RMSE and wrong-association rate against the clutter rate.
``--quick`` flies 3 seeds of 10 s and 3 clutter rates (a smoke run, not a result).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float, run_episodes
from agents.io.outputs import atomic_produce, write_text_atomic
from quadslam_env.config.files import available_scenarios

KNOWN = {"lidar": {"association": "known", "clutter_rate": 0.0}}
NN = {"estimator": {"params": {"association": "nn"}}}
ISAM2 = {"estimator": {"name": "isam2"}}
ISAM2_NN = {"estimator": {"name": "isam2", "params": {"association": "nn"}}}
CLUTTER_RATES = (0.0, 1.0, 2.0, 5.0, 10.0)
SWEEP_SCENARIOS = ("paper_ekf_figure8_unknown", "ekf_close_pairs_unknown")
METRICS = (
    "est_pos_rmse_m",
    "map_rmse_m",
    "anees_pose",
    "assoc_wrong_rate",
    "assoc_missed_rate",
    "spurious_landmarks",
)


@dataclass(frozen=True)
class Row:
    """One line of the table: a scenario and the overrides that select the method."""

    label: str
    scenario: str
    overrides: dict[str, Any] = field(default_factory=dict)


ROWS = (
    Row("EKF-SLAM, known association", "paper_ekf_figure8_unknown", KNOWN),
    Row("EKF-SLAM, nearest neighbour", "paper_ekf_figure8_unknown", NN),
    Row("EKF-SLAM, JCBB", "paper_ekf_figure8_unknown"),
    Row("iSAM2, known association", "paper_ekf_figure8_unknown", {**KNOWN, **ISAM2}),
    Row("iSAM2, nearest neighbour", "paper_ekf_figure8_unknown", ISAM2_NN),
    Row("iSAM2, JCBB", "paper_ekf_figure8_unknown", ISAM2),
    Row("FastSLAM, known association", "fastslam_helix_unknown", KNOWN),
    Row("FastSLAM, maximum likelihood", "fastslam_helix_unknown"),
    Row("held-out pairs: EKF known", "ekf_close_pairs_unknown", KNOWN),
    Row("held-out pairs: EKF NN", "ekf_close_pairs_unknown", NN),
    Row("held-out pairs: EKF JCBB", "ekf_close_pairs_unknown"),
)


def _fly(scenario: str, overrides: dict[str, Any], seeds: list[int]) -> list[dict[str, Any]]:
    """DF-LQR episodes on ``scenario`` with ``overrides`` (as lanes of the vector env)."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.control.dflqr import DFLQRPolicy

    env = gym.make("QuadSLAM-v0", scenario=scenario, **overrides)
    try:
        return run_episodes(env, DFLQRPolicy.from_env(env), seeds)
    finally:
        env.close()


def _summary(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Medians of :data:`METRICS` (None where no episode has the value) and divergences."""
    out: dict[str, Any] = {}
    for key in METRICS:
        vals = np.array([e.get(key) for e in episodes], dtype=float)
        vals = vals[np.isfinite(vals)]
        out[key] = json_float(np.median(vals)) if vals.size else None
    out["divergences"] = sum(bool(e["terminated"]) for e in episodes)
    out["episodes"] = len(episodes)
    return out


def _usable(row: Row) -> str | None:
    """Why ``row`` cannot run here (its scenario or estimator is missing), or None."""
    import importlib.util

    from quadslam_env.config.scenario import load_scenario
    from quadslam_env.schema import ConfigError

    if row.scenario not in available_scenarios():
        return f"scenario {row.scenario!r} is not shipped"
    name = row.overrides.get("estimator", {}).get("name")
    if name == "isam2" and importlib.util.find_spec("gtsam") is None:
        return "GTSAM not installed (pip install 'quadslam[gtsam]')"
    try:
        load_scenario(row.scenario)
    except ConfigError as exc:
        return str(exc)
    return None


def run_study(seeds: int, quick: bool) -> dict[str, Any]:
    """Fly every row and the clutter sweep; the result as plain data (see :func:`write_json`).

    Args:
        seeds: Episodes per row and per clutter rate (seeds 0 … seeds-1).
        quick: 10 s episodes and the clutter rates 0, 2, 10.
    """
    seed_list = list(range(seeds))
    short: dict[str, Any] = {"episode": {"duration_s": 10.0}} if quick else {}
    rows: list[dict[str, Any]] = []
    for row in ROWS:
        skip = _usable(row)
        if skip is not None:
            rows.append({"label": row.label, "scenario": row.scenario, "skipped": skip})
            continue
        tic = time.perf_counter()
        episodes = _fly(row.scenario, _merge(row.overrides, short), seed_list)
        rows.append(
            {
                "label": row.label,
                "scenario": row.scenario,
                "overrides": row.overrides,
                "summary": _summary(episodes),
                "wall_s": round(time.perf_counter() - tic, 1),
                "episodes": episodes,
            }
        )
    sweep = []
    for scenario in SWEEP_SCENARIOS:
        for rate in (0.0, 2.0, 10.0) if quick else CLUTTER_RATES:
            for method in ("nn", "jcbb"):
                over = {"lidar": {"clutter_rate": rate},
                        "estimator": {"params": {"association": method}}}  # fmt: skip
                episodes = _fly(scenario, _merge(over, short), seed_list)
                sweep.append(_sweep_entry(scenario, rate, method, episodes))
    return {"settings": {"seeds": seeds, "quick": quick}, "rows": rows, "clutter": sweep}


def _sweep_entry(
    scenario: str, rate: float, method: str, episodes: list[dict[str, Any]]
) -> dict[str, Any]:
    return {
        "scenario": scenario,
        "clutter_rate": rate,
        "association": method,
        "summary": _summary(episodes),
        "est_pos_rmse_m": [e["est_pos_rmse_m"] for e in episodes],
        "assoc_wrong_rate": [e.get("assoc_wrong_rate") for e in episodes],
    }


def _merge(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    from quadslam_env.config.files import deep_merge

    return deep_merge(a, b)


def format_study(result: dict[str, Any]) -> str:
    """The table (one line per row; medians over the seeds) and the clutter sweep."""

    def cell(value: Any, fmt: str) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        return fmt.format(value)

    head = (
        f"{'configuration':32s} {'pos m':>7s} {'map m':>7s} {'ANEES':>6s} {'wrong':>6s} "
        f"{'missed':>6s} {'spur.':>5s} {'div.':>5s}"
    )
    lines = [head, "-" * len(head)]
    for row in result["rows"]:
        if "skipped" in row:
            lines.append(f"{row['label']:32s} skipped: {row['skipped']}")
            continue
        s = row["summary"]
        lines.append(
            f"{row['label']:32s} {cell(s['est_pos_rmse_m'], '{:7.4f}')} "
            f"{cell(s['map_rmse_m'], '{:7.4f}')} {cell(s['anees_pose'], '{:6.2f}')} "
            f"{cell(s['assoc_wrong_rate'], '{:6.4f}'):>6s} "
            f"{cell(s['assoc_missed_rate'], '{:6.3f}'):>6s} "
            f"{cell(s['spurious_landmarks'], '{:5.0f}'):>5s} "
            f"{s['divergences']:>2d}/{s['episodes']:<2d}"
        )
    lines += [
        "",
        f"{'scenario':26s} {'clutter/scan':>12s} {'method':>6s} {'pos m':>7s} {'wrong':>7s} "
        f"{'div.':>5s}",
    ]
    for entry in result["clutter"]:
        s = entry["summary"]
        lines.append(
            f"{entry['scenario']:26s} {entry['clutter_rate']:12.0f} {entry['association']:>6s} "
            f"{cell(s['est_pos_rmse_m'], '{:7.4f}')} {cell(s['assoc_wrong_rate'], '{:7.4f}')} "
            f"{s['divergences']:>2d}/{s['episodes']:<2d}"
        )
    return "\n".join(lines)


def write_json(result: dict[str, Any], path: Path) -> None:
    """The result as JSON (rows with their episodes, the clutter sweep)."""
    write_text_atomic(path, json.dumps(result, indent=1) + "\n")


def plot_study(result: dict[str, Any], folder: Path) -> Path:
    """``association_clutter.png`` in ``folder`` (returned): median position RMSE and
    wrong-association rate against the clutter rate (NN and JCBB), with the seeds'
    interquartile range."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(9.5, 3.6), constrained_layout=True)
    axes = fig.subplots(1, 2)
    styles = {"nn": ("o", "tab:blue"), "jcbb": ("s", "tab:orange")}
    for scenario, line in zip(SWEEP_SCENARIOS, ("-", "--"), strict=False):
        for method, (marker, color) in styles.items():
            entries = [
                e for e in result["clutter"]
                if e["association"] == method and e["scenario"] == scenario
            ]  # fmt: skip
            rates = [e["clutter_rate"] for e in entries]
            for ax, key in zip(axes, ("est_pos_rmse_m", "assoc_wrong_rate"), strict=True):
                vals = [np.array([v for v in e[key] if v is not None], float) for e in entries]
                med = [np.median(v) if v.size else np.nan for v in vals]
                lo = [np.percentile(v, 25) if v.size else np.nan for v in vals]
                hi = [np.percentile(v, 75) if v.size else np.nan for v in vals]
                ax.plot(rates, med, line, marker=marker, color=color,
                        label=f"{method.upper()}, {scenario}")  # fmt: skip
                ax.fill_between(rates, lo, hi, color=color, alpha=0.12)
    axes[0].set_ylabel("position RMSE [m]")
    axes[0].set_yscale("log")
    axes[1].set_ylabel("wrong-association rate")
    for ax in axes:
        ax.set_xlabel("clutter rate [false returns per scan]")
        ax.grid(alpha=0.3)
    axes[1].legend(fontsize=7)
    fig.suptitle("EKF-SLAM with unlabeled returns (detection 0.9): median and IQR over seeds")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "association_clutter.png"
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=120))
    return path
