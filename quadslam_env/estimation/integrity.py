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
landmark test's threshold ``χ²_3(1 − p_fa/(2k))``::

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


@dataclass(frozen=True)
class MonitorSettings:
    """What a monitoring estimator is told (from the scenario's ``integrity`` section).

    Attributes:
        p_fa: False-alarm budget of one scan's tests, in (0, 1).
        exclude: Leave out the landmarks found faulty (False: detect only).
        max_exclusions: Most landmarks left out of one scan.
        readmit_s: A landmark left out is dropped from the map and may enter it again (from
            a new sighting) this many seconds later, s.
    """

    p_fa: float
    exclude: bool
    max_exclusions: int
    readmit_s: float

    def landmark_thresholds(self, capacity: int) -> FloatArray:
        """(capacity + 1,) the landmark test's threshold ``χ²_3(1 − p_fa/(2k))`` by k (inf at
        k = 0)."""
        k = np.arange(capacity + 1, dtype=float)
        out = np.full(capacity + 1, math.inf)
        out[1:] = chi2_isf(self.p_fa / (2.0 * k[1:]), 3.0)
        return out

    def scan_thresholds(self, capacity: int) -> FloatArray:
        """(3 capacity + 1,) the scan test's threshold ``χ²_m(1 − p_fa/2)`` by degrees of
        freedom m (inf at m = 0)."""
        dof = np.arange(3 * capacity + 1, dtype=float)
        out = np.full(3 * capacity + 1, math.inf)
        out[1:] = chi2_isf(self.p_fa / 2.0, dof[1:])
        return out


def protection_levels(
    pos_var: FloatArray, separation: FloatArray, hypotheses: FloatArray, p_fa: float, p_hmi: float
) -> tuple[FloatArray, FloatArray]:
    """Horizontal and vertical protection levels of B lanes (module docstring).

    Args:
        pos_var: (B, 3) position variances (N, E, D) of the solution, m².
        separation: (B, 3) the largest separation variances of the last scan per axis, m².
        hypotheses: (B,) the number k of landmarks they cover (0: none).
        p_fa: False-alarm budget of a scan's tests, in (0, 1).
        p_hmi: Integrity risk per step, in (0, 1).

    Returns:
        ``(hpl, vpl)`` (B,) in m (NaN where a variance is not finite).
    """
    k = np.asarray(hypotheses, dtype=float)
    kk = np.maximum(k, 1.0)
    threshold = np.where(k > 0, chi2_isf(p_fa / (2.0 * kk), 3.0), 0.0)
    k_h = -ndtri(p_hmi / (8.0 * (k + 1.0)))
    k_v = -ndtri(p_hmi / (4.0 * (k + 1.0)))
    sep = np.maximum(np.asarray(separation, dtype=float), 0.0)
    var = np.maximum(np.asarray(pos_var, dtype=float), 0.0)
    scale = np.stack([k_h, k_h, k_v], axis=-1)
    levels = np.sqrt(threshold[:, None] * sep) + scale * np.sqrt(var + sep)
    hpl = np.hypot(levels[:, 0], levels[:, 1])
    return hpl, levels[:, 2]
