"""Is a seed set's attitude ANEES in the first seconds the filter's or its noise draws'?

For each set of ten seeds, flies ``paper_ekf_figure8`` (DF-LQR on EKF-SLAM, the scalar env)
for ``--duration`` seconds per seed and records, per step, the filter's attitude NEES (its
3×3 marginal, as ``quadslam study estimators`` computes it) and the gyro's white-noise draws
(the standard normals the simulated IMU scales by σ_ω). On the paper's IMU (no bias) and with
the scenario's zero initial attitude variance, the attitude error in the first seconds is the
gyro noise integrated, less what the LiDAR corrects: a filter that is consistent follows its
draws. The draws' own statistic, independent of any filter, is the random walk
``W_T = Σ_{k ≤ n} z_k / √n`` (n the samples up to T s) per axis: ``Σ_axes W_T²`` is χ²(3) for
honest draws, and its mean over ten seeds has the same 95% interval [1.68, 4.70] as the
filter's 10-run attitude ANEES.

    python tools/attitude_noise_draws.py --out docs/results/attitude_noise_draws.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.lab.estimator_studies.particle_nees import block_nees
from quadslam_env.metrics.step import anees_bounds
from quadslam_env.models.frames import wrap_angle
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.types import EUL

GYRO = slice(3, 6)
"""The gyro's white-noise columns of the IMU's 12 normals per sample (accel 0:3, gyro 3:6,
then the drift steps)."""


def fly(seed: int, duration_s: float) -> tuple[np.ndarray, np.ndarray, float]:
    """One seed: the filter's attitude NEES per step (K,), the gyro normals drawn (S, 3) in
    sample order, and the IMU sample period in s."""
    blocks: list[np.ndarray] = []
    refill = ImuBatch._refill

    def recording(self: ImuBatch, lanes: np.ndarray) -> None:
        empty = lanes[self._cursor[lanes] >= self.BLOCK]
        refill(self, lanes)
        blocks.extend(self._noise[lane, :, GYRO].copy() for lane in empty.tolist())

    ImuBatch._refill = recording  # type: ignore[method-assign]
    try:
        env = gym.make(
            "QuadSLAM-v0", scenario="paper_ekf_figure8", episode={"duration_s": duration_s}
        )
        policy = DFLQRPolicy.from_env(env)
        obs, _ = env.reset(seed=seed)
        core = env.unwrapped.core  # type: ignore[attr-defined]
        nees: list[float] = []
        done = False
        while not done:
            action, _ = policy.predict(obs, deterministic=True)
            obs, _, terminated, truncated, _ = env.step(action)
            est, x = core.est, core.vehicle.state[0]
            err = np.zeros(9)
            err[6:] = wrap_angle(est.euler[0] - x[EUL])
            cov = est.pose_cov[0]
            nees.append(block_nees(err, cov)["att"])
            done = terminated or truncated
        period = core.imu.period
        env.close()
    finally:
        ImuBatch._refill = refill  # type: ignore[method-assign]
    return np.array(nees), np.concatenate(blocks), period


def walk_nees(normals: np.ndarray, n: int) -> float:
    """``Σ_axes (Σ_{k<n} z_k / √n)²`` of the first ``n`` samples' normals (S, 3): χ²(3)."""
    w = normals[:n].sum(axis=0) / np.sqrt(n)
    return float(w @ w)


def pool(n_seeds: int, window_s: float) -> dict[str, Any]:
    """The draws' walk statistic over ``window_s`` on seeds 0 … n_seeds − 1: its mean (3 for
    honest draws) and, over the disjoint sets of ten seeds, the share of sets whose mean is
    outside the 10-run interval [1.68, 4.70], and the largest set mean."""
    stats = []
    for seed in range(n_seeds):
        _, normals, period = fly(seed, window_s)
        stats.append(walk_nees(normals, round(window_s / period)))
    sets = np.array(stats[: n_seeds // 10 * 10]).reshape(-1, 10).mean(axis=1)
    low, high = anees_bounds(3, 10)
    return {
        "seeds": n_seeds,
        "window_s": window_s,
        "mean": float(np.mean(stats)),
        "sets_outside": float(np.mean((sets < low) | (sets > high))),
        "largest_set_mean": float(sets.max()),
    }


def main() -> None:
    """Write, per seed set, the filter's attitude ANEES and the draws' walk statistic."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--sets", default="100,200,300,310,320,330,340,350")
    parser.add_argument("--duration", type=float, default=6.0, help="seconds per flight")
    parser.add_argument("--windows", default="1,3,6", help="walk windows T, s")
    parser.add_argument(
        "--pool", type=int, default=500, help="seeds 0… of the draws' check (1 s flights)"
    )
    args = parser.parse_args()
    windows = [float(w) for w in args.windows.split(",")]
    result: dict[str, Any] = {"command": "python tools/attitude_noise_draws.py", "sets": {}}
    per_seed: list[tuple[float, float]] = []
    for first in (int(s) for s in args.sets.split(",")):
        rows = [fly(seed, args.duration) for seed in range(first, first + 10)]
        period = rows[0][2]
        filt = float(np.mean([r[0].mean() for r in rows]))
        walks = {
            f"{w:g}": float(np.mean([walk_nees(r[1], round(w / period)) for r in rows]))
            for w in windows
        }
        result["sets"][str(first)] = {"filter_att_anees": filt, "gyro_walk_anees": walks}
        last = round(windows[-1] / period)
        per_seed += [(float(r[0].mean()), walk_nees(r[1], last)) for r in rows]
        print(first, f"filter {filt:.2f}", {k: round(v, 2) for k, v in walks.items()}, flush=True)
    a = np.array(per_seed)
    result["per_seed_correlation"] = float(np.corrcoef(a[:, 0], a[:, 1])[0, 1])
    print("per-seed correlation", round(result["per_seed_correlation"], 3))
    result["pool"] = pool(args.pool, windows[0])
    print("pool", result["pool"])
    args.out.write_text(json.dumps(result, indent=2) + "\n")


if __name__ == "__main__":
    main()
