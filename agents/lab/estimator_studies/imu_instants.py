"""An IMU slower than the control: the estimate at the IMU instants and between them.

``quadslam study imu-instants --scenario paper_ekf_figure8 --seeds 10 \
--set imu.rate_hz=10``

With a slow IMU the env reports, between two IMU samples, the filter's belief carried forward
with the last sample held (:mod:`quadslam_env.runtime.imu_replay`). This flies the DF-LQR on the
estimate (each seed a lane of one vector env, as ``quadslam run``) and splits the steps into
those at an IMU instant (every m-th step, where the output is the filter itself) and those
between: per seed the position and attitude RMSE, and the pose ANEES (9 DOF) pooled over the
seeds, of each set.
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.io.overrides import parse_overrides
from agents.lab.estimator_studies.degradation import save_json, seeded_lanes


def split_at_instants(
    scenario: str, seeds: Sequence[int], overrides: dict[str, Any]
) -> dict[str, Any]:
    """Fly the seeds for one episode each and summarise the two sets of steps.

    Returns:
        ``{"steps_per_imu", "at_imu" {...}, "between" {...}}`` with, per set, the median over
        seeds of the position RMSE (m) and attitude RMSE (deg), and the pooled pose ANEES.
    """
    env, policy, obs, core = seeded_lanes(scenario, seeds, overrides)
    pos, att, nees = [], [], []
    for _ in range(core.max_steps):
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        pos.append(info["est_pos_err_m"])
        att.append(info["est_att_err_deg"])
        nees.append(info["est_nees_pose"])
        if (term | trunc).any():  # a lane ended: the rest would mix episodes
            break
    env.close()
    m = core.scenario.steps_per_imu
    at = (np.arange(len(pos)) + 1) % m == 0
    out: dict[str, Any] = {"steps_per_imu": m, "steps": len(pos)}
    for name, sel in (("at_imu", at), ("between", ~at)):
        if not sel.any():
            continue
        p, a, n = (np.array(v)[sel] for v in (pos, att, nees))
        out[name] = {
            "pos_rmse_m": float(np.median(np.sqrt(np.mean(p**2, axis=0)))),
            "att_rmse_deg": float(np.median(np.sqrt(np.mean(a**2, axis=0)))),
            "anees_pose": float(np.mean(n)),
        }
    return out


def main(argv: Sequence[str] | None = None) -> int:
    """``quadslam study imu-instants``: print (and with ``--json`` write) the split."""
    parser = argparse.ArgumentParser(prog="quadslam study imu-instants", description=__doc__)
    from agents.io.paths import check_output_file

    parser.add_argument("--scenario", default="paper_ekf_figure8")
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--set", action="append", default=[], metavar="SECTION.KEY=VALUE")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args(argv)
    if args.json is not None:
        check_output_file(args.json, "--json")  # before the flight
    result = split_at_instants(args.scenario, range(args.seeds), parse_overrides(args.set))
    result = {"scenario": args.scenario, "seeds": args.seeds, "set": args.set, **result}
    print(json.dumps(result, indent=1))
    if args.json is not None:
        return save_json(args.json, result, parser.prog)  # atomic; kept on a full disk
    return 0
