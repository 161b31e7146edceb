"""``quadslam study cooperative``: does sharing maps make a team's maps better, and does the
fusion stay consistent (docs/team.md "The cooperative study")?

Teams of N = 1, 2 and 4 vehicles on the paper's figure-8 (``paper_ekf_figure8``, the unknown
map, the vehicles phase-shifted by the team's default offsets), each flown by DF-LQR on its own
EKF-SLAM estimate, on held-out seeds, every vehicle of a seed in the same world. The rows of a
team size are the fusion modes on the same seeds (:data:`ROWS`): ``independent`` (the baseline),
covariance intersection with the messages' defaults (0.2 messages per second, the sender's
joint landmark covariance), CI after every scan, CI with the block covariances only (the ``k ·
blockdiag`` bound), and the naive fusion of the default messages; the largest team also
flies ``independent`` and CI with the ranges between vehicles fused by CI
(:data:`RANGE_ROWS`). A team of one has only ``independent`` (no one to talk to). With the
``gtsam`` extra, teams of N ≥ 2 also fly the iSAM2 smoother (:data:`ISAM2_ROWS`): each
vehicle its own (``isam2_independent``) and one smoother of the whole team
(``centralised``: every vehicle's IMU and LiDAR factors in one graph, the reference of the
decentralised modes), and for the largest team the ranges between vehicles as factors of that
graph (``centralised_ranges``, :data:`ISAM2_RANGE_ROWS`); their ratio is to
``isam2_independent``'s, and the centralised rows' kB are not counted (every measurement is
assumed at the one estimator).

Per row: the team map RMSE (the mean over the vehicles of each one's map RMSE at its last step;
mean over seeds) and its ratio to ``independent``'s of the same N, the union map RMSE, the team
position RMSE of the vehicles' estimates, the landmark ANEES pooled over every vehicle's mapped
landmarks of every seed at its last step, with the two-sided 95% χ² interval of that many 3-DOF
samples (:func:`~quadslam_env.metrics.anees_bounds`; it treats a vehicle's landmarks as
independent, which they are not, so the interval is narrower than it should be), the vehicles
that ended early, the kB broadcast per episode and the median CI weight ω of the fused ranges
(ω → 1: a range fused with almost no weight). The figure: one seed's map of vehicle 0 at
the end in each mode of the largest team, the error of each landmark and its 2σ ellipse
magnified (86% of the errors inside for a consistent 2-D estimate). ``--quick`` flies 3 seeds
of 20 s (a smoke run, not a result).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float
from agents.io.cpus import cpu_model
from agents.io.outputs import atomic_produce, write_text_atomic
from agents.lab.estimator_studies.flown_tasks import has_isam2, map_tasks

SCENARIO = "paper_ekf_figure8"
TEAM_SIZES = (1, 2, 4)
ROWS: dict[str, dict[str, Any]] = {
    "independent": {"fusion": "independent"},
    "ci": {"fusion": "ci"},
    "ci_every_scan": {"fusion": "ci", "message_rate_hz": None},
    "ci_blocks": {"fusion": "ci", "message_covariance": "blocks"},
    "naive": {"fusion": "naive"},
}
"""The rows of a team of N ≥ 2: the ``team`` settings of each. The default message rate, 0.2
Hz, was chosen on seeds 0–2 (30 s; every scan, 1, 0.5, 0.2 and 0.1 Hz measured), not on the
study's seeds."""
ISAM2_ROWS: dict[str, dict[str, Any]] = {
    "isam2_independent": {"fusion": "independent"},
    "centralised": {"fusion": "centralised"},
}
"""The rows of a team of N ≥ 2 flown with ``estimator.name: isam2`` (the study's scenario and
settings otherwise), when GTSAM is installed."""
ISAM2_RANGE_ROWS: dict[str, dict[str, Any]] = {
    "centralised_ranges": {"fusion": "centralised", "ranges": True, "range_fusion": "factor"},
}
"""The largest team's iSAM2 row with the ranges between vehicles as factors of the graph."""
RANGE_ROWS: dict[str, dict[str, Any]] = {
    "independent_ranges": {"fusion": "independent", "ranges": True, "range_fusion": "ci"},
    "ci_ranges": {"fusion": "ci", "ranges": True, "range_fusion": "ci"},
}
"""The rows of the largest team only: with the ranges between vehicles fused by CI (the range
defaults: σ 0.1 m at 10 Hz)."""
MAGNIFY = 50.0
"""The figure's errors and ellipses are drawn this many times their size (errors are cm in a
field of tens of m)."""


def fly(n_vehicles: int, row: str, seed: int, duration_s: float | None) -> dict[str, Any]:
    """One episode of a team of ``n_vehicles`` with ``ROWS[row]``; its end-of-episode terms and
    vehicle 0's final map (ids, means, covariances, truth; :func:`run_study` keeps it for the
    first seed of each row, the figure's)."""
    import gymnasium as gym

    from agents.control.dflqr import DFLQRPolicy
    from quadslam_env.team.env import parallel_env

    episode = {} if duration_s is None else {"duration_s": duration_s}
    policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-v0", scenario=SCENARIO, episode=episode))
    estimator = "isam2" if _isam2(row) else None
    env = parallel_env(n_vehicles=n_vehicles, scenario=SCENARIO, team=_team(row),
                       estimator_name=estimator, episode=episode)  # fmt: skip
    obs, _ = env.reset(seed=seed)
    last: dict[str, dict[str, Any]] = {}
    omegas: list[float] = []  # the CI weights of the fused ranges
    while env.agents:
        obs, _, _, _, infos = env.step({a: policy.predict(obs[a])[0] for a in env.agents})
        last.update(infos)
        omegas += [i["team_range_ci_weight"] for i in infos.values() if "team_range_ci_weight" in i]
    final = last[max(last, key=lambda a: env.core.steps[env.possible_agents.index(a)])]
    ids, means, covs = env.core.estimator.lane_estimate(0).mapped_landmarks(0)
    truth, ends = env.core.landmarks[0, ids], list(last.values())
    return {
        "seed": seed,
        "map_rmse_m": json_float(final["team_episode_map_rmse_m"]),
        "union_map_rmse_m": json_float(final["team_episode_union_map_rmse_m"]),
        "pos_rmse_m": json_float(final["team_episode_est_pos_rmse_m"]),
        "nees_sum": json_float(sum(i["est_landmark_anees"] * i["est_n_mapped"] for i in ends)),
        "landmarks": int(sum(i["est_n_mapped"] for i in ends)),
        "ended_early": int(sum(bool(i.get("termination_reason")) for i in ends)),
        "bytes": float(final.get("team_episode_bytes_sent", 0.0)),
        "range_omega_median": float(np.median(omegas)) if omegas else None,
        "range_omega_below_0.99": float(np.mean(np.less(omegas, 0.99))) if omegas else None,
        "map0": {"ids": ids.tolist(), "means": means.tolist(), "covs": covs.tolist(),
                 "truth": truth.tolist()},
    }  # fmt: skip


def _rows(n_vehicles: int, largest: int, isam2: bool) -> tuple[str, ...]:
    """The rows of a team of ``n_vehicles``: ``independent`` alone for one vehicle, else
    :data:`ROWS`, :data:`ISAM2_ROWS` with ``isam2``, and :data:`RANGE_ROWS` too for the
    ``largest`` team."""
    if n_vehicles == 1:
        return ("independent",)
    rows = (*ROWS, *(ISAM2_ROWS if isam2 else ()))
    if n_vehicles < largest:
        return rows
    return (*rows, *RANGE_ROWS, *(ISAM2_RANGE_ROWS if isam2 else ()))


def _team(row: str) -> dict[str, Any]:
    """The ``team`` settings of ``row`` (:data:`ROWS`, :data:`ISAM2_ROWS`, :data:`RANGE_ROWS`,
    :data:`ISAM2_RANGE_ROWS`)."""
    return {**ROWS, **ISAM2_ROWS, **RANGE_ROWS, **ISAM2_RANGE_ROWS}[row]


def _isam2(row: str) -> bool:
    """Whether ``row`` is flown with the iSAM2 smoother."""
    return row in ISAM2_ROWS or row in ISAM2_RANGE_ROWS


def _baseline(row: str) -> str:
    """The row a row's map RMSE is divided by: the independent row of its estimator."""
    return "isam2_independent" if _isam2(row) else "independent"


def _fly_task(task: tuple[int, str, int, float | None]) -> dict[str, Any]:
    return fly(*task)


def run_study(
    seeds: int,
    first_seed: int,
    quick: bool,
    jobs: int = 1,
    sizes: tuple[int, ...] = TEAM_SIZES,
    duration_s: float | None = None,
) -> dict[str, Any]:
    """Every row of every team size on seeds ``first_seed …``; the result as plain data.

    Args:
        seeds: Episodes per row.
        first_seed: First held-out seed.
        quick: 20 s episodes (else the scenario's 50 s).
        jobs: Episodes flown at a time, each in its own spawned process (1: in this one); the
            results do not depend on it.
        sizes: The team sizes N.
        duration_s: The episodes' length, s (default: 20 s quick, else the scenario's 50 s).
    """
    duration = duration_s if duration_s is not None else 20.0 if quick else None
    isam2 = has_isam2("cooperative")
    cells = [(n, row) for n in sizes for row in _rows(n, max(sizes), isam2)]
    tasks = [
        (n, row, s, duration) for n, row in cells for s in range(first_seed, first_seed + seeds)
    ]
    flown = map_tasks(_fly_task, tasks, jobs)
    for i in range(len(cells)):  # the figure's map: each row's first seed only
        for episode in flown[i * seeds + 1 : (i + 1) * seeds]:
            del episode["map0"]
    rows: list[dict[str, Any]] = []
    for i, (n, row) in enumerate(cells):
        rows.append({"n_vehicles": n, "row": row, "team": _team(row),
                     "summary": row_summary(flown[i * seeds : (i + 1) * seeds]),
                     "episodes": flown[i * seeds : (i + 1) * seeds]})  # fmt: skip
    base = {(r["n_vehicles"], r["row"]): r["summary"]["map_rmse_m"] for r in rows}
    for r in rows:
        den = base[r["n_vehicles"], _baseline(r["row"])]
        r["summary"]["vs_independent"] = _ratio(r["summary"]["map_rmse_m"], den)
    settings = {"scenario": SCENARIO, "seeds": seeds, "first_seed": first_seed, "quick": quick,
                "duration_s": duration, "team_sizes": list(sizes),
                "machine": cpu_model()}  # fmt: skip
    return {"settings": settings, "rows": rows}


def row_summary(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """A row's figures over its episodes (module docstring)."""
    from quadslam_env.metrics.step import anees_bounds

    count = sum(e["landmarks"] for e in episodes)
    nees = [e["nees_sum"] for e in episodes]
    anees = sum(nees) / count if count and all(v is not None for v in nees) else math.inf
    lo, hi = anees_bounds(3, count) if count else (math.nan, math.nan)
    return {
        "map_rmse_m": _mean(e["map_rmse_m"] for e in episodes),
        "union_map_rmse_m": _mean(e["union_map_rmse_m"] for e in episodes),
        "pos_rmse_m": _mean(e["pos_rmse_m"] for e in episodes),
        "landmark_anees": json_float(anees),
        "anees_95": [lo, hi],
        "ended_early": int(sum(e["ended_early"] for e in episodes)),
        "kb_sent": _kb(e["bytes"] for e in episodes),
        "range_omega_median": _median(e["range_omega_median"] for e in episodes),
    }


def _mean(values: Any) -> float | None:
    """The mean, or None when a value is missing (a non-finite one)."""
    got = list(values)
    return None if any(v is None for v in got) else float(np.mean(got))


def _kb(values: Any) -> float | None:
    """The mean of the episodes' bytes in kB (None: not counted)."""
    got = list(values)
    return None if any(v is None for v in got) else float(np.mean(got)) / 1e3


def _median(values: Any) -> float | None:
    """The median of the values that are there (None: none is)."""
    got = [v for v in values if v is not None]
    return float(np.median(got)) if got else None


def _ratio(num: float | None, den: float | None) -> float | None:
    return None if num is None or not den else num / den


def format_study(result: dict[str, Any]) -> str:
    """The result as a Markdown table."""
    s = result["settings"]
    head = ("N", "fusion", "team map RMSE (m)", "× independent", "union map RMSE (m)",
            "position RMSE (m)", "landmark ANEES", "95% interval", "ended early",
            "kB per episode", "ranges' ω (median)")  # fmt: skip
    out = [f"{s['scenario']}, seeds {s['first_seed']}–{s['first_seed'] + s['seeds'] - 1}"
           f"{' (quick: 20 s)' if s['quick'] else ''}", "",
           "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]  # fmt: skip

    def cell(value: Any, fmt: str) -> str:
        return "–" if value is None else fmt.format(value)

    for r in result["rows"]:
        m = r["summary"]
        lo, hi = m["anees_95"]
        vehicles = r["n_vehicles"] * len(r["episodes"])
        out.append("| " + " | ".join((
            str(r["n_vehicles"]), r["row"], cell(m["map_rmse_m"], "{:.4f}"),
            cell(m["vs_independent"], "{:.2f}"), cell(m["union_map_rmse_m"], "{:.4f}"),
            cell(m["pos_rmse_m"], "{:.4f}"), cell(m["landmark_anees"], "{:.3g}"),
            f"[{lo:.2f}, {hi:.2f}]", f"{m['ended_early']} of {vehicles}",
            cell(m["kb_sent"], "{:.0f}"), cell(m["range_omega_median"], "{:.6f}"),
        )) + " |")  # fmt: skip
    return "\n".join(out)


def write_json(result: dict[str, Any], path: Path) -> None:
    """The result as JSON (rows with their episodes)."""
    write_text_atomic(path, json.dumps(result, indent=1) + "\n")


def plot_study(result: dict[str, Any], folder: Path) -> Path:
    """``cooperative_map.png`` in ``folder`` (returned): the first seed's map of vehicle 0 at
    its end in each row of the largest team, the true landmarks as dots, each estimate's error
    as a line from its true position and its 2σ horizontal ellipse around the estimate, both
    :data:`MAGNIFY` times their size."""
    from matplotlib.figure import Figure
    from matplotlib.patches import Ellipse

    n = max(result["settings"]["team_sizes"])
    shown = (*ROWS, *ISAM2_ROWS)
    rows = [r for r in result["rows"] if r["n_vehicles"] == n and r["row"] in shown]
    fig = Figure(figsize=(4.0 * len(rows), 4.2), constrained_layout=True)
    axes = fig.subplots(1, len(rows), squeeze=False)[0]
    for ax, r in zip(axes, rows, strict=True):
        m = r["episodes"][0]["map0"]
        truth, means = np.array(m["truth"]).reshape(-1, 3), np.array(m["means"]).reshape(-1, 3)
        covs = np.array(m["covs"]).reshape(-1, 3, 3)
        shown = truth[:, :2] + MAGNIFY * (means - truth)[:, :2]
        ax.plot(truth[:, 0], truth[:, 1], "k.", ms=3, label="true landmark")
        for t, e, c in zip(truth[:, :2], shown, covs, strict=True):
            ax.plot([t[0], e[0]], [t[1], e[1]], "C3-", lw=0.8)
            vals, vecs = np.linalg.eigh(c[:2, :2])
            angle = math.degrees(math.atan2(vecs[1, 1], vecs[0, 1]))
            w, h = 2 * 2 * MAGNIFY * np.sqrt(np.maximum(vals[::-1], 0.0))
            ax.add_patch(Ellipse(tuple(e), w, h, angle=angle, fill=False, color="C0", lw=0.7))
        summary = r["summary"]
        ax.set_title(f"{r['row']}: map RMSE {summary['map_rmse_m'] or math.nan:.3f} m\n"
                     f"(mean of {len(r['episodes'])} seeds; seed {r['episodes'][0]['seed']} shown)",
                     fontsize=9)  # fmt: skip
        ax.set_xlabel("north (m)")
        ax.set_aspect("equal")
    axes[0].set_ylabel("east (m)")
    fig.suptitle(f"vehicle 0's map, team of {n}: errors (red) and 2σ ellipses (blue) ×{MAGNIFY:g}")
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "cooperative_map.png"
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=110))
    return path
