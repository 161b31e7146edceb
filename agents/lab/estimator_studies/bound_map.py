"""The map's own Cramér–Rao bound in ``quadslam study bound``: the landmark block of the SLAM
bound (:func:`estimators.pcrb.slam_bound`, its ``landmark_var``) next to the estimator's map.

Per step the metric is the map RMSE of :mod:`quadslam_env.metrics`,
``√((1/n) Σ_j ‖l̂_j − l_j‖²)`` over the n landmarks the estimate has mapped, and its bound is
eq. (2) of :mod:`estimators.pcrb`, ``(1/n) Σ_j tr B_{l_j l_j}`` over the same landmarks
(:func:`estimators.pcrb.map_error_bound`). Both are reported, as for the pose, as an
RMSE-equivalent ``√(mean over steps)`` over the flight (the steps with a mapped landmark) and
its steady state (the second half), and at the last step (``final``: the episode's
``map_rmse_m``, the figure the papers give); per landmark, the final bound ``√tr B_ll`` next to
the final error ``‖l̂ − l‖``.

Only with known association, where the estimate names its landmarks by their true ids: an
unknown association's map is scored through the env's matching, which the bound has not.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.pcrb import map_error_bound
from quadslam_env.types import FloatArray


def landmark_sq_errors(means: FloatArray, mapped: np.ndarray, truth: FloatArray) -> FloatArray:
    """Squared error norm of each mapped landmark of one lane, by id.

    Args:
        means: (W, 3) the estimate's landmark positions by id (N, m).
        mapped: (W,) bool, which ids it has mapped.
        truth: (L, 3) the true landmarks (N, m).

    Returns:
        (L,) ``‖l̂_j − l_j‖²`` in m², NaN for a landmark not mapped.
    """
    n = truth.shape[0]
    width = min(n, mapped.shape[0])
    out = np.full(n, np.nan)
    ids = np.flatnonzero(mapped[:width])
    out[ids] = ((means[ids] - truth[ids]) ** 2).sum(axis=1)
    return out


def _rms(values: FloatArray) -> float:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values))) if values.size else math.nan


@dataclass
class MapSeries:
    """One seed's map errors and the map block of its bound, per step (steps 1 … K).

    Attributes:
        err2: (K, L) squared error norm of each landmark in m², NaN where not mapped.
        bound_var: (K, L, 3) per-axis variance bound of each landmark in m² (NaN before its
            first sighting), :attr:`estimators.pcrb.BoundResult.landmark_var`.
        sightings: (L,) int, the scans that saw each landmark.
        first_seen_s: (L,) time of each landmark's first sighting in s (NaN: never seen).
    """

    err2: FloatArray
    bound_var: FloatArray
    sightings: np.ndarray
    first_seen_s: FloatArray

    def mapped(self) -> np.ndarray:
        """(K, L) bool, the landmarks the estimate has mapped at each step."""
        return np.isfinite(self.err2)

    def bound_ms(self) -> FloatArray:
        """(K,) the mean-square bound of the map RMSE over the mapped landmarks, m²."""
        return map_error_bound(self.bound_var, self.mapped())

    def est_ms(self) -> FloatArray:
        """(K,) the estimate's mean-square map error over its mapped landmarks, m²."""
        mapped = self.mapped()
        count = mapped.sum(axis=1)
        total = np.where(mapped, self.err2, 0.0).sum(axis=1)
        out = np.full(count.shape, np.nan)
        np.divide(total, count, out=out, where=count > 0)
        return out

    def summary(self, t: FloatArray, steady_from_s: float) -> dict[str, Any]:
        """RMSE-equivalents of the map bound and RMSEs of the map: over the flight, its
        steady state (``t > steady_from_s``) and at the last step; the final landmarks."""
        b2, e2 = self.bound_ms(), self.est_ms()
        steady = t > steady_from_s
        out: dict[str, Any] = {}
        for span, sel in (("", slice(None)), ("_steady", steady)):
            out[f"bound_map_rmse_m{span}"] = _rms(b2[sel])
            out[f"est_map_rmse_m{span}"] = _rms(e2[sel])
        out["bound_map_rmse_m_final"] = _rms(b2[-1:])
        out["est_map_rmse_m_final"] = _rms(e2[-1:])
        out["n_mapped_final"] = int(self.mapped()[-1].sum())
        out["landmarks"] = self.landmark_rows()
        return out

    def landmark_rows(self) -> list[dict[str, Any]]:
        """Per landmark the bound sees: id, first sighting (s), scans that saw it, the final
        bound ``√tr B_ll`` (m) and the final error ``‖l̂ − l‖`` (m, ``None`` if not mapped)."""
        rows = []
        final_bound = np.sqrt(self.bound_var[-1].sum(axis=1))
        for j in np.flatnonzero(np.isfinite(final_bound)).tolist():
            err = self.err2[-1, j]
            rows.append(
                {
                    "id": j,
                    "first_seen_s": float(self.first_seen_s[j]),
                    "scans": int(self.sightings[j]),
                    "bound_m": float(final_bound[j]),
                    "est_err_m": float(math.sqrt(err)) if math.isfinite(err) else None,
                }
            )
        return rows


def map_series(
    err2: FloatArray,
    bound_var: FloatArray,
    dt: float,
    scan_steps: np.ndarray,
    scan_ids: list[np.ndarray],
) -> MapSeries:
    """One seed's :class:`MapSeries` from the recorder's errors and the bound's map block.

    Args:
        err2: (K, L) squared landmark errors, steps 1 … K (:func:`landmark_sq_errors`).
        bound_var: (K, L, 3) the bound's per-axis landmark variances at the same steps.
        dt: Step in s. scan_steps: (S,) the steps at whose end the LiDAR scanned.
        scan_ids: S arrays of the landmark ids truly visible in those scans.
    """
    n = bound_var.shape[1]
    sightings = np.zeros(n, dtype=np.int64)
    first = np.full(n, np.nan)
    for step, ids in zip(np.asarray(scan_steps).tolist(), scan_ids, strict=True):
        sightings[ids] += 1
        new = ids[np.isnan(first[ids])]
        first[new] = step * dt
    return MapSeries(err2=err2, bound_var=bound_var, sightings=sightings, first_seen_s=first)
