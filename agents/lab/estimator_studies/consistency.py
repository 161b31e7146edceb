"""Monte-Carlo consistency of an estimator with control and estimation decoupled.

The DF-LQR flies on an observation built from the **true** state (through the oracle's
snapshot), so the trajectory does not depend on the estimate; the estimator under test runs in
the env as usual and its pose NEES is recorded every step. Over ``n`` seeded runs the average
NEES at each time, ``ANEES_k = mean_runs NEES_k``, is compared with the two-sided 95% interval
of ``χ²(9 n) / n`` (Bar-Shalom, Li & Kirubarajan, §5.4).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import gymnasium as gym
import numpy as np

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from estimators.oracle import OracleBatch
from quadslam_env.metrics.step import anees_bounds


@dataclass
class ConsistencyResult:
    """ANEES over time and summary figures of a Monte-Carlo run.

    Attributes:
        t: (K,) times in s.
        nees: (n_runs, K) pose NEES of each run.
        anees: (K,) average over runs.
        bounds: Two-sided 95% interval of the ANEES.
        share_inside: Fraction of time steps with the ANEES inside the interval.
        pos_rmse_m: (n_runs,) position RMSE of each run.
        terminated: Number of runs that ended early.
        nees_pos: (n_runs, K) position NEES of each run (3 DOF).
    """

    t: np.ndarray
    nees: np.ndarray
    anees: np.ndarray
    bounds: tuple[float, float]
    share_inside: float
    pos_rmse_m: np.ndarray
    terminated: int
    nees_pos: np.ndarray | None = None

    def block_consistency(self, which: str = "pos") -> tuple[float, tuple[float, float], float]:
        """``(pooled ANEES, 95% interval of the n-run ANEES, share of steps inside it)`` of
        the pose (9 DOF, ``which="pose"``) or position (3 DOF, ``"pos"``) NEES."""
        nees, dof = (self.nees, 9) if which == "pose" else (self.nees_pos, 3)
        if nees is None:
            raise ValueError("no position NEES recorded")
        anees = nees.mean(axis=0)
        lo, hi = anees_bounds(dof, nees.shape[0])
        return float(anees.mean()), (lo, hi), float(np.mean((anees >= lo) & (anees <= hi)))


def truth_observation(env: Any, oracle: OracleBatch) -> np.ndarray:
    """The observation the env would emit if its estimator returned the true state.

    ``oracle`` is a one-lane :class:`~estimators.oracle.OracleBatch` (reused between calls).
    """
    base = env.unwrapped
    landmarks = np.asarray(base.landmarks, dtype=float)
    oracle.set_truth(base.true_state[None], landmarks[None], np.array([len(landmarks)]))
    return base.observation_from(oracle.lane_estimate(0))


def run_consistency(
    n_runs: int = 20, seed0: int = 0, env_id: str = "QuadSLAM-EKF-v0", **env_kwargs: Any
) -> ConsistencyResult:
    """Fly ``n_runs`` seeded episodes with a truth-driven DF-LQR and collect pose NEES."""
    env = gym.make(env_id, **env_kwargs)
    policy = DFLQRPolicy.from_env(env)
    oracle = OracleBatch(num_lanes=1, landmark_capacity=0)
    runs, runs_pos, rmses, terminated = [], [], [], 0
    for i in range(n_runs):
        env.reset(seed=seed0 + i)
        nees, nees_pos, pos_sq, t = [], [], [], []
        while True:
            action, _ = policy.predict(truth_observation(env, oracle))
            _, _, term, trunc, info = env.step(action)
            nees.append(info.get("est_nees_pose", np.nan))
            nees_pos.append(info.get("est_nees_pos", np.nan))
            pos_sq.append(info["est_pos_err_m"] ** 2)
            t.append(info["t"])
            if term or trunc:
                terminated += int(term)
                break
        runs.append(nees)
        runs_pos.append(nees_pos)
        rmses.append(float(np.sqrt(np.mean(pos_sq))))
    env.close()
    length = min(len(r) for r in runs)
    nees_arr = np.array([r[:length] for r in runs])
    anees = nees_arr.mean(axis=0)
    lo, hi = anees_bounds(9, n_runs)
    inside = float(np.mean((anees >= lo) & (anees <= hi)))
    return ConsistencyResult(
        t=np.array(t[:length]),
        nees=nees_arr,
        anees=anees,
        bounds=(lo, hi),
        share_inside=inside,
        pos_rmse_m=np.array(rmses),
        terminated=terminated,
        nees_pos=np.array([r[:length] for r in runs_pos]),
    )
