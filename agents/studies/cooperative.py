"""A first measurement of the team's map fusion (docs/team.md "A first measurement"):
``python -m agents.studies.cooperative [--seeds 10] [--vehicles 4] [--duration 50]``.

N vehicles on the paper's figure-8 (``paper_ekf_figure8``, phase-shifted by the team's default
offsets), each flown by DF-LQR on its own EKF-SLAM estimate, with ``team.fusion``
``independent``, ``ci`` and ``naive`` on the same seeds. Per fusion mode: the team map RMSE and
the union map RMSE at the episode's end (mean over seeds), the landmark ANEES pooled over every
vehicle's mapped landmarks of every seed at the end, with its two-sided 95% χ² interval
(``anees_bounds(3, count)``, which treats the landmarks as independent), the vehicles that
diverged and the bytes sent.
"""

from __future__ import annotations

import argparse
import math
import platform
from typing import Any

import numpy as np

MODES = ("independent", "ci", "naive")
SCENARIO = "paper_ekf_figure8"


def fly(mode: str, seed: int, n_vehicles: int, duration_s: float) -> dict[str, Any]:
    """One episode of the team with ``team.fusion = mode``; its end-of-episode terms."""
    import gymnasium as gym

    from agents.control.dflqr import DFLQRPolicy
    from quadslam_env.team import parallel_env

    episode = {"duration_s": duration_s}
    policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-v0", scenario=SCENARIO, episode=episode))
    env = parallel_env(n_vehicles=n_vehicles, scenario=SCENARIO, team={"fusion": mode},
                       episode=episode)  # fmt: skip
    obs, _ = env.reset(seed=seed)
    last: dict[str, dict[str, Any]] = {}
    while env.agents:
        obs, _, _, _, infos = env.step({a: policy.predict(obs[a])[0] for a in env.agents})
        last.update(infos)
    final = last[max(last, key=lambda a: env.core.steps[env.possible_agents.index(a)])]
    nees = sum(i["est_landmark_anees"] * i["est_n_mapped"] for i in last.values())
    return {
        "map_rmse_m": final["team_episode_map_rmse_m"],
        "union_map_rmse_m": final["team_episode_union_map_rmse_m"],
        "nees_sum": nees,
        "landmarks": sum(i["est_n_mapped"] for i in last.values()),
        "diverged": sum(bool(i.get("termination_reason")) for i in last.values()),
        "bytes": final.get("team_episode_bytes_sent", 0.0),
    }


def run_study(seeds: int, n_vehicles: int, duration_s: float) -> dict[str, Any]:
    """Every mode on seeds ``0 … seeds-1``; the rows of :func:`format_study`."""
    from quadslam_env.metrics import anees_bounds

    rows = {}
    for mode in MODES:
        runs = [fly(mode, seed, n_vehicles, duration_s) for seed in range(seeds)]
        count = int(sum(r["landmarks"] for r in runs))
        rows[mode] = {
            "map_rmse_m": float(np.mean([r["map_rmse_m"] for r in runs])),
            "union_map_rmse_m": float(np.mean([r["union_map_rmse_m"] for r in runs])),
            "landmark_anees": sum(r["nees_sum"] for r in runs) / count,
            "anees_95": anees_bounds(3, count),
            "diverged": int(sum(r["diverged"] for r in runs)),
            "kb_sent": float(np.mean([r["bytes"] for r in runs])) / 1e3,
        }
    base = rows["independent"]["map_rmse_m"]
    for row in rows.values():
        row["rmse_ratio"] = row["map_rmse_m"] / base if base > 0 else math.nan
    settings = {
        "seeds": seeds,
        "n_vehicles": n_vehicles,
        "duration_s": duration_s,
        "scenario": SCENARIO,
        "machine": platform.processor() or platform.machine(),
    }
    return {"settings": settings, "rows": rows}


def format_study(result: dict[str, Any]) -> str:
    """The result as a Markdown table."""
    s = result["settings"]
    out = [
        f"{s['n_vehicles']} vehicles, {s['scenario']}, {s['seeds']} seeds, {s['duration_s']} s",
        "",
        "| fusion | team map RMSE (m) | × independent | union map RMSE (m) | landmark ANEES "
        "| 95% interval | diverged vehicles | kB sent per episode |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for mode, r in result["rows"].items():
        lo, hi = r["anees_95"]
        out.append(
            f"| {mode} | {r['map_rmse_m']:.4f} | {r['rmse_ratio']:.2f} | "
            f"{r['union_map_rmse_m']:.4f} | {r['landmark_anees']:.3g} | [{lo:.2f}, {hi:.2f}] | "
            f"{r['diverged']} | {r['kb_sent']:.0f} |"
        )
    return "\n".join(out)


def main(argv: list[str] | None = None) -> None:
    """The command line (module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--vehicles", type=int, default=4)
    parser.add_argument("--duration", type=float, default=50.0)
    args = parser.parse_args(argv)
    print(format_study(run_study(args.seeds, args.vehicles, args.duration)))


if __name__ == "__main__":
    main()
