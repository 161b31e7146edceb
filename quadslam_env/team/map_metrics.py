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

from quadslam_env.estimation import BatchEstimator, ReportsLandmarkCovariances
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


def _lanes_anees(
    mapped: np.ndarray, means: FloatArray, covs: FloatArray, truth: FloatArray
) -> FloatArray:
    """:func:`landmark_anees` of k lanes at once.

    Args:
        mapped: (k, L) bool each lane's mapped landmarks, by id.
        means: (k, L, 3) their estimates, m, N frame.
        covs: (k, L, 3, 3) their covariances, m².
        truth: (L, 3) the true positions, m, N frame.

    Returns:
        (k,) each lane's landmark ANEES (NaN with nothing mapped).
    """
    lane, ids = np.nonzero(mapped)
    n = mapped.sum(axis=1)
    out = np.full(mapped.shape[0], math.nan)
    try:  # all at once; a covariance that is not positive definite: lane by lane below
        err = (means[lane, ids] - truth[ids])[:, :, None]
        y = np.linalg.solve(np.linalg.cholesky(covs[lane, ids]), err)
        total = np.bincount(lane, weights=np.sum(y * y, axis=(1, 2)), minlength=n.size)
        out[n > 0] = total[n > 0] / n[n > 0]
    except np.linalg.LinAlgError:
        for row in np.flatnonzero(n).tolist():
            got = mapped[row]
            out[row] = landmark_anees(means[row, got], covs[row, got], truth[got])
    return out


class MapMetrics:
    """Each vehicle's latest map and the team's terms over them (module docstring).

    Args:
        n_vehicles: N.
    """

    def __init__(self, n_vehicles: int) -> None:
        self.n_vehicles = n_vehicles
        self._mapped = np.zeros((n_vehicles, 0), dtype=bool)  # (N, L) the latest maps, by id
        self._means = np.zeros((n_vehicles, 0, 3))
        self._anees = np.full(n_vehicles, math.nan)

    def reset(self) -> None:
        """Forget the maps of the last episode."""
        self._mapped[:] = False
        self._anees[:] = math.nan

    def observe(
        self, estimator: BatchEstimator, truth: FloatArray, count: int, lanes: np.ndarray
    ) -> FloatArray:
        """Read the maps of the vehicles ``lanes`` (N,) bool after a reset or a step: all at
        once from an estimator that :class:`ReportsLandmarkCovariances`, else from each
        vehicle's lane snapshot.

        Args:
            estimator: The core's estimator.
            truth: (≥ count, 3) the shared true landmark positions, m, N frame.
            count: The number of true landmarks (a phantom's id, beyond them, is left out).
            lanes: (N,) bool the vehicles to read.

        Returns:
            (N,) each vehicle's ``est_landmark_anees`` (NaN outside ``lanes`` or with
            nothing mapped).
        """
        if self._mapped.shape[1] != count:
            self._mapped = np.zeros((self.n_vehicles, count), dtype=bool)
            self._means = np.zeros((self.n_vehicles, count, 3))
        sel = np.flatnonzero(lanes)
        if isinstance(estimator, ReportsLandmarkCovariances):
            est = estimator.estimate()
            mapped = est.landmark_mapped[sel, :count]
            means = est.landmark_means[sel, :count]
            covs = estimator.landmark_covariances()[sel, :count]
        else:
            mapped = np.zeros((sel.size, count), dtype=bool)
            means, covs = np.zeros((sel.size, count, 3)), np.zeros((sel.size, count, 3, 3))
            for row, i in enumerate(sel.tolist()):
                ids, m, c = estimator.lane_estimate(i).mapped_landmarks(0)
                keep = ids < count
                mapped[row, ids[keep]] = True
                means[row, ids[keep]], covs[row, ids[keep]] = m[keep], c[keep]
        self._mapped[sel], self._means[sel] = mapped, means
        self._anees[sel] = _lanes_anees(mapped, means, covs, truth[:count])
        out = np.full(self.n_vehicles, math.nan)
        out[sel] = self._anees[sel]
        return out

    def terms(self, truth: FloatArray, lanes: np.ndarray) -> dict[str, float]:
        """:data:`TERMS` over the latest maps of the vehicles ``lanes`` (N,) bool (NaN where
        none has a landmark mapped)."""
        mapped, means = self._mapped[lanes], self._means[lanes]
        count = mapped.shape[1]
        err2 = np.sum((means - truth[:count]) ** 2, axis=2)  # (k, L)
        n = mapped.sum(axis=1)
        if not n.any():
            return {"team_map_rmse_m": math.nan, "team_union_map_rmse_m": math.nan,
                    "team_n_mapped": 0.0}  # fmt: skip
        has = n > 0
        rmse = np.sqrt(np.sum(err2 * mapped, axis=1)[has] / n[has])
        union = mapped.any(axis=0)  # (L,): the lowest-numbered vehicle's estimate of each
        first = np.argmax(mapped, axis=0)[union]
        union_err2 = err2[first, np.flatnonzero(union)]
        return {
            "team_map_rmse_m": float(np.mean(rmse)),
            "team_union_map_rmse_m": math.sqrt(float(np.mean(union_err2))),
            "team_n_mapped": float(union.sum()),
        }

    def summary(self, truth: FloatArray) -> dict[str, float]:
        """The episode's ``team_episode_*`` terms over every vehicle's last map, and
        ``team_episode_landmark_anees``, the mean of the vehicles' last landmark ANEES."""
        every = np.ones(self.n_vehicles, dtype=bool)
        out = {f"team_episode_{k[5:]}": v for k, v in self.terms(truth, every).items()}
        finite = self._anees[np.isfinite(self._anees)]
        out["team_episode_landmark_anees"] = float(np.mean(finite)) if finite.size else math.nan
        return out
