"""Graceful degradation: an estimator with the landmarks out of view and back.

``quadslam study degradation --scenario ekf_out_of_view_600s --seeds 5 --json FILE``

The DF-LQR flies on the estimate, each seed a lane of one vector env. Per lane and step it
records whether the last scan returned a landmark, the position error and the position NEES
(3 DOF), and reports:

- the gaps: the share of steps whose last scan saw no landmark and the gap lengths (s);
- honesty while dead-reckoning: the pooled position NEES over the steps in gaps (3 for a
  consistent filter) and the share of those steps inside the two-sided 95% χ²(3) interval;
- re-lock: the position error when a gap ends (the dead-reckoning drift) and
  :data:`AFTER_S` seconds later, and the pooled NEES over those seconds;
- the worst position NEES and how each episode ended (a termination is a true failure only
  where the estimate really was inconsistent).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
from scipy.stats import chi2

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.io.overrides import parse_overrides

AFTER_S = 5.0
"""Seconds after a gap's end at which the re-lock error is read."""


def seeded_lanes(
    scenario: str, seeds: Sequence[int], overrides: dict[str, Any]
) -> tuple[Any, DFLQRPolicy, np.ndarray, Any]:
    """A vector env with one lane per seed, reset with those seeds, and the DF-LQR on it.

    Returns:
        ``(env, policy, obs (B, n), core)``: the env's :class:`~quadslam_env.core.SimCore`
        gives the analyses what the info dicts do not (covariances, particles).
    """
    env = gym.make_vec(
        "QuadSLAM-v0",
        num_envs=len(seeds),
        vectorization_mode="vector_entry_point",
        scenario=scenario,
        **overrides,
    )
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=list(seeds))  # type: ignore[arg-type]
    return env, policy, obs, env.unwrapped.core  # type: ignore[attr-defined]


def save_json(path: Path, result: dict[str, Any], prog: str) -> int:
    """Write an analysis's ``--json`` result atomically (folders made as needed), say where.

    Written through :class:`agents.io.outputs.Saver`: a crash or a full disk never leaves a
    truncated file, and a result that cannot be written where asked is saved next to it or
    in a temporary folder.

    Args:
        path: The ``--json`` file.
        result: The result document.
        prog: The command's name for the error line (``quadslam study degradation``).

    Returns:
        0, or 2 after one line on stderr naming the file and where the result went instead.
    """
    from agents.io.outputs import OutputWriteError, Saver

    saver = Saver()
    text = json.dumps(result, indent=1) + "\n"
    print(f"json: {saver.write_text(path, text, '--json')}")
    try:
        saver.check()
    except OutputWriteError as exc:
        print(f"{prog}: error: {exc}", file=sys.stderr)
        return 2
    return 0


def record(scenario: str, seeds: Sequence[int], overrides: dict[str, Any]) -> dict[str, Any]:
    """Fly ``seeds`` (one lane each) to the end of their first episode.

    Returns:
        ``{"t", "n_visible", "pos_err_m", "nees_pos"}`` (K, B) arrays (NaN after a lane's
        end), ``"end"`` the B termination reasons ("" at the time limit) and ``"dt"``.
    """
    b = len(seeds)
    env, policy, obs, core = seeded_lanes(scenario, seeds, overrides)
    keys = ("t", "n_visible", "pos_err_m", "nees_pos")
    rows: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    live = np.ones(b, dtype=bool)
    end = [""] * b
    for _ in range(core.max_steps):
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        names = ("t", "est_n_visible", "est_pos_err_m", "est_nees_pos")
        for key, name in zip(keys, names, strict=True):
            rows[key].append(np.where(live, info[name], math.nan))
        for lane in np.flatnonzero(live & term).tolist():
            end[lane] = str(info["termination_reason"][lane])
        live &= ~(term | trunc)
        if not live.any():
            break
    env.close()
    out: dict[str, Any] = {k: np.array(v) for k, v in rows.items()}
    out["end"] = end
    out["dt"] = float(core.dt)
    return out


def _gaps(blind: np.ndarray) -> list[tuple[int, int]]:
    """``(start, stop)`` step ranges of the runs of True in ``blind`` (K,) that end before
    the record does (a gap still open at the end never re-locks)."""
    edges = np.diff(np.r_[0, blind.astype(np.int8), 0])
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    return [(int(a), int(z)) for a, z in zip(starts, stops, strict=True) if z < blind.shape[0]]


def summarise(rec: dict[str, Any], after_s: float = AFTER_S) -> dict[str, Any]:
    """The figures of the module docstring from a :func:`record`."""
    dt = rec["dt"]
    lo, hi = chi2.ppf(0.025, 3), chi2.ppf(0.975, 3)
    after = round(after_s / dt)
    per_seed = []
    pooled: dict[str, list[float]] = {"gap": [], "view": [], "after": []}
    drift, relock = [], []
    for lane in range(rec["t"].shape[1]):
        valid = np.isfinite(rec["t"][:, lane])
        nees = rec["nees_pos"][valid, lane]
        err = rec["pos_err_m"][valid, lane]
        blind = rec["n_visible"][valid, lane] == 0
        gaps = _gaps(blind)
        after_mask = np.zeros(blind.shape[0], dtype=bool)
        for _, stop in gaps:
            after_mask[stop : stop + after] = True
            drift.append(float(err[stop - 1]))
            if stop + after < err.shape[0]:
                relock.append(float(err[stop + after]))
        pooled["gap"].extend(nees[blind].tolist())
        pooled["view"].extend(nees[~blind & ~after_mask].tolist())
        pooled["after"].extend(nees[after_mask].tolist())
        per_seed.append(
            {
                "duration_s": float(valid.sum() * dt),
                "end": rec["end"][lane],
                "blind_share": float(blind.mean()),
                "gap_s": [round((z - a) * dt, 2) for a, z in gaps],
                "nees_pos_in_gaps": float(nees[blind].mean()) if blind.any() else math.nan,
                "max_nees_pos": float(nees.max()),
                "max_pos_err_m": float(err.max()),
            }
        )
    gap = np.array(pooled["gap"])
    return {
        "dof": 3,
        "nees_interval_95": [float(lo), float(hi)],
        "episodes_ended_early": sum(1 for s in per_seed if s["end"]),
        "blind_share": float(np.mean([s["blind_share"] for s in per_seed])),
        "n_gaps": len(drift),
        "gap_s_median": float(np.median([g for s in per_seed for g in s["gap_s"]] or [math.nan])),
        "nees_pos_in_gaps": float(gap.mean()) if gap.size else math.nan,
        "nees_pos_in_gaps_inside_95": float(np.mean((gap >= lo) & (gap <= hi)))
        if gap.size
        else math.nan,
        "nees_pos_in_view": float(np.mean(pooled["view"])),
        "nees_pos_after_gap": float(np.mean(pooled["after"])) if pooled["after"] else math.nan,
        "max_nees_pos": float(max(s["max_nees_pos"] for s in per_seed)),
        "pos_err_at_gap_end_m": _spread(drift),
        f"pos_err_{after_s:g}s_after_gap_m": _spread(relock),
        "per_seed": per_seed,
    }


def _spread(values: list[float]) -> dict[str, float]:
    if not values:
        return {"median": math.nan, "max": math.nan}
    return {"median": float(np.median(values)), "max": float(np.max(values))}


def format_summary(summary: dict[str, Any]) -> str:
    """A short text report of :func:`summarise`."""
    lo, hi = summary["nees_interval_95"]
    after = next(k for k in summary if k.startswith("pos_err_") and k.endswith("after_gap_m"))
    lines = [
        f"episodes ended early: {summary['episodes_ended_early']} of {len(summary['per_seed'])}"
        f" ({', '.join(s['end'] or 'time limit' for s in summary['per_seed'])})",
        f"steps with no landmark in the last scan: {summary['blind_share']:.0%}; "
        f"{summary['n_gaps']} gaps, median {summary['gap_s_median']:.1f} s",
        f"position NEES (3 DOF) in gaps: {summary['nees_pos_in_gaps']:.2f} "
        f"({summary['nees_pos_in_gaps_inside_95']:.0%} of the steps in [{lo:.2f}, {hi:.2f}]); "
        f"in view: {summary['nees_pos_in_view']:.2f}; first {AFTER_S:g} s after a gap: "
        f"{summary['nees_pos_after_gap']:.2f}; worst: {summary['max_nees_pos']:.1f}",
        "position error at a gap's end: median {median:.2f} m, max {max:.2f} m".format(
            **summary["pos_err_at_gap_end_m"]
        ),
        f"{AFTER_S:g} s after: "
        + "median {median:.3f} m, max {max:.3f} m".format(**summary[after]),
    ]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """``quadslam study degradation``: record, summarise, print, write ``--json``."""
    parser = argparse.ArgumentParser(prog="quadslam study degradation", description=__doc__)
    from agents.io.paths import check_output_file

    parser.add_argument("--scenario", default="ekf_out_of_view_600s")
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.json is not None:
        check_output_file(args.json, "--json")  # before the flight
    overrides = parse_overrides(args.set)
    seeds = list(range(args.seed, args.seed + args.seeds))
    summary = summarise(record(args.scenario, seeds, overrides))
    summary = {"scenario": args.scenario, "seeds": seeds, "set": args.set, **summary}
    print(format_summary(summary))
    if args.json is not None:
        return save_json(args.json, summary, parser.prog)
    return 0
