"""Tentative landmarks: the M-of-N rule that keeps clutter out of a map (unknown association).

A LiDAR return that gates with no map landmark may be a new landmark or a false return. It
starts a *candidate* (its position and 3×3 covariance in N, from the inverse LiDAR model at the
current estimate) instead of entering the map. In each later scan, every return that again
gates with no map landmark is compared with the candidates by its squared Mahalanobis distance
``Δᵀ (P_c + P_y)⁻¹ Δ`` against the χ²₃ gate (the nearest compatible candidate not yet matched
in this scan); a match counts a hit and replaces the candidate's position and covariance by the
new observation's (re-observations share the pose error, so fusing them would understate the
covariance). A candidate with ``confirm_hits`` (M) hits within its first ``confirm_window``
(N) scans is *confirmed* — the return that completes it enters the map — and is dropped when
its N scans pass without. M = N = 1 puts every new return in the map at once (the papers'
known-association behaviour). A false return uniform over the FOV volume almost never
reappears within a gate, so it is dropped.

One "map" (a lane of EKF-SLAM, or a particle of FastSLAM) holds T candidate slots:

    pos (T, 3) m, cov (T, 3, 3) m², hits (T,) int, age (T,) int (scans since creation; -1: free)

:class:`Candidates` holds them for B maps; the numba functions handle one map per call.
"""

from __future__ import annotations

import numpy as np

from estimators.association import solve3_nis
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

FREE = -1
"""``age`` of an unused candidate slot."""


@kernel
def m_of_n(hits: int, age: int, confirm_hits: int, confirm_window: int) -> int:
    """The M-of-N rule at the end of a scan for a tentative landmark with ``hits`` hits, now
    in its scan number ``age`` (0: the scan that created it).

    Returns:
        1 to confirm (M = ``confirm_hits`` reached), -1 to drop (its N = ``confirm_window``
        scans are over without), 0 to keep waiting.
    """
    if hits >= confirm_hits:
        return 1
    if age + 1 >= confirm_window:
        return -1
    return 0


@kernel
def observe_candidate_slot(
    pos: FloatArray,
    cov: FloatArray,
    hits: np.ndarray,
    age: np.ndarray,
    matched: np.ndarray,
    p: FloatArray,
    P: FloatArray,
    gate: float,
    confirm_hits: int,
) -> int:
    """Feed one unassociated return, seen at ``p`` (3,) with covariance ``P`` (3, 3), to the
    candidates of one map.

    It matches the nearest compatible candidate not yet ``matched`` (T,) in this scan (which
    then counts a hit and takes ``p``, ``P``), or starts a new candidate in a free slot (none
    free: the return is dropped).

    Returns:
        The slot the return went to (-1: dropped). The return confirms that candidate iff
        ``hits[slot] >= confirm_hits`` (its hits reach ``confirm_hits``): the caller maps the
        return as a new landmark; the slot is freed.
    """
    best, slot = gate, -1
    d = np.empty(3)
    A = np.empty((3, 3))
    for c in range(age.shape[0]):
        if age[c] == FREE or matched[c]:
            continue
        for r in range(3):
            d[r] = p[r] - pos[c, r]
            for t in range(3):
                A[r, t] = cov[c, r, t] + P[r, t]
        d2 = solve3_nis(A, 0, d)
        if d2 <= best:
            best, slot = d2, c
    if slot < 0:  # a new candidate
        for c in range(age.shape[0]):
            if age[c] == FREE:
                slot = c
                break
        if slot < 0:
            return -1
        age[slot] = 0
        hits[slot] = 0
    hits[slot] += 1
    matched[slot] = True
    pos[slot] = p
    cov[slot] = P
    if hits[slot] >= confirm_hits:
        age[slot] = FREE
    return slot


@kernel
def observe_candidate(
    pos: FloatArray,
    cov: FloatArray,
    hits: np.ndarray,
    age: np.ndarray,
    matched: np.ndarray,
    p: FloatArray,
    P: FloatArray,
    gate: float,
    confirm_hits: int,
) -> bool:
    """:func:`observe_candidate_slot`, returning True when the return confirms a candidate
    (the caller maps the return as a new landmark; the slot is freed)."""
    slot = observe_candidate_slot(pos, cov, hits, age, matched, p, P, gate, confirm_hits)
    return slot >= 0 and hits[slot] >= confirm_hits


@kernel
def age_candidates(age: np.ndarray, matched: np.ndarray, confirm_window: int) -> None:
    """End of a scan: drop candidates whose ``confirm_window`` scans have passed, age the
    others by one scan and clear ``matched``."""
    for c in range(age.shape[0]):
        matched[c] = False
        if age[c] == FREE:
            continue
        if age[c] + 1 >= confirm_window:
            age[c] = FREE
        else:
            age[c] += 1


class Candidates:
    """Tentative-landmark slots of B maps (lanes or particles), as (B, T, …) arrays.

    Attributes:
        pos: (B, T, 3) positions in N, m.
        cov: (B, T, 3, 3) covariances in m².
        hits: (B, T) int hits so far.
        age: (B, T) int scans since creation (:data:`FREE` for an unused slot).
        matched: (B, T) bool, matched in the scan being processed (scratch).

    Args:
        num_maps: B.
        slots: T, candidates per map; a return that finds all T in use is dropped.
    """

    def __init__(self, num_maps: int, slots: int) -> None:
        self.pos = np.zeros((num_maps, slots, 3))
        self.cov = np.zeros((num_maps, slots, 3, 3))
        self.hits = np.zeros((num_maps, slots), dtype=np.int64)
        self.age = np.full((num_maps, slots), FREE, dtype=np.int64)
        self.matched = np.zeros((num_maps, slots), dtype=np.bool_)

    def clear(self, maps: np.ndarray) -> None:
        """Drop every candidate of ``maps`` (k,) int."""
        self.age[maps] = FREE
        self.hits[maps] = 0
        self.matched[maps] = False

    def at_least(self, slots: int) -> Candidates:
        """These candidates, or a copy with room for ``slots`` per map (the new ones free)."""
        have = self.age.shape[1]
        if have >= slots:
            return self
        wider = Candidates(self.age.shape[0], slots)
        for name in ("pos", "cov", "hits", "age", "matched"):
            getattr(wider, name)[:, :have] = getattr(self, name)
        return wider

    def take(self, maps: np.ndarray) -> None:
        """Keep the candidates of ``maps`` (B,) int, map b taking those of ``maps[b]`` (copies;
        FastSLAM's resampling)."""
        self.pos = self.pos[maps]
        self.cov = self.cov[maps]
        self.hits = self.hits[maps]
        self.age = self.age[maps]
        self.matched = self.matched[maps]

    def active(self) -> np.ndarray:
        """(B,) int candidates in use per map."""
        return (self.age != FREE).sum(axis=1)
