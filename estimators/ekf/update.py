"""Numba kernel of the batched EKF-SLAM correction: χ² gate, stacked update, registration.

One call of :func:`update_lanes` handles every scanning lane (seed 001 eq. 37–53):

1. the observed mapped (or, in known-map mode, known) landmarks are predicted with the LiDAR
   model and stacked into ``H`` over the columns ``[s, m_κ]`` (eq. 34, 40);
2. each landmark is gated on its own 3-DOF NIS ``ν_iᵀ S_ii⁻¹ ν_i`` (rejections counted), and
   with the integrity monitor on the scan is tested, its faulty landmarks left out
   (:mod:`estimators.ekf.fde`);
3. the accepted ones form one update touching only the rows ``[s, m_κ]`` of P:
   ``U = H P[idx, :]`` (= ``(P Hᵀ)ᵀ``), ``S = U[:, idx] Hᵀ + R`` (eq. 38), ``S = L Lᵀ``,
   ``Wᵀ = L⁻¹ U``, ``x += W L⁻¹ ν`` (eq. 42) and ``P -= W Wᵀ`` (= ``K S Kᵀ``, eq. 43);
4. observed unmapped landmarks are registered in ascending id order (eq. 44–53,
   :mod:`estimators.ekf.register`).

A failed step (singular or non-positive-definite S, a non-finite result, a covariance
diagonal that would turn negative) is skipped and sets the lane's ``diverged`` flag;
registration still runs after a skipped update.
"""

from __future__ import annotations

import math

import numpy as np

from estimators.association import solve3_nis
from estimators.ekf.correction import (
    correction,
    innovation_covariance,
    predicted_measurements,
    relinearise,
    stacked_gain,
)
from estimators.ekf.fde import leave_out, monitored
from estimators.ekf.kernels import (
    D_DIVERGED,
    D_N_REJECTED,
    D_N_REJECTED_LAST,
    D_N_UPDATES,
    D_NIS,
    D_NIS_DOF,
    D_SEPARATION,
    sync_lane,
)
from estimators.ekf.register import register_new
from quadslam_env.models.frames import wrap_pi
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.types import EUL, POS, POSE_DIM, FloatArray

DIAG_FLOOR = -1e-9
"""Most negative posterior variance accepted as round-off."""


def stacked_model(
    xb: FloatArray, lms: FloatArray, lm_cols: np.ndarray | None
) -> tuple[np.ndarray, FloatArray, FloatArray]:
    """Stacked observation model of k landmarks as dense arrays (eq. 34 and 40).

    Args:
        xb: (n,) total state of one lane.
        lms: (k, 3) landmark positions in N, m.
        lm_cols: (3k,) their columns in x, or ``None`` for known (non-state) landmarks.

    Returns:
        ``(cols, h, H)``: ``cols`` (d,) the columns ``[s, m_κ]`` of x the model depends on
        (d = 9 + 3k, or 9 for known landmarks), ``h`` (3k,) the predicted (α, β, δ) and
        ``H`` (3k, d) = ``∂h/∂x[cols]``.
    """
    k = lms.shape[0]
    h = np.empty((k, 3))
    blocks = np.empty((k, 3, 9))
    predicted_measurements(xb, np.ascontiguousarray(lms, dtype=float), h, blocks)
    cols = np.arange(POSE_DIM) if lm_cols is None else np.r_[np.arange(POSE_DIM), lm_cols]
    H = np.zeros((k, 3, cols.shape[0]))
    H[:, :, POS] = blocks[:, :, 0:3]
    H[:, :, EUL] = blocks[:, :, 3:6]
    if lm_cols is not None:
        for i in range(k):
            H[i, :, POSE_DIM + 3 * i : POSE_DIM + 3 * i + 3] = blocks[i, :, 6:9]
    return cols, h.ravel(), H.reshape(3 * k, -1)


@kernel
def subtract_outer(Pb: FloatArray, Wt: FloatArray, nb: int) -> None:
    """``P[:n, :n] -= W Wᵀ`` (eq. 43) for ``Wt = Wᵀ`` (m, n), exactly symmetric.

    The lower triangle is computed (each ``(W Wᵀ)_ij`` summed over a in order, then
    subtracted) and mirrored. Two rows of P share every load of ``Wᵀ`` and four terms of the
    sum are added per pass: measured 2x faster than one row and one term at a time, with
    bitwise the same result.
    """
    m = Wt.shape[0]
    m4 = m - m % 4
    acc0 = np.empty(nb)
    acc1 = np.empty(nb)
    for i in range(0, nb - 1, 2):  # rows i and i + 1, columns 0 … i + 1
        acc0[: i + 2] = 0.0
        acc1[: i + 2] = 0.0
        for a in range(0, m4, 4):
            W0, W1, W2, W3 = Wt[a], Wt[a + 1], Wt[a + 2], Wt[a + 3]
            u0, u1, u2, u3 = W0[i], W1[i], W2[i], W3[i]
            v0, v1, v2, v3 = W0[i + 1], W1[i + 1], W2[i + 1], W3[i + 1]
            for j in range(i + 2):
                e0, e1, e2, e3 = W0[j], W1[j], W2[j], W3[j]
                acc0[j] = acc0[j] + u0 * e0 + u1 * e1 + u2 * e2 + u3 * e3
                acc1[j] = acc1[j] + v0 * e0 + v1 * e1 + v2 * e2 + v3 * e3
        for a in range(m4, m):
            Wa = Wt[a]
            u, v = Wa[i], Wa[i + 1]
            for j in range(i + 2):
                acc0[j] += u * Wa[j]
                acc1[j] += v * Wa[j]
        P0, P1 = Pb[i], Pb[i + 1]
        for j in range(i + 1):
            P0[j] -= acc0[j]
        for j in range(i + 2):
            P1[j] -= acc1[j]
    if nb % 2:  # the last row when n is odd
        i = nb - 1
        for j in range(nb):
            acc = 0.0
            for a in range(m):
                acc += Wt[a, i] * Wt[a, j]
            Pb[i, j] -= acc
    for i in range(nb):
        for j in range(i):
            Pb[j, i] = Pb[i, j]


@kernel
def innovation(y: FloatArray, h: FloatArray, out: FloatArray) -> None:
    """``out = y − h`` (3,) for measurements (α, β, δ), the angles wrapped to (−π, π]."""
    out[0] = wrap_pi(y[0] - h[0])
    out[1] = wrap_pi(y[1] - h[1])
    out[2] = y[2] - h[2]


@inline_kernel
def _select(
    S: FloatArray,
    U: FloatArray,
    nu: FloatArray,
    gate: float,
    monitor: FloatArray,
    thresholds: tuple[FloatArray, FloatArray, FloatArray],
    keep: np.ndarray,
    excluded: np.ndarray,
    diag: FloatArray,
    b: int,
    windows: tuple[np.ndarray, FloatArray, np.ndarray],
) -> bool:
    """Which of one lane's k observed landmarks the update uses (``keep`` (k,), all True on
    entry): the per-landmark χ² gate, then the integrity monitor's tests (``monitor``,
    ``thresholds``; ``windows``: the k ids and the lane's sequential windows and sightings by
    id: see :func:`update_lanes`). Returns False (the lane flagged diverged) on a singular S."""
    k = keep.shape[0]
    if monitor[0] < 1.5:  # no exclusion: the per-landmark χ² gate on the 3×3 blocks of S
        for i in range(k):
            nis_i = solve3_nis(S, 3 * i, nu[3 * i : 3 * i + 3])
            if not math.isfinite(nis_i):
                diag[D_DIVERGED, b] = 1.0
                return False
            keep[i] = nis_i <= gate
    # The monitor tests the landmarks kept: detection only, on the gated ones (the update
    # stays the unmonitored one); with exclusion, all of them (its tests replace the gate).
    if monitor[0] > 0.5:
        if not keep.any():  # every landmark gated out: no hypothesis to bound
            for r in range(4):
                diag[D_SEPARATION + r, b] = 0.0
        elif not monitored(S, U, nu, monitor, thresholds, keep, excluded, diag, b, windows):
            return False
    return True


@kernel
def _update_mapped(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    lms: FloatArray,
    cols: np.ndarray,
    y: FloatArray,
    r_diag: FloatArray,
    gate: float,
    tol: float,
    max_iter: int,
    diag: FloatArray,
    b: int,
    monitor: FloatArray,
    thresholds: tuple[FloatArray, FloatArray, FloatArray],
    excluded: np.ndarray,
    windows: tuple[np.ndarray, FloatArray, np.ndarray],
) -> None:
    """Gated stacked update of one lane with ``lms`` (k, 3) observed as ``y``, iterated beyond
    ``tol`` noise stds (inf: never; ``correction.relinearise``), its NIS at the prior;
    ``excluded`` (k,) set where the integrity monitor leaves a landmark out (:func:`_select`)."""
    k = lms.shape[0]
    h = np.empty((k, 3))
    U = np.empty((3 * k, nb))
    S = np.empty((3 * k, 3 * k))
    innovation_covariance(xb, Pb, nb, lms, cols, r_diag, h, U, S)
    nu = np.empty(3 * k)
    for i in range(k):
        innovation(y[i], h[i], nu[3 * i : 3 * i + 3])
    keep = np.ones(k, dtype=np.bool_)
    if not _select(S, U, nu, gate, monitor, thresholds, keep, excluded, diag, b, windows):
        return
    n_keep = 0
    for i in range(k):
        n_keep += keep[i]
    diag[D_N_REJECTED_LAST, b] = k - n_keep
    diag[D_N_REJECTED, b] += k - n_keep
    if n_keep == 0:
        return
    m = 3 * n_keep
    idx = np.empty(m, dtype=np.int64)
    a = 0
    for i in range(k):
        if keep[i]:
            idx[a], idx[a + 1], idx[a + 2] = 3 * i, 3 * i + 1, 3 * i + 2
            a += 3
    Wt = np.empty((m, nb))
    z = np.empty(m)
    if not stacked_gain(S, U, nu, idx, Wt, z):
        diag[D_DIVERGED, b] = 1.0
        return
    nis = 0.0
    for a in range(m):
        nis += z[a] * z[a]
    dx = np.zeros(nb)
    correction(Wt, z, dx)
    if tol < math.inf:  # the iterated update where the first-order one is not linear enough
        kept = np.flatnonzero(keep)
        relinearise(xb, Pb, nb, lms[kept], cols[kept], y[kept], r_diag, tol, max_iter, dx, Wt, z)
    wsq = np.zeros(nb)
    for a in range(m):
        Wa = Wt[a]
        for j in range(nb):
            wsq[j] += Wa[j] * Wa[j]
    total = 0.0
    negative = False
    for j in range(nb):
        total += dx[j]
        negative = negative or Pb[j, j] - wsq[j] < DIAG_FLOOR
    if not math.isfinite(nis) or not math.isfinite(total) or negative:
        diag[D_DIVERGED, b] = 1.0
        return
    for j in range(nb):
        xb[j] += dx[j]
    subtract_outer(Pb, Wt, nb)
    xb[6] = wrap_pi(xb[6])
    xb[8] = wrap_pi(xb[8])
    diag[D_NIS, b] = nis
    diag[D_NIS_DOF, b] = m
    diag[D_N_UPDATES, b] += 1.0


@inline_kernel
def _split_visible(
    visible: np.ndarray, mapped: np.ndarray, known: bool, readmit_at: FloatArray, t: float
) -> tuple[np.ndarray, int, np.ndarray, int]:
    """``(obs, k_obs, new, k_new)``: of one lane's returned ids ``visible`` (L,) bool, the
    mapped ones (``obs[:k_obs]``, to correct with) and the unmapped ones (``new[:k_new]``, to
    register; none in known-map mode), in id order; ids the integrity monitor left out are
    skipped until their readmission time ``readmit_at`` (Lmax,) s (−inf: never left out)."""
    L = visible.shape[0]
    obs = np.empty(L, dtype=np.int64)
    new = np.empty(L, dtype=np.int64)
    k_obs = 0
    k_new = 0
    for j in range(L):
        if visible[j] and not readmit_at[j] > t:
            if mapped[j]:
                obs[k_obs] = j
                k_obs += 1
            elif not known:
                new[k_new] = j
                k_new += 1
    return obs, k_obs, new, k_new


@inline_kernel
def _gather(
    obs: np.ndarray,
    xb: FloatArray,
    nv: int,
    slot_of_id: np.ndarray,
    known: bool,
    known_pos: FloatArray,
    meas: FloatArray,
) -> tuple[FloatArray, np.ndarray, FloatArray]:
    """``(lms (k, 3), cols (k,), y (k, 3))`` of one lane's observed mapped ids ``obs`` (k,):
    their positions (in x, or known), their first columns in x (-1: known) and their
    measurements from the lane's ``meas`` (L, 3)."""
    k = obs.shape[0]
    lms = np.empty((k, 3))
    cols = np.full(k, -1, dtype=np.int64)
    y = np.empty((k, 3))
    # Element by element throughout this module's kernels: an array assignment compiles
    # numba's shape-mismatch message (~2 s of first-use compile).
    for i in range(k):
        j = obs[i]
        if not known:
            cols[i] = nv + 3 * slot_of_id[j]
        for r in range(3):
            y[i, r] = meas[j, r]
            lms[i, r] = known_pos[j, r] if known else xb[cols[i] + r]
    return lms, cols, y


@kernel
def update_lanes(
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    stale: np.ndarray,
    slot_of_id: np.ndarray,
    id_of_slot: np.ndarray,
    mapped: np.ndarray,
    known: np.ndarray,
    known_pos: FloatArray,
    diag: FloatArray,
    lanes: np.ndarray,
    visible: np.ndarray,
    meas: FloatArray,
    r_diag: FloatArray,
    gate: float,
    t: FloatArray,
    monitor: FloatArray,
    thresholds: tuple[FloatArray, FloatArray, FloatArray],
    readmit_at: FloatArray,
    seq_stats: FloatArray,
    seq_count: np.ndarray,
    tol: float = math.inf,
    max_iter: int = 0,
) -> None:
    """Correct each lane in ``lanes`` with its scan (through the integrity monitor when it is
    on), drop the landmarks it left out, then register the lane's new landmarks.

    Args:
        x: (B, nmax) means; P: (B, nmax, nmax) covariances; n: (B,) int state sizes.
        nv: Vehicle-state size (9, or 13 with biases).
        stale: (B,) bool, lanes whose columns ``P[nv:n, :nv]`` must be rebuilt first.
        slot_of_id: (B, Lmax) int, map slot of each landmark id (-1: unmapped).
        id_of_slot: (B, Lmax) int, landmark id of each map slot.
        mapped: (B, Lmax) bool, ids mapped (SLAM) or known (known-map lanes).
        known: (B,) bool, lanes in known-map mode (their unknown ids are ignored).
        known_pos: (B, Lmax, 3) known landmark positions in N, m.
        diag: (15, B) diagnostics (rows ``D_*``).
        lanes: (k,) int, the scanning lanes.
        visible: (B, L) bool with L ≤ Lmax, returned landmark ids.
        meas: (B, L, 3) their measurements (α rad, β rad, δ m).
        r_diag: (3,) measurement noise variances.
        gate: Per-landmark NIS threshold (inf: no gating).
        t: (B,) scan times, s.
        monitor: (3,) the integrity monitor: mode (0 off, 1 detect, 2 exclude), the most
            exclusions of one scan, the readmission delay in s (:mod:`estimators.ekf.fde`).
        thresholds: Its thresholds (landmark, scan, sequential:
            :class:`estimators.ekf.fde.IntegrityMonitor`).
        readmit_at: (B, Lmax) time from which each id may be used again, s (−inf: always).
        seq_stats, seq_count: (B, Lmax, W), (B, Lmax) int: its sequential windows by id.
        tol: Linearisation error in noise stds above which an update is iterated (inf:
            never; :mod:`estimators.ekf.correction`). max_iter: Most iterations.
    """
    for b in lanes:
        xb, Pb, nb = x[b], P[b], n[b]
        if stale[b]:
            sync_lane(Pb, nb, nv)
            stale[b] = False
        obs, k_obs, new, k_new = _split_visible(
            visible[b], mapped[b], known[b], readmit_at[b], t[b]
        )
        if monitor[0] > 0.0 and k_obs == 0:  # no landmark to test: no fault hypothesis
            for r in range(4):
                diag[D_SEPARATION + r, b] = 0.0
        if k_obs:
            lms, cols, y = _gather(obs[:k_obs], xb, nv, slot_of_id[b], known[b], known_pos[b],
                                   meas[b])  # fmt: skip
            excluded = np.zeros(k_obs, dtype=np.bool_)
            _update_mapped(
                xb, Pb, nb, lms, cols, y, r_diag, gate, tol, max_iter, diag, b, monitor,
                thresholds, excluded, (obs[:k_obs], seq_stats[b], seq_count[b]),
            )  # fmt: skip
            for i in range(k_obs):
                if excluded[i]:
                    leave_out(b, obs[i], t[b] + monitor[2], x, P, n, nv, slot_of_id, id_of_slot,
                               mapped, known, readmit_at, seq_count, diag)  # fmt: skip
        if k_new:
            register_new(b, new[:k_new], x, P, n, nv, meas, r_diag, slot_of_id, id_of_slot,
                          mapped, diag)  # fmt: skip


@kernel
def first_nonfinite_lane(lanes: np.ndarray, visible: np.ndarray, meas: FloatArray) -> int:
    """The first lane of ``lanes`` with a non-finite visible measurement, or -1."""
    for b in lanes:
        for j in range(visible.shape[1]):
            if visible[b, j]:
                for r in range(3):
                    if not math.isfinite(meas[b, j, r]):
                        return b
    return -1
