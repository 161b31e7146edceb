"""The team's terms in every vehicle's ``info`` (docs/team.md "Info"): the team's position
error now, the closest two vehicles, and the team's position RMSE over the episode.

Each vehicle's own terms are the single env's (its ``est_*`` errors, ``episode_*`` summaries
when it ends); these add what only the team has:

- ``team_est_pos_rmse_m``: √(mean of ``est_pos_err_m``² over the vehicles of the step), m;
- ``team_min_separation_m``: the smallest true distance between two of them, m (N ≥ 2);
- ``team_episode_est_pos_rmse_m``: √(Σ ``est_pos_err_m``² / Σ steps) over every vehicle's
  steps of the episode, m, in the infos of the step that ends the last vehicles.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.team.collision import min_separation
from quadslam_env.types import POS, FloatArray


class TeamMetrics:
    """The team's terms of one episode.

    Args:
        n_vehicles: N.
    """

    def __init__(self, n_vehicles: int) -> None:
        self.n_vehicles = int(n_vehicles)
        self._sum_sq = 0.0
        self._steps = 0

    def reset(self) -> None:
        """Start a new episode's sums."""
        self._sum_sq = 0.0
        self._steps = 0

    def terms(self, pos_err: FloatArray, state: FloatArray, lanes: np.ndarray) -> dict[str, float]:
        """The team's terms of a reset or a step.

        Args:
            pos_err: (N,) each vehicle's ``est_pos_err_m``, m.
            state: (N, 12) true states.
            lanes: (N,) bool, the vehicles reset or stepped now.

        Returns:
            ``team_est_pos_rmse_m`` and, with N ≥ 2, ``team_min_separation_m`` (NaN where they
            do not apply).
        """
        err = pos_err[lanes]
        out = {
            "team_est_pos_rmse_m": math.sqrt(float(np.mean(err * err))) if err.size else math.nan
        }
        if self.n_vehicles >= 2:
            out["team_min_separation_m"] = min_separation(state[:, POS], lanes)
        return out

    def add(self, pos_err: FloatArray, lanes: np.ndarray) -> None:
        """Count the step of the vehicles ``lanes`` (N,) bool with their errors ``pos_err``
        (N,) m in the episode's sums."""
        err = pos_err[lanes]
        self._sum_sq += float(np.dot(err, err))
        self._steps += int(err.size)

    def summary(self) -> dict[str, float]:
        """``team_episode_est_pos_rmse_m`` over the steps counted since :meth:`reset`."""
        rmse = math.sqrt(self._sum_sq / self._steps) if self._steps else math.nan
        return {"team_episode_est_pos_rmse_m": rmse}
