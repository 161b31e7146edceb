"""Numba kernels of EKF-SLAM's data association front end (``lidar.association: unknown``).

For each scanning lane, :func:`associate_lanes` turns the unlabeled returns into the labeled
scan that :func:`estimators.ekf.update.update_lanes` corrects with (seed 004 §5), and
:func:`settle_tentative` then applies the M-of-N rule:

1. every landmark in the state (confirmed or tentative) or in the known map is predicted
   with the joint innovation covariance ``S = H P Hᵀ + R`` of
   :func:`~estimators.ekf.update.innovation_covariance` (the update's own model);
2. each (return, landmark) pair is gated on its individual 3-DOF NIS and the returns are
   associated by nearest neighbour or JCBB (:mod:`estimators.association`);
3. a return outside a wider gate (``new_landmark_probability``) of every landmark starts a
   **tentative** landmark (the wider gate keeps a true landmark's rare return outside the
   association gate from starting a duplicate of it): it is registered
   at once like any new landmark (eq. 44–53, so the map is anchored from the first sight,
   as with known association) under the lowest free label, and flagged tentative;
4. a return that is within the wider gate of some landmark but left unpaired, and every unpaired
   return of a known-map lane, is dropped;
5. after the update, a tentative landmark paired in ``confirm_hits`` (M) of its first
   ``confirm_window`` (N) scans is confirmed; one whose N scans pass without is removed from
   the state (:func:`~estimators.ekf.kernels.remove_landmark`: deleting a landmark's rows and
   columns of x and P is exact marginalisation, and a false return that no later return paired
   has given the pose no information, so clutter leaves no trace).

Labels are the estimator's own names for landmarks (unrelated to the simulator's ids), reused
after a removal; a known-map lane labels returns with the known map's ids. Tentative
landmarks are not reported as mapped, and a return paired with one counts as unassociated.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.association import (
    UNASSOCIATED,
    chi2_threshold,
    individual_nis,
    jcbb,
    joint_thresholds,
    nearest_neighbour,
)
from estimators.ekf.kernels import D_N_MAPPED, remove_landmark, sync_lane
from estimators.ekf.settings import EkfSlamSettings
from estimators.ekf.state import EkfState
from estimators.ekf.update import first_nonfinite_lane, innovation, innovation_covariance
from estimators.tentative import m_of_n
from quadslam_env.models.jit import inline_kernel, kernel
from quadslam_env.types import FloatArray


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
    new_gate: float,
    thresholds: FloatArray,
    use_jcbb: bool,
    tentative: np.ndarray,
    hits: np.ndarray,
    age: np.ndarray,
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
        new_gate: A return within this NIS (≥ ``gate``) of a landmark never starts a new one.
        thresholds: (≥ R + 1,) joint-compatibility thresholds χ²_{3k}(p) (JCBB).
        use_jcbb: JCBB when True, else nearest neighbour.
        tentative, hits, age: (B, Lcap) per label: tentative flag, scans paired, scans since
            creation; new tentative labels are written here.
        visible: (B, Lcap) bool, written for the scanning lanes: the labels returned.
        meas: (B, Lcap, 3), written: the return of each label.
        assoc: (B, R) int, written for the scanning lanes: each return's label or -1.
    """
    lmax = mapped.shape[1]
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
            _pair_returns(
                xb, Pb, nb, lms, cols, returns[b], r_diag, gate, new_gate, thresholds, use_jcbb,
                paired, gated,
            )  # fmt: skip
        _label_returns(
            paired, gated, ids, known[b], returns[b], mapped[b], visible[b], tentative[b],
            hits[b], age[b], meas[b], assoc[b],
        )  # fmt: skip


@inline_kernel
def _pair_returns(
    xb: FloatArray,
    Pb: FloatArray,
    nb: int,
    lms: FloatArray,
    cols: np.ndarray,
    returns: FloatArray,
    r_diag: FloatArray,
    gate: float,
    new_gate: float,
    thresholds: FloatArray,
    use_jcbb: bool,
    paired: np.ndarray,
    gated: np.ndarray,
) -> None:
    """Pair one lane's r returns with its m mapped landmarks (JCBB or nearest neighbour).

    Args:
        xb, Pb, nb: The lane's mean (≥n,), covariance (≥n, ≥n) and state size n.
        lms: (m, 3) the landmarks' positions (N, m); cols: (m,) their first state column
            (-1: known landmark).
        returns: (≥r, 3) the lane's returns (α rad, β rad, δ m).
        r_diag, gate, new_gate, thresholds, use_jcbb: As in :func:`associate_lanes`.
        paired: (r,) int, written: each return's landmark index into ``lms`` or -1.
        gated: (r,) bool, updated: set where a return is within ``new_gate`` of a landmark.
    """
    m = lms.shape[0]
    r = paired.shape[0]
    h = np.empty((m, 3))
    U = np.empty((3 * m, nb))
    S = np.empty((3 * m, 3 * m))
    innovation_covariance(xb, Pb, nb, lms, cols, r_diag, h, U, S)
    nu = np.empty((r, m, 3))
    for i in range(r):
        for a in range(m):
            innovation(returns[i], h[a], nu[i, a])
    d2 = np.empty((r, m))
    individual_nis(nu, S, d2)
    for i in range(r):
        for a in range(m):
            gated[i] = gated[i] or d2[i, a] <= new_gate
    if use_jcbb:
        jcbb(nu, S, d2, gate, thresholds, paired)
    else:
        nearest_neighbour(d2, gate, paired)


@inline_kernel
def _label_returns(
    paired: np.ndarray,
    gated: np.ndarray,
    ids: np.ndarray,
    known: bool,
    returns: FloatArray,
    mapped: np.ndarray,
    visible: np.ndarray,
    tentative: np.ndarray,
    hits: np.ndarray,
    age: np.ndarray,
    meas: FloatArray,
    assoc: np.ndarray,
) -> None:
    """Give each of one lane's returns a label: its paired landmark's, else (not within
    ``new_gate`` of one, not in a known map) a new tentative landmark's, the lowest free one.

    Args:
        paired, gated: (r,) from :func:`_pair_returns`; ids: (≥m,) int, the label of each
            paired index.
        known: Whether the lane is in known-map mode.
        returns: (≥r, 3) the lane's returns.
        mapped, visible, tentative, hits, age, meas, assoc: The lane's rows of the arrays of
            :func:`associate_lanes`; written as described there.
    """
    lmax = mapped.shape[0]
    free = 0
    for i in range(paired.shape[0]):
        if paired[i] >= 0:
            label = ids[paired[i]]
            hits[label] += 1
        elif gated[i] or known:
            continue  # ambiguous, or not in a known map: dropped
        else:  # a new tentative landmark under the lowest free label
            while free < lmax and (mapped[free] or visible[free]):
                free += 1
            if free == lmax:
                continue  # no label left (the caller reserves enough)
            label = free
            tentative[label] = True
            hits[label] = 1
            age[label] = 0
        visible[label] = True
        meas[label] = returns[i]
        assoc[i] = label


@kernel
def settle_tentative(
    x: FloatArray,
    P: FloatArray,
    n: np.ndarray,
    nv: int,
    slot_of_id: np.ndarray,
    id_of_slot: np.ndarray,
    mapped: np.ndarray,
    tentative: np.ndarray,
    hits: np.ndarray,
    age: np.ndarray,
    lanes: np.ndarray,
    count: np.ndarray,
    confirm_hits: int,
    confirm_window: int,
    diag: FloatArray,
    assoc: np.ndarray,
) -> None:
    """After the scan's update: confirm, keep or remove each tentative landmark of the
    scanning ``lanes`` (:func:`estimators.tentative.m_of_n`), then unpair the returns whose
    label is not a confirmed landmark (a tentative one, or a registration that failed)."""
    for b in lanes:
        for label in range(mapped.shape[1]):
            if not tentative[b, label]:
                continue
            if not mapped[b, label]:  # its registration failed
                tentative[b, label] = False
                continue
            rule = m_of_n(hits[b, label], age[b, label], confirm_hits, confirm_window)
            if rule > 0:
                tentative[b, label] = False
            elif rule < 0:
                remove_landmark(x[b], P[b], n[b], nv, slot_of_id[b], id_of_slot[b], label)
                n[b] -= 3
                mapped[b, label] = False
                tentative[b, label] = False
            else:
                age[b, label] += 1
        diag[D_N_MAPPED, b] = (n[b] - nv) // 3
        for i in range(count[b]):
            label = assoc[b, i]
            if label >= 0 and (tentative[b, label] or not mapped[b, label]):
                assoc[b, i] = UNASSOCIATED


class UnlabeledScans:
    """:class:`~estimators.ekf.filter.EkfSlamBatch`'s methods for unlabeled scans (a mixin
    over the filter's :class:`~estimators.ekf.state.EkfState`)."""

    associates_unlabeled = True
    num_lanes: int
    nv: int
    settings: EkfSlamSettings
    gate_threshold: float
    state: EkfState
    _thresholds: FloatArray

    def _ensure_ids(self, count: int) -> None:
        raise NotImplementedError  # the filter's

    def update(self, t: Any, lanes: Any, visible: Any, meas: Any, sigma: Any) -> None:
        raise NotImplementedError  # the filter's

    def update_unlabeled(
        self,
        t: FloatArray,
        lanes: np.ndarray,
        count: np.ndarray,
        returns: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Associate ``lanes``' unlabeled returns, then correct as :meth:`update` does.

        The association front end (:mod:`estimators.ekf.associate`: χ² gate, NN or JCBB,
        tentative landmarks under the M-of-N rule) labels the returns with map slots (or the
        known map's ids); :attr:`last_association` holds each return's label afterwards.

        Args:
            t: (B,) scan times in s (unused).
            lanes: (k,) int, lanes that scan.
            count: (B,) int returns per lane.
            returns: (B, R, 3) returns (α rad, β rad, δ m), in any order; rows ``≥ count``
                are not read.
            sigma: (3,) measurement noise stds (σ_α rad, σ_β rad, σ_δ m).

        Raises:
            ValueError: On a non-finite return (nothing is changed then).
        """
        lanes = np.ascontiguousarray(lanes, dtype=np.int64).reshape(-1)
        count = np.ascontiguousarray(count, dtype=np.int64)
        returns = np.ascontiguousarray(returns, dtype=float)
        width = returns.shape[1]
        present = np.arange(width) < count[:, None]
        bad = first_nonfinite_lane(lanes, present, returns)
        if bad >= 0:
            raise ValueError(f"update: lane {bad}: scan measurements must be finite")
        if self.state.assoc.shape[1] < width:
            self.state.assoc = np.full((self.num_lanes, width), UNASSOCIATED, dtype=np.int64)
            self._thresholds = joint_thresholds(width, self.settings.gate_probability)
        self.state.assoc[lanes] = UNASSOCIATED
        if lanes.size == 0:
            return
        self._ensure_ids(int(((self.state.n[lanes] - self.nv) // 3 + count[lanes]).max()))
        lcap = self.state.landmark_capacity
        visible = np.zeros((self.num_lanes, lcap), dtype=bool)
        meas = np.zeros((self.num_lanes, lcap, 3))
        r_diag = np.asarray(sigma, dtype=float).reshape(3) ** 2
        cfg, st = self.settings, self.state
        associate_lanes(
            st.x, st.P, st.n, self.nv, st.stale, st.slot_of_id, st.mapped, st.known, st.known_pos,
            lanes, count, returns, r_diag, self.gate_threshold,
            chi2_threshold(3, cfg.new_landmark_probability), self._thresholds,
            cfg.association == "jcbb", st.tentative, st.hits, st.age, visible, meas, st.assoc,
        )  # fmt: skip
        self.update(t, lanes, visible, meas, sigma)
        settle_tentative(
            st.x, st.P, st.n, self.nv, st.slot_of_id, st.id_of_slot, st.mapped, st.tentative,
            st.hits, st.age, lanes, count, cfg.confirm_hits, cfg.confirm_window, st.diag, st.assoc,
        )  # fmt: skip

    @property
    def last_association(self) -> np.ndarray:
        """(B, R) int label of each return of the lanes' last unlabeled scans (-1: none):
        map slots in SLAM lanes, known-map ids in known-map lanes (read only)."""
        out = self.state.assoc.view()
        out.flags.writeable = False
        return out

    @property
    def tentative_count(self) -> np.ndarray:
        """(B,) int tentative landmarks each lane holds (unknown association)."""
        return self.state.tentative.sum(axis=1)
