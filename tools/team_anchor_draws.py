"""Is the centralised team's landmark ANEES its graph's or its seeds' initial-error draws?

A team's map is anchored only by the vehicles' start priors (docs/team-fusion.md "One smoother
of the team"): the error of the frame is the information-weighted mean of the vehicles'
initial position errors, ``e = I⁻¹ Σ_i P_i⁻¹ δρ_i`` with ``I = Σ_i P_i⁻¹`` (P_i the
position block of vehicle i's P0, δρ_i its drawn initial error), and no measurement corrects
it. Its NEES ``eᵀ I e`` is χ²(3) for honest draws, so its mean over the study's seeds says how
large these seeds' draws are, and per seed it can be set beside the map's ANEES
(``docs/results/cooperative.json``, the ``centralised`` rows). Only resets, no flight::

    python tools/team_anchor_draws.py --out docs/results/cooperative_anchor_draws.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np
from scipy.stats import chi2

from quadslam_env.team.env import parallel_env
from quadslam_env.types import POS

SCENARIO = "paper_ekf_figure8"
"""The cooperative study's scenario."""


def anchor_nees(n_vehicles: int, seed: int) -> float:
    """The NEES of the frame error of a team of ``n_vehicles`` reset with ``seed``."""
    env = parallel_env(
        n_vehicles=n_vehicles,
        scenario=SCENARIO,
        team={"fusion": "centralised"},
        estimator_name="isam2",
    )
    env.reset(seed=seed)
    est, state = env.core.est, env.core.vehicle.state
    errors = est.position - state[:, POS]
    assert est.pose_cov is not None  # iSAM2 reports its covariance
    infos = [np.linalg.inv(P[:3, :3]) for P in est.pose_cov]
    total = sum(infos)
    e = np.linalg.solve(total, sum(W @ r for W, r in zip(infos, errors, strict=True)))
    return float(e @ total @ e)


def main() -> None:
    """Write, per team size, each seed's anchor NEES beside its map ANEES, their correlation
    and the anchor's mean against its χ² interval."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--study", type=Path, default=Path("docs/results/cooperative.json"))
    args = parser.parse_args()
    study = json.loads(args.study.read_text())
    result: dict[str, Any] = {"command": "python tools/team_anchor_draws.py", "sizes": {}}
    for row in study["rows"]:
        if row["row"] != "centralised":
            continue
        n, episodes = row["n_vehicles"], row["episodes"]
        anchor = np.array([anchor_nees(n, e["seed"]) for e in episodes])
        maps = np.array([e["nees_sum"] / e["landmarks"] for e in episodes])
        dof = 3 * len(episodes)
        low, high = chi2.ppf([0.025, 0.975], dof) / len(episodes)
        result["sizes"][str(n)] = {
            "seeds": [e["seed"] for e in episodes],
            "anchor_nees": anchor.round(3).tolist(),
            "map_anees": maps.round(3).tolist(),
            "correlation": float(np.corrcoef(anchor, maps)[0, 1]),
            "anchor_mean": float(anchor.mean()),
            "anchor_mean_95": [float(low), float(high)],
        }
        print(n, f"anchor mean {anchor.mean():.2f} in [{low:.2f}, {high:.2f}]",
              f"correlation {result['sizes'][str(n)]['correlation']:.2f}")  # fmt: skip
    args.out.write_text(json.dumps(result, indent=1) + "\n")


if __name__ == "__main__":
    main()
