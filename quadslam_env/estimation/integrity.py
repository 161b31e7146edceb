"""Integrity at the estimator boundary: what a monitoring estimator is told, and the protection
levels from what it reports (docs/integrity.md).

An estimator that :class:`~quadslam_env.estimation.protocol.MonitorsIntegrity` is given a
:class:`MonitorSettings` (the false-alarm budget, exclusion, readmission) and reports, per lane
in its snapshot's diagnostics, the counts of its tests and, of its last scan, the largest
position *separation variances* per axis and the number of landmarks (fault hypotheses) they
cover (EKF-SLAM: :mod:`estimators.ekf.fde`). :func:`protection_levels` turns those and the
position covariance into horizontal and vertical protection levels.

Protection levels (solution separation; Joerger, Chan & Pervan 2014, "Solution Separation
Versus Residual-Based RAIM", NAVIGATION 61(4)). Per axis q of N, E, D, with σ_q² the position
variance of the solution, ``D_q`` the largest separation variance over the k landmarks (the
subset solution that leaves out landmark i has the variance ``σ_q² + D_iq``) and ``T_k`` the
landmark test's threshold ``χ²_3(1 − p/(2k))``, p the one-scan tests' budget
(:attr:`MonitorSettings.snapshot_p_fa`: ``p_fa``, or half of it beside the sequential test)::

    PL_q = √(T_k D_q) + K_q σ_q,(i) ,    σ_q,(i) = √(σ_q² + D_q),

the worst of the k faulty hypotheses: under hypothesis i left undetected (``t_i ≤ T_k``) the
separation along q is at most ``√(T_k D_iq)`` (Cauchy–Schwarz on ``Δ_iᵀ D_i⁺ Δ_i = t_i``) and the
subset solution's error is Gaussian; the term grows with ``D_iq``, so the largest one is the
worst. With no landmark (k = 0) it is the fault-free ``K_q σ_q``. The integrity risk
``p_hmi`` is split evenly between the horizontal and the vertical, the two horizontal axes and
the k + 1 hypotheses, two-sided: ``K_N = K_E = Φ⁻¹(1 − p_hmi / (8 (k + 1)))``,
``K_D = Φ⁻¹(1 − p_hmi / (4 (k + 1)))``, and ``HPL = √(PL_N² + PL_E²)``, ``VPL = PL_D`` (the
horizontal error is inside HPL whenever both axes are inside theirs). No prior probability of a
landmark fault is assumed (each hypothesis is taken as present), which is conservative.

Between scans the separations of the last scan are held while σ grows with the prediction
(the separations' own growth over one scan period is neglected), so the levels are defined
on every step.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.special import gammainccinv, ndtri

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

SEPARATION_KEYS = ("pl_sep_n", "pl_sep_e", "pl_sep_d", "pl_hypotheses")
"""Diagnostics of a monitoring estimator's last scan: the largest position separation
variances (N, E, D) in m² and the number of landmarks they cover."""
COUNT_KEYS = ("fde_tests", "fde_alarms", "fde_exclusions", "fde_unresolved")
"""Diagnostics of a monitoring estimator since each lane's reset: scans tested, alarms,
landmarks excluded and alarms that exclusion could not resolve (the scan not used)."""


def chi2_isf(p: FloatArray | float, dof: FloatArray | float) -> FloatArray:
    """The upper-tail quantile of χ² with ``dof`` degrees of freedom: ``P(χ² > x) = p``
    (scipy.special: scipy.stats costs a second to import)."""
    return np.asarray(2.0 * gammainccinv(0.5 * np.asarray(dof), p), dtype=float)


def landmark_thresholds(p_fa: float, capacity: int, dof: float = 3.0) -> FloatArray:
    """(capacity + 1,) the threshold ``χ²_dof(1 − p_fa/(2k))`` of one of k landmark tests that
    share half of the budget ``p_fa`` by the number k of landmarks tested (inf at k = 0).

    With ``dof = 3`` it is the landmark test's ``T_k``: the monitor's test and the protection
    levels' bound on an undetected separation; with ``dof = 3n`` the sequential test of a
    landmark's last n statistics (:meth:`MonitorSettings.sequential_thresholds`).
    """
    k = np.arange(capacity + 1, dtype=float)
    out = np.full(capacity + 1, math.inf)
    out[1:] = chi2_isf(p_fa / (2.0 * k[1:]), dof)
    return out


@dataclass(frozen=True)
class MonitorSettings:
    """What a monitoring estimator is told (from the scenario's ``integrity`` section).

    Attributes:
        p_fa: False-alarm budget of one scan's tests, in (0, 1).
        exclude: Leave out the landmarks found faulty (False: detect only).
        max_exclusions: Most landmarks left out of one scan.
        readmit_s: A landmark left out is dropped from the map and may enter it again (from
            a new sighting) this many seconds later, s.
        sequential_window: W, the sightings of a landmark its sequential test sums (``None``:
            no sequential test).
    """

    p_fa: float
    exclude: bool
    max_exclusions: int
    readmit_s: float
    sequential_window: int | None = None

    @property
    def snapshot_p_fa(self) -> float:
        """The budget of the one-scan tests (the scan's and the landmarks'): all of ``p_fa``,
        or half of it beside the sequential test, which has the other half (Bonferroni: the
        three tests' union alarms on at most ``p_fa`` of the fault-free scans)."""
        return self.p_fa if self.sequential_window is None else 0.5 * self.p_fa

    def landmark_thresholds(self, capacity: int) -> FloatArray:
        """(capacity + 1,) :func:`landmark_thresholds` of the one-scan budget."""
        return landmark_thresholds(self.snapshot_p_fa, capacity)

    def scan_thresholds(self, capacity: int) -> FloatArray:
        """(3 capacity + 1,) the scan test's threshold ``χ²_m(1 − p/2)`` by degrees of freedom
        m (inf at m = 0), p the one-scan budget."""
        dof = np.arange(3 * capacity + 1, dtype=float)
        out = np.full(3 * capacity + 1, math.inf)
        out[1:] = chi2_isf(self.snapshot_p_fa / 2.0, dof[1:])
        return out

    def sequential_thresholds(self, capacity: int) -> FloatArray:
        """(capacity + 1, W + 1) the sequential test's threshold ``χ²_3n(1 − p_fa/(2k))`` of a
        landmark's last n ≤ W statistics by the number k of landmarks tested (row) and n
        (column); inf at k = 0 or n = 0. The sequential tests of a scan's k landmarks share
        half of ``p_fa``. Without the test, (capacity + 1, 1) of inf."""
        window = self.sequential_window or 0
        out = np.full((capacity + 1, window + 1), math.inf)
        for n in range(1, window + 1):
            out[:, n] = landmark_thresholds(self.p_fa, capacity, 3.0 * n)
        return out


class LevelFactors:
    """The factors of the protection levels by the number k of hypotheses, for the budgets
    ``p_fa`` and ``p_hmi`` (module docstring), tabulated once up to the largest k asked for.

    Args:
        p_fa: False-alarm budget of a scan's tests, in (0, 1).
        p_hmi: Integrity risk per step, in (0, 1).
    """

    def __init__(self, p_fa: float, p_hmi: float) -> None:
        self.p_fa, self.p_hmi = float(p_fa), float(p_hmi)
        self._tables = np.zeros((3, 0))

    def tables(self, k_max: int) -> FloatArray:
        """(3, ≥ k_max + 1) rows ``T_k`` (0 at k = 0), ``K_N = K_E`` and ``K_D`` by k."""
        if self._tables.shape[1] <= k_max:
            k = np.arange(2 * k_max + 2, dtype=float)
            threshold = landmark_thresholds(self.p_fa, k.shape[0] - 1)
            threshold[0] = 0.0  # no landmark: no faulty hypothesis to bound
            k_h = -ndtri(self.p_hmi / (8.0 * (k + 1.0)))
            k_v = -ndtri(self.p_hmi / (4.0 * (k + 1.0)))
            self._tables = np.ascontiguousarray(np.stack([threshold, k_h, k_v]))
        return self._tables


@kernel
def levels_lanes(
    pose_cov: FloatArray,
    sep_n: FloatArray,
    sep_e: FloatArray,
    sep_d: FloatArray,
    hypotheses: FloatArray,
    tables: FloatArray,
    hpl: FloatArray,
    vpl: FloatArray,
) -> None:
    """``PL_q = √(T_k D_q) + K_q √(σ_q² + D_q)`` per axis, ``HPL = √(PL_N² + PL_E²)``,
    ``VPL = PL_D`` of each lane (module docstring; the separations ``sep_*`` (B,) per axis,
    ``tables`` of :meth:`LevelFactors.tables`); NaN stays NaN."""
    pl = np.empty(3)
    for b in range(hpl.shape[0]):
        k = int(hypotheses[b])
        for q in range(3):
            v = pose_cov[b, q, q]
            d = sep_n[b] if q == 0 else (sep_e[b] if q == 1 else sep_d[b])
            v = 0.0 if v < 0.0 else v  # round-off below zero; NaN is kept
            d = 0.0 if d < 0.0 else d
            scale = tables[2, k] if q == 2 else tables[1, k]
            pl[q] = math.sqrt(tables[0, k] * d) + scale * math.sqrt(v + d)
        hpl[b] = math.sqrt(pl[0] * pl[0] + pl[1] * pl[1])
        vpl[b] = pl[2]


def protection_levels(
    pose_cov: FloatArray, separation: FloatArray, hypotheses: FloatArray, factors: LevelFactors
) -> tuple[FloatArray, FloatArray]:
    """Horizontal and vertical protection levels of B lanes (module docstring).

    Args:
        pose_cov: (B, ≥3, ≥3) covariances whose leading 3×3 block is the position's (N, E, D)
            of the solution, m².
        separation: (3, B) the largest separation variances of the last scan per axis, m².
        hypotheses: (B,) the number k of landmarks they cover (0: none).
        factors: The budgets' factors.

    Returns:
        ``(hpl, vpl)`` (B,) in m (NaN where a variance is not finite).
    """
    k = np.asarray(hypotheses, dtype=float)
    tables = factors.tables(int(k.max(initial=0.0)))
    hpl, vpl = np.empty(k.shape[0]), np.empty(k.shape[0])
    sep = np.asarray(separation, dtype=float)
    levels_lanes(np.asarray(pose_cov, dtype=float), sep[0], sep[1], sep[2], k, tables, hpl, vpl)
    return hpl, vpl
