"""Consistency of a particle filter in the loop: NEES per block, lineages, gauge share.

``quadslam study particle-nees --scenario paper_fastslam_helix --seeds 10 --duration 30
[--n 100,250,500,1000] [--set SECTION.KEY=VALUE ...] --json FILE``

The DF-LQR flies on the estimate, each seed a lane of one vector env (as ``quadslam run``). Per
lane and step it records the NEES of the pose ``(ρ, v_B, Λ)`` (9 DOF) and of its position,
velocity and attitude blocks (3 DOF each, each against its own marginal covariance), the
position and yaw errors and standard deviations, and the mean error of the mapped landmarks.
Per episode it reports the ANEES of each block (the time average, as ``quadslam run``'s
``anees_pose``), the position RMSE, and for FastSLAM the number of distinct initial particles
that are still ancestors of the particle set (``lineage``) at the end and when it first fell to
one. The *gauge share* is ``1 − RMS(ρ̂ − ρ − ē_map) / RMS(ρ̂ − ρ)`` with ``ē_map`` the mean error
of the mapped landmarks: near 1 when the vehicle's error is a shift of the whole solution (vehicle
and map together), which no relative measurement can see. ``--n`` repeats the run for several
particle counts (``estimator.params.n_particles``).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.io.overrides import parse_overrides
from agents.lab.estimator_studies.degradation import save_json, seeded_lanes
from quadslam_env.estimation.lane_loop import LaneLoop
from quadslam_env.estimation.protocol import HasParticles
from quadslam_env.models.frames import wrap_angle
from quadslam_env.types import EUL, POS, VEL

BLOCKS = {"pos": slice(0, 3), "vel": slice(3, 6), "att": slice(6, 9)}
"""The 3-DOF blocks of the 9-DOF pose ``(ρ m, v_B m/s, Λ rad)``."""


def block_nees(err: np.ndarray, cov: np.ndarray) -> dict[str, float]:
    """NEES of the pose error (9,) and of each block against its marginal (3, 3) covariance.

    Args:
        err: (9,) pose error ``(ρ̂ − ρ, v̂_B − v_B, wrap(Λ̂ − Λ))``. cov: (9, 9) covariance.

    Returns:
        ``{"pose", "pos", "vel", "att"}``; NaN where the covariance is singular.
    """
    out = {}
    for name, s in {"pose": slice(0, 9), **BLOCKS}.items():
        e, P = err[s], cov[s, s]
        try:
            out[name] = float(e @ np.linalg.solve(P, e))
        except np.linalg.LinAlgError:
            out[name] = math.nan
    return out


def record(
    scenario: str, seeds: Sequence[int], overrides: dict[str, Any], duration_s: float | None
) -> list[dict[str, Any]]:
    """Fly ``seeds`` (one lane each) to the end of their first episode; one record per seed.

    Returns:
        Per seed: ``"t"`` (K,) s, ``"nees"`` {block: (K,)}, ``"pos_err"`` (K, 3) m,
        ``"map_err"`` (K, 3) m (NaN before a landmark is mapped), ``"pos_sd"`` (K,) m (RMS
        of the three σ), ``"yaw_err"``/``"yaw_sd"`` (K,) rad, ``"lineages"`` (K,) (-1 for a
        filter without particles) and ``"end"``, the termination reason ("" at the time limit).
    """
    if duration_s is not None:
        overrides = {
            **overrides,
            "episode": {**overrides.get("episode", {}), "duration_s": duration_s},
        }
    b = len(seeds)
    env, policy, obs, core = seeded_lanes(scenario, seeds, overrides)
    lanes = core.estimator.lanes if isinstance(core.estimator, LaneLoop) else [None] * b
    recs: list[dict[str, Any]] = [
        {"t": [], "nees": {k: [] for k in ("pose", *BLOCKS)}, "pos_err": [], "map_err": [],
         "pos_sd": [], "yaw_err": [], "yaw_sd": [], "lineages": [], "end": ""}
        for _ in range(b)
    ]  # fmt: skip
    live = np.ones(b, dtype=bool)
    for _ in range(core.max_steps):
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        for lane in np.flatnonzero(live).tolist():
            rec, est = recs[lane], core.estimator.lane_estimate(lane)
            x = core.vehicle.state[lane]
            err = np.r_[
                est.position[0] - x[POS],
                est.vel_body[0] - x[VEL],
                wrap_angle(est.euler[0] - x[EUL]),
            ]
            pose_cov = est.pose_cov[0]
            for k, v in block_nees(err, pose_cov).items():
                rec["nees"][k].append(v)
            rec["t"].append(float(core.t[lane]))
            rec["pos_err"].append(err[POS])
            rec["pos_sd"].append(math.sqrt(np.trace(pose_cov[POS, POS]) / 3.0))
            rec["yaw_err"].append(float(err[8]))
            rec["yaw_sd"].append(math.sqrt(pose_cov[8, 8]))
            ids = est.landmark_ids()
            n_true = int(core.n_landmarks[lane])
            ok = ids < n_true
            if ok.any():  # landmark ids index the lane's true landmarks
                truth = core.landmarks[lane, ids[ok]]
                rec["map_err"].append((est.landmark_means[0, ids[ok]] - truth).mean(axis=0))
            else:
                rec["map_err"].append(np.full(3, math.nan))
            filt = lanes[lane]
            count = np.unique(filt.lineage).size if isinstance(filt, HasParticles) else -1
            rec["lineages"].append(int(count))
        for lane in np.flatnonzero(live & term).tolist():
            recs[lane]["end"] = str(info["termination_reason"][lane])
        live &= ~(term | trunc)
        if not live.any():
            break
    env.close()
    return recs


def summarise_episode(rec: dict[str, Any], dt: float) -> dict[str, Any]:
    """Per-episode figures of one :func:`record` entry (see the module docstring)."""
    pos_err = np.array(rec["pos_err"])
    map_err = np.array(rec["map_err"])
    lineages = np.array(rec["lineages"])
    rms = math.sqrt(float(np.mean(np.sum(pos_err**2, axis=1))))
    mapped = np.all(np.isfinite(map_err), axis=1)
    rel = pos_err[mapped] - map_err[mapped]
    rel_rms = math.sqrt(float(np.mean(np.sum(rel**2, axis=1)))) if mapped.any() else math.nan
    one = np.flatnonzero(lineages == 1)
    return {
        "duration_s": len(rec["pos_err"]) * dt,
        "end": rec["end"],
        **{f"anees_{k}": float(np.nanmean(v)) for k, v in rec["nees"].items()},
        "est_pos_rmse_m": rms,
        "pos_sd_rms_m": math.sqrt(float(np.mean(np.square(rec["pos_sd"])))),
        "yaw_err_rms_deg": math.degrees(math.sqrt(float(np.mean(np.square(rec["yaw_err"]))))),
        "yaw_sd_rms_deg": math.degrees(math.sqrt(float(np.mean(np.square(rec["yaw_sd"]))))),
        "gauge_share": 1.0 - rel_rms / rms if rms > 0.0 else math.nan,
        "lineages_end": int(lineages[-1]),
        "t_one_lineage_s": float((one[0] + 1) * dt) if one.size else math.nan,
    }


def summarise(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """Median (and min, max) over episodes of every numeric figure; early ends counted."""
    out: dict[str, Any] = {"episodes_ended_early": sum(1 for e in episodes if e["end"])}
    for key in episodes[0]:
        if key == "end":
            continue
        v = np.array([e[key] for e in episodes], dtype=float)
        if np.all(np.isnan(v)):
            out[key] = {"median": math.nan, "min": math.nan, "max": math.nan}
            continue
        out[key] = {
            "median": float(np.nanmedian(v)),
            "min": float(np.nanmin(v)),
            "max": float(np.nanmax(v)),
        }
    return out


def format_row(label: str, s: dict[str, Any]) -> str:
    """One line of the text table for a :func:`summarise` result."""
    m = {k: v["median"] for k, v in s.items() if isinstance(v, dict)}
    return (
        f"{label:>10} {m['anees_pose']:7.2f} {m['anees_pos']:6.2f} {m['anees_vel']:6.2f} "
        f"{m['anees_att']:6.2f} {m['est_pos_rmse_m']:7.4f} {m['pos_sd_rms_m']:7.4f} "
        f"{m['yaw_err_rms_deg']:6.2f} {m['yaw_sd_rms_deg']:6.2f} {m['gauge_share']:6.2f} "
        f"{m['lineages_end']:5.0f} {m['t_one_lineage_s']:6.1f} {s['episodes_ended_early']:4d}"
    )


HEADER = (
    f"{'N':>10} {'ANEES':>7} {'pos':>6} {'vel':>6} {'att':>6} {'pos m':>7} {'pos σ':>7} "
    f"{'yaw°':>6} {'yaw σ':>6} {'gauge':>6} {'lin.':>5} {'t→1 s':>6} {'end':>4}"
)


def main(argv: Sequence[str] | None = None) -> int:
    """``quadslam study particle-nees``: record, summarise, print, write ``--json``."""
    parser = argparse.ArgumentParser(prog="quadslam study particle-nees", description=__doc__)
    from agents.io.paths import check_output_file

    parser.add_argument("--scenario", default="paper_fastslam_helix")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--seed", type=int, default=0, help="first seed")
    parser.add_argument("--duration", type=float, default=None, help="episode length in s")
    parser.add_argument("--n", default=None, help="particle counts, comma-separated")
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.json is not None:
        check_output_file(args.json, "--json")  # before the flights
    overrides = parse_overrides(args.set)
    seeds = list(range(args.seed, args.seed + args.seeds))
    counts = [int(c) for c in args.n.split(",")] if args.n else [None]
    rows = []
    print(HEADER)
    for n in counts:
        ov = overrides
        if n is not None:
            est = overrides.get("estimator", {})
            ov = {
                **overrides,
                "estimator": {**est, "params": {**est.get("params", {}), "n_particles": n}},
            }
        env = gym.make("QuadSLAM-v0", scenario=args.scenario, **ov)
        dt = float(env.unwrapped.dt)  # type: ignore[attr-defined]
        env.close()
        episodes = [
            summarise_episode(r, dt) for r in record(args.scenario, seeds, ov, args.duration)
        ]
        summary = summarise(episodes)
        rows.append({"n_particles": n, "summary": summary, "episodes": episodes})
        print(format_row("default" if n is None else str(n), summary))
    if args.json is not None:
        out = {
            "scenario": args.scenario,
            "seeds": seeds,
            "duration_s": args.duration,
            "set": args.set,
            "rows": rows,
        }
        return save_json(args.json, out, parser.prog)
    return 0
