"""Accuracy and consistency metrics: the only module that sees truth and estimate together.

Per step (DESIGN.md §5): position, inertial-velocity and attitude errors, NEES of the 9-DOF pose
(ρ, v_B, Λ) and of the position, map RMSE over mapped landmarks, bias errors. Per episode:
RMSEs, the average NEES (ANEES) and the share of steps whose NEES lies inside the two-sided 95%
χ² interval. NEES is NaN when the estimator reports no covariance (the oracle).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.stats import chi2

from estimators.base import POSE_DIM, Estimate
from quadslam_env.models.rotations import (
    FloatArray,
    dcm_from_euler,
    rotation_angle_between,
    wrap_angle,
)

NEES_POSE_BOUNDS_95 = (float(chi2.ppf(0.025, POSE_DIM)), float(chi2.ppf(0.975, POSE_DIM)))
"""Two-sided 95% interval of a single 9-DOF NEES sample."""


def anees_bounds(dof: int, n_runs: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided χ² interval of the average NEES over ``n_runs`` independent runs.

    ``n_runs · ANEES ~ χ²(n_runs · dof)``, so the bounds are ``χ²⁻¹(q; n·dof) / n``.
    """
    lo = chi2.ppf((1.0 - prob) / 2.0, dof * n_runs) / n_runs
    hi = chi2.ppf(1.0 - (1.0 - prob) / 2.0, dof * n_runs) / n_runs
    return float(lo), float(hi)


def pose_error(true_state: FloatArray, est: Estimate) -> FloatArray:
    """(9,) pose error ``x̂ - x`` over (ρ, v_B, Λ) with wrapped Euler differences."""
    err = np.empty(POSE_DIM)
    err[0:3] = est.position - true_state[0:3]
    err[3:6] = est.vel_body - true_state[3:6]
    err[6:9] = wrap_angle(est.euler - true_state[6:9])
    return err


def pose_nees(err: FloatArray, cov: FloatArray | None) -> tuple[float, float]:
    """NEES of the whole error and of its first three components from one Cholesky factor.

    With ``P = L Lᵀ`` and ``y = L⁻¹ e``, ``NEES = ‖y‖²``; the leading 3×3 block of ``L`` is the
    Cholesky factor of the leading block of ``P``, so the position NEES is ``‖y[:3]‖²``.
    A zero variance (e.g. seed 001 Table 7's attitude P0) is handled by a jitter of 1e-9 of the
    largest variance.

    Returns:
        ``(nees, nees_first3)``: NaN without a covariance (the oracle); ``inf`` when ``cov`` is
        not positive semi-definite (the factorisation fails), which the env treats as estimator
        divergence.
    """
    if cov is None:
        return math.nan, math.nan
    scale = max(float(np.max(np.diag(cov))), 1e-12)
    try:
        L = np.linalg.cholesky(cov + (1e-9 * scale) * np.eye(cov.shape[0]))
    except np.linalg.LinAlgError:
        return math.inf, math.inf
    y = np.linalg.solve(L, err)
    return float(y @ y), float(y[0:3] @ y[0:3])


def map_rmse(est: Estimate, true_ids: np.ndarray, true_points: FloatArray) -> float:
    """RMS of the 3D error over the mapped landmarks (m); NaN when nothing is mapped."""
    if est.landmark_ids.size == 0:
        return math.nan
    idx = np.searchsorted(true_ids, est.landmark_ids)
    diff = est.landmark_means - true_points[idx]
    return math.sqrt(float(np.einsum("ij,ij->", diff, diff)) / diff.shape[0])


def step_metrics(
    true_state: FloatArray,
    true_dcm: FloatArray,
    est: Estimate,
    true_ids: np.ndarray,
    true_points: FloatArray,
    true_bias: FloatArray | None,
) -> dict[str, float]:
    """The ``est_*`` terms of one step (DESIGN.md §4 ``info``); undefined terms are absent.

    Args:
        true_state: (12,) true state.
        true_dcm: (3, 3) true ``C_NB``.
        est: The estimator's snapshot.
        true_ids: (L,) sorted true landmark ids.
        true_points: (L, 3) true landmark positions.
        true_bias: (6,) true total IMU bias (accel, gyro) or ``None``.
    """
    err = pose_error(true_state, est)
    att = rotation_angle_between(true_dcm, dcm_from_euler(est.euler))
    cov = est.pose_cov
    vel_err = est.vel_inertial - true_dcm @ true_state[3:6]
    nees_pose, nees_pos = pose_nees(err, cov)
    out = {
        "est_pos_err_m": _norm3(err[0:3]),
        "est_vel_err_mps": _norm3(vel_err),
        "est_att_err_deg": math.degrees(att),
        "est_n_mapped": float(est.landmark_ids.size),
    }
    # Terms that do not apply (no covariance, nothing mapped, no bias estimate) are left out,
    # so the same seed gives equal info dicts (NaN != NaN).
    for key, value in (
        ("est_nees_pose", nees_pose),
        ("est_nees_pos", nees_pos),
        ("est_map_rmse_m", map_rmse(est, true_ids, true_points)),
    ):
        if not math.isnan(value):
            out[key] = value
    for name, est_bias, sl in (
        ("accel", est.accel_bias, slice(0, 3)),
        ("gyro", est.gyro_bias, slice(3, 6)),
    ):
        if true_bias is not None and est_bias is not None:
            err_norm = _norm3(est_bias - true_bias[sl])
            out[f"est_{name}_bias_err"] = err_norm
            true_norm = _norm3(true_bias[sl])
            if true_norm > 0.0:
                # ‖b̂ - b‖ / ‖b‖: the "within 20% of the true value" criterion of seed 000.
                out[f"est_{name}_bias_rel_err"] = err_norm / true_norm
    return out


def _norm3(vec: FloatArray) -> float:
    """Euclidean norm of a (3,) vector (cheaper than ``np.linalg.norm`` on tiny arrays)."""
    return math.sqrt(float(vec[0] * vec[0] + vec[1] * vec[1] + vec[2] * vec[2]))


@dataclass
class EpisodeMetrics:
    """Accumulates per-step terms into the ``episode_*`` summary of the last ``info``.

    Running sums only (O(1) memory), so hour-long episodes do not grow with the step count.
    """

    steps: int = 0
    pos_sq: float = 0.0
    vel_sq: float = 0.0
    att_sq: float = 0.0
    track_sq: float = 0.0
    nees_pose_sum: float = 0.0
    nees_pose_n: int = 0
    nees_pose_inside: int = 0
    nees_pos_sum: float = 0.0
    nees_pos_n: int = 0
    last_map_rmse: float = math.nan
    last_n_mapped: float = 0.0
    last_bias_rel_err: tuple[float, float] = (math.nan, math.nan)

    def add(self, info: dict[str, float]) -> None:
        """Record one step's ``info`` terms (NaN/inf NEES values are left out of the ANEES)."""
        self.steps += 1
        self.pos_sq += info["est_pos_err_m"] ** 2
        self.vel_sq += info["est_vel_err_mps"] ** 2
        self.att_sq += info["est_att_err_deg"] ** 2
        self.track_sq += info["track_pos_err_m"] ** 2
        nees_pose = info.get("est_nees_pose", math.nan)
        nees_pos = info.get("est_nees_pos", math.nan)
        if math.isfinite(nees_pose):
            lo, hi = NEES_POSE_BOUNDS_95
            self.nees_pose_sum += nees_pose
            self.nees_pose_n += 1
            self.nees_pose_inside += int(lo <= nees_pose <= hi)
        if math.isfinite(nees_pos):
            self.nees_pos_sum += nees_pos
            self.nees_pos_n += 1
        self.last_map_rmse = info.get("est_map_rmse_m", math.nan)
        self.last_n_mapped = info["est_n_mapped"]
        self.last_bias_rel_err = (
            info.get("est_accel_bias_rel_err", math.nan),
            info.get("est_gyro_bias_rel_err", math.nan),
        )

    def summary(self) -> dict[str, float]:
        """Episode RMSEs, ANEES and the share of steps inside the 95% χ² bounds."""
        n = self.steps

        def rms(total: float) -> float:
            return math.sqrt(total / n) if n else math.nan

        def ratio(num: float, den: int) -> float:
            return num / den if den else math.nan

        return {
            "episode_steps": float(n),
            "episode_est_pos_rmse_m": rms(self.pos_sq),
            "episode_est_vel_rmse_mps": rms(self.vel_sq),
            "episode_est_att_rmse_deg": rms(self.att_sq),
            "episode_track_pos_rmse_m": rms(self.track_sq),
            "episode_map_rmse_m": self.last_map_rmse,
            "episode_n_mapped": self.last_n_mapped,
            "episode_accel_bias_rel_err": self.last_bias_rel_err[0],
            "episode_gyro_bias_rel_err": self.last_bias_rel_err[1],
            "episode_anees_pose": ratio(self.nees_pose_sum, self.nees_pose_n),
            "episode_anees_pos": ratio(self.nees_pos_sum, self.nees_pos_n),
            "episode_nees_pose_in_bounds": ratio(self.nees_pose_inside, self.nees_pose_n),
        }
