"""Fault detection and exclusion (FDE) of one EKF-SLAM scan update, its solution separations,
and the monitor as the filter holds it (:class:`IntegrityMonitor`).

The monitor of docs/integrity.md "The monitor", run on the k landmarks a scan observes before
the stacked update (:func:`estimators.ekf.update.update_lanes`), with ``Σ = S⁻¹`` over the
landmarks kept (S the innovation covariance of seed 001 eq. 38, ν the innovations):

* **scan test** — the scan's NIS ``q = νᵀ Σ ν`` (χ² with 3k degrees of freedom when the filter
  is consistent and no landmark is faulty) against ``χ²_3k(1 − p_fa/2)``;
* **landmark tests** — for each kept landmark i the drop of the scan's NIS when its return is
  left out, ``t_i = g_iᵀ Σ_ii⁻¹ g_i`` with ``g = Σ ν`` (the 3-DOF χ² of the *solution
  separation* of hypothesis i, see below), against ``χ²_3(1 − p_fa/(2k))`` (Bonferroni: the two
  tests share the false-alarm budget p_fa);
* **sequential test** (with ``sequential_window`` W) — for each landmark tested the sum of its
  ``t_i`` over its last n = min(c, W) sightings (c those since it was last left out), against
  ``χ²_3n(1 − p_fa/(2k))``: a χ² with 3n degrees of freedom when the filter is consistent, the
  innovations of a Kalman filter being white, so the statistics of different scans are
  independent. It is the χ² test of a change in the mean of a Kalman filter's innovations
  over a finite moving window (Basseville & Nikiforov 1993, "Detection of Abrupt Changes:
  Theory and Application", Prentice Hall; in Kalman-filter integrity monitoring: Joerger &
  Pervan 2013, "Kalman Filter-Based Integrity Monitoring Against Sensor Faults", J. Guidance,
  Control, and Dynamics 36(2)). A landmark that drifts slowly grows each ``t_i`` little; the
  sum over n scans grows with the sum of their noncentralities while its noise grows as √n.
  The one-scan tests then get half of p_fa (scan test ``χ²_3k(1 − p_fa/4)``, landmark tests
  ``χ²_3(1 − p_fa/(4k))``) and the sequential tests the other half, so the three together
  alarm on at most p_fa of the fault-free scans;
* **exclusion** — on an alarm, the landmark with the largest ``t_i`` (on a sequential alarm
  alone: the largest window sum over its threshold) is left out and the one-scan tests are run
  again on the rest (the sequential ones keep their first-pass result), up to
  ``max_exclusions`` times; if an alarm persists the scan is not used at all (*unresolved*).

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
from estimators.ekf.state import EkfState
from quadslam_env.estimation.integrity import MonitorSettings
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
def sequential_tests(
    t: FloatArray,
    keep: np.ndarray,
    ids: np.ndarray,
    stats: FloatArray,
    count: np.ndarray,
    seq_thr: FloatArray,
    excess: FloatArray,
) -> None:
    """Append each tested landmark's statistic to its window and give its sequential test.

    Landmark i's window holds its last ``n = min(c, W)`` statistics ``t_i`` (c its sightings
    since it was last left out or its lane reset); their sum is tested against
    ``χ²_3n(1 − p_fa/(2k))`` (module docstring).

    Args:
        t: (≥ kept,) the statistics ``t_a`` of the kept landmarks, in their order.
        keep: (k,) bool, the landmarks tested.
        ids: (k,) int, their landmark ids.
        stats: (Lmax, W) float, each id's window of statistics (a ring of W), in and out.
        count: (Lmax,) int, each id's sightings so far, in and out.
        seq_thr: (≥ kept + 1, W + 1) thresholds by landmarks tested and window length.
        excess: (k,) filled: each tested landmark's window sum over its threshold (an alarm
            above 1), 0 for those not tested.
    """
    window = stats.shape[1]
    kept = 0
    for i in range(keep.shape[0]):
        kept += keep[i]
    a = 0
    for i in range(keep.shape[0]):
        excess[i] = 0.0
        if not keep[i]:
            continue
        j = ids[i]
        c = count[j]
        stats[j, c % window] = t[a]
        count[j] = c + 1
        n = min(c + 1, window)
        total = 0.0
        for r in range(n):
            total += stats[j, r]
        excess[i] = total / seq_thr[kept, n]
        a += 1


@kernel
def alarmed(
    scan_alarm: bool, t: FloatArray, lm_thr: float, keep: np.ndarray, excess: FloatArray
) -> int:
    """The landmark an alarm points at, by its index among all k (-1: no alarm): on a one-scan
    alarm (the scan test's ``scan_alarm``, or a kept landmark's ``t_a`` (in ``t[:kept]``) above
    ``lm_thr``) the kept landmark with the largest ``t_a``; else, on a sequential alarm (an
    ``excess`` (k,) above 1), the kept landmark with the largest excess."""
    k = keep.shape[0]
    worst, a, target = -1, -1, -1
    for i in range(k):
        if keep[i]:
            a += 1
            if worst < 0 or t[a] > t[worst]:
                worst, target = a, i
    if scan_alarm or t[worst] > lm_thr:
        return target
    target = -1
    for i in range(k):
        if keep[i] and excess[i] > 1.0 and (target < 0 or excess[i] > excess[target]):
            target = i
    return target


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
    ids: np.ndarray,
    stats: FloatArray,
    count: np.ndarray,
    seq_thr: FloatArray,
) -> int:
    """Test one lane's scan of k landmarks, exclude the faulty ones, and give the separations.

    Args:
        S: (3k, 3k) innovation covariance (seed 001 eq. 38).
        U: (3k, n) ``H P⁻`` over the lane's state (its first three columns: the position).
        nu: (3k,) innovations (angles wrapped).
        lm_thr: (≥ k + 1,) the landmark test's threshold by the number of kept landmarks,
            ``χ²_3(1 − p/(2k))`` (p the one-scan budget).
        scan_thr: (≥ 3k + 1,) the scan test's threshold by degrees of freedom,
            ``χ²_m(1 − p/2)``.
        exclude: Leave out the landmark found faulty (False: detection only).
        max_exclusions: Most landmarks left out of one scan.
        keep: (k,) bool, in: the landmarks to test (at least one); out: those the update is
            to use (none if unresolved).
        sep: (4,) filled: the largest position separation variances (N, E, D) in m² over the
            kept landmarks, and their number (the hypotheses of the protection level); zero
            when the scan is not used.
        ids, stats, count, seq_thr: The sequential test (:func:`sequential_tests`): the k
            landmarks' ids, the lane's windows (Lmax, W) and sightings (Lmax,), the thresholds
            (≥ k + 1, W + 1); W = 0: no sequential test.

    Returns:
        One of ``FDE_*``.
    """
    k = nu.shape[0] // 3
    sep[:] = 0.0
    idx = np.empty(3 * k, dtype=np.int64)
    Sigma = np.empty((3 * k, 3 * k))
    t = np.empty(k)
    excess = np.zeros(k)
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
        if excluded == 0 and stats.shape[1] > 0:  # the first pass: every landmark tested
            sequential_tests(t, keep, ids, stats, count, seq_thr, excess)
        target = alarmed(q > scan_thr[m], t, lm_thr[kept], keep, excess)
        if target < 0:
            break
        if not exclude:
            status = FDE_DETECTED
            break
        if excluded == max_exclusions:
            keep[:] = False
            return FDE_UNRESOLVED
        keep[target] = False
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
    thresholds: tuple[FloatArray, FloatArray, FloatArray],
    keep: np.ndarray,
    excluded: np.ndarray,
    diag: FloatArray,
    b: int,
    windows: tuple[np.ndarray, FloatArray, np.ndarray],
) -> bool:
    """Run the integrity monitor on one lane's scan (:func:`~estimators.ekf.fde.monitor_scan`)
    and count its outcome in ``diag``; ``monitor`` = (mode: 1 detect, 2 exclude, the most
    exclusions, the readmission delay s), ``thresholds`` = (landmark, scan, sequential),
    ``windows`` = (the scan's k landmark ids, the lane's sequential windows (Lmax, W) and
    sightings (Lmax,) by id). Returns False if S is not positive definite (the lane is flagged
    diverged)."""
    sep = np.empty(4)
    lm_thr, scan_thr, seq_thr = thresholds
    ids, stats, count = windows
    status = monitor_scan(S, U, nu, lm_thr, scan_thr, monitor[0] > 1.5, int(monitor[1]), keep,
                          sep, ids, stats, count, seq_thr)  # fmt: skip
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
    seq_count: np.ndarray,
    diag: FloatArray,
) -> None:
    """Landmark ``j`` of lane ``b``, found faulty, is not used until ``until`` s; in a SLAM
    lane it is also dropped from the map (marginalised: a moved landmark must not drag the
    vehicle), to be registered anew from a sighting after that time. Its sequential test
    starts afresh (``seq_count`` (B, Lmax): no sightings)."""
    readmit_at[b, j] = until
    seq_count[b, j] = 0
    if known[b]:
        return
    remove_landmark(x[b], P[b], n[b], nv, slot_of_id[b], id_of_slot[b], j)
    n[b] -= 3
    mapped[b, j] = False
    diag[D_N_MAPPED, b] = (n[b] - nv) // 3


# ------------------------------------------------------------- the monitor as the filter holds it

Thresholds = tuple[FloatArray, FloatArray, FloatArray]
"""The tests' thresholds as the update kernel takes them: (landmark, scan, sequential)."""

_OFF = np.zeros(3)
"""The monitor arguments of the update kernel when there is no monitor."""
_NO_THRESHOLDS = np.full(1, np.inf)
_NO_SEQUENTIAL = np.full((1, 1), np.inf)


class IntegrityMonitor:
    """:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity` for
    :class:`~estimators.ekf.filter.EkfSlamBatch` (a mixin): the scan tests, exclusion and
    solution separations of this module's kernels on every later update."""

    monitors_integrity = True
    state: EkfState
    _monitor: MonitorSettings | None = None
    _thresholds_for = -1
    _monitor_thresholds: Thresholds = (_NO_THRESHOLDS, _NO_THRESHOLDS, _NO_SEQUENTIAL)

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Monitor every later scan with ``settings`` (``None``: no monitor, the default); the
        lanes' sequential windows start empty."""
        self._monitor = settings
        self._thresholds_for = -1
        window = 0 if settings is None else settings.sequential_window or 0
        self.state.set_window(window)

    def monitor_arguments(self, capacity: int) -> tuple[FloatArray, Thresholds]:
        """``(monitor (3,), thresholds)`` of the update kernel for scans of up to ``capacity``
        landmarks: the mode (0 off, 1 detect, 2 exclude), the most exclusions and the
        readmission delay, and the tests' thresholds (landmark, scan, sequential; tabulated
        once per capacity)."""
        cfg = self._monitor
        if cfg is None:
            return _OFF, (_NO_THRESHOLDS, _NO_THRESHOLDS, _NO_SEQUENTIAL)
        if self._thresholds_for != capacity:
            self._monitor_thresholds = (
                cfg.landmark_thresholds(capacity),
                cfg.scan_thresholds(capacity),
                cfg.sequential_thresholds(capacity),
            )
            self._thresholds_for = capacity
        mode = 2.0 if cfg.exclude else 1.0
        args = np.array([mode, float(cfg.max_exclusions), cfg.readmit_s])
        return args, self._monitor_thresholds
