"""Plots of ``quadslam bench --plots DIR``: estimator scaling and vector-env throughput."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from agents.io.outputs import Saver
from agents.lab.bench.envs import VECTOR_SCENARIOS

Series = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]


def series(entries: list[dict[str, Any]], group: str, name: str, x: str, **fixed: Any) -> Series:
    """``(x, median, min, max)`` arrays of the entries ``group/name`` sorted by param ``x``.

    Args:
        entries: The JSON entries.
        group: Entry group.
        name: Entry name.
        x: Param on the x axis (entries without it are skipped).
        **fixed: Params the entries must have with these values.
    """
    rows = [
        e
        for e in entries
        if e["group"] == group
        and e["name"] == name
        and x in e["params"]
        and all(e["params"].get(k) == v for k, v in fixed.items())
    ]
    rows.sort(key=lambda e: e["params"][x])
    return (
        np.array([e["params"][x] for e in rows]),
        np.array([e["median"] for e in rows]),
        np.array([e["min"] for e in rows]),
        np.array([e["max"] for e in rows]),
    )


def plot(ax: Any, data: Series, label: str, color: str | None = None) -> None:
    """Median with min–max error bars (nothing for an empty series)."""
    x, med, lo, hi = data
    if x.size:
        ax.errorbar(
            x, med, yerr=[med - lo, hi - med], fmt="o-", ms=3, capsize=2, label=label, color=color
        )


def _ekf_figure(plt: Any, entries: list[dict[str, Any]]) -> Any:
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    plot(axes[0], series(entries, "ekf_slam", "predict", "n_mapped"), "predict")
    axes[0].set_xlabel("mapped landmarks")
    axes[0].set_ylabel("time [ms]")
    axes[0].set_title("EKF-SLAM prediction")
    n_big = max(
        (
            e["params"].get("n_mapped", 0)
            for e in entries
            if e["name"] == "update" and e["group"] == "ekf_slam" and "n_observed" in e["params"]
        ),
        default=0,
    )
    plot(axes[1], series(entries, "ekf_slam", "update", "n_mapped", n_observed=10), "10 observed")
    axes[1].set_xlabel("mapped landmarks")
    axes[1].set_title("EKF-SLAM update")
    ax_obs = axes[1].twiny()
    plot(
        ax_obs,
        series(entries, "ekf_slam", "update", "n_observed", n_mapped=n_big),
        f"{n_big} mapped (top axis: observed)",
        color="C1",
    )
    axes[1].legend(fontsize=7, loc="upper left")
    ax_obs.legend(fontsize=7, loc="lower right")
    plot(axes[2], series(entries, "ekf_slam", "registration", "n_new"), "registration")
    axes[2].set_xlabel("new landmarks in one scan")
    axes[2].set_title("EKF-SLAM registration")
    return fig


def _fastslam_figure(plt: Any, entries: list[dict[str, Any]]) -> Any:
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    sizes = sorted({e["params"]["n_landmarks"] for e in entries if e["group"] == "fastslam"})
    for name, ax in zip(("predict", "update"), axes, strict=True):
        for n_lm in sizes:
            data = series(entries, "fastslam", name, "n_particles", n_landmarks=n_lm)
            plot(ax, data, f"{n_lm} landmarks")
        ax.set_xlabel("particles")
        ax.set_ylabel("time [ms]")
        ax.set_title(f"FastSLAM {name}")
        ax.legend(fontsize=7)
    return fig


def _lanes_axis(ax: Any, entries: list[dict[str, Any]], group: str) -> None:
    """Log x axis of lanes B, ticked at the measured B."""
    from matplotlib.ticker import NullLocator

    lanes = sorted({e["params"]["num_envs"] for e in entries if e["group"] == group})
    ax.set_xscale("log")
    ax.set_xticks(lanes, [str(b) for b in lanes])
    ax.xaxis.set_minor_locator(NullLocator())
    ax.set_xlabel("lanes B")


def _vector_figure(plt: Any, entries: list[dict[str, Any]]) -> Any:
    """env-steps/s vs B (log–log) per scenario: one process, worker splits; peak RSS."""
    memory = series(entries, "memory", "peak_rss/ekf_unknown_map", "num_envs")
    vector = {e["name"] for e in entries if e["group"] == "vector"}
    panels = []  # (scenario label, its series names)
    for label, _, _ in VECTOR_SCENARIOS:
        prefix = f"env_steps_per_s/{label}"
        names = sorted(n for n in vector if n == prefix or n.startswith(prefix + "/"))
        if names:
            panels.append((label, prefix, names))
    n_panels = len(panels) + (1 if memory[0].size else 0)
    fig, axes = plt.subplots(1, n_panels, figsize=(4.2 * n_panels, 3.8), squeeze=False)
    axes = axes[0]
    for ax, (label, prefix, names) in zip(axes, panels, strict=False):
        for name in names:
            tail = name[len(prefix) :].lstrip("/").replace("_", " ")
            plot(ax, series(entries, "vector", name, "num_envs"), tail or "1 process")
        _lanes_axis(ax, entries, "vector")
        ax.set_yscale("log")
        ax.set_ylabel("env-steps/s")
        ax.set_title(label.replace("_", " "))
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    if memory[0].size:
        ax = axes[-1]
        plot(ax, memory, "EKF unknown map")
        _lanes_axis(ax, entries, "memory")
        ax.set_ylabel("peak RSS [MB]")
        ax.set_title("memory (fresh process)")
        ax.grid(True, which="both", alpha=0.3)
    return fig


def write_plots(
    entries: list[dict[str, Any]], out_dir: Path, saver: Saver | None = None
) -> list[Path]:
    """Write the PNGs whose measurements are in ``entries``.

    Files: ``ekf_scaling.png``, ``fastslam_scaling.png`` (estimator time vs map size and
    particles) and ``vector_scaling.png`` (env-steps/s vs lanes B per scenario, peak RSS).

    Args:
        entries: Bench result entries.
        out_dir: Folder for the PNGs (created when missing).
        saver: Writes atomically and records failures (see :class:`agents.io.outputs.Saver`);
            without one, a failed write raises after every plot was written somewhere.

    Returns:
        Where each file was written.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    own = saver is None
    saver = saver or Saver()
    groups = {e["group"] for e in entries}
    figures = (
        ("ekf_scaling.png", {"ekf_slam"}, _ekf_figure),
        ("fastslam_scaling.png", {"fastslam"}, _fastslam_figure),
        ("vector_scaling.png", {"vector", "memory"}, _vector_figure),
    )
    paths = []
    for filename, needs, make in figures:
        if not needs & groups:
            continue
        fig = make(plt, entries)
        fig.tight_layout()
        paths.append(saver.save_figure(fig, out_dir / filename, "--plots", dpi=110))
        plt.close(fig)
    if own:
        saver.check()
    return paths
