"""The outputs of ``quadslam study bound`` (:mod:`agents.lab.estimator_studies.bound`): the per-seed
table, the map's table, the figures and the command itself.

The pose figure shows the first seed's per-axis errors with ±√ of the bound's diagonal and
every seed's error norm against the bound's √trace; the map figure (unknown map) every
landmark's final error against its bound ``√tr B_ll`` and the map RMSE over time against the
map bound (:mod:`agents.lab.estimator_studies.bound_map`).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from agents.lab.estimator_studies.bound import BLOCKS, SeedBound, run_bound_study
from agents.lab.estimator_studies.phases import format_phases, phase_ratios


def _cell(fmt: str, value: Any) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return fmt.format(value)


def _table(result: dict[str, Any], cols: list[tuple[str, str, str]]) -> list[str]:
    """Rows per seed, then the median and pooled rows, aligned; ``cols`` (label, key, fmt)."""
    rows = [[c[0] for c in cols]]
    for rec in result["seeds"]:
        rows.append([_cell(fmt, rec.get(key)) for _, key, fmt in cols])
    for stat in ("median", "pooled"):
        rows.append(
            [stat] + [_cell(fmt, result["summary"][key].get(stat)) for _, key, fmt in cols[1:]]
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(cols))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    lines.insert(1, "-" * len(lines[0]))
    lines.insert(len(lines) - 2, "-" * len(lines[0]))
    return lines


def format_bound(result: dict[str, Any]) -> str:
    """Per-seed table and the summary as text (the map's below it when there is one)."""
    cols = [
        ("seed", "seed", "{:d}"),
        ("pos bound", "bound_pos_rmse_m", "{:.4f}"),
        ("pos est", "est_pos_rmse_m", "{:.4f}"),
        ("steady bound", "bound_pos_rmse_m_steady", "{:.4f}"),
        ("steady est", "est_pos_rmse_m_steady", "{:.4f}"),
        ("vel bound", "bound_vel_rmse_mps", "{:.4f}"),
        ("vel est", "est_vel_rmse_mps", "{:.4f}"),
        ("att bound°", "bound_att_rmse_deg", "{:.4f}"),
        ("att est°", "est_att_rmse_deg", "{:.4f}"),
    ]
    head = (
        f"{result['scenario']} / {result['estimator']}: PCRB (RMSE-equivalent √trace) vs "
        f"estimate RMSE; steady state {result['settings']['steady_state']}"
    )
    text = head + "\n" + "\n".join(_table(result, cols))
    if "bound_map_rmse_m" in result["summary"]:
        text += "\n\n" + format_map(result)
    return text


def format_map(result: dict[str, Any]) -> str:
    """The map's table: the map RMSE's bound and the estimate's, over the flight, in the
    steady state and at the last step, per seed and as median and pooled RMS."""
    cols = [
        ("seed", "seed", "{:d}"),
        ("mapped", "n_mapped_final", "{:d}"),
        ("map bound", "bound_map_rmse_m", "{:.4f}"),
        ("map est", "est_map_rmse_m", "{:.4f}"),
        ("steady bound", "bound_map_rmse_m_steady", "{:.4f}"),
        ("steady est", "est_map_rmse_m_steady", "{:.4f}"),
        ("final bound", "bound_map_rmse_m_final", "{:.4f}"),
        ("final est", "est_map_rmse_m_final", "{:.4f}"),
    ]
    result = {**result, "summary": {**result["summary"], "n_mapped_final": {}}}
    head = "map RMSE [m]: PCRB of the landmark block (eq. 2 of estimators.pcrb) vs estimate"
    return head + "\n" + "\n".join(_table(result, cols))


def bound_figure(result: dict[str, Any], series: list[SeedBound]) -> Any:
    """Left: the first seed's per-axis errors with ±√ of the bound's diagonal; right: the
    error norm of every seed, its RMS over seeds and the bound's √trace (mean over seeds).

    Returns:
        A matplotlib ``Figure`` (not attached to pyplot).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12.0, 9.0), layout="constrained")
    axes = fig.subplots(3, 2, sharex=True)
    first = series[0]
    axis_keys = ("pos_var_axes", "vel_var_axes", "euler_var_axes")
    trace_keys = ("pos_m2", "vel_m2ps2", "att_rad2")
    labels = (
        ("position error [m]", "‖position error‖ [m]"),
        ("inertial velocity error [m/s]", "‖velocity error‖ [m/s]"),
        ("Euler angle error [deg]", "attitude error angle [deg]"),
    )
    colors = ("tab:blue", "tab:orange", "tab:green")
    for j, (_, _, scale, _) in enumerate(BLOCKS):
        ax = axes[j, 0]
        sd = scale * np.sqrt(np.clip(first.bound[axis_keys[j]], 0.0, None))
        for a in range(3):
            ax.plot(first.t, scale * first.err_axes[:, 3 * j + a], lw=0.8, color=colors[a],
                    label="xyz"[a] if j < 2 else "φθψ"[a])  # fmt: skip
            ax.fill_between(first.t, -sd[:, a], sd[:, a], color=colors[a], alpha=0.12, lw=0)
        ax.set_ylabel(labels[j][0])
        ax.legend(loc="upper right", fontsize=7, ncol=3, title="shaded: ±√bound", title_fontsize=7)
        ax.grid(alpha=0.3)
        ax = axes[j, 1]
        length = min(len(s.t) for s in series)
        t = series[0].t[:length]
        errs = np.array([scale * s.err_norm[:length, j] for s in series])
        for e in errs:
            ax.plot(t, e, color="0.75", lw=0.5)
        ax.plot(t, np.sqrt(np.mean(errs**2, axis=0)), color="k", lw=1.2, label="RMS over seeds")
        bound = np.array([s.bound[trace_keys[j]][:length] for s in series])
        line = scale * np.sqrt(bound.mean(axis=0))
        ax.plot(t, line, color="tab:red", lw=1.5, label="PCRB √trace (mean over seeds)")
        ax.set_ylim(bottom=0.1 * float(np.median(line)))  # the zero prior's start: off scale
        ax.set_ylabel(labels[j][1])
        ax.set_yscale("log")
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3, which="both")
    axes[2, 0].set_xlabel("t [s]")
    axes[2, 1].set_xlabel("t [s]")
    n = len(series)
    fig.suptitle(
        f"{result['scenario']} / {result['estimator']}: error vs posterior Cramér–Rao bound "
        f"(left: seed {first.seed}; right: {n} seed(s), grey = each seed)"
    )
    return fig


def _rms_over_seeds(ms: np.ndarray) -> np.ndarray:
    """(K,) ``√(mean over seeds)`` of (n, K) mean squares, over the seeds defined at each step
    (NaN where none is)."""
    count = np.isfinite(ms).sum(axis=0)
    total = np.where(np.isfinite(ms), ms, 0.0).sum(axis=0)
    out = np.full(ms.shape[1], np.nan)
    np.divide(total, count, out=out, where=count > 0)
    return np.sqrt(out)


def figure_name(result: dict[str, Any], stem: str = "bound") -> str:
    """``<stem>_<scenario>.png``, or ``<stem>_<scenario>_<estimator>.png`` for an estimator
    other than the scenario's (``stem``: ``bound`` for the pose, ``bound_map`` for the map)."""
    suffix = f"_{result['estimator']}" if result["settings"].get("estimator_override") else ""
    return f"{stem}_{result['scenario']}{suffix}.png"


def map_figure(result: dict[str, Any], series: list[SeedBound]) -> Any:
    """Left: every landmark's final error ``‖l̂ − l‖`` against its bound ``√tr B_ll`` (one
    point per landmark and seed); right: the map RMSE of every seed, its RMS over seeds and
    the bound's RMSE-equivalent (eq. 2 of :mod:`estimators.pcrb`, pooled over seeds).

    Returns:
        A matplotlib ``Figure`` (not attached to pyplot).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(12.0, 4.8), layout="constrained")
    left, right = fig.subplots(1, 2)
    rows = [r for s in result["seeds"] for r in s["landmarks"] if r["est_err_m"] is not None]
    bound = np.array([r["bound_m"] for r in rows])
    err = np.array([r["est_err_m"] for r in rows])
    left.scatter(bound, err, s=8, alpha=0.6, label="landmark (final)")
    top = float(max(bound.max(), err.max())) if rows else 1.0
    left.plot([0.0, top], [0.0, top], color="tab:red", lw=1.0, label="error = bound")
    gauge = math.sqrt(sum(result["settings"]["bound_model"]["pose_prior_diag"][:3]))
    if gauge > 0.0:  # no landmark's bound is below the prior's position σ (the SLAM gauge)
        left.axvline(gauge, color="0.4", ls="--", lw=0.8, label="√tr P0_ρ (the gauge)")
    left.set_xlabel("bound √tr B_ll [m]")
    left.set_ylabel("final error ‖l̂ − l‖ [m]")
    left.legend(loc="upper left", fontsize=8)
    left.grid(alpha=0.3)
    length = min(len(s.t) for s in series)
    t = series[0].t[:length]
    maps = [s.map for s in series if s.map is not None]
    est = np.array([m.est_ms()[:length] for m in maps])
    for e in est:
        right.plot(t, np.sqrt(e), color="0.75", lw=0.5)
    rms = _rms_over_seeds(est)
    line = _rms_over_seeds(np.array([m.bound_ms()[:length] for m in maps]))
    right.plot(t, rms, color="k", lw=1.2, label="RMS over seeds")
    right.plot(t, line, color="tab:red", lw=1.5, label="PCRB (mean square over seeds)")
    right.set_xlabel("t [s]")
    right.set_ylabel("map RMSE [m]")
    right.set_yscale("log")
    right.legend(loc="upper right", fontsize=8)
    right.grid(alpha=0.3, which="both")
    fig.suptitle(
        f"{result['scenario']} / {result['estimator']}: map error vs its posterior Cramér–Rao "
        f"bound ({len(series)} seed(s), grey = each seed)"
    )
    return fig


def cli_bound(args: Any) -> int:
    """``quadslam study bound``: fly, bound, print the table, write JSON and the figure."""
    from agents.io.outputs import Saver, clean_json
    from agents.io.overrides import parse_overrides
    from agents.io.paths import check_output_dir, check_output_file

    if args.json is not None:  # every output path before the flight
        check_output_file(args.json, "--json")
    if args.plots is not None:
        check_output_dir(args.plots, "--plots")
    seeds = list(range(args.seed, args.seed + args.seeds))
    result, series = run_bound_study(
        args.scenario, seeds, args.duration, parse_overrides(args.set), args.estimator
    )
    print(format_bound(result))
    if args.phases is not None:
        result["phases"] = phase_ratios(series, args.phases, BLOCKS)
        print(format_phases(result["phases"], BLOCKS))
    saver = Saver()
    if args.json is not None:
        print(f"json: {saver.write_json(args.json, clean_json(result), '--json')}")
    if args.plots is not None:
        fig = bound_figure(result, series)
        path = args.plots / figure_name(result)
        print(f"figure: {saver.save_figure(fig, path, '--plots')}")
        if all(s.map is not None for s in series):
            path = args.plots / figure_name(result, "bound_map")
            print(f"figure: {saver.save_figure(map_figure(result, series), path, '--plots')}")
    saver.check()
    return 0
