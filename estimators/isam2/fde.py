"""Fault detection and exclusion in the iSAM2 smoother: EKF-SLAM's monitor
(:mod:`estimators.ekf.fde`) on the smoother's belief at each scan (docs/integrity.md).

Before a scan's keyframe enters the graph, the returns of the landmarks already in it (known
map: of the map) are tested on what the smoother predicts for them: the latest keyframe
predicted with the IMU to the scan, with the joint marginal ``Σ`` of that pose and those k
landmarks. With the LiDAR factor's Jacobians ``J = [H_x, H_l]`` at the estimate
(:func:`~estimators.isam2.factors.lidar_error`, seed 001 eq. 30–31, 40):

    ν = z − h(X̂, l̂),    S = J Σ Jᵀ + I_k ⊗ R,    U = J Σ_{:,δt} C_NBᵀ,

the innovations, their covariance, and their cross-covariance with the position error in N
(the Pose3 tangent's δt is in B, and ρ ← ρ + C_NB δt). These are the innovation, S and ``H P⁻``
of a Kalman update at the scan linearised at the smoother's estimate, so
:func:`~estimators.ekf.fde.monitor_scan` runs on them unchanged: the scan test, the landmark
tests, the sequential test, exclusion and the solution separations of the protection levels.
It also uses the same thresholds (:class:`~quadslam_env.estimation.integrity.MonitorSettings`).
The smoother has no χ² gate on labeled returns, so detection (``monitor: detect``) tests every
return and changes nothing in the graph.

**Exclusion in a smoother.** The returns of a landmark found faulty are not added, and none of
its returns is used until ``readmit_s`` later. In SLAM its variable is *retired*: the variable
stays in the graph with its earlier factors but no new factor reaches it, which for the
vehicle's states is what EKF-SLAM's marginalisation of the landmark does (its past returns keep
the information they gave). Taking a variable out of a Bayes tree is not cheap, so it is not
taken out. The landmark's id now names a new key, so a sighting after readmission puts a new
variable at the inverse model (eq. 44–45): the landmark is re-initialised where it now is, not
where it was. In a team's smoother (``team.fusion: centralised``) the vehicles share the ids'
keys, as they share the map.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from estimators.ekf.fde import FDE_EXCLUDED, FDE_PASS, FDE_SINGULAR, FDE_UNRESOLVED, monitor_scan
from estimators.isam2.associate import (
    SIGMA_FLOOR,
    Labeled,
    PosePrediction,
    innovation_covariance,
    stacked_jacobian,
)
from estimators.isam2.factors import lidar_error
from quadslam_env.estimation.integrity import COUNT_KEYS, SEPARATION_KEYS, MonitorSettings
from quadslam_env.types import FloatArray

RETIRED_BASE = 10**7
"""First key index of a retired landmark's successor: ids below it are the map's, those from it
on the re-initialised landmarks' (in order of retirement), below 10⁸, where the fixed-lag
window's key names stop (:data:`~estimators.isam2.team.VEHICLE_STRIDE`)."""


class LandmarkKeys:
    """Each landmark id's key index: the id itself until the monitor retires the landmark,
    then its successor's (:data:`RETIRED_BASE` on)."""

    def __init__(self) -> None:
        self._index: dict[int, int] = {}
        self.retired = 0

    def index(self, lm_id: int) -> int:
        """The key index of landmark ``lm_id``'s current variable."""
        return self._index.get(lm_id, lm_id)

    def retire(self, lm_id: int) -> None:
        """Give ``lm_id`` a new key index (its next sighting makes a new variable).

        Raises:
            OverflowError: The successors' indices would reach 10⁸.
        """
        if RETIRED_BASE + self.retired >= 10**8:
            raise OverflowError(
                f"isam2: {self.retired} landmarks retired; at most {9 * RETIRED_BASE}"
            )
        self._index[lm_id] = RETIRED_BASE + self.retired
        self.retired += 1


_NO_WINDOW = (np.zeros((1, 0)), np.zeros(1, dtype=np.int64))
"""The sequential windows without the sequential test (never read)."""


class Isam2Monitor:
    """:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity` for
    :class:`~estimators.isam2.estimator.Isam2Slam` (a mixin; module docstring). Its counts and
    the last scan's separations go in the snapshot's diagnostics while a monitor is set."""

    monitors_integrity = True
    _monitor: MonitorSettings | None = None
    _thresholds_for = -1  # the scan size the thresholds are tabulated for
    _tables: tuple[FloatArray, FloatArray, FloatArray]
    _team: list[Any]
    _vehicle: int
    _known: dict[int, FloatArray] | None
    _lm_means: dict[int, FloatArray]
    _lm_covs: dict[int, FloatArray] | None
    _lm_map: Any
    _cache: Any
    _state_cache: Any
    _scan_joint: Callable[[PosePrediction, list[int]], FloatArray]  # the estimator's

    @property
    def monitoring(self) -> bool:
        """Whether a monitor is set."""
        return self._monitor is not None

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Monitor every later scan with ``settings`` (``None``: no monitor, the default); the
        counts and sequential windows start afresh."""
        self._monitor = settings
        self._thresholds_for = -1
        self._reset_monitor()

    def _reset_monitor(self) -> None:
        """A new run: no counts, no separations, every landmark usable, windows empty."""
        self._fde_counts = np.zeros(len(COUNT_KEYS))
        self._fde_sep = np.zeros(len(SEPARATION_KEYS))
        self._readmit_at: dict[int, float] = {}
        window = 0 if self._monitor is None else self._monitor.sequential_window or 0
        self._seq = (np.zeros((0, window)), np.zeros(0, dtype=np.int64)) if window else _NO_WINDOW
        # Shared by a team's vehicles, as the map is (vehicle 0's reset starts them afresh,
        # and the team env resets it first).
        self._landmark_keys = LandmarkKeys() if self._vehicle == 0 else self._team[0]._landmark_keys

    def _monitor_diagnostics(self) -> dict[str, float]:
        """The counts since the reset and the last scan's separations, when monitoring."""
        if self._monitor is None:
            return {}
        out = dict(zip(COUNT_KEYS, self._fde_counts.tolist(), strict=True))
        out.update(zip(SEPARATION_KEYS, self._fde_sep.tolist(), strict=True))
        return out

    def _monitor_scan(
        self, scan: Labeled, sigma: FloatArray, pred: PosePrediction, t: float
    ) -> Labeled:
        """Test ``scan``'s returns on the belief ``pred`` at the scan time ``t`` s, and give the
        scan with the returns to add (module docstring).

        Raises:
            FloatingPointError: The innovation covariance is not positive definite (the
                estimator then reports divergence).
            ValueError: A landmark id at or above :data:`RETIRED_BASE`.
        """
        cfg = self._monitor
        assert cfg is not None
        if any(i >= RETIRED_BASE for i in scan.ids):
            raise ValueError(f"update: landmark ids must be below {RETIRED_BASE} with a monitor")
        usable = [j for j, i in enumerate(scan.ids) if not self._readmit_at.get(i, -math.inf) > t]
        known = self._known
        mapped = self._lm_means if known is None else known
        rows = [j for j in usable if scan.ids[j] in mapped]
        self._fde_sep[:] = 0.0  # no landmark tested: no fault hypothesis to bound
        keep = np.ones(len(rows), dtype=bool)
        if rows:
            ids = [scan.ids[j] for j in rows]
            lms = np.array([mapped[i] for i in ids], dtype=float)
            S, U, nu = self._innovations(pred, ids, lms, scan.meas[rows], sigma)
            keep = self._test(S, U, nu, np.array(ids, dtype=np.int64), cfg, t)
        tested = {j: bool(keep[a]) for a, j in enumerate(rows)}
        used = [j for j in usable if tested.get(j, True)]
        return Labeled([scan.ids[j] for j in used], scan.meas[used].reshape(-1, 3), scan.earlier)

    def _innovations(
        self,
        pred: PosePrediction,
        ids: list[int],
        lms: FloatArray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(S (3k, 3k), U (3k, 3), ν (3k,))`` of the k returns ``meas`` of the landmarks
        ``ids`` at ``lms`` (k, 3) m, N (module docstring)."""
        e, H_pose, H_lm = lidar_error(pred.dcm, pred.position, lms, meas)
        joint = self._scan_joint(pred, ids)
        r_diag = np.maximum(np.asarray(sigma, dtype=float).reshape(3), SIGMA_FLOOR) ** 2
        S = innovation_covariance(H_pose, H_lm, joint, r_diag)
        U = np.ascontiguousarray((stacked_jacobian(H_pose, H_lm) @ joint[:, 3:6]) @ pred.dcm.T)
        if not (np.isfinite(S).all() and np.isfinite(U).all()):
            raise FloatingPointError("isam2: non-finite innovation covariance in the monitor")
        return S, U, np.ascontiguousarray(-e.reshape(-1))  # ν = z − h = −e (angles wrapped)

    def _test(
        self,
        S: FloatArray,
        U: FloatArray,
        nu: FloatArray,
        ids: np.ndarray,
        cfg: MonitorSettings,
        t: float,
    ) -> np.ndarray:
        """Run :func:`~estimators.ekf.fde.monitor_scan` on k landmarks ``ids`` and count its
        outcome; returns (k,) bool, the returns to use. A landmark excluded is left out until
        ``t + readmit_s`` and, in SLAM, retired."""
        k = ids.shape[0]
        lm_thr, scan_thr, seq_thr = self._thresholds(cfg, k)
        stats, count = self._windows(int(ids.max()) + 1)
        keep = np.ones(k, dtype=bool)
        sep = np.empty(len(SEPARATION_KEYS))
        status = monitor_scan(S, U, nu, lm_thr, scan_thr, cfg.exclude, cfg.max_exclusions, keep,
                              sep, ids, stats, count, seq_thr)  # fmt: skip
        if status == FDE_SINGULAR:
            raise FloatingPointError(
                "isam2: the monitor's innovation covariance is not positive definite"
            )
        counts = self._fde_counts  # COUNT_KEYS: tests, alarms, exclusions, unresolved
        counts[0] += 1.0
        counts[1] += float(status != FDE_PASS)
        counts[3] += float(status == FDE_UNRESOLVED)
        self._fde_sep[:] = sep
        if status == FDE_EXCLUDED:
            for lm_id in ids[~keep].tolist():
                counts[2] += 1.0
                self._leave_out(lm_id, t + cfg.readmit_s)
        return keep

    def _leave_out(self, lm_id: int, until: float) -> None:
        """Landmark ``lm_id`` found faulty: not used until ``until`` s, its sequential test
        afresh and, in SLAM, its variable retired (module docstring)."""
        self._readmit_at[lm_id] = until
        stats, count = self._seq
        if stats.shape[1]:
            count[lm_id] = 0
        if self._known is not None:
            return
        self._landmark_keys.retire(lm_id)
        self._lm_means.pop(lm_id, None)  # the map the keyframe after this scan reads
        if self._lm_covs is not None:
            self._lm_covs.pop(lm_id, None)
        self._lm_map = None
        self._cache = self._state_cache = None

    def _thresholds(
        self, cfg: MonitorSettings, k: int
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """The tests' thresholds (landmark, scan, sequential) for scans of up to k landmarks,
        tabulated again only when a scan has more than before."""
        if self._thresholds_for < k:
            capacity = max(k, 2 * self._thresholds_for, 16)
            self._tables = (
                cfg.landmark_thresholds(capacity),
                cfg.scan_thresholds(capacity),
                cfg.sequential_thresholds(capacity),
            )
            self._thresholds_for = capacity
        return self._tables

    def _windows(self, rows: int) -> tuple[FloatArray, np.ndarray]:
        """The sequential windows (Lmax, W) and sightings (Lmax,) by id, with Lmax ≥ ``rows``
        (grown, their contents kept)."""
        stats, count = self._seq
        if stats.shape[1] and stats.shape[0] < rows:
            n = max(rows, 2 * stats.shape[0])
            grown = (np.zeros((n, stats.shape[1])), np.zeros(n, dtype=np.int64))
            grown[0][: stats.shape[0]] = stats
            grown[1][: count.shape[0]] = count
            self._seq = stats, count = grown
        return stats, count
