"""The team's map against the true landmark field (docs/team.md "Info"): each vehicle's
landmark consistency, the team's map error and how much of the field the team has mapped.

Per vehicle (its lane snapshot: the mapped landmarks' means and 3×3 covariances by id):

- ``est_landmark_anees``: the mean over its mapped landmarks j of the NEES
  ``(l̂_j − l_j)ᵀ P_jj⁻¹ (l̂_j − l_j)`` (3 DOF each; ``‖L⁻¹e‖²`` with ``P_jj = L Lᵀ``, the
  pose NEES's :func:`quadslam_env.metrics.cholesky_nees` where a block is not positive
  definite);

for the team (the vehicles of the step):

- ``team_map_rmse_m``: the mean over the vehicles with a landmark mapped of their own map RMSE,
  √(mean over its mapped landmarks of ‖l̂_j − l_j‖²) (the single env's ``est_map_rmse_m`` of
  the same step: messages are fused at the start of a step);
- ``team_union_map_rmse_m``: the map RMSE of the union of the vehicles' maps, where each
  landmark takes the estimate of the lowest-numbered vehicle that has mapped it (vehicle 0's
  map, completed by vehicle 1's, …; with fusion each estimate already holds what the vehicle
  received);
- ``team_n_mapped``: the landmarks mapped by at least one vehicle.

The episode summaries take each vehicle's map at its last step (``team_episode_*``).
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.estimation import BatchEstimator
from quadslam_env.metrics import cholesky_nees
from quadslam_env.types import FloatArray

TERMS = ("team_map_rmse_m", "team_union_map_rmse_m", "team_n_mapped")
"""The team's map terms of every vehicle's info, and (as ``team_episode_*``) of the summary."""


def landmark_anees(means: FloatArray, covs: FloatArray, truth: FloatArray) -> float:
    """Mean NEES of landmark estimates against the truth.

    Args:
        means: (k, 3) estimated landmark positions, m, N frame.
        covs: (k, 3, 3) their covariances, m².
        truth: (k, 3) the true positions, m, N frame.

    Returns:
        ``(1/k) Σ_j e_jᵀ P_jj⁻¹ e_j`` (NaN for k = 0; inf if a covariance is not positive
        semi-definite).
    """
    if means.shape[0] == 0:
        return math.nan
    err = means - truth
    try:  # all at once; a covariance that is not positive definite: one by one below
        y = np.linalg.solve(np.linalg.cholesky(covs), err[:, :, None])
        return float(np.sum(y * y)) / means.shape[0]
    except np.linalg.LinAlgError:
        pass
    L, y = np.empty((3, 3)), np.empty(3)
    total = 0.0
    for j in range(means.shape[0]):
        total += cholesky_nees(covs[j], err[j], L, y)[0]
    return total / means.shape[0]


class MapMetrics:
    """Each vehicle's latest map and the team's terms over them (module docstring).

    Args:
        n_vehicles: N.
    """

    def __init__(self, n_vehicles: int) -> None:
        self.n_vehicles = n_vehicles
        self._maps: list[tuple[np.ndarray, FloatArray] | None] = [None] * n_vehicles
        self._anees = np.full(n_vehicles, math.nan)

    def reset(self) -> None:
        """Forget the maps of the last episode."""
        self._maps = [None] * self.n_vehicles
        self._anees[:] = math.nan

    def observe(
        self, estimator: BatchEstimator, truth: FloatArray, count: int, lanes: np.ndarray
    ) -> FloatArray:
        """Read the maps of the vehicles ``lanes`` (N,) bool after a reset or a step.

        Args:
            estimator: The core's estimator (each vehicle's lane snapshot is read).
            truth: (≥ count, 3) the shared true landmark positions, m, N frame.
            count: The number of true landmarks.
            lanes: (N,) bool the vehicles to read.

        Returns:
            (N,) each vehicle's ``est_landmark_anees`` (NaN outside ``lanes`` or with
            nothing mapped).
        """
        out = np.full(self.n_vehicles, math.nan)
        for i in np.flatnonzero(lanes).tolist():
            ids, means, covs = estimator.lane_estimate(i).mapped_landmarks(0)
            keep = ids < count  # a phantom's id is no landmark of the field
            ids, means, covs = ids[keep], means[keep], covs[keep]
            self._maps[i] = (ids, means)
            out[i] = self._anees[i] = landmark_anees(means, covs, truth[ids])
        return out

    def terms(self, truth: FloatArray, lanes: np.ndarray) -> dict[str, float]:
        """:data:`TERMS` over the latest maps of the vehicles ``lanes`` (N,) bool (NaN where
        none has a landmark mapped)."""
        rmse: list[float] = []
        union: dict[int, FloatArray] = {}
        for i in np.flatnonzero(lanes).tolist():
            held = self._maps[i]
            if held is None or held[0].size == 0:
                continue
            ids, means = held
            rmse.append(math.sqrt(float(np.mean(np.sum((means - truth[ids]) ** 2, axis=1)))))
            for j, mean in zip(ids.tolist(), means, strict=True):
                union.setdefault(j, mean)
        if not union:
            return {"team_map_rmse_m": math.nan, "team_union_map_rmse_m": math.nan,
                    "team_n_mapped": 0.0}  # fmt: skip
        ids = np.fromiter(union, dtype=np.int64)
        means = np.stack(list(union.values()))
        err2 = np.sum((means - truth[ids]) ** 2, axis=1)
        return {
            "team_map_rmse_m": float(np.mean(rmse)),
            "team_union_map_rmse_m": math.sqrt(float(np.mean(err2))),
            "team_n_mapped": float(ids.size),
        }

    def summary(self, truth: FloatArray) -> dict[str, float]:
        """The episode's ``team_episode_*`` terms over every vehicle's last map, and
        ``team_episode_landmark_anees``, the mean of the vehicles' last landmark ANEES."""
        every = np.ones(self.n_vehicles, dtype=bool)
        out = {f"team_episode_{k[5:]}": v for k, v in self.terms(truth, every).items()}
        finite = self._anees[np.isfinite(self._anees)]
        out["team_episode_landmark_anees"] = float(np.mean(finite)) if finite.size else math.nan
        return out
