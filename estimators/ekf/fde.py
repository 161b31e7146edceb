"""Fault detection and exclusion (FDE) of one EKF-SLAM scan update, and its solution separations.

The monitor of docs/integrity.md "The monitor", run on the k landmarks a scan observes before
the stacked update (:func:`estimators.ekf.update.update_lanes`), with ``Σ = S⁻¹`` over the
landmarks kept (S the innovation covariance of seed 001 eq. 38, ν the innovations):

* **scan test** — the scan's NIS ``q = νᵀ Σ ν`` (χ² with 3k degrees of freedom when the filter
  is consistent and no landmark is faulty) against ``χ²_3k(1 − p_fa/2)``;
* **landmark tests** — for each kept landmark i the drop of the scan's NIS when its return is
  left out, ``t_i = g_iᵀ Σ_ii⁻¹ g_i`` with ``g = Σ ν`` (the 3-DOF χ² of the *solution
  separation* of hypothesis i, see below), against ``χ²_3(1 − p_fa/(2k))`` (Bonferroni: the two
  tests share the false-alarm budget p_fa);
* **exclusion** — on an alarm, the landmark with the largest ``t_i`` is left out and both tests
  are run again on the rest, up to ``max_exclusions`` times; if the alarm persists the scan is
  not used at all (*unresolved*).

The separations are those of Joerger, Chan & Pervan (2014), "Solution Separation Versus
Residual-Based RAIM", NAVIGATION 61(4), written for one Kalman update: the subset solution that
leaves out landmark i has the posterior ``P_(i)``, and with ``A = H P⁻`` the separation
``Δ_i = x̂ − x̂_(i)`` and its covariance ``D_i = P_(i) − P`` are (block inversion of Σ)

    Δ_i = (Σ A)_iᵀ Σ_ii⁻¹ g_i,     D_i = (Σ A)_iᵀ Σ_ii⁻¹ (Σ A)_i,

so ``Δ_iᵀ D_i⁺ Δ_i = t_i``. Of ``D_i`` the monitor keeps the position diagonal, the largest over
the kept landmarks per axis (N, E, D): the protection level of each axis grows with it
(:func:`quadslam_env.estimation.integrity.protection_levels`).
"""

from __future__ import annotations

import numpy as np

from estimators.association import solve3_nis
from estimators.ekf.kernels import (
    D_DIVERGED,
    D_FDE_ALARMS,
    D_FDE_EXCLUSIONS,
    D_FDE_TESTS,
    D_FDE_UNRESOLVED,
    D_N_MAPPED,
    D_SEPARATION,
    remove_landmark,
)
from quadslam_env.models.jit import kernel
from quadslam_env.models.linalg import cholesky_lower
from quadslam_env.types import FloatArray

FDE_PASS, FDE_EXCLUDED, FDE_DETECTED, FDE_UNRESOLVED, FDE_SINGULAR = range(5)
"""Outcomes of :func:`monitor_scan`: no alarm; an alarm resolved by exclusion; an alarm not
acted on (detection only); an alarm that exclusion could not resolve (the scan is not used);
an innovation covariance that is not positive definite."""


@kernel
def subset_inverse(S: FloatArray, keep: np.ndarray, idx: np.ndarray, Sigma: FloatArray) -> int:
    """``Σ = S[idx][:, idx]⁻¹`` over the rows of the kept landmarks.

    Args:
        S: (3k, 3k) innovation covariance of k landmarks.
        keep: (k,) bool, the landmarks kept.
        idx: (3k,) int, filled: ``idx[:m]`` the rows of the kept landmarks (m = 3 × kept).
        Sigma: (3k, 3k), filled: ``Σ`` in its leading (m, m) block.

    Returns:
        m, or -1 if the kept block is not positive definite.
    """
    m = 0
    for i in range(keep.shape[0]):
        if keep[i]:
            idx[m], idx[m + 1], idx[m + 2] = 3 * i, 3 * i + 1, 3 * i + 2
            m += 3
    L = np.empty((m, m))
    for a in range(m):
        for c in range(a + 1):
            L[a, c] = S[idx[a], idx[c]]
    if not cholesky_lower(L):
        return -1
    Li = np.zeros((m, m))  # L⁻¹ by forward substitution, column by column of I
    for c in range(m):
        Li[c, c] = 1.0 / L[c, c]
        for a in range(c + 1, m):
            acc = 0.0
            for j in range(c, a):
                acc -= L[a, j] * Li[j, c]
            Li[a, c] = acc / L[a, a]
    for a in range(m):  # Σ = L⁻ᵀ L⁻¹, symmetric
        for c in range(a + 1):
            acc = 0.0
            for j in range(a, m):
                acc += Li[j, a] * Li[j, c]
            Sigma[a, c] = acc
            Sigma[c, a] = acc
    return m


@kernel
def landmark_tests(
    Sigma: FloatArray, m: int, nu: FloatArray, idx: np.ndarray, t: FloatArray
) -> float:
    """The scan's NIS ``q = νᵀ Σ ν`` and each kept landmark's ``t_a = g_aᵀ Σ_aa⁻¹ g_a`` into
    ``t[:m // 3]`` (``g = Σ ν``), for Σ (m, m) and the innovations ``nu`` (3k,) at rows ``idx``."""
    g = np.zeros(m)
    q = 0.0
    for a in range(m):
        acc = 0.0
        for c in range(m):
            acc += Sigma[a, c] * nu[idx[c]]
        g[a] = acc
        q += nu[idx[a]] * acc
    for a in range(m // 3):
        t[a] = solve3_nis(Sigma, 3 * a, g[3 * a : 3 * a + 3])
    return q


@kernel
def separation_variances(
    Sigma: FloatArray, m: int, U: FloatArray, idx: np.ndarray, sep: FloatArray
) -> None:
    """``sep`` (3,) = the largest position diagonal ``(D_a)_qq`` over the kept landmarks a, per
    axis q (N, E, D), of ``D_a = (Σ A)_aᵀ Σ_aa⁻¹ (Σ A)_a`` with ``A = U[idx, 0:3]`` (the
    position columns of ``H P⁻``), m²."""
    GA = np.zeros((m, 3))
    for a in range(m):
        for c in range(m):
            s = Sigma[a, c]
            Uc = U[idx[c]]
            for q in range(3):
                GA[a, q] += s * Uc[q]
    sep[:] = 0.0
    v = np.empty(3)
    for a in range(m // 3):
        for q in range(3):
            for r in range(3):
                v[r] = GA[3 * a + r, q]
            d = solve3_nis(Sigma, 3 * a, v)
            if d > sep[q]:
                sep[q] = d


@kernel
def monitor_scan(
    S: FloatArray,
    U: FloatArray,
    nu: FloatArray,
    lm_thr: FloatArray,
    scan_thr: FloatArray,
    exclude: bool,
    max_exclusions: int,
    keep: np.ndarray,
    sep: FloatArray,
) -> int:
    """Test one lane's scan of k landmarks, exclude the faulty ones, and give the separations.

    Args:
        S: (3k, 3k) innovation covariance (seed 001 eq. 38).
        U: (3k, n) ``H P⁻`` over the lane's state (its first three columns: the position).
        nu: (3k,) innovations (angles wrapped).
        lm_thr: (≥ k + 1,) the landmark test's threshold by the number of kept landmarks,
            ``χ²_3(1 − p_fa/(2k))``.
        scan_thr: (≥ 3k + 1,) the scan test's threshold by degrees of freedom,
            ``χ²_m(1 − p_fa/2)``.
        exclude: Leave out the landmark found faulty (False: detection only).
        max_exclusions: Most landmarks left out of one scan.
        keep: (k,) bool, in: the landmarks to test (at least one); out: those the update is
            to use (none if unresolved).
        sep: (4,) filled: the largest position separation variances (N, E, D) in m² over the
            kept landmarks, and their number (the hypotheses of the protection level); zero
            when the scan is not used.

    Returns:
        One of ``FDE_*``.
    """
    k = nu.shape[0] // 3
    sep[:] = 0.0
    idx = np.empty(3 * k, dtype=np.int64)
    Sigma = np.empty((3 * k, 3 * k))
    t = np.empty(k)
    status = FDE_PASS
    excluded = 0
    while True:
        m = subset_inverse(S, keep, idx, Sigma)
        if m < 0:
            keep[:] = False
            return FDE_SINGULAR
        kept = m // 3
        if kept == 0:  # every landmark left out: nothing to test, the prediction stands
            return status
        q = landmark_tests(Sigma, m, nu, idx, t)
        worst = 0
        for a in range(kept):
            if t[a] > t[worst]:
                worst = a
        if not (q > scan_thr[m] or t[worst] > lm_thr[kept]):
            break
        if not exclude:
            status = FDE_DETECTED
            break
        if excluded == max_exclusions:
            keep[:] = False
            return FDE_UNRESOLVED
        a = -1  # the worst kept landmark's index among all k
        for i in range(k):
            a += keep[i]
            if keep[i] and a == worst:
                keep[i] = False
                break
        excluded += 1
        status = FDE_EXCLUDED
    separation_variances(Sigma, m, U, idx, sep)
    sep[3] = kept
    return status


@kernel
def monitored(
    S: FloatArray,
    U: FloatArray,
    nu: FloatArray,
    monitor: FloatArray,
    lm_thr: FloatArray,
    scan_thr: FloatArray,
    keep: np.ndarray,
    excluded: np.ndarray,
    diag: FloatArray,
    b: int,
) -> bool:
    """Run the integrity monitor on one lane's scan (:func:`~estimators.ekf.fde.monitor_scan`)
    and count its outcome in ``diag``; ``monitor`` = (mode: 1 detect, 2 exclude, the most
    exclusions, the readmission delay s). Returns False if S is not positive definite (the
    lane is flagged diverged)."""
    sep = np.empty(4)
    status = monitor_scan(S, U, nu, lm_thr, scan_thr, monitor[0] > 1.5, int(monitor[1]), keep, sep)
    if status == FDE_SINGULAR:
        diag[D_DIVERGED, b] = 1.0
        return False
    diag[D_FDE_TESTS, b] += 1.0
    if status != FDE_PASS:
        diag[D_FDE_ALARMS, b] += 1.0
    if status == FDE_UNRESOLVED:
        diag[D_FDE_UNRESOLVED, b] += 1.0
    if status == FDE_EXCLUDED:
        for i in range(keep.shape[0]):
            excluded[i] = not keep[i]
            diag[D_FDE_EXCLUSIONS, b] += excluded[i]
    for r in range(4):
        diag[D_SEPARATION + r, b] = sep[r]
    return True


@kernel
def leave_out(
    b: int,
    j: int,
    until: float,
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    slot_of_id: np.ndarray,
    id_of_slot: np.ndarray,
    mapped: np.ndarray,
    known: np.ndarray,
    readmit_at: FloatArray,
    diag: FloatArray,
) -> None:
    """Landmark ``j`` of lane ``b``, found faulty, is not used until ``until`` s; in a SLAM
    lane it is also dropped from the map (marginalised: a moved landmark must not drag the
    vehicle), to be registered anew from a sighting after that time."""
    readmit_at[b, j] = until
    if known[b]:
        return
    remove_landmark(x[b], P[b], n[b], nv, slot_of_id[b], id_of_slot[b], j)
    n[b] -= 3
    mapped[b, j] = False
    diag[D_N_MAPPED, b] = (n[b] - nv) // 3
