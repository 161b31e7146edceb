"""The team's map against the true landmark field (docs/team.md "Info"): each vehicle's
landmark consistency, the team's map error and how much of the field the team has mapped.

Per vehicle (its mapped landmarks' means and 3×3 covariances by id, read for all vehicles at
once from an estimator that reports them, else from each one's lane snapshot):

- ``est_landmark_anees``: the mean over its mapped landmarks j of the NEES
  ``(l̂_j − l_j)ᵀ P_jj⁻¹ (l̂_j − l_j)`` (3 DOF each; ``‖L⁻¹e‖²`` with ``P_jj = L Lᵀ``, the
  pose NEES's :func:`quadslam_env.metrics.cholesky_nees`);

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
from typing import cast

import numpy as np

from quadslam_env.estimation.protocol import BatchEstimator, ReportsLandmarkCovariances
from quadslam_env.metrics.step import cholesky_nees
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

TERMS = ("team_map_rmse_m", "team_union_map_rmse_m", "team_n_mapped")
"""The team's map terms of every vehicle's info, and (as ``team_episode_*``) of the summary."""


@kernel
def lanes_map_errors(
    mapped: np.ndarray,
    means: FloatArray,
    covs: FloatArray,
    truth: FloatArray,
    nees: FloatArray,
    sq: FloatArray,
) -> None:
    """Each lane's sums over its mapped landmarks of the NEES and the squared error, in place.

    Args:
        mapped: (k, L) bool each lane's mapped landmarks, by id.
        means: (k, L, 3) their estimates, m, N frame.
        covs: (k, L, 3, 3) their covariances, m².
        truth: (L, 3) the true positions, m, N frame.
        nees: (k,) out: Σ_j e_jᵀ P_jj⁻¹ e_j (:func:`~quadslam_env.metrics.cholesky_nees`; inf
            when a block is not positive semi-definite).
        sq: (k,) out: Σ_j ‖e_j‖², m².
    """
    L, y, e = np.empty((3, 3)), np.empty(3), np.empty(3)
    for b in range(mapped.shape[0]):
        nees[b] = sq[b] = 0.0
        for j in range(mapped.shape[1]):
            if not mapped[b, j]:
                continue
            for a in range(3):
                e[a] = means[b, j, a] - truth[j, a]
                sq[b] += e[a] * e[a]
            nees[b] += cholesky_nees(covs[b, j], e, L, y)[0]


@kernel
def team_map_errors(
    mapped: np.ndarray, means: FloatArray, rmse: FloatArray, lanes: np.ndarray, truth: FloatArray
) -> tuple[float, float, float]:
    """The team's map terms over the vehicles ``lanes``.

    Args:
        mapped: (N, L) bool each vehicle's latest map, by id.
        means: (N, L, 3) its estimates, m, N frame.
        rmse: (N,) each vehicle's map RMSE, m (NaN: nothing mapped).
        lanes: (N,) bool the vehicles of the step.
        truth: (L, 3) the true positions, m, N frame.

    Returns:
        ``(team_map_rmse_m, team_union_map_rmse_m, team_n_mapped)``: the mean of the vehicles'
        map RMSEs, the RMSE of the union of their maps (each landmark the estimate of the
        lowest-numbered vehicle that has it), its landmarks (NaN, NaN, 0 with none mapped).
    """
    total, k = 0.0, 0
    for i in range(rmse.shape[0]):
        if lanes[i] and rmse[i] == rmse[i]:
            total += rmse[i]
            k += 1
    sq, n = 0.0, 0
    for j in range(mapped.shape[1]):
        for i in range(mapped.shape[0]):
            if lanes[i] and mapped[i, j]:
                for a in range(3):
                    d = means[i, j, a] - truth[j, a]
                    sq += d * d
                n += 1
                break
    if n == 0:
        return math.nan, math.nan, 0.0
    return total / k, math.sqrt(sq / n), float(n)


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
        self._rmse = np.full(n_vehicles, math.nan)
        self._batched: bool | None = None  # the estimator reports every lane's covariances

    def reset(self) -> None:
        """Forget the maps of the last episode."""
        self._mapped[:] = False
        self._anees[:] = self._rmse[:] = math.nan

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
        if self._batched is None:  # a runtime protocol's check is slow: once per estimator
            self._batched = isinstance(estimator, ReportsLandmarkCovariances)
        if self._batched:
            est = estimator.estimate()
            mapped = est.landmark_mapped[sel, :count]
            means = est.landmark_means[sel, :count]
            covs = cast(ReportsLandmarkCovariances, estimator).landmark_covariances()[sel, :count]
        else:
            mapped = np.zeros((sel.size, count), dtype=bool)
            means, covs = np.zeros((sel.size, count, 3)), np.zeros((sel.size, count, 3, 3))
            for row, i in enumerate(sel.tolist()):
                ids, m, c = estimator.lane_estimate(i).mapped_landmarks(0)
                keep = ids < count
                mapped[row, ids[keep]] = True
                means[row, ids[keep]], covs[row, ids[keep]] = m[keep], c[keep]
        self._mapped[sel], self._means[sel] = mapped, means
        nees, sq = np.empty(sel.size), np.empty(sel.size)
        lanes_map_errors(mapped, means, covs, truth[:count], nees, sq)
        n = mapped.sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):  # nothing mapped: NaN
            self._anees[sel] = np.where(n > 0, nees / n, math.nan)
            self._rmse[sel] = np.where(n > 0, np.sqrt(sq / n), math.nan)
        out = np.full(self.n_vehicles, math.nan)
        out[sel] = self._anees[sel]
        return out

    def terms(self, truth: FloatArray, lanes: np.ndarray) -> dict[str, float]:
        """:data:`TERMS` over the latest maps of the vehicles ``lanes`` (N,) bool (NaN where
        none has a landmark mapped)."""
        count = self._mapped.shape[1]
        rmse, union, n = team_map_errors(
            self._mapped, self._means, self._rmse, lanes, truth[:count]
        )
        return {"team_map_rmse_m": rmse, "team_union_map_rmse_m": union, "team_n_mapped": n}

    def summary(self, truth: FloatArray) -> dict[str, float]:
        """The episode's ``team_episode_*`` terms over every vehicle's last map, and
        ``team_episode_landmark_anees``, the mean of the vehicles' last landmark ANEES."""
        every = np.ones(self.n_vehicles, dtype=bool)
        out = {f"team_episode_{k[5:]}": v for k, v in self.terms(truth, every).items()}
        finite = self._anees[np.isfinite(self._anees)]
        out["team_episode_landmark_anees"] = float(np.mean(finite)) if finite.size else math.nan
        return out
