"""Accuracy and consistency metrics: the only module that sees truth and estimate together.

Per step (docs/design.md §5): position, inertial-velocity and attitude errors, NEES of the
9-DOF pose (ρ, v_B, Λ) and of the position, map RMSE over mapped landmarks, bias errors. Per
episode: RMSEs, the average NEES (ANEES) and the share of steps whose NEES lies inside the
two-sided 95% χ² interval. NEES is NaN when the estimator reports no covariance (the oracle).

Everything works on B lanes at once (a leading batch axis); a term that does not apply to a
lane (no covariance, nothing mapped, no bias estimate) is NaN there.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.stats import chi2

from quadslam_env.estimation import BatchEstimate
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


# Columns of the metrics kernel's output, in order.
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
)


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


def _metric_keys(has_bias: tuple[bool, bool]) -> tuple[tuple[str, int], ...]:
    """(key, row) of the :data:`METRIC_KEYS` that apply given which biases are estimated."""
    skip = {f"est_{name}_{kind}" for name, has in zip(("accel", "gyro"), has_bias, strict=True)
            if not has for kind in ("bias_err", "bias_rel_err")}  # fmt: skip
    return tuple((key, j) for j, key in enumerate(METRIC_KEYS) if key not in skip)


_KEYS_BY_BIAS = {(a, g): _metric_keys((a, g)) for a in (False, True) for g in (False, True)}
_NO_COV = np.zeros((1, POSE_DIM, POSE_DIM))


def metric_columns(
    true_state: FloatArray,
    est: BatchEstimate,
    true_landmarks: FloatArray,
    true_bias: FloatArray,
    out: FloatArray,
) -> tuple[tuple[str, int], ...]:
    """Write the ``est_*`` terms of one step of B lanes into the rows of ``out``.

    Args: as :func:`step_metrics`, and ``out`` (≥ len(METRIC_KEYS), B), whose first rows
    receive the terms in :data:`METRIC_KEYS` order (the leading rows of a larger array).

    Returns:
        ``(key, row)`` of the terms that apply (the bias terms only where estimated).
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
    return _KEYS_BY_BIAS[has_bias]


def step_metrics(
    true_state: FloatArray,
    est: BatchEstimate,
    true_landmarks: FloatArray,
    true_bias: FloatArray,
) -> dict[str, FloatArray]:
    """The ``est_*`` terms of one step of B lanes (docs/design.md §4 ``info``), each (B,).

    Args:
        true_state: (B, 12) true states.
        est: The estimator's belief of the lanes.
        true_landmarks: (B, L, 3) true landmark positions by id (NED, m).
        true_bias: (B, 6) true total IMU bias (accel m/s², gyro rad/s).

    Returns:
        The terms of :data:`METRIC_KEYS`: position, inertial-velocity and attitude error, the
        number of mapped landmarks, pose and position NEES, map RMSE over the mapped landmarks
        and, where biases are estimated, ``est_{accel,gyro}_bias_err`` and ``…_rel_err``
        (‖b̂ - b‖ / ‖b‖). NaN marks a term that does not apply to a lane (no covariance,
        nothing mapped, no bias estimate, zero true bias); bias terms are left out entirely
        when the estimator estimates no biases.
    """
    out = np.empty((len(METRIC_KEYS), true_state.shape[0]))
    keys = metric_columns(true_state, est, true_landmarks, true_bias, out)
    return {key: out[j] for key, j in keys}


MATCH_RADIUS_M = 0.5
"""A mapped landmark with no true landmark this close (in the vehicle frame) is spurious."""

ASSOCIATION_KEYS = (
    "assoc_n_returns",
    "assoc_n_associated",
    "assoc_n_wrong",
    "assoc_n_true",
    "assoc_n_missed",
)
"""Per-scan association counts (unknown association; 0 in lanes that did not scan)."""


@kernel
def _match_lanes(
    means: FloatArray,
    mapped: np.ndarray,
    est_pose: FloatArray,
    true_landmarks: FloatArray,
    n_true: np.ndarray,
    true_pose: FloatArray,
    radius: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (B, Le) (see :func:`match_landmarks`); poses are (B, 6) (ρ, Λ)."""
    d_est = np.empty(3)
    d_true = np.empty((true_landmarks.shape[1], 3))
    for b in range(mapped.shape[0]):
        ce = dcm_from_trig(
            math.cos(est_pose[b, 3]), math.sin(est_pose[b, 3]), math.cos(est_pose[b, 4]),
            math.sin(est_pose[b, 4]), math.cos(est_pose[b, 5]), math.sin(est_pose[b, 5]),
        )  # fmt: skip
        ct = dcm_from_trig(
            math.cos(true_pose[b, 3]), math.sin(true_pose[b, 3]), math.cos(true_pose[b, 4]),
            math.sin(true_pose[b, 4]), math.cos(true_pose[b, 5]), math.sin(true_pose[b, 5]),
        )  # fmt: skip
        for j in range(n_true[b]):  # C_NBᵀ (l − ρ): the true map about the true pose
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    acc += ct[3 * c + r] * (true_landmarks[b, j, c] - true_pose[b, c])
                d_true[j, r] = acc
        for i in range(mapped.shape[1]):
            out[b, i] = -1
            if not mapped[b, i]:
                continue
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    acc += ce[3 * c + r] * (means[b, i, c] - est_pose[b, c])
                d_est[r] = acc
            best = radius * radius
            for j in range(n_true[b]):
                d2 = 0.0
                for r in range(3):
                    d2 += (d_est[r] - d_true[j, r]) ** 2
                if d2 <= best:
                    best = d2
                    out[b, i] = j


def match_landmarks(
    means: FloatArray,
    mapped: np.ndarray,
    est_pose: FloatArray,
    true_landmarks: FloatArray,
    n_true: np.ndarray,
    true_pose: FloatArray,
) -> np.ndarray:
    """Name each mapped landmark by its nearest true landmark within :data:`MATCH_RADIUS_M`.

    With unknown association an estimator names landmarks itself; this matching (the truth
    the simulator alone knows) is what the map RMSE and the association metrics use. It is
    done in the vehicle frame, as the sensor sees the map: ``C_NB(Λ̂)ᵀ (l̂ − ρ̂)`` against
    ``C_NB(Λ)ᵀ (l − ρ)``, so a SLAM map that drifts together with its vehicle (an unobservable
    offset) still matches.

    Args:
        means: (B, Le, 3) estimated landmark positions by estimator label (N, m).
        mapped: (B, Le) bool, labels in the map.
        est_pose: (B, 6) estimated (ρ̂ m, Λ̂ rad).
        true_landmarks: (B, L, 3) true positions by id (N, m); lane b uses the first
            ``n_true[b]`` rows.
        n_true: (B,) int.
        true_pose: (B, 6) true (ρ m, Λ rad).

    Returns:
        (B, Le) int: the true id of each label, -1 for unmapped labels and spurious entries.
    """
    out = np.empty(mapped.shape, dtype=np.int64)
    _match_lanes(
        np.ascontiguousarray(means, dtype=float),
        np.ascontiguousarray(mapped, dtype=bool),
        np.ascontiguousarray(est_pose, dtype=float),
        np.ascontiguousarray(true_landmarks, dtype=float),
        np.ascontiguousarray(n_true, dtype=np.int64),
        np.ascontiguousarray(true_pose, dtype=float),
        MATCH_RADIUS_M,
        out,
    )
    return out


def association_counts(
    truth: np.ndarray, labels: np.ndarray, count: np.ndarray, match: np.ndarray
) -> dict[str, FloatArray]:
    """Association counts of one scan of B lanes (:data:`ASSOCIATION_KEYS`, each (B,)).

    A return is *associated* when the estimator paired it with a map entry (label ≥ 0); it is
    *wrong* when that entry is not matched to the return's true landmark (a false return
    paired with anything is wrong); a *true* return (from a landmark) left unpaired is
    *missed*.

    Args:
        truth: (B, R) true landmark id of each return, -1 for a false return.
        labels: (B, ≥ R) the estimator's label of each return, -1 for none.
        count: (B,) returns per lane (0: the lane did not scan).
        match: (B, Le) true id of each label (:func:`match_landmarks`).
    """
    width = truth.shape[1]
    present = np.arange(width) < count[:, None]
    labels = np.pad(labels[:, :width], ((0, 0), (0, max(0, width - labels.shape[1]))),
                    constant_values=-1)  # fmt: skip
    associated = present & (labels >= 0)
    padded = np.pad(match, ((0, 0), (0, 1)), constant_values=-1)  # column -1: no entry
    named = np.take_along_axis(padded, np.where(labels < match.shape[1], labels, -1), axis=1)
    true_ret = present & (truth >= 0)
    return {
        "assoc_n_returns": count.astype(float),
        "assoc_n_associated": associated.sum(axis=1).astype(float),
        "assoc_n_wrong": (associated & ((truth < 0) | (named != truth))).sum(axis=1).astype(float),
        "assoc_n_true": true_ret.sum(axis=1).astype(float),
        "assoc_n_missed": (true_ret & ~associated).sum(axis=1).astype(float),
    }


# Episode accumulators, one column each: (summary key, per-step info key). The RMS columns
# hold sums of squares; the "last" columns the latest value; the NEES columns are handled apart.
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
_INPUT_KEYS = (*(k for _, k in _RMS), *(k for _, k in _LAST), "est_nees_pose", "est_nees_pos", "t")
_N_RMS, _N_LAST = len(_RMS), len(_LAST)
# Accumulator columns: steps, RMS sums, last values, then NEES pose (sum, count, inside the 95%
# bounds) and NEES position (sum, count).
_COLS = 1 + _N_RMS + _N_LAST + 5
_ALL_INPUT_COLS = np.arange(len(_INPUT_KEYS))
PHASES = ("transient", "steady")
"""The two phases of an episode: ``t ≤ settle_s`` and ``t > settle_s`` (docs: metrics)."""
SETTLE_TOL_S = 1e-9
"""A step at ``t ≤ settle_s + SETTLE_TOL_S`` is in the transient (``t`` is ``steps·dt``)."""


def phase_key(name: str, phase: str) -> str:
    """The per-phase name of an episode summary: the phase before the unit suffix
    (``episode_track_pos_rmse_m`` → ``episode_track_pos_rmse_steady_m``), else at the end
    (``episode_anees_pose`` → ``episode_anees_pose_steady``)."""
    stem, _, unit = name.rpartition("_")
    if unit in ("m", "mps", "deg"):
        return f"{stem}_{phase}_{unit}"
    return f"{name}_{phase}"


def input_columns(rows: dict[str, int]) -> np.ndarray:
    """The row of each episode input key in an array whose rows are named by ``rows``
    (key → index), -1 for a key it lacks: the ``cols`` of :meth:`EpisodeMetrics.add_columns`."""
    return np.array([rows.get(key, -1) for key in _INPUT_KEYS], dtype=np.int64)


@kernel
def _accumulate(
    acc: FloatArray,
    values: FloatArray,
    cols: np.ndarray,
    sel: np.ndarray,
    lo: float,
    hi: float,
    settle: float,
) -> None:
    """Add one step's terms to the lanes selected by ``sel`` (B,): term j of
    :data:`_INPUT_KEYS` is the (B,) row ``values[cols[j]]`` (NaN where ``cols[j]`` < 0).

    ``acc`` is (3, B, cols): the whole episode, the transient and the steady state; each step
    goes to the whole episode and to the phase its time ``t`` falls in."""
    n_rms, n_last = len(_RMS), len(_LAST)
    nees_col = 1 + n_rms + n_last
    t_col = cols[n_rms + n_last + 2]
    nan = math.nan
    for b in range(acc.shape[1]):
        if not sel[b]:
            continue
        t = values[t_col, b] if t_col >= 0 else nan
        phase = 2 if t > settle else 1  # NaN time (no "t" row): the transient
        for ph in (0, phase):
            a = acc[ph, b]
            a[0] += 1.0
            for j in range(n_rms):
                a[1 + j] += (values[cols[j], b] if cols[j] >= 0 else nan) ** 2
            for j in range(n_last):
                c = cols[n_rms + j]
                a[1 + n_rms + j] = values[c, b] if c >= 0 else nan
            for k in range(2):  # pose, position; NaN/inf NEES values stay out of the ANEES
                c = cols[n_rms + n_last + k]
                v = values[c, b] if c >= 0 else nan
                if math.isfinite(v):
                    col = nees_col + 3 * k
                    a[col] += v
                    a[col + 1] += 1.0
                    if k == 0 and lo <= v <= hi:
                        a[col + 2] += 1.0


class EpisodeMetrics:
    """Accumulates per-step terms of B lanes into the ``episode_*`` summaries.

    Running sums only (O(1) memory per lane), so hour-long episodes do not grow with the step
    count. Each RMSE and NEES summary is kept over the whole episode and over each of
    :data:`PHASES` (named by :func:`phase_key`): the transient ``t ≤ settle_s`` and the steady
    state ``t > settle_s``, ``t`` being the step's ``t`` term.

    With ``association`` (unknown data association) it also sums the
    :data:`ASSOCIATION_KEYS` counts into ``episode_assoc_wrong_rate`` (wrong / associated
    returns), ``episode_assoc_missed_rate`` (missed / true returns) and keeps the last
    ``spurious_landmarks``.

    Args:
        num_lanes: B.
        association: Summarise the association terms too.
        settle_s: End of the transient, s.
    """

    def __init__(
        self, num_lanes: int = 1, association: bool = False, settle_s: float = 0.0
    ) -> None:
        self.num_lanes = num_lanes
        self.association = association
        self.settle_s = float(settle_s)
        self._acc = np.zeros((1 + len(PHASES), num_lanes, _COLS))  # whole, transient, steady
        self._assoc = np.zeros((num_lanes, len(ASSOCIATION_KEYS) + 1))  # sums, last spurious
        self._all = np.ones(num_lanes, dtype=bool)
        self.reset(np.arange(num_lanes))

    def reset(self, lanes: np.ndarray) -> None:
        """Zero the sums of the lanes selected by the (B,) mask or index array ``lanes``."""
        self._acc[:, lanes] = 0.0
        self._acc[:, lanes, 1 + _N_RMS : 1 + _N_RMS + _N_LAST] = math.nan
        self._assoc[lanes] = 0.0

    def add(self, info: dict[str, FloatArray], lanes: np.ndarray | None = None) -> None:
        """Record one step's terms of the lanes selected by the (B,) mask ``lanes``.

        Values are (B,) arrays (or numbers, broadcast to every lane). NaN/inf NEES values are
        left out of the ANEES; a missing key counts as NaN (a missing ``t``: the transient).
        """
        values = np.empty((len(_INPUT_KEYS), self.num_lanes))
        for j, key in enumerate(_INPUT_KEYS):
            values[j] = info.get(key, math.nan)
        self.add_columns(values, _ALL_INPUT_COLS, lanes)
        if self.association:
            self.add_association(info, lanes)

    def add_columns(
        self, values: FloatArray, cols: np.ndarray, lanes: np.ndarray | None = None
    ) -> None:
        """Record one step's terms from the rows of one array (no association terms).

        Args:
            values: (K, B) terms of the lanes, one row per term.
            cols: (len(_INPUT_KEYS),) int, the row of each input key (-1: absent, NaN);
                see :func:`input_columns`.
            lanes: (B,) bool lanes to record (default: all).
        """
        sel = self._all if lanes is None else lanes
        lo, hi = NEES_POSE_BOUNDS_95
        _accumulate(self._acc, values, cols, sel, lo, hi, self.settle_s + SETTLE_TOL_S)

    def add_association(self, info: dict[str, FloatArray], lanes: np.ndarray | None) -> None:
        """Record one step's :data:`ASSOCIATION_KEYS` counts and ``spurious_landmarks``."""
        sel = self._all if lanes is None else lanes
        if self.association:
            for j, key in enumerate(ASSOCIATION_KEYS):  # counts: never NaN
                np.add(self._assoc[:, j], info[key], out=self._assoc[:, j], where=sel)
            np.copyto(self._assoc[:, -1], info["spurious_landmarks"], where=sel)

    def summary(self) -> dict[str, FloatArray]:
        """Episode RMSEs, ANEES and the share of steps inside the 95% χ² bounds, each (B,),
        over the whole episode and per phase (NaN for a phase without steps)."""
        out = {"episode_steps": self._acc[0, :, 0].copy()}
        out.update(_rms_nees(self._acc[0], ""))
        for j, (name, _) in enumerate(_LAST):
            out[name] = self._acc[0, :, 1 + _N_RMS + j].copy()
        for p, phase in enumerate(PHASES, start=1):
            out[f"episode_steps_{phase}"] = self._acc[p, :, 0].copy()
            out.update(_rms_nees(self._acc[p], phase))
        if self.association:
            with np.errstate(invalid="ignore", divide="ignore"):
                _, n_assoc, n_wrong, n_true, n_missed, spurious = self._assoc.T
                out["episode_assoc_wrong_rate"] = n_wrong / n_assoc
                out["episode_assoc_missed_rate"] = n_missed / n_true
                out["episode_spurious_landmarks"] = spurious.copy()
        return out


def _rms_nees(acc: FloatArray, phase: str) -> dict[str, FloatArray]:
    """The RMSE and NEES summaries of one phase's (B, cols) sums (``phase`` "" = whole)."""

    def key(name: str) -> str:
        return phase_key(name, phase) if phase else name

    n = acc[:, 0]
    out: dict[str, FloatArray] = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for j, (name, _) in enumerate(_RMS):
            out[key(name)] = np.where(n > 0, np.sqrt(acc[:, 1 + j] / n), math.nan)
        s, c, inside, s3, c3 = acc[:, 1 + _N_RMS + _N_LAST :].T
        out[key("episode_anees_pose")] = np.where(c > 0, s / c, math.nan)
        out[key("episode_nees_pose_in_bounds")] = np.where(c > 0, inside / c, math.nan)
        out[key("episode_anees_pos")] = np.where(c3 > 0, s3 / c3, math.nan)
    return out
