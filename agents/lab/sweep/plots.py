"""Summary plots of a sweep table: each metric against each swept setting, per estimator.

For every swept setting (a column of the table that takes several values besides the seed:
a ``set`` or ``hyperparams`` key, the scenario, the env id, …) one figure
``OUT/plots/<setting>.png`` has one panel per metric (:data:`agents.lab.sweep.table.
SUMMARY_METRICS` that the jobs report); each line is one estimator (and one value of every
other swept setting): the median over the episodes, with a bar from the 25th to the 75th
percentile. Numeric settings get a numeric (logarithmic when they span more than a decade
and a half) axis, others one tick per value. A sweep with no swept setting besides the
estimator gets ``OUT/plots/metrics.png``: the episodes' distribution per estimator.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from agents.lab.sweep.table import SUMMARY_METRICS, varying_columns

_SETTINGS = ("scenario", "env", "algo", "policy")
_LABELS = {
    "track_pos_rmse_steady_m": "true tracking RMSE, steady state [m]",
    "est_pos_rmse_steady_m": "estimated position RMSE, steady state [m]",
    "est_pos_rmse_m": "estimated position RMSE [m]",
    "track_pos_rmse_m": "true tracking RMSE [m]",
    "anees_pose": "pose ANEES",
    "map_rmse_m": "map RMSE [m]",
}


def plot_sweep(df: Any, setting_cols: list[str], folder: Path, saver: Any) -> list[Path]:
    """Write the summary plots of a sweep table; returns where each PNG went.

    Args:
        df: The table (:func:`agents.lab.sweep.table.build_table`).
        setting_cols: Its ``set``/``hyperparams`` columns.
        folder: ``OUT/plots``.
        saver: An :class:`agents.io.outputs.Saver` (atomic writes).
    """
    ok = df[df["status"] == "ok"]
    metrics = [m for m in SUMMARY_METRICS if m in ok and ok[m].notna().any()]
    if ok.empty or not metrics:
        return []
    swept = varying_columns(ok, [*_SETTINGS, *setting_cols])
    written = []
    for x in swept:
        rows = ok[ok[x].notna()]  # the jobs that set x (other blocks may not)
        others = [c for c in ["estimator", *swept] if c != x]
        others = [c for c in others if rows[c].nunique(dropna=False) > 1] or ["estimator"]
        fig = _figure_vs(rows, x, others, metrics)
        name = re.sub(r"[^A-Za-z0-9_.-]+", "_", x)
        written.append(saver.save_figure(fig, folder / f"{name}.png", "--out"))
    if not swept:
        fig = _figure_distribution(ok, metrics)
        written.append(saver.save_figure(fig, folder / "metrics.png", "--out"))
    return written


def _numeric(values: list[Any]) -> bool:
    return all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)


def _figure_vs(ok: Any, x: str, groups: list[str], metrics: list[str]) -> Any:
    """One panel per metric: median and quartiles of the metric against ``x``, per group."""
    from matplotlib.figure import Figure

    xs_all = [v for v in ok[x].dropna().unique().tolist()]
    numeric = _numeric(xs_all)
    order = sorted(xs_all) if numeric else sorted(xs_all, key=str)
    fig = Figure(figsize=(4.2 * len(metrics), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(metrics)))
    parts = list(ok.groupby(groups, sort=True, dropna=False))
    for ax, metric in zip(axes, metrics, strict=True):
        for g, (key, part) in enumerate(parts):
            label = " / ".join(str(k) for k in (key if isinstance(key, tuple) else (key,)))
            # Categories: points side by side around each tick, not joined by lines.
            shift = 0.0 if numeric else 0.3 * (g - (len(parts) - 1) / 2) / max(len(parts), 1)
            pos, med, lo, hi = [], [], [], []
            for i, value in enumerate(order):
                vals = part.loc[part[x] == value, metric].dropna().to_numpy(dtype=float)
                if vals.size:
                    q25, q50, q75 = np.percentile(vals, [25, 50, 75])
                    pos.append(float(value) if numeric else i + shift)
                    med.append(q50)
                    lo.append(q50 - q25)
                    hi.append(q75 - q50)
            if pos:
                style = "-" if numeric else "none"
                ax.errorbar(pos, med, yerr=[lo, hi], marker="o", ls=style, capsize=3, label=label)
        if numeric:
            positive = [float(v) for v in order if float(v) > 0]
            if len(positive) == len(order) and max(positive) / min(positive) > 30:
                ax.set_xscale("log")
        else:
            ax.set_xticks(range(len(order)), [str(v) for v in order], rotation=20, ha="right")
        ax.set_xlabel(x)
        ax.set_ylabel(_LABELS.get(metric, metric))
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, title=" / ".join(groups), title_fontsize=7)
    fig.suptitle(f"median and quartiles over episodes vs {x}", fontsize=10)
    return fig


def _figure_distribution(ok: Any, metrics: list[str]) -> Any:
    """Box plots of each metric per estimator (a sweep over seeds only)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=(3.6 * len(metrics), 3.8), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(metrics)))
    labels, parts = [], []
    for key, part in ok.groupby(["scenario", "estimator"], sort=True):
        labels.append(" / ".join(str(k) for k in key))
        parts.append(part)
    for ax, metric in zip(axes, metrics, strict=True):
        data = [p[metric].dropna().to_numpy(dtype=float) for p in parts]
        ax.boxplot(data, tick_labels=labels)
        ax.set_ylabel(_LABELS.get(metric, metric))
        ax.tick_params(axis="x", labelsize=7, rotation=15)
        ax.grid(axis="y", alpha=0.3)
    fig.suptitle(f"{len(ok)} episodes", fontsize=10)
    return fig
