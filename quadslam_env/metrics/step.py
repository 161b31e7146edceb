"""Per-step accuracy and consistency metrics of the estimate against the truth.

Per step (docs/design.md §5): position, inertial-velocity and attitude errors, NEES of the
9-DOF pose (ρ, v_B, Λ) and of the position, map RMSE over mapped landmarks, bias errors, and
for an estimator with wind states its horizontal wind and that wind's error
(:func:`wind_columns`). NEES is NaN when the estimator reports no covariance (the oracle).

Everything works on B lanes at once (a leading batch axis); a term that does not apply to a
lane (no covariance, nothing mapped, no bias estimate) is NaN there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.frames import dcm_from_trig, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.models.linalg import cholesky_lower
from quadslam_env.types import POSE_DIM, FloatArray

NEES_POSE_BOUNDS_95 = (float(chi2.ppf(0.025, POSE_DIM)), float(chi2.ppf(0.975, POSE_DIM)))
"""Two-sided 95% interval of a single 9-DOF NEES sample."""


def anees_bounds(dof: int, n_runs: int, prob: float = 0.95) -> tuple[float, float]:
    """Two-sided χ² interval of the average NEES over ``n_runs`` independent runs.

    ``n_runs · ANEES ~ χ²(n_runs · dof)``, so the bounds are ``χ²⁻¹(q; n·dof) / n``.
    """
    lo = chi2.ppf((1.0 - prob) / 2.0, dof * n_runs) / n_runs
    hi = chi2.ppf(1.0 - (1.0 - prob) / 2.0, dof * n_runs) / n_runs
    return float(lo), float(hi)


@kernel
def cholesky_nees(cov: FloatArray, err: FloatArray, L: FloatArray, y: FloatArray) -> tuple:
    """NEES ``eᵀP⁻¹e`` of one error and of its first three components, from one factor.

    With ``P = L Lᵀ`` and ``y = L⁻¹ e``, ``NEES = ‖y‖²``; the leading 3×3 block of ``L`` is the
    Cholesky factor of the leading block of ``P``, so the position NEES is ``‖y[:3]‖²``. A zero
    variance (e.g. seed 001 Table 7's attitude P0) is handled by a jitter of 1e-9 of the largest
    variance.

    Args:
        cov: (n, n) covariance.
        err: (n,) error.
        L: (n, n) work space for the factor.
        y: (n,) work space for ``L⁻¹ e``.

    Returns:
        ``(nees, nees_first3)``; ``inf`` when ``cov`` is not positive semi-definite (a pivot is
        not positive, or not finite), which the env treats as estimator divergence.
    """
    n = err.shape[0]
    scale = 1e-12
    for i in range(n):
        scale = max(scale, cov[i, i])
    for i in range(n):
        for j in range(i + 1):
            L[i, j] = cov[i, j]
        L[i, i] += 1e-9 * scale
    if not cholesky_lower(L):
        return math.inf, math.inf
    nees = nees3 = 0.0
    for j in range(n):  # forward substitution y = L⁻¹ e
        v = err[j]
        for k in range(j):
            v -= L[j, k] * y[k]
        y[j] = v / L[j, j]
        nees += y[j] * y[j]
        if j == 2:
            nees3 = nees
    if not math.isfinite(nees):
        return math.inf, math.inf
    return nees, nees3


WIND_METRIC_KEYS = ("est_wind_n_mps", "est_wind_e_mps", "est_wind_err_mps")
"""The wind terms of :func:`wind_columns`, in row order."""

# Columns of the metrics kernel's output, in order, then the wind terms (wind_columns).
METRIC_KEYS = (
    "est_pos_err_m",
    "est_vel_err_mps",
    "est_att_err_deg",
    "est_n_mapped",
    "est_nees_pose",
    "est_nees_pos",
    "est_map_rmse_m",
    "est_accel_bias_err",
    "est_accel_bias_rel_err",
    "est_gyro_bias_err",
    "est_gyro_bias_rel_err",
    *WIND_METRIC_KEYS,
)
_WIND = slice(len(METRIC_KEYS) - len(WIND_METRIC_KEYS), len(METRIC_KEYS))


@kernel
def _metrics_lanes(
    state: FloatArray,
    pos: FloatArray,
    vel_body: FloatArray,
    vel_inertial: FloatArray,
    euler: FloatArray,
    cov: FloatArray,
    has_cov: bool,
    lm_means: FloatArray,
    lm_mapped: np.ndarray,
    true_lm: FloatArray,
    true_bias: FloatArray,
    biases: FloatArray,
    has_bias: tuple,
    out: FloatArray,
) -> None:
    """Fill ``out`` (≥ len(METRIC_KEYS), B) with the terms of :func:`step_metrics`, one row each."""
    nan = math.nan
    err = np.empty(POSE_DIM)
    L = np.empty((POSE_DIM, POSE_DIM))
    y = np.empty(POSE_DIM)
    width = min(lm_mapped.shape[1], true_lm.shape[1])
    for b in range(state.shape[0]):
        x = state[b]
        for i in range(3):
            err[i] = pos[b, i] - x[i]
            err[3 + i] = vel_body[b, i] - x[3 + i]
            err[6 + i] = wrap_pi(euler[b, i] - x[6 + i])
        out[0, b] = math.sqrt(err[0] ** 2 + err[1] ** 2 + err[2] ** 2)
        # True C_NB, the inertial velocity error, and the attitude error as the rotation angle
        # θ of C_trueᵀ C_est (no Euler parametrisation, no wrap-around). ‖C_true − C_est‖_F² =
        # 2(3 − tr C_trueᵀC_est) = 8 sin²(θ/2), so θ = 2 asin(‖ΔC‖_F / √8): unlike acos of the
        # trace, well conditioned near θ = 0 (and exactly 0 for equal attitudes).
        ct = dcm_from_trig(
            math.cos(x[6]), math.sin(x[6]), math.cos(x[7]), math.sin(x[7]),
            math.cos(x[8]), math.sin(x[8]),
        )  # fmt: skip
        ce = dcm_from_trig(
            math.cos(euler[b, 0]), math.sin(euler[b, 0]), math.cos(euler[b, 1]),
            math.sin(euler[b, 1]), math.cos(euler[b, 2]), math.sin(euler[b, 2]),
        )  # fmt: skip
        dc2 = 0.0
        sq = 0.0
        for r in range(3):
            v_true = ct[3 * r] * x[3] + ct[3 * r + 1] * x[4] + ct[3 * r + 2] * x[5]
            sq += (vel_inertial[b, r] - v_true) ** 2
            for c in range(3):
                dc2 += (ct[3 * r + c] - ce[3 * r + c]) ** 2
        out[1, b] = math.sqrt(sq)
        out[2, b] = math.degrees(2.0 * math.asin(min(1.0, math.sqrt(dc2 / 8.0))))
        if has_cov:
            out[4, b], out[5, b] = cholesky_nees(cov[b], err, L, y)
        else:
            out[4, b] = out[5, b] = nan
        n_mapped = 0
        sq = 0.0
        for j in range(lm_mapped.shape[1]):
            if lm_mapped[b, j]:
                n_mapped += 1
                if j < width:
                    for i in range(3):
                        sq += (lm_means[b, j, i] - true_lm[b, j, i]) ** 2
        out[3, b] = n_mapped
        out[6, b] = math.sqrt(sq / n_mapped) if n_mapped > 0 else nan
        for k in range(2):  # accelerometer, gyro
            col = 7 + 2 * k
            if not has_bias[k]:
                out[col, b] = out[col + 1, b] = nan
                continue
            e2 = t2 = 0.0
            for i in range(3):
                e2 += (biases[k, b, i] - true_bias[b, 3 * k + i]) ** 2
                t2 += true_bias[b, 3 * k + i] ** 2
            out[col, b] = math.sqrt(e2)
            # ‖b̂ − b‖ / ‖b‖: the "within 20% of the true value" criterion of seed 000.
            out[col + 1, b] = math.sqrt(e2) / math.sqrt(t2) if t2 > 0.0 else nan


def _metric_keys(has_bias: tuple[bool, bool], has_wind: bool) -> tuple[tuple[str, int], ...]:
    """(key, row) of the :data:`METRIC_KEYS` that apply given which biases are estimated and
    whether the wind is."""
    skip = {f"est_{name}_{kind}" for name, has in zip(("accel", "gyro"), has_bias, strict=True)
            if not has for kind in ("bias_err", "bias_rel_err")}  # fmt: skip
    if not has_wind:
        skip.update(WIND_METRIC_KEYS)
    return tuple((key, j) for j, key in enumerate(METRIC_KEYS) if key not in skip)


def wind_columns(est: BatchEstimate, true_wind: FloatArray | None, out: FloatArray) -> bool:
    """Write the estimated horizontal wind and its error into the rows of ``out``.

    Args:
        est: The estimator's belief of B lanes (``est.wind`` (B, 2) or ``None``).
        true_wind: (B, 3) the wind the lanes flew in over the step (steady plus gust, N, m/s),
            or ``None`` in still air.
        out: (3, B) receives :data:`WIND_METRIC_KEYS`: ŵ_N, ŵ_E (m/s) and
            ``‖(ŵ_N, ŵ_E) − (w_N, w_E)‖`` (m/s); NaN when the estimator has no wind states.

    Returns:
        Whether the terms apply (the estimator reports a wind).
    """
    wind = est.wind
    if wind is None:
        out[:] = math.nan
        return False
    out[0] = wind[:, 0]
    out[1] = wind[:, 1]
    if true_wind is None:
        np.hypot(wind[:, 0], wind[:, 1], out=out[2])
    else:
        np.hypot(wind[:, 0] - true_wind[:, 0], wind[:, 1] - true_wind[:, 1], out=out[2])
    return True


_KEYS_BY_TERMS = {
    (a, g, w): _metric_keys((a, g), w) for a in (False, True) for g in (False, True)
    for w in (False, True)
}  # fmt: skip
_NO_COV = np.zeros((1, POSE_DIM, POSE_DIM))


def metric_columns(
    true_state: FloatArray,
    est: BatchEstimate,
    true_landmarks: FloatArray,
    true_bias: FloatArray,
    out: FloatArray,
    true_wind: FloatArray | None = None,
) -> tuple[tuple[str, int], ...]:
    """Write the ``est_*`` terms of one step of B lanes into the rows of ``out``.

    Args: as :func:`step_metrics`, and ``out`` (≥ len(METRIC_KEYS), B), whose first rows
    receive the terms in :data:`METRIC_KEYS` order (the leading rows of a larger array).

    Returns:
        ``(key, row)`` of the terms that apply (the bias terms only where estimated, the wind
        terms only where the estimator has wind states).
    """
    b = true_state.shape[0]
    accel_bias, gyro_bias = est.accel_bias, est.gyro_bias
    has_bias = (accel_bias is not None, gyro_bias is not None)
    biases = np.zeros((2, b, 3))
    if accel_bias is not None:
        biases[0] = accel_bias
    if gyro_bias is not None:
        biases[1] = gyro_bias
    cov = est.pose_cov
    _metrics_lanes(
        true_state,
        est.position,
        est.vel_body,
        est.vel_inertial,
        est.euler,
        _NO_COV if cov is None else cov,
        cov is not None,
        est.landmark_means,
        est.landmark_mapped,
        true_landmarks,
        true_bias,
        biases,
        has_bias,
        out,
    )
    has_wind = wind_columns(est, true_wind, out[_WIND])
    return _KEYS_BY_TERMS[has_bias[0], has_bias[1], has_wind]


def step_metrics(
    true_state: FloatArray,
    est: BatchEstimate,
    true_landmarks: FloatArray,
    true_bias: FloatArray,
    true_wind: FloatArray | None = None,
) -> dict[str, FloatArray]:
    """The ``est_*`` terms of one step of B lanes (docs/design.md §4 ``info``), each (B,).

    Args:
        true_state: (B, 12) true states.
        est: The estimator's belief of the lanes.
        true_landmarks: (B, L, 3) true landmark positions by id (NED, m).
        true_bias: (B, 6) true total IMU bias (accel m/s², gyro rad/s).
        true_wind: (B, 3) the wind the lanes flew in (N, m/s), or ``None`` (still air).

    Returns:
        The terms of :data:`METRIC_KEYS`: position, inertial-velocity and attitude error, the
        number of mapped landmarks, pose and position NEES, map RMSE over the mapped landmarks,
        where biases are estimated, ``est_{accel,gyro}_bias_err`` and ``…_rel_err``
        (‖b̂ - b‖ / ‖b‖), and where the wind is, :data:`WIND_METRIC_KEYS`. NaN marks a term
        that does not apply to a lane (no covariance, nothing mapped, no bias estimate, zero
        true bias); bias and wind terms are left out entirely when the estimator does not
        estimate them.
    """
    out = np.empty((len(METRIC_KEYS), true_state.shape[0]))
    keys = metric_columns(true_state, est, true_landmarks, true_bias, out, true_wind)
    return {key: out[j] for key, j in keys}
