"""Learning curves of a run folder: episode returns against env steps and wall-clock time."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np

from agents.io.outputs import atomic_produce


def read_monitor_episodes(monitor_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episodes from SB3 ``*.monitor.csv`` files, in wall-clock order.

    Returns:
        ``(wall-clock time at episode end in s since the first session started, returns,
        lengths)``; the episodes of a resumed run's sessions are ordered by their real time.
    """
    rows: list[tuple[float, float, int]] = []
    starts: list[float] = []
    for path in sorted(Path(monitor_dir).glob("*.monitor.csv")):
        lines = path.read_text().splitlines()
        try:  # '#{"t_start": …}': a resumed run's sessions each have their own file
            t_start = float(json.loads(lines[0][1:])["t_start"])
        except (IndexError, ValueError, KeyError, TypeError):
            t_start = 0.0
        starts.append(t_start)
        for line in lines[2:]:  # '#{json}' header, then 'r,l,t'
            parts = line.split(",")
            if len(parts) >= 3:
                try:
                    rows.append((t_start + float(parts[2]), float(parts[0]), int(float(parts[1]))))
                except ValueError:
                    continue
    rows.sort()
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    t, r, length = (np.array(c) for c in zip(*rows, strict=True))
    return t - min(starts), r, length.astype(int)


def read_progress(run_dir: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(env steps, wall-clock s)`` at each log dump of ``logs/progress.csv`` (may be empty)."""
    path = Path(run_dir) / "logs" / "progress.csv"
    steps: list[float] = []
    wall: list[float] = []
    if path.is_file():
        with path.open() as fh:
            for row in csv.DictReader(fh):
                try:
                    step, elapsed = (
                        float(row["time/total_timesteps"]),
                        float(row["time/time_elapsed"]),
                    )
                except (KeyError, TypeError, ValueError):
                    continue
                steps.append(step)
                wall.append(elapsed)
    return np.array(steps), np.array(wall)


def plot_learning_curve(run_dir: str | Path) -> Path:
    """Write ``learning_curve.png``: returns against env steps and against wall-clock time.

    Training episodes come from the monitor file, evaluations from ``eval/evaluations.npz``.
    Env steps and wall-clock time are paired through the log dumps of ``logs/progress.csv``
    (with many lanes, the completed episodes' lengths alone lag the step count by up to one
    episode per lane).

    Returns:
        The PNG path.
    """
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    t_end, returns, lengths = read_monitor_episodes(run_dir / "monitor")
    log_steps, log_wall = read_progress(run_dir)
    # A resumed run's later sessions log elsewhere: pair through progress.csv only if it is one.
    resumed = len(list((run_dir / "monitor").glob("*.monitor.csv"))) > 1
    paired = log_steps.size >= 2 and not resumed
    steps = np.interp(t_end, log_wall, log_steps) if paired else np.cumsum(lengths)
    fig = Figure(figsize=(9, 8), layout="constrained")
    ax_r, ax_w, ax_l = fig.subplots(3, 1)
    if returns.size:
        window = max(1, min(50, returns.size // 10))
        for ax, x in ((ax_r, steps), (ax_w, t_end / 60.0)):
            ax.plot(x, returns, ".", ms=3, alpha=0.35, color="tab:blue", label="episode")
            if window > 1:
                smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
                ax.plot(x[window - 1 :], smooth, color="tab:blue", label=f"mean of {window}")
        ax_l.plot(steps, lengths, ".", ms=3, alpha=0.5, color="tab:gray")
    evals = run_dir / "eval" / "evaluations.npz"
    if evals.exists():
        with np.load(evals) as data:
            ts, res, ep_len = data["timesteps"], data["results"], data["ep_lengths"]
        if ts.size:
            mean, std = res.mean(axis=1), res.std(axis=1)
            style = {"fmt": "o-", "color": "tab:red", "ms": 4, "capsize": 3}
            ax_r.errorbar(ts, mean, yerr=std, label="evaluation", **style)
            if paired:
                wall = np.interp(ts, log_steps, log_wall) / 60.0
                ax_w.errorbar(wall, mean, yerr=std, label="evaluation", **style)
            ax_l.plot(ts, ep_len.mean(axis=1), "o-", color="tab:red", ms=4)
    if not returns.size and not evals.exists():
        ax_r.text(0.5, 0.5, "no completed episodes", ha="center", transform=ax_r.transAxes)
    ax_r.set_xlabel("environment steps")
    ax_w.set_xlabel("wall-clock time [min]")
    for ax in (ax_r, ax_w):
        ax.set_ylabel("episode return")
        ax.grid(alpha=0.3)
        if ax.get_legend_handles_labels()[0]:
            ax.legend(loc="lower right")
    ax_l.set_ylabel("episode length [steps]")
    ax_l.set_xlabel("environment steps")
    ax_l.grid(alpha=0.3)
    fig.suptitle(run_dir.name, fontsize=10)
    out = run_dir / "learning_curve.png"
    atomic_produce(out, lambda tmp: fig.savefig(tmp, dpi=110))
    return out
