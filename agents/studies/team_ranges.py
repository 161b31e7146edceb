"""``python -m agents.studies.team_ranges``: do the ranges between vehicles make a team's
estimates better (docs/team.md "Ranges between vehicles")?

A team of N vehicles on the paper's figure-8 (``paper_ekf_figure8``, the team's default phase
offsets), each flown by DF-LQR on its own EKF-SLAM estimate, on the same seeds in every row
(:data:`ROWS`): ``independent``; ``independent`` with the ranges fused by CI
(``team.ranges``, ``range_fusion: ci``, the range defaults: σ 0.1 m at 10 Hz); landmark
messages fused by CI; and both. Per row, means over the seeds: the team position RMSE
(``team_episode_est_pos_rmse_m``), the team map RMSE (``team_episode_map_rmse_m``), the union
map RMSE, the vehicles that ended early, the kB broadcast per episode, and the CI weight ω of
the fused ranges (median and the share below 0.99; ω → 1 is a range fused with almost no
weight).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np

SCENARIO = "paper_ekf_figure8"
ROWS: dict[str, dict[str, Any]] = {
    "independent": {"fusion": "independent"},
    "independent + ranges ci": {"fusion": "independent", "ranges": True, "range_fusion": "ci"},
    "ci": {"fusion": "ci"},
    "ci + ranges ci": {"fusion": "ci", "ranges": True, "range_fusion": "ci"},
}
"""The rows: the ``team`` settings of each."""


def fly(n_vehicles: int, team: dict[str, Any], seed: int, duration_s: float) -> dict[str, Any]:
    """One team episode of ``duration_s`` s: its end-of-episode terms and the fused ranges' ω."""
    import gymnasium as gym

    from agents.control.dflqr import DFLQRPolicy
    from quadslam_env.team import parallel_env

    episode = {"duration_s": duration_s}
    policy = DFLQRPolicy.from_env(gym.make("QuadSLAM-v0", scenario=SCENARIO, episode=episode))
    env = parallel_env(n_vehicles=n_vehicles, scenario=SCENARIO, team=team, episode=episode)
    obs, _ = env.reset(seed=seed)
    last: dict[str, dict[str, Any]] = {}
    omegas: list[float] = []
    while env.agents:
        obs, _, _, _, infos = env.step({a: policy.predict(obs[a])[0] for a in env.agents})
        last.update(infos)
        omegas += [i["team_range_ci_weight"] for i in infos.values() if "team_range_ci_weight" in i]
    final = last[max(last, key=lambda a: env.core.steps[env.possible_agents.index(a)])]
    return {
        "seed": seed,
        "pos_rmse_m": float(final["team_episode_est_pos_rmse_m"]),
        "map_rmse_m": float(final["team_episode_map_rmse_m"]),
        "union_map_rmse_m": float(final["team_episode_union_map_rmse_m"]),
        "ended_early": int(sum(bool(i.get("termination_reason")) for i in last.values())),
        "bytes": float(final.get("team_episode_bytes_sent", 0.0)),
        "omegas": omegas,
    }


def summarise(episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """A row's means over its episodes, and its fused ranges' ω."""
    omegas = np.concatenate([np.asarray(e["omegas"], dtype=float) for e in episodes])
    return {
        "pos_rmse_m": float(np.mean([e["pos_rmse_m"] for e in episodes])),
        "map_rmse_m": float(np.mean([e["map_rmse_m"] for e in episodes])),
        "union_map_rmse_m": float(np.mean([e["union_map_rmse_m"] for e in episodes])),
        "ended_early": int(sum(e["ended_early"] for e in episodes)),
        "kb_sent": float(np.mean([e["bytes"] for e in episodes]) / 1e3),
        "omega_median": float(np.median(omegas)) if omegas.size else None,
        "omega_below_0.99": float(np.mean(omegas < 0.99)) if omegas.size else None,
    }


def table(rows: dict[str, dict[str, Any]], n_vehicles: int, seeds: int) -> str:
    """The rows as a Markdown table."""
    base = rows["independent"]
    lines = [
        "| team | position RMSE (m) | × independent | team map RMSE (m) | × independent | "
        "union map RMSE (m) | vehicles ended early | kB sent per episode | ranges' ω: median, "
        "share < 0.99 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for name, r in rows.items():
        omega = (
            "–"
            if r["omega_median"] is None
            else f"{r['omega_median']:.6f}, {r['omega_below_0.99']:.3f}"
        )
        lines.append(
            f"| {name} | {r['pos_rmse_m']:.4f} | {r['pos_rmse_m'] / base['pos_rmse_m']:.3f} | "
            f"{r['map_rmse_m']:.4f} | {r['map_rmse_m'] / base['map_rmse_m']:.3f} | "
            f"{r['union_map_rmse_m']:.4f} | {r['ended_early']} of {n_vehicles * seeds} | "
            f"{r['kb_sent']:.0f} | {omega} |"
        )
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> int:
    """Fly every row on the seeds, print the table (and write ``--json``)."""
    parser = argparse.ArgumentParser(
        prog="python -m agents.studies.team_ranges", description=__doc__
    )
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--vehicles", type=int, default=4)
    parser.add_argument("--duration", type=float, default=50.0, help="episode length, s")
    parser.add_argument("--json", default=None, help="write the rows and episodes here")
    args = parser.parse_args(argv)
    seeds = range(args.first_seed, args.first_seed + args.seeds)
    episodes = {
        name: [fly(args.vehicles, team, s, args.duration) for s in seeds]
        for name, team in ROWS.items()
    }
    rows = {name: summarise(eps) for name, eps in episodes.items()}
    print(table(rows, args.vehicles, args.seeds))
    if args.json is not None:
        with open(args.json, "w", encoding="utf-8") as f:
            json.dump({"rows": rows, "episodes": episodes, "argv": list(argv or sys.argv[1:])}, f)
    return 0


if __name__ == "__main__":
    sys.exit(main())
