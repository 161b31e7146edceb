"""Per-particle maximum-likelihood data association of FastSLAM (``lidar.association: unknown``).

Montemerlo & Thrun, "Simultaneous localization and mapping with unknown data association
using FastSLAM" (ICRA 2003), with seed 004 §5 (χ² gate on the Mahalanobis distance, the
nearest-neighbour rule, the maximum-likelihood criterion; eq. 34, the factorisation that gives
every particle its own map): each particle carries its own association hypothesis. For
particle i and a scan of unlabeled returns ``z_1 … z_R``:

1. each of the particle's landmarks j is predicted with its own EKF, ``h_j``, ``S_j = H Σ_j Hᵀ
   + R`` (:func:`~estimators.fastslam.landmarks.landmark_prediction`, the update's model).
   With the filter's likelihood inflation λ (``likelihood_inflation``, 1 = none) the
   association works with the innovation covariance ``λ S_j`` throughout, as the weights
   do for labeled scans: every return gets ``q_rj = ν_rjᵀ (λS_j)⁻¹ ν_rj`` and
   ``p_rj = N(ν_rj; 0, λ S_j)`` (:func:`~estimators.fastslam.landmarks.innovation_loglik`);
2. pair (r, j) is *compatible* when it passes the individual gate ``q_rj ≤ χ²₃(p)`` and is at
   least as likely as a new landmark, ``p_rj ≥ p0``; the compatible pairs are assigned
   greedily by likelihood, each return and each landmark at most once
   (:func:`~estimators.association.nearest_neighbour` on ``−log p_rj``): the maximum-likelihood
   association with FastSLAM's new-landmark rule (``max_j p_rj < p0`` → new landmark);
3. a paired return updates its landmark's EKF (with S, not λS); the particle's weight is
   multiplied by the chosen pairs' ``p_rj`` and by ``p0`` for every unpaired return, so the
   particles' association hypotheses compete through resampling (a factor common to all
   particles, such as ``p0`` for a return no particle pairs, cancels in the normalisation);
4. a return with no compatible landmark feeds the particle's tentative landmarks (the M-of-N
   rule of :mod:`estimators.tentative`, at the χ²₃(p) gate on the two sightings' positions
   with their inverse-model covariances) and, when it confirms one, enters the particle's map
   in its next free slot with the initialisation of a first sighting
   (:func:`~estimators.fastslam.landmarks.landmark_init`); a return whose compatible
   landmarks were all taken by other returns (ambiguous) is dropped, as is every unpaired
   return in known-map mode.

A particle's map is the slots ``0 … n_i − 1`` of the (N, Lcap) landmark arrays; a slot index
is the particle's label of that landmark.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from estimators.association import nearest_neighbour
from estimators.fastslam.landmarks import (
    Mat3,
    innovation_loglik,
    landmark_ekf_one,
    landmark_init,
    landmark_prediction,
    particle_dcm,
    rows_of,
)
from estimators.fastslam.settings import AssociationSettings, scan_noise
from estimators.tentative import Candidates, age_candidates, observe_candidate
from quadslam_env.estimation.measurements import LidarScan
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.models.jit import kernel
from quadslam_env.models.lidar import body_from_measure
from quadslam_env.types import EUL, MEAS_DIM, POS, FloatArray


@kernel
def _scaled(S_inv: Mat3, det: float, inflation: float) -> tuple[Mat3, float]:
    """``(λS)⁻¹`` and ``log det(λS)`` from ``S⁻¹`` (rows) and ``det S`` (λ = ``inflation``)."""
    k = 1.0 / inflation
    rows = (
        (S_inv[0][0] * k, S_inv[0][1] * k, S_inv[0][2] * k),
        (S_inv[1][0] * k, S_inv[1][1] * k, S_inv[1][2] * k),
        (S_inv[2][0] * k, S_inv[2][1] * k, S_inv[2][2] * k),
    )
    return rows, math.log(det) + 3.0 * math.log(inflation)


_MARGIN = 1.01
"""Safety factor on the screening bounds of :func:`_screen` (they must never reject a pair
that passes the gate, whatever the rounding)."""


@kernel
def _screen(
    mu: FloatArray,
    sigma: FloatArray,
    pos: FloatArray,
    C: Mat3,
    returns: FloatArray,
    dirs: FloatArray,
    R: FloatArray,
    gate: float,
    near: np.ndarray,
) -> bool:
    """Cheap necessary condition for ``νᵀ S⁻¹ ν ≤ gate`` of one landmark with each return.

    For a positive definite S, ``νᵀ S⁻¹ ν ≥ ν_k² / S_kk`` for every channel k, and
    ``S_kk ≤ ‖∂h_k/∂c‖² tr Σ + R_kk`` with ``‖∂α/∂c‖ = 1/‖c_12‖``, ``‖∂β/∂c‖ = 1/‖c‖`` and
    ``‖∂δ/∂c‖ = 1`` (seed 001 eq. 40). A pair can pass the gate only if its range difference
    obeys ``ν_δ² ≤ gate S_δδ`` and, since the angle θ between the two directions is at most
    ``|ν_α| + |ν_β|`` (a meridian then a parallel arc), ``θ² ≤ 2 gate (S_αα + S_ββ)``, so
    ``cos θ ≥ 1 − θ²/2`` (gate × :data:`_MARGIN`²). This costs a rotation, a square root and
    a dot product per return instead of the prediction's Jacobian and inverse, so landmarks
    far from every return are skipped, exactly: no pair that passes the gate is rejected.

    Args:
        mu: (3,) landmark mean in N, m. sigma: (3, 3) its covariance in m².
        pos: (3,) vehicle position in N, m. C: Rows of ``C_NB``.
        returns: (R, 3) returns (α rad, β rad, δ m). dirs: (R, 3) their unit directions in B.
        R: (3, 3) diagonal measurement noise (λR when the association inflates S by λ).
        gate: The gate on ``νᵀ S⁻¹ ν`` (with S inflated by the same λ, pass ``λ·gate``).
        near: (R,) bool, written: the return may pass the gate.

    Returns:
        Whether any return may pass the gate.
    """
    d0, d1, d2 = mu[0] - pos[0], mu[1] - pos[1], mu[2] - pos[2]
    c0 = C[0][0] * d0 + C[1][0] * d1 + C[2][0] * d2  # c = C_NBᵀ (μ − ρ)
    c1 = C[0][1] * d0 + C[1][1] * d1 + C[2][1] * d2
    c2 = C[0][2] * d0 + C[1][2] * d1 + C[2][2] * d2
    horiz2 = c0 * c0 + c1 * c1
    dist2 = horiz2 + c2 * c2
    dist = math.sqrt(dist2)
    tr = sigma[0, 0] + sigma[1, 1] + sigma[2, 2]
    g = gate * _MARGIN * _MARGIN
    # θ² ≤ (|ν_α| + |ν_β|)² ≤ 2 (ν_α² + ν_β²) ≤ 2 g (S_αα + S_ββ), and cos θ ≥ 1 − θ²/2.
    theta2 = 2.0 * g * (tr / max(horiz2, 1e-12) + R[0, 0] + tr / max(dist2, 1e-12) + R[1, 1])
    cos_min = (1.0 - 0.5 * theta2) * dist
    range2 = g * (tr + R[2, 2]) + 1e-12
    found = False
    for a in range(returns.shape[0]):
        dr = returns[a, 2] - dist
        near[a] = (
            dr * dr <= range2
            and dirs[a, 0] * c0 + dirs[a, 1] * c1 + dirs[a, 2] * c2 >= cos_min  # cos θ ‖c‖
        )
        found = found or near[a]
    return found


@kernel
def associate_particles(
    x: FloatArray,
    mu: FloatArray,
    sigma: FloatArray,
    n_lm: np.ndarray,
    returns: FloatArray,
    dirs: FloatArray,
    R: FloatArray,
    gate: float,
    log_p0: float,
    inflation: float,
    assoc: np.ndarray,
    unexplained: np.ndarray,
    loglik: FloatArray,
    nis: FloatArray,
    n_paired: np.ndarray,
) -> None:
    """Steps 1–3 in every particle: gate, pair by likelihood, update the paired EKFs, weigh.

    Args:
        x: (N, 12) particle states (ρ m and Λ rad are used).
        mu: (N, Lcap, 3) landmark means in N, m; ``sigma`` (N, Lcap, 3, 3) in m². Particle i's
            landmarks are slots ``0 … n_lm[i] − 1``; the paired ones are updated in place.
        n_lm: (N,) int landmarks per particle.
        returns: (R, 3) unlabeled returns (α rad, β rad, δ m).
        dirs: (R, 3) their unit directions in B, ``ϱ(α, β, 1)``.
        R: (3, 3) diagonal measurement noise.
        gate: Individual gate χ²₃(p).
        log_p0: log of the new-landmark likelihood p0.
        inflation: λ ≥ 1: the association's innovation covariance is λS (gate, likelihoods,
            weights); the EKF updates use S.
        assoc: (N, ≥ R) int, written (first R columns): each return's slot, -1 for none.
        unexplained: (N, ≥ R) bool, written: the return had no compatible landmark.
        loglik: (N,) receives ``Σ_paired log N(ν; 0, λS) + (R − paired) log p0``.
        nis: (N,) receives ``Σ_paired νᵀ S⁻¹ ν`` (not inflated).
        n_paired: (N,) int receives the number of paired returns.
    """
    n_particles, r = x.shape[0], returns.shape[0]
    noise = rows_of(R)
    cost = np.full((r, mu.shape[1]), np.inf)
    paired = np.empty(r, dtype=np.int64)
    near = np.empty(r, dtype=np.bool_)
    for i in range(n_particles):
        pos = x[i, POS]
        C = particle_dcm(x[i])
        m = n_lm[i]
        unexplained[i, :r] = True
        for j in range(m):
            cost[:, j] = np.inf
            if not _screen(mu[i, j], sigma[i, j], pos, C, returns, dirs, R, inflation * gate, near):
                continue
            h, _, S_inv, det = landmark_prediction(mu[i, j], sigma[i, j], pos, C, noise)
            T_inv, log_det = _scaled(S_inv, det, inflation)
            for a in range(r):
                if not near[a]:
                    continue
                _, q, ll = innovation_loglik(returns[a], h, T_inv, log_det)
                if q <= gate and ll >= log_p0:  # NaN fails both
                    cost[a, j] = -ll
                    unexplained[i, a] = False
        nearest_neighbour(cost[:, :m], -log_p0, paired)
        ll_sum, nis_sum, count = 0.0, 0.0, 0
        for a in range(r):
            j = paired[a]
            assoc[i, a] = j
            if j < 0:
                ll_sum += log_p0
                continue
            ll, q = landmark_ekf_one(mu[i, j], sigma[i, j], pos, C, returns[a], noise)
            ll_sum += -cost[a, j] if math.isfinite(ll) else ll  # a broken update: -inf/NaN
            nis_sum += q
            count += 1
        loglik[i], nis[i], n_paired[i] = ll_sum, nis_sum, count


@kernel
def add_tentative(
    mu: FloatArray,
    sigma: FloatArray,
    n_lm: np.ndarray,
    cols: np.ndarray,
    new_mu: FloatArray,
    new_sigma: FloatArray,
    unexplained: np.ndarray,
    gate: float,
    cand_pos: FloatArray,
    cand_cov: FloatArray,
    cand_hits: np.ndarray,
    cand_age: np.ndarray,
    cand_matched: np.ndarray,
    confirm_hits: int,
    confirm_window: int,
    assoc: np.ndarray,
) -> None:
    """Step 4 in every particle: unexplained returns feed the tentative landmarks (M-of-N);
    a confirmed one is mapped in the particle's next slot. Then the candidates age a scan.

    Args:
        mu, sigma, n_lm: The landmark arrays and map sizes (see :func:`associate_particles`);
            the caller guarantees ``n_lm[i] + len(cols) ≤ Lcap``.
        cols: (c,) int the returns unexplained in some particle.
        new_mu: (N, c, 3) and new_sigma: (N, c, 3, 3) their landmark position in m and
            covariance in m² from each particle's pose (``landmark_init``).
        unexplained: (N, ≥ R) bool from :func:`associate_particles`.
        gate: χ²₃(p), the candidates' gate.
        cand_pos, cand_cov, cand_hits, cand_age, cand_matched: (N, T, …) tentative landmarks
            per particle (:class:`~estimators.tentative.Candidates`), updated in place.
        confirm_hits, confirm_window: The M-of-N rule.
        assoc: (N, ≥ R) int: a confirming return gets its new slot.
    """
    for i in range(n_lm.shape[0]):
        for c in range(cols.shape[0]):
            a = cols[c]
            if not unexplained[i, a]:
                continue
            if observe_candidate(
                cand_pos[i], cand_cov[i], cand_hits[i], cand_age[i], cand_matched[i],
                new_mu[i, c], new_sigma[i, c], gate, confirm_hits,
            ):  # fmt: skip
                s = n_lm[i]
                mu[i, s] = new_mu[i, c]
                sigma[i, s] = new_sigma[i, c]
                n_lm[i] = s + 1
                assoc[i, a] = s
        age_candidates(cand_age[i], cand_matched[i], confirm_window)


CANDIDATE_SLOTS = 32
"""Initial tentative landmarks per particle, at least twice the largest scan seen (a return
that finds all in use is dropped; clutter 2 per scan over 5 scans keeps about 10 in use)."""

_INITIAL_CAPACITY = 16
"""Landmark slots per particle allocated at the first unlabeled scan (doubled as needed)."""


class ScanAssociation(NamedTuple):
    """What one unlabeled scan gave every particle (:meth:`ParticleMaps.associate`).

    Attributes:
        mu: (N, Lcap, 3) landmark means in N, m after the scan (the input or a grown copy).
        sigma: (N, Lcap, 3, 3) their covariances in m².
        loglik: (N,) each particle's log-likelihood of its association,
            ``Σ_paired log N(ν; 0, λS) + (R − paired) log p0``.
        nis: (N,) each particle's NIS ``Σ_paired νᵀ S⁻¹ ν`` (not inflated).
        dof: (N,) int degrees of freedom of that NIS, 3 × paired returns.
    """

    mu: FloatArray
    sigma: FloatArray
    loglik: FloatArray
    nis: FloatArray
    dof: np.ndarray


class ParticleMaps:
    """Bookkeeping of the per-particle maps under unknown association.

    The landmark EKFs themselves stay in the filter's (N, Lcap, …) arrays; this object holds
    each particle's map size, its tentative landmarks and the particle whose map is reported.

    Attributes:
        known: Known-map mode (every particle holds the whole known map, nothing is added).
        size: (N,) int landmarks per particle (slots ``0 … size[i] − 1``).
        candidates: Tentative landmarks, T ≥ max(:data:`CANDIDATE_SLOTS`, 2 × the largest
            scan) per particle (none in known-map mode).
        report: The particle whose map and association are reported: the highest-weight
            particle after the last scan's weighting, followed through resampling.
        assoc: (N, R) int slot of each return of the last scan per particle (-1: none).
        n_paired: (N,) int paired returns per particle in the last scan.

    Args:
        n_particles: N.
        known_ids: Known-map mode: (L,) int the landmark id of each slot; else ``None``.
    """

    def __init__(self, n_particles: int, known_ids: np.ndarray | None) -> None:
        self.known = known_ids is not None
        self._known_ids = np.zeros(0, dtype=np.int64) if known_ids is None else known_ids
        self.size = np.full(n_particles, self._known_ids.size, dtype=np.int64)
        self.candidates = Candidates(n_particles, 0)
        self.report = 0
        self.assoc = np.zeros((n_particles, 0), dtype=np.int64)
        self._unexplained = np.zeros((n_particles, 0), dtype=np.bool_)
        self.n_paired = np.zeros(n_particles, dtype=np.int64)

    def fit(self, mu: FloatArray, sigma: FloatArray, returns: int) -> tuple[FloatArray, FloatArray]:
        """Landmark arrays with room for ``returns`` new landmarks in every particle.

        Args:
            mu: (N, Lcap, 3) means. sigma: (N, Lcap, 3, 3) covariances.
            returns: Returns in the coming scan (each may confirm one landmark).

        Returns:
            ``(mu, sigma)``: the same arrays, or copies with at least double the capacity.
        """
        need = int(self.size.max()) + returns
        cap = mu.shape[1]
        if need <= cap:
            return mu, sigma
        cap = max(need, 2 * cap, _INITIAL_CAPACITY)
        n = mu.shape[0]
        grown_mu, grown_sigma = np.zeros((n, cap, 3)), np.zeros((n, cap, 3, 3))
        grown_mu[:, : mu.shape[1]] = mu
        grown_sigma[:, : mu.shape[1]] = sigma
        return grown_mu, grown_sigma

    def associate(
        self,
        x: FloatArray,
        mu: FloatArray,
        sigma: FloatArray,
        meas: FloatArray,
        R: FloatArray,
        cfg: AssociationSettings,
        inflation: float,
    ) -> ScanAssociation:
        """One scan: :func:`associate_particles`, then :func:`add_tentative` (SLAM only).

        Fills :attr:`assoc` and :attr:`n_paired`; the inverse model (``landmark_init``) is
        evaluated only for the returns that some particle could not explain.

        Args:
            x: (N, 12) particle states. mu: (N, Lcap, 3), sigma: (N, Lcap, 3, 3) landmark
                EKFs, updated in place (or grown, see :meth:`fit`).
            meas: (R, 3) unlabeled returns (α rad, β rad, δ m). R: (3, 3) measurement noise.
            cfg: Association settings. inflation: λ ≥ 1 (``likelihood_inflation``).

        Returns:
            The landmark arrays after the scan and each particle's likelihood and NIS.
        """
        k, n = meas.shape[0], self.size.shape[0]
        if self.assoc.shape[1] < k:
            self.assoc = np.full((n, k), -1, dtype=np.int64)
            self._unexplained = np.zeros((n, k), dtype=np.bool_)
        if not self.known:
            mu, sigma = self.fit(mu, sigma, k)
        dirs = body_from_measure(np.column_stack([meas[:, 0:2], np.ones(k)]))
        loglik, nis = np.empty(n), np.empty(n)
        associate_particles(
            x, mu, sigma, self.size, meas, dirs, R, cfg.gate, math.log(cfg.new_landmark_likelihood),
            inflation, self.assoc, self._unexplained, loglik, nis, self.n_paired,
        )  # fmt: skip
        result = ScanAssociation(mu, sigma, loglik, nis, MEAS_DIM * self.n_paired)
        if self.known:
            return result  # unpaired returns are dropped
        cols = np.flatnonzero(self._unexplained[:, :k].any(axis=0))
        new_mu, new_sigma = landmark_init(x[:, POS], dcm_from_euler_batch(x[:, EUL]), meas[cols], R)
        cand = self.candidates.at_least(max(CANDIDATE_SLOTS, 2 * k))
        self.candidates = cand
        add_tentative(
            mu, sigma, self.size, cols, new_mu, new_sigma, self._unexplained, cfg.gate,
            cand.pos, cand.cov, cand.hits, cand.age, cand.matched, cfg.confirm_hits,
            cfg.confirm_window, self.assoc,
        )  # fmt: skip
        return result

    def labels(self, particle: int, returns: int) -> np.ndarray:
        """(returns,) int the last scan's association in ``particle`` as labels: its slots,
        or in known-map mode the known ids (-1: none)."""
        slots = self.assoc[particle, :returns].copy()
        if not self.known:
            return slots
        return np.where(slots >= 0, self._known_ids[np.maximum(slots, 0)], -1)

    def resample(self, idx: np.ndarray, weights: FloatArray) -> None:
        """Particle i becomes a copy of particle ``idx[i]``.

        The reported particle moves to the first copy of itself; if it was not drawn, to the
        first copy of the highest-weight particle of ``weights`` (N,) (systematic resampling
        always draws that one), else to particle 0.
        """
        self.size = self.size[idx]
        self.candidates.take(idx)
        self.assoc = self.assoc[idx]
        self._unexplained = self._unexplained[idx]
        self.n_paired = self.n_paired[idx]
        for wanted in (self.report, int(np.argmax(weights))):
            copies = np.flatnonzero(idx == wanted)
            if copies.size:
                self.report = int(copies[0])
                return
        self.report = 0


def unlabeled_returns(scan: LidarScan) -> tuple[FloatArray, FloatArray]:
    """The returns of an unlabeled scan and their noise covariance.

    Returns:
        ``(meas, R)``: the returns (k, 3) (α rad, β rad, δ m) and R (3, 3) (:func:`scan_noise`).

    Raises:
        ValueError: Malformed returns.
    """
    meas = np.asarray(scan.meas, dtype=float)
    k = meas.shape[0] if meas.ndim == 2 else -1
    if meas.shape != (k, 3) or not np.all(np.isfinite(meas)):
        raise ValueError("update: scan.meas must be a finite (k, 3) array")
    return meas, scan_noise(scan.sigma)
