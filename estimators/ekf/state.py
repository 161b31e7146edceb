"""The per-lane buffers of EKF-SLAM over B lanes, as one typed container.

:class:`~estimators.ekf.filter.EkfSlamBatch` owns one :class:`EkfState`; its kernels
(:mod:`estimators.ekf.kernels`, :mod:`estimators.ekf.update`, :mod:`estimators.ekf.associate`)
take the arrays and update them in place. The layout of lane b's state (seed 001 eq. 21–23)::

    x[b] = (s, b_imu, m)        s = (ρ [m, N], v_B [m/s, B], Λ [rad]), b_imu = (b_ω, b_az)
    P[b]                        covariance of x[b] (eq. 23)

with ``nmax = nv + 3 S`` (nv = 9 or 13 vehicle and bias states, S landmark slots); only the
first ``n[b]`` entries are in use. Landmarks are identified by ids ``0 … Lmax-1`` and fill the
slots in registration order. ``S`` is ``Lmax`` while any lane runs SLAM and 0 when every lane
localises against a known map (:meth:`EkfSlamBatch._fit_state_slots`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from estimators.ekf.kernels import D_NIS, sync_lane
from quadslam_env.types import FloatArray

_FILL = {"slot_of_id": -1, "id_of_slot": -1, "readmit_at": -math.inf}
"""The neutral value of the arrays whose neutral value is not 0 (:meth:`EkfState.resize`)."""


@dataclass
class EkfState:
    """The EKF-SLAM state of B lanes (all arrays have the lane axis first).

    Attributes:
        x: (B, nmax) total means (s, b_imu, m); entries ``≥ n[b]`` are unused.
        P: (B, nmax, nmax) total covariances; only the lower blocks are current while
            ``stale[b]`` (the prediction updates ``P_vv`` and ``P_vm`` only).
        n: (B,) int, used length of each lane's x.
        stale: (B,) bool, lanes whose ``P_mv`` block lags ``P_vm`` (synced before reading P).
        known: (B,) bool, lanes localising against a known map (no landmark states).
        rates: (B, 3) bias-corrected body rates ω̂ of the last IMU sample, rad/s, B.
        diag: (D, B) diagnostics by row (``estimators.ekf.kernels.DIAGNOSTIC_NAMES``).
        slot_of_id: (B, Lmax) int, map slot of each landmark id (-1: none).
        id_of_slot: (B, Lmax) int, landmark id in each map slot (-1: free).
        mapped: (B, Lmax) bool, ids in the lane's state (or its known map).
        known_pos: (B, Lmax, 3) known-map landmark positions by id, m, N.
        tentative: (B, Lmax) bool, unknown association: ids in the state but not yet
            confirmed (not reported).
        hits: (B, Lmax) int, unknown association: scans that matched each tentative id.
        age: (B, Lmax) int, unknown association: scans since each tentative id was created.
        assoc: (B, R) int, the label of each return of the lanes' last unlabeled scans (-1:
            none); R grows with the widest scan.
        readmit_at: (B, Lmax) time from which the integrity monitor lets each id be used
            again, s (−inf: never left out; :mod:`estimators.ekf.fde`).
        seq_stats: (B, Lmax, W) the integrity monitor's sequential test: each id's last W
            landmark statistics, a ring (W = 0: no sequential test).
        seq_count: (B, Lmax) int, each id's sightings in it since it was last left out.
    """

    x: FloatArray
    P: FloatArray
    n: np.ndarray
    stale: np.ndarray
    known: np.ndarray
    rates: FloatArray
    diag: FloatArray
    slot_of_id: np.ndarray
    id_of_slot: np.ndarray
    mapped: np.ndarray
    known_pos: FloatArray
    tentative: np.ndarray
    hits: np.ndarray
    age: np.ndarray
    assoc: np.ndarray
    readmit_at: FloatArray
    seq_stats: FloatArray
    seq_count: np.ndarray

    @classmethod
    def empty(cls, num_lanes: int, nv: int, num_diagnostics: int) -> EkfState:
        """B lanes of nv vehicle states each, no landmark ids or slots, no scan returns."""
        b = num_lanes
        return cls(
            x=np.zeros((b, nv)),
            P=np.zeros((b, nv, nv)),
            n=np.full(b, nv, dtype=np.int64),
            stale=np.zeros(b, dtype=bool),
            known=np.zeros(b, dtype=bool),
            rates=np.zeros((b, 3)),
            diag=np.zeros((num_diagnostics, b)),
            slot_of_id=np.full((b, 0), -1, dtype=np.int64),
            id_of_slot=np.full((b, 0), -1, dtype=np.int64),
            mapped=np.zeros((b, 0), dtype=bool),
            known_pos=np.zeros((b, 0, 3)),
            tentative=np.zeros((b, 0), dtype=bool),
            hits=np.zeros((b, 0), dtype=np.int64),
            age=np.zeros((b, 0), dtype=np.int64),
            assoc=np.zeros((b, 0), dtype=np.int64),
            readmit_at=np.zeros((b, 0)),
            seq_stats=np.zeros((b, 0, 0)),
            seq_count=np.zeros((b, 0), dtype=np.int64),
        )

    @property
    def landmark_capacity(self) -> int:
        """Lmax: landmark ids allocated per lane."""
        return int(self.mapped.shape[1])

    def resize(self, lmax: int, slots: int, nv: int) -> None:
        """Reallocate for ``lmax`` landmark ids and ``slots`` landmark states per lane
        (``nmax = nv + 3 slots``), keeping the content that fits; new entries take each
        array's neutral value (0, False, -1 for the id/slot maps, −inf for readmission)."""
        b = self.x.shape[0]
        nmax = nv + 3 * slots
        shapes = {
            "x": (b, nmax),
            "P": (b, nmax, nmax),
            "slot_of_id": (b, lmax),
            "id_of_slot": (b, lmax),
            "mapped": (b, lmax),
            "known_pos": (b, lmax, 3),
            "tentative": (b, lmax),
            "hits": (b, lmax),
            "age": (b, lmax),
            "readmit_at": (b, lmax),
            "seq_stats": (b, lmax, self.seq_stats.shape[2]),
            "seq_count": (b, lmax),
        }
        for field in fields(self):
            shape = shapes.get(field.name)
            if shape is None:
                continue
            old = getattr(self, field.name)
            fill = _FILL.get(field.name, 0)
            new = np.full(shape, fill, dtype=old.dtype)
            # the old content fills the leading corner (all of it that fits)
            corner = tuple(slice(0, min(e, f)) for e, f in zip(old.shape, shape, strict=True))
            new[corner] = old[corner]
            setattr(self, field.name, new)

    def sync(self, lane: int, nv: int) -> None:
        """Make lane ``lane``'s P fully symmetric again, if its ``P_mv`` block lags (after a
        prediction, which updates ``P_vv`` and ``P_vm`` only; ``nv`` vehicle states)."""
        if self.stale[lane]:
            sync_lane(self.P[lane], int(self.n[lane]), nv)
            self.stale[lane] = False

    def clear_lane(self, lane: int, nv: int, unassociated: int) -> None:
        """Start lane ``lane`` afresh: nv vehicle states, no landmarks, no diagnostics (NaN NIS),
        nothing left out, no association (labels ``unassociated``); x and P are the caller's."""
        self.n[lane] = nv
        self.stale[lane] = False
        self.diag[:, lane] = 0.0
        self.diag[D_NIS, lane] = math.nan  # undefined before the first update
        self.slot_of_id[lane] = -1
        self.id_of_slot[lane] = -1
        self.mapped[lane] = False
        self.tentative[lane] = False
        self.known_pos[lane] = 0.0
        self.assoc[lane] = unassociated
        self.readmit_at[lane] = -math.inf
        self.seq_stats[lane] = 0.0
        self.seq_count[lane] = 0

    def set_window(self, window: int) -> None:
        """Sequential windows of ``window`` statistics per id (0: none), all lanes' empty."""
        b, lmax = self.seq_count.shape
        self.seq_stats = np.zeros((b, lmax, window))
        self.seq_count[:] = 0
