"""Data association of unlabeled LiDAR returns: χ² gating, nearest neighbour and JCBB.

Seed 004 §5 (and Neira & Tardós 2001, "Data association in stochastic mapping using the joint
compatibility test", IEEE T-RA 17(6)). The inputs are Gaussian predictions of M map landmarks'
measurements and R returns:

- ``nu[i, j]`` (3,) the innovation of return i under landmark j, ``z_i − h_j`` (angles wrapped);
- ``S`` (3M, 3M) the joint innovation covariance of the M predictions,
  ``S = H P Hᵀ + R`` with H stacked over the landmarks (its off-diagonal blocks are the
  correlations through the shared pose and map errors);
- ``d2[i, j] = nu[i, j]ᵀ S_jj⁻¹ nu[i, j]`` the individual squared Mahalanobis distance.

**Individual compatibility**: pair (i, j) is a candidate iff ``d2[i, j] ≤ χ²₃(p)``.

**Nearest neighbour** (:func:`nearest_neighbour`): candidate pairs are taken in increasing
``d2``, each return and each landmark at most once (a global greedy assignment, so two returns
never update one landmark).

**Joint compatibility branch and bound** (:func:`jcbb`): the hypothesis ``ℋ`` (each return
paired with a distinct candidate landmark or with none) with the most pairings whose joint NIS
``ν_ℋᵀ S_ℋ⁻¹ ν_ℋ ≤ χ²_{3|ℋ|}(p)``; among equally large ones, the smallest joint NIS. The search
visits returns in order, extends the Cholesky factor of ``S_ℋ`` by one 3-row block per pairing
(so a branch costs O(|ℋ|²) instead of a new factorisation) and prunes a branch that cannot reach
the best pairing count found so far.

Each function handles one lane (numba ``@njit``); the callers loop over lanes or particles.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.special import gammaincinv

from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.types import FloatArray

UNASSOCIATED = -1
"""Association of a return paired with no landmark."""


def chi2_threshold(dof: int, prob: float) -> float:
    """The ``prob`` quantile of χ² with ``dof`` degrees of freedom (inf when prob ≥ 1)."""
    if prob >= 1.0:
        return math.inf
    return float(2.0 * gammaincinv(0.5 * dof, prob))


def joint_thresholds(max_pairs: int, prob: float) -> FloatArray:
    """(max_pairs + 1,) joint-compatibility thresholds: entry k is ``χ²_{3k}(prob)`` (k ≥ 1)."""
    out = np.zeros(max_pairs + 1)
    for k in range(1, max_pairs + 1):
        out[k] = chi2_threshold(3 * k, prob)
    return out


@kernel
def solve3_nis(S: FloatArray, o: int, nu: FloatArray) -> float:
    """``νᵀ S_oo⁻¹ ν`` for the 3×3 block of ``S`` at offset ``o`` and ν (3,) (Cholesky);
    inf when the block is not positive definite."""
    a = S[o, o]
    if not a > 0.0:
        return math.inf
    l00 = math.sqrt(a)
    l10 = S[o + 1, o] / l00
    l20 = S[o + 2, o] / l00
    b = S[o + 1, o + 1] - l10 * l10
    if not b > 0.0:
        return math.inf
    l11 = math.sqrt(b)
    l21 = (S[o + 2, o + 1] - l20 * l10) / l11
    c = S[o + 2, o + 2] - l20 * l20 - l21 * l21
    if not c > 0.0:
        return math.inf
    l22 = math.sqrt(c)
    z0 = nu[0] / l00
    z1 = (nu[1] - l10 * z0) / l11
    z2 = (nu[2] - l20 * z0 - l21 * z1) / l22
    return z0 * z0 + z1 * z1 + z2 * z2


@kernel
def individual_nis(nu: FloatArray, S: FloatArray, d2: FloatArray) -> None:
    """Fill ``d2`` (R, M) with ``nu[i, j]ᵀ S_jj⁻¹ nu[i, j]`` for ``nu`` (R, M, 3), S (3M, 3M)."""
    for i in range(nu.shape[0]):
        for j in range(nu.shape[1]):
            d2[i, j] = solve3_nis(S, 3 * j, nu[i, j])


@kernel
def nearest_neighbour(d2: FloatArray, gate: float, out: np.ndarray) -> None:
    """Global greedy nearest neighbour: ``out`` (R,) the landmark of each return or -1.

    Repeatedly pairs the free return and free landmark with the smallest ``d2`` ≤ ``gate``.
    """
    r, m = d2.shape
    out[:] = UNASSOCIATED
    taken = np.zeros(m, dtype=np.bool_)
    for _ in range(min(r, m)):
        best, bi, bj = gate, -1, -1
        for i in range(r):
            if out[i] >= 0:
                continue
            for j in range(m):
                if not taken[j] and d2[i, j] <= best:
                    best, bi, bj = d2[i, j], i, j
        if bi < 0:
            return
        out[bi] = bj
        taken[bj] = True


@kernel
def _extend(
    S: FloatArray,
    L: FloatArray,
    z: FloatArray,
    lms: np.ndarray,
    k: int,
    j: int,
    nu: FloatArray,
) -> float:
    """Append landmark j (innovation ``nu`` (3,)) as pairing k to the factor of ``S_ℋ``.

    ``L[:3k, :3k]`` is the Cholesky factor of the joint innovation covariance of the k
    landmarks ``lms[:k]`` and ``z[:3k] = L⁻¹ ν_ℋ``; rows ``3k … 3k+2`` of ``L`` and ``z`` are
    written. Returns the NIS increment ``‖z[3k:3k+3]‖²`` (inf if ``S_ℋ`` would not be positive
    definite).
    """
    o = 3 * k
    oj = 3 * j
    for r in range(3):  # L21 = B L11⁻ᵀ, B the (3, 3k) block S[j, ℋ]
        row = o + r
        for c in range(o):
            acc = S[oj + r, 3 * lms[c // 3] + c % 3]
            for t in range(c):
                acc -= L[row, t] * L[c, t]
            L[row, c] = acc / L[c, c]
    for r in range(3):  # L22 = chol(S_jj − L21 L21ᵀ)
        row = o + r
        for c in range(r + 1):
            acc = S[oj + r, oj + c]
            for t in range(o + c):
                acc -= L[row, t] * L[o + c, t]
            if c == r:
                if not acc > 0.0:
                    return math.inf
                L[row, row] = math.sqrt(acc)
            else:
                L[row, o + c] = acc / L[o + c, o + c]
    inc = 0.0
    for r in range(3):  # z2 = L22⁻¹ (ν − L21 z1)
        row = o + r
        acc = nu[r]
        for t in range(row):
            acc -= L[row, t] * z[t]
        z[row] = acc / L[row, row]
        inc += z[row] * z[row]
    return inc


@inline_kernel
def _candidates(d2: FloatArray, gate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The individually compatible landmarks of each return, for :func:`jcbb`'s search.

    Args:
        d2: (R, M) individual NIS.
        gate: Individual-compatibility threshold ``χ²₃(p)``.

    Returns:
        ``cand`` (R, M) int: return i's candidates, nearest first (the order in which its
        branches are tried), in its first ``n_cand[i]`` entries; ``n_cand`` (R,) int;
        ``ahead`` (R + 1,) int: the most pairings still possible after return i (the returns
        > i that have a candidate).
    """
    r_count, m = d2.shape
    cand = np.full((r_count, m), -1, dtype=np.int64)
    n_cand = np.zeros(r_count, dtype=np.int64)
    for i in range(r_count):
        order = np.argsort(d2[i])
        for j in order:
            if d2[i, j] <= gate:
                cand[i, n_cand[i]] = j
                n_cand[i] += 1
    ahead = np.zeros(r_count + 1, dtype=np.int64)
    for i in range(r_count - 1, -1, -1):
        ahead[i] = ahead[i + 1] + (1 if n_cand[i] > 0 else 0)
    return cand, n_cand, ahead


@kernel
def jcbb(
    nu: FloatArray,
    S: FloatArray,
    d2: FloatArray,
    gate: float,
    thresholds: FloatArray,
    out: np.ndarray,
) -> float:
    """Joint compatibility branch and bound (Neira & Tardós 2001) for one scan.

    Args:
        nu: (R, M, 3) innovations of each (return, landmark) pair.
        S: (3M, 3M) joint innovation covariance of the M landmarks' predictions.
        d2: (R, M) individual NIS (:func:`individual_nis`).
        gate: Individual-compatibility threshold ``χ²₃(p)``.
        thresholds: (≥ R + 1,) joint thresholds, entry k = ``χ²_{3k}(p)``.
        out: (R,) int, written: the landmark of each return or -1.

    Returns:
        The joint NIS of the chosen hypothesis (0 when it pairs nothing).
    """
    r_count, m = d2.shape
    out[:] = UNASSOCIATED
    cand, n_cand, ahead = _candidates(d2, gate)
    if ahead[0] == 0:
        return 0.0
    L = np.zeros((3 * r_count, 3 * r_count))
    z = np.zeros(3 * r_count)
    lms = np.zeros(r_count, dtype=np.int64)
    used = np.zeros(m, dtype=np.bool_)
    current = np.full(r_count, -1, dtype=np.int64)
    option = np.full(r_count, -1, dtype=np.int64)  # branch tried at each level (n_cand: null)
    k_at = np.zeros(r_count + 1, dtype=np.int64)  # pairings before level i
    nis_at = np.zeros(r_count + 1)
    best_k, best_nis = -1, math.inf
    i = 0
    while i >= 0:
        if current[i] >= 0:  # leave the branch taken at this level
            used[current[i]] = False
            current[i] = -1
        option[i] += 1
        if option[i] > n_cand[i]:  # every branch of level i done: back up
            option[i] = -1
            i -= 1
            continue
        k = k_at[i]
        if option[i] < n_cand[i]:
            j = cand[i, option[i]]
            if used[j] or k + 1 + ahead[i + 1] < best_k:
                continue
            nis = nis_at[i] + _extend(S, L, z, lms, k, j, nu[i, j])
            if not nis <= thresholds[k + 1]:
                continue
            current[i] = j
            used[j] = True
            lms[k] = j
            k_next, nis_next = k + 1, nis
        else:  # return i unpaired
            if k + ahead[i + 1] < best_k:
                continue
            k_next, nis_next = k, nis_at[i]
        if i + 1 == r_count:  # a complete hypothesis
            if k_next > best_k or (k_next == best_k and nis_next < best_nis):
                best_k, best_nis = k_next, nis_next
                out[:] = current
            continue
        i += 1
        k_at[i] = k_next
        nis_at[i] = nis_next
    return best_nis if best_k > 0 else 0.0
