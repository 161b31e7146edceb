"""Accuracy and consistency metrics: the only module that sees truth and estimate together.

Per step (DESIGN.md §5): position, inertial-velocity and attitude errors, NEES of the 9-DOF pose
(ρ, v_B, Λ) and of the position, map RMSE over mapped landmarks, bias errors. Per episode:
RMSEs, the average NEES (ANEES) and the share of steps whose NEES lies inside the two-sided 95%
χ² interval. NEES is NaN when the estimator reports no covariance (the oracle).

Everything works on B lanes at once (a leading batch axis); a term that does not apply to a
lane (no covariance, nothing mapped, no bias estimate) is NaN there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from estimators.base import POSE_DIM
from estimators.batch import BatchEstimate
from quadslam_env.models.rotations import FloatArray, dcm_from_euler_batch, wrap_angle

NEES_POSE_BOUNDS_95 = (float(chi2.ppf(0.025, POSE_DIM)), float(chi2.ppf(0.975, POSE_DIM)))
"""Two-sided 95% interval of a single 9-DOF NEES sample."""

_EYE = np.eye(POSE_DIM)


def anees_bounds(dof: int, n_runs: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided χ² interval of the average NEES over ``n_runs`` independent runs.

    ``n_runs · ANEES ~ χ²(n_runs · dof)``, so the bounds are ``χ²⁻¹(q; n·dof) / n``.
    """
    lo = chi2.ppf((1.0 - prob) / 2.0, dof * n_runs) / n_runs
    hi = chi2.ppf(1.0 - (1.0 - prob) / 2.0, dof * n_runs) / n_runs
    return float(lo), float(hi)


def pose_nees(err: FloatArray, cov: FloatArray | None) -> tuple[FloatArray, FloatArray]:
    """NEES of whole errors and of their first three components from one Cholesky factor.

    With ``P = L Lᵀ`` and ``y = L⁻¹ e``, ``NEES = ‖y‖²``; the leading 3×3 block of ``L`` is the
    Cholesky factor of the leading block of ``P``, so the position NEES is ``‖y[:3]‖²``.
    A zero variance (e.g. seed 001 Table 7's attitude P0) is handled by a jitter of 1e-9 of the
    largest variance.

    Args:
        err: (B, 9) errors.
        cov: (B, 9, 9) covariances, or ``None``.

    Returns:
        ``(nees (B,), nees_first3 (B,))``: NaN without a covariance (the oracle); ``inf`` in a
        lane whose covariance is not positive semi-definite (the factorisation fails), which
        the env treats as estimator divergence.
    """
    b = err.shape[0]
    if cov is None:
        return np.full(b, math.nan), np.full(b, math.nan)
    scale = np.maximum(np.max(np.diagonal(cov, axis1=1, axis2=2), axis=1), 1e-12)
    A = cov + (1e-9 * scale)[:, None, None] * _EYE
    nees, nees3 = np.full(b, math.inf), np.full(b, math.inf)
    try:
        ok = np.ones(b, dtype=bool)
        L = np.linalg.cholesky(A)
    except np.linalg.LinAlgError:  # find the failing lanes one by one (rare)
        L = np.zeros_like(A)
        for i in range(b):
            try:
                L[i] = np.linalg.cholesky(A[i])
            except np.linalg.LinAlgError:
                ok[i] = False
    y = np.linalg.solve(L[ok], err[ok, :, None])[:, :, 0]
    nees[ok] = np.einsum("ij,ij->i", y, y)
    nees3[ok] = np.einsum("ij,ij->i", y[:, :3], y[:, :3])
    return nees, nees3


def step_metrics(
    true_state: FloatArray,
    true_dcm: FloatArray,
    est: BatchEstimate,
    true_landmarks: FloatArray,
    true_bias: FloatArray,
) -> dict[str, FloatArray]:
    """The ``est_*`` terms of one step of B lanes (DESIGN.md §4 ``info``), each (B,).

    Args:
        true_state: (B, 12) true states.
        true_dcm: (B, 3, 3) true ``C_NB``.
        est: The estimator's belief of the lanes.
        true_landmarks: (B, L, 3) true landmark positions by id (NED, m).
        true_bias: (B, 6) true total IMU bias (accel m/s², gyro rad/s).

    Returns:
        ``est_pos_err_m``, ``est_vel_err_mps``, ``est_att_err_deg``, ``est_n_mapped``,
        ``est_nees_pose``, ``est_nees_pos``, ``est_map_rmse_m`` and, where biases are
        estimated, ``est_{accel,gyro}_bias_err`` and ``…_rel_err`` (‖b̂ - b‖ / ‖b‖, seed 000's
        "within 20%" criterion; NaN for a zero true bias). NaN marks a term that does not apply.
    """
    err = np.empty((true_state.shape[0], POSE_DIM))
    err[:, 0:3] = est.position - true_state[:, 0:3]
    err[:, 3:6] = est.vel_body - true_state[:, 3:6]
    err[:, 6:9] = wrap_angle(est.euler - true_state[:, 6:9])
    # Rotation angle of C_trueᵀ C_est: no Euler parametrisation, no wrap-around.
    trace = np.einsum("bij,bij->b", true_dcm, dcm_from_euler_batch(est.euler))
    att = np.arccos(np.clip(0.5 * (trace - 1.0), -1.0, 1.0))
    vel_err = est.vel_inertial - np.einsum("bij,bj->bi", true_dcm, true_state[:, 3:6])
    nees_pose, nees_pos = pose_nees(err, est.pose_cov)
    width = min(est.landmark_mapped.shape[1], true_landmarks.shape[1])
    mapped = est.landmark_mapped[:, :width]
    n_mapped = est.landmark_mapped.sum(axis=1)
    diff = est.landmark_means[:, :width] - true_landmarks[:, :width]
    sq = np.where(mapped, np.einsum("bij,bij->bi", diff, diff), 0.0).sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        map_rmse = np.where(n_mapped > 0, np.sqrt(sq / np.maximum(n_mapped, 1)), math.nan)
    out = {
        "est_pos_err_m": _norm(err[:, 0:3]),
        "est_vel_err_mps": _norm(vel_err),
        "est_att_err_deg": np.degrees(att),
        "est_n_mapped": n_mapped.astype(float),
        "est_nees_pose": nees_pose,
        "est_nees_pos": nees_pos,
        "est_map_rmse_m": map_rmse,
    }
    for name, est_bias, sl in (
        ("accel", est.accel_bias, slice(0, 3)),
        ("gyro", est.gyro_bias, slice(3, 6)),
    ):
        if est_bias is not None:
            err_norm = _norm(est_bias - true_bias[:, sl])
            true_norm = _norm(true_bias[:, sl])
            out[f"est_{name}_bias_err"] = err_norm
            with np.errstate(invalid="ignore", divide="ignore"):
                out[f"est_{name}_bias_rel_err"] = np.where(
                    true_norm > 0.0, err_norm / true_norm, math.nan
                )
    return out


def _norm(vec: FloatArray) -> FloatArray:
    """Row norms of (B, 3) vectors."""
    return np.sqrt(np.einsum("ij,ij->i", vec, vec))


_RMS = (
    ("episode_est_pos_rmse_m", "est_pos_err_m"),
    ("episode_est_vel_rmse_mps", "est_vel_err_mps"),
    ("episode_est_att_rmse_deg", "est_att_err_deg"),
    ("episode_track_pos_rmse_m", "track_pos_err_m"),
)
_LAST = (
    ("episode_map_rmse_m", "est_map_rmse_m"),
    ("episode_n_mapped", "est_n_mapped"),
    ("episode_accel_bias_rel_err", "est_accel_bias_rel_err"),
    ("episode_gyro_bias_rel_err", "est_gyro_bias_rel_err"),
)


class EpisodeMetrics:
    """Accumulates per-step terms of B lanes into the ``episode_*`` summaries.

    Running sums only (O(1) memory per lane), so hour-long episodes do not grow with the step
    count.

    Args:
        num_lanes: B.
    """

    def __init__(self, num_lanes: int = 1) -> None:
        self.num_lanes = num_lanes
        self.reset(np.ones(num_lanes, dtype=bool))

    def reset(self, lanes: np.ndarray) -> None:
        """Zero the sums of the lanes selected by the (B,) mask or index array ``lanes``."""
        b = self.num_lanes
        if not hasattr(self, "steps"):
            self.steps = np.zeros(b)
            self.sq = {key: np.zeros(b) for _, key in _RMS}
            self.last = {key: np.full(b, math.nan) for _, key in _LAST}
            self.nees_pose = np.zeros((3, b))  # sum, count, inside the 95% bounds
            self.nees_pos = np.zeros((2, b))  # sum, count
        self.steps[lanes] = 0.0
        for arr in self.sq.values():
            arr[lanes] = 0.0
        for arr in self.last.values():
            arr[lanes] = math.nan
        self.nees_pose[:, lanes] = 0.0
        self.nees_pos[:, lanes] = 0.0

    def add(self, info: dict[str, FloatArray], lanes: np.ndarray | None = None) -> None:
        """Record one step's terms of the lanes selected by the (B,) mask ``lanes``.

        Values are (B,) arrays (or numbers, broadcast to every lane). NaN/inf NEES values are
        left out of the ANEES; a missing key counts as NaN.
        """
        b = self.num_lanes
        sel = np.ones(b, dtype=bool) if lanes is None else lanes

        def lanes_of(key: str) -> FloatArray:
            return np.broadcast_to(np.asarray(info.get(key, math.nan), dtype=float), (b,))

        self.steps[sel] += 1.0
        for _, key in _RMS:
            self.sq[key][sel] += lanes_of(key)[sel] ** 2
        for _, key in _LAST:
            self.last[key][sel] = lanes_of(key)[sel]
        lo, hi = NEES_POSE_BOUNDS_95
        for acc, key in ((self.nees_pose, "est_nees_pose"), (self.nees_pos, "est_nees_pos")):
            value = lanes_of(key)
            ok = sel & np.isfinite(value)
            acc[0, ok] += value[ok]
            acc[1, ok] += 1.0
            if acc.shape[0] == 3:
                acc[2, ok] += (lo <= value[ok]) & (value[ok] <= hi)

    def summary(self) -> dict[str, FloatArray]:
        """Episode RMSEs, ANEES and the share of steps inside the 95% χ² bounds, each (B,)."""
        n = self.steps
        with np.errstate(invalid="ignore", divide="ignore"):
            out = {"episode_steps": n.copy()}
            for name, key in _RMS:
                out[name] = np.where(n > 0, np.sqrt(self.sq[key] / n), math.nan)
            for name, key in _LAST:
                out[name] = self.last[key].copy()
            s, c, inside = self.nees_pose
            out["episode_anees_pose"] = np.where(c > 0, s / c, math.nan)
            out["episode_nees_pose_in_bounds"] = np.where(c > 0, inside / c, math.nan)
            s, c = self.nees_pos
            out["episode_anees_pos"] = np.where(c > 0, s / c, math.nan)
        return out
