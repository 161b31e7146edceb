"""Learning curves of a run folder: episode returns against env steps and wall-clock time."""

from __future__ import annotations

from pathlib import Path

import numpy as np


def read_monitor_episodes(monitor_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episodes from SB3 ``*.monitor.csv`` files, in wall-clock order.

    Returns:
        ``(timesteps at episode end (cumulative over envs), returns, lengths)``.
    """
    rows: list[tuple[float, float, int]] = []
    for path in sorted(Path(monitor_dir).glob("*.monitor.csv")):
        lines = path.read_text().splitlines()
        for line in lines[2:]:  # '#{json}' header, then 'r,l,t'
            parts = line.split(",")
            if len(parts) >= 3:
                try:
                    rows.append((float(parts[2]), float(parts[0]), int(float(parts[1]))))
                except ValueError:
                    continue
    rows.sort()
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    _, r, length = (np.array(c) for c in zip(*rows, strict=True))
    return np.cumsum(length), r, length.astype(int)


def plot_learning_curve(run_dir: str | Path) -> Path:
    """Write ``learning_curve.png``: training episode returns (Monitor) and evaluations.

    Returns:
        The PNG path.
    """
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    steps, returns, lengths = read_monitor_episodes(run_dir / "monitor")
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    ax_r, ax_l = fig.subplots(2, 1, sharex=True)
    if returns.size:
        ax_r.plot(steps, returns, ".", ms=3, alpha=0.35, color="tab:blue", label="episode")
        window = max(1, min(50, returns.size // 10))
        if window > 1:
            smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
            ax_r.plot(steps[window - 1 :], smooth, color="tab:blue", label=f"mean of {window}")
        ax_l.plot(steps, lengths, ".", ms=3, alpha=0.5, color="tab:gray")
    evals = run_dir / "eval" / "evaluations.npz"
    if evals.exists():
        with np.load(evals) as data:
            ts, res, ep_len = data["timesteps"], data["results"], data["ep_lengths"]
        if ts.size:
            mean, std = res.mean(axis=1), res.std(axis=1)
            ax_r.errorbar(
                ts, mean, yerr=std, fmt="o-", color="tab:red", ms=4, capsize=3, label="evaluation"
            )
            ax_l.plot(ts, ep_len.mean(axis=1), "o-", color="tab:red", ms=4)
    if not returns.size and not evals.exists():
        ax_r.text(0.5, 0.5, "no completed episodes", ha="center", transform=ax_r.transAxes)
    ax_r.set_ylabel("episode return")
    ax_r.grid(alpha=0.3)
    if ax_r.get_legend_handles_labels()[0]:
        ax_r.legend(loc="lower right")
    ax_l.set_ylabel("episode length [steps]")
    ax_l.set_xlabel("environment steps")
    ax_l.grid(alpha=0.3)
    fig.suptitle(run_dir.name, fontsize=10)
    out = run_dir / "learning_curve.png"
    fig.savefig(out, dpi=110)
    return out
