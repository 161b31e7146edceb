"""Numba kernel of EKF-SLAM's data association front end (``lidar.association: unknown``).

For each scanning lane, :func:`associate_lanes` turns the unlabeled returns into the labeled
scan that :func:`estimators.ekf.update.update_lanes` corrects with (seed 004 §5):

1. every mapped (or known) landmark is predicted with the joint innovation covariance
   ``S = H P Hᵀ + R`` of :func:`~estimators.ekf.update.innovation_covariance` (the same
   model the update uses);
2. each (return, landmark) pair is gated on its individual 3-DOF NIS and the returns are
   associated by nearest neighbour or JCBB (:mod:`estimators.association`);
3. a return that gates with *no* landmark feeds the lane's tentative landmarks
   (:mod:`estimators.tentative`, the M-of-N rule); the return that confirms a candidate is
   labeled with the next free map slot, so ``update_lanes`` registers it (eq. 44–53);
4. a return that gates with some landmark but is left unpaired (an ambiguous return) is
   dropped, as is every unpaired return of a known-map lane.

The labels of an unknown-map lane are its map slots in order of confirmation (they are the
estimator's own names, unrelated to the simulator's landmark ids); a known-map lane labels
returns with the known map's ids.
"""

from __future__ import annotations

import numpy as np

from estimators.association import UNASSOCIATED, individual_nis, jcbb, nearest_neighbour
from estimators.ekf.kernels import sync_lane
from estimators.ekf.update import innovation, innovation_covariance, inverse_measurements
from estimators.tentative import age_candidates, observe_candidate
from quadslam_env.models.jit import kernel
from quadslam_env.types import POSE_DIM, FloatArray


@kernel
def associate_lanes(
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    stale: np.ndarray,
    slot_of_id: np.ndarray,
    mapped: np.ndarray,
    known: np.ndarray,
    known_pos: FloatArray,
    lanes: np.ndarray,
    count: np.ndarray,
    returns: FloatArray,
    r_diag: FloatArray,
    gate: float,
    thresholds: FloatArray,
    use_jcbb: bool,
    cand_pos: FloatArray,
    cand_cov: FloatArray,
    cand_hits: np.ndarray,
    cand_age: np.ndarray,
    cand_matched: np.ndarray,
    confirm_hits: int,
    confirm_window: int,
    visible: np.ndarray,
    meas: FloatArray,
    assoc: np.ndarray,
) -> None:
    """Associate each scanning lane's returns; write the labeled scan and the association.

    Args:
        x, P, n, nv, stale, slot_of_id, mapped, known, known_pos: The filter's buffers (see
            :func:`estimators.ekf.update.update_lanes`); stale lanes are synchronised here.
        lanes: (k,) int, the scanning lanes.
        count: (B,) int returns per lane.
        returns: (B, R, 3) returns (α rad, β rad, δ m); rows ``≥ count[b]`` unused.
        r_diag: (3,) measurement noise variances.
        gate: Individual-compatibility threshold χ²₃(p).
        thresholds: (≥ R + 1,) joint-compatibility thresholds χ²_{3k}(p) (JCBB).
        use_jcbb: JCBB when True, else nearest neighbour.
        cand_pos, cand_cov, cand_hits, cand_age, cand_matched: (B, T, …) tentative
            landmarks per lane (:mod:`estimators.tentative`).
        confirm_hits, confirm_window: The M-of-N rule.
        visible: (B, Lcap) bool, written for the scanning lanes: the labels returned.
        meas: (B, Lcap, 3), written: the return of each label.
        assoc: (B, R) int, written for the scanning lanes: each return's label or -1.
    """
    lmax = mapped.shape[1]
    lm1 = np.empty((1, 3))
    Plx = np.empty((3, POSE_DIM))
    Pll = np.empty((3, 3))
    for b in lanes:
        xb, Pb, nb = x[b], P[b], n[b]
        if stale[b]:
            sync_lane(Pb, nb, nv)
            stale[b] = False
        visible[b, :] = False
        assoc[b, :] = UNASSOCIATED
        r = count[b]
        ids = np.empty(lmax, dtype=np.int64)
        m = 0
        for j in range(lmax):
            if mapped[b, j]:
                ids[m] = j
                m += 1
        paired = np.full(r, UNASSOCIATED, dtype=np.int64)
        gated = np.zeros(r, dtype=np.bool_)
        if m and r:
            lms = np.empty((m, 3))
            cols = np.full(m, -1, dtype=np.int64)
            for a in range(m):
                if known[b]:
                    lms[a] = known_pos[b, ids[a]]
                else:
                    cols[a] = nv + 3 * slot_of_id[b, ids[a]]
                    lms[a] = xb[cols[a] : cols[a] + 3]
            h = np.empty((m, 3))
            U = np.empty((3 * m, nb))
            S = np.empty((3 * m, 3 * m))
            innovation_covariance(xb, Pb, nb, lms, cols, r_diag, h, U, S)
            nu = np.empty((r, m, 3))
            for i in range(r):
                for a in range(m):
                    innovation(returns[b, i], h[a], nu[i, a])
            d2 = np.empty((r, m))
            individual_nis(nu, S, d2)
            for i in range(r):
                for a in range(m):
                    gated[i] = gated[i] or d2[i, a] <= gate
            if use_jcbb:
                jcbb(nu, S, d2, gate, thresholds, paired)
            else:
                nearest_neighbour(d2, gate, paired)
        n_new = 0
        first_free = (nb - nv) // 3
        for i in range(r):
            if paired[i] >= 0:
                label = ids[paired[i]]
            elif gated[i] or known[b]:
                continue  # ambiguous, or not in a known map: dropped
            else:
                inverse_measurements(xb, Pb, POSE_DIM, returns[b, i : i + 1], r_diag, lm1, Plx, Pll)
                if not observe_candidate(
                    cand_pos[b], cand_cov[b], cand_hits[b], cand_age[b], cand_matched[b],
                    lm1[0], Pll, gate, confirm_hits,
                ):  # fmt: skip
                    continue
                label = first_free + n_new
                n_new += 1
            visible[b, label] = True
            meas[b, label] = returns[b, i]
            assoc[b, i] = label
        age_candidates(cand_age[b], cand_matched[b], confirm_window)
