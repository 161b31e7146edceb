"""The scalar EKF-SLAM estimator: one lane of :class:`~estimators.ekf.filter.EkfSlamBatch`.

It implements :class:`quadslam_env.estimation.protocol.Estimator` over the batch filter with
one lane, for a caller that feeds one vehicle's samples and scans by hand (the env builds the
batch filter itself, registered as ``"ekf_slam"``). Scans may carry any integer
landmark ids (e.g. 7, 42): the wrapper numbers them ``0, 1, …`` in order of first appearance
(ascending within a scan, so registration order is kept) and the batch filter works on those.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from estimators.ekf.filter import EkfSlamBatch
from estimators.ekf.settings import EkfSlamSettings
from quadslam_env.estimation import Estimate
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import FloatArray

_INITIAL_LANDMARK_CAPACITY = 32


class EkfSlam:
    """EKF-SLAM of seed 001 §2.3 with known data association (one vehicle).

    Args:
        vehicle: Nominal vehicle parameters (unused: the process model is driven by the IMU).
        **params: ``estimator.params``, see :class:`~estimators.ekf.settings.EkfSlamSettings`
            (``process_noise``, ``estimate_imu_bias``, ``gyro_bias_sigma0``,
            ``accel_bias_sigma0``, ``gyro_bias_walk``, ``accel_bias_walk``,
            ``gate_probability``, ``imu_noise_in_q``). Known-map mode is selected by passing
            ``known_landmarks=(ids, positions)`` to :meth:`reset`.

    Raises:
        ValueError: Unknown key, wrong type or out-of-range value (the message names the key,
            the value and what is allowed).
    """

    associates_unlabeled = True

    def __init__(self, vehicle: Any = None, **params: Any) -> None:
        self._filter = EkfSlamBatch(1, _INITIAL_LANDMARK_CAPACITY, vehicle, **params)
        self.last_association = np.zeros(0, dtype=np.int64)
        """(k,) landmark id each return of the last unlabeled scan was paired with (-1)."""
        self.vehicle = vehicle
        self._index: dict[int, int] = {}  # landmark id → filter id
        self._ids: list[int] = []  # filter id → landmark id
        self._lane = np.zeros(1, dtype=np.int64)
        self._active = np.ones(1, dtype=bool)
        self._t = np.zeros(1)
        self._accel = np.zeros((1, 3))
        self._gyro = np.zeros((1, 3))
        self._thrust = np.zeros(1)
        self._torque = np.zeros((1, 3))

    # ------------------------------------------------------------------ settings
    @property
    def known_map(self) -> bool:
        """True after a reset with ``known_landmarks`` (localisation only)."""
        return bool(self._filter.known_map[0])

    @property
    def settings(self) -> EkfSlamSettings:
        """The validated settings."""
        return self._filter.settings

    def __getattr__(self, name: str) -> Any:
        # Settings read as attributes, as before (``f.gate_threshold``, ``f.estimate_imu_bias``,
        # …). Private names are never forwarded, so copying and unpickling cannot recurse.
        if not name.startswith("_") and hasattr(EkfSlamSettings, name):
            return getattr(self._filter.settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    @property
    def capacity(self) -> int:
        """Current length of the state buffer (at least doubles when it grows)."""
        return self._filter.state_capacity

    @property
    def state_dim(self) -> int:
        """Current size n of the total state x = (s, b, m)."""
        return int(self._filter.state_dim[0])

    # ------------------------------------------------------------------ estimator protocol
    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start a new run (seed 001 §2.3.1: no landmarks are mapped at the start).

        Args:
            mean0: (12,) initial mean (ρ [m, N], v_B [m/s], Λ [rad], ω [rad/s]).
            cov0: (12, 12) initial covariance; its (9, 9) top-left block becomes ``P_ss``.
            rng: Unused (the EKF is deterministic); accepted for the protocol.
            known_landmarks: ``(ids (L,), positions (L, 3) [m, N])`` to localise against a
                known map (no landmark states); ``None`` for full SLAM.

        Raises:
            ValueError: Wrong shapes, non-finite values, or a malformed known map.
        """
        index: dict[int, int] = {}
        known = None
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(int).reshape(-1)
            pos = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            for i in ids.tolist():
                index.setdefault(i, len(index))
            known = [(np.array([index[i] for i in ids.tolist()], dtype=np.int64), pos)]
        self._filter.reset_lanes(
            self._lane, np.asarray(mean0, float)[None], np.asarray(cov0, float)[None], [rng], known
        )
        self._index = index
        self._ids = list(index)

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Propagate over one IMU sample period (seed 001 eq. 24–29).

        Args:
            imu: Sample with ``accel`` (3,) specific force [m/s², B] (only the z component is
                used, eq. 25), ``gyro`` (3,) [rad/s, B], and their per-sample noise stds.
            control: Applied control (unused: the process is driven by the IMU, eq. 24).
            dt: Sample period in s (> 0).

        Raises:
            ValueError: If ``dt`` is not a positive finite number.
        """
        del control
        self._accel[0] = imu.accel
        self._gyro[0] = imu.gyro
        self._filter.predict(
            self._t,
            self._accel,
            self._gyro,
            imu.accel_sigma,
            imu.gyro_sigma,
            self._thrust,
            self._torque,
            dt,
            self._active,
        )

    def update(self, scan: LidarScan) -> None:
        """Correct with one LiDAR scan, then register new landmarks (eq. 37–53).

        See :meth:`EkfSlamBatch.update`; ids outside the known map are ignored in known-map
        mode.

        Args:
            scan: Scan with sorted ``ids`` (k,), ``meas`` (k, 3) = (α rad, β rad, δ m) and
                ``sigma`` (3,) noise stds. An empty scan is a no-op.

        Raises:
            ValueError: If the measurements are not a finite (k, 3) array.
        """
        if scan.ids is None:
            self._update_unlabeled(scan)
            return
        ids = [int(i) for i in np.asarray(scan.ids).reshape(-1).tolist()]
        k = len(ids)
        if k == 0:
            return
        meas = np.asarray(scan.meas, dtype=float)
        if meas.shape != (k, 3) or not np.isfinite(meas).all():
            raise ValueError(f"update: scan.meas must be a finite ({k}, 3) array")
        rows: list[int] = []
        cols: list[int] = []
        for j, i in enumerate(ids):
            c = self._index.get(i)
            if c is None:
                if self.known_map:
                    continue  # not in the known map: ignored
                c = self._index[i] = len(self._ids)
                self._ids.append(i)
            rows.append(j)
            cols.append(c)
        width = max(self._filter.landmark_capacity, len(self._ids))
        visible = np.zeros((1, width), dtype=bool)
        visible[0, cols] = True
        meas_by_id = np.zeros((1, width, 3))
        meas_by_id[0, cols] = meas[rows]
        self._filter.update(self._t, self._lane, visible, meas_by_id, scan.sigma)

    def _update_unlabeled(self, scan: LidarScan) -> None:
        """Unlabeled scan (unknown association): see :meth:`EkfSlamBatch.update_unlabeled`.
        New map entries are named by their filter label."""
        meas = np.asarray(scan.meas, dtype=float)
        k = meas.shape[0] if meas.ndim == 2 else -1
        if meas.shape != (k, 3) or not np.isfinite(meas).all():
            raise ValueError("update: scan.meas must be a finite (k, 3) array")
        self._filter.update_unlabeled(self._t, self._lane, np.array([k]), meas[None], scan.sigma)
        if not self.known_map:  # the filter's labels are the landmark ids
            self._ids = list(range(self._filter.landmark_capacity))
            self._index = {i: i for i in self._ids}
        self.last_association = np.array(
            [self._ids[c] if c >= 0 else -1 for c in self._filter.last_association[0, :k]],
            dtype=np.int64,
        )

    def estimate(self) -> Estimate:
        """Snapshot of the belief (copies), landmarks sorted by id.

        Returns:
            :class:`Estimate` (see :meth:`EkfSlamBatch.lane_estimate`).
        """
        est = self._filter.lane_estimate(0)
        if not est.landmark_ids.size:
            return est
        ids = np.array(self._ids, dtype=int)[est.landmark_ids]
        order = np.argsort(ids, kind="stable")
        return dataclasses.replace(
            est,
            landmark_ids=ids[order],
            landmark_means=est.landmark_means[order],
            landmark_covs=est.landmark_covs[order],
        )

    # ------------------------------------------------------------------ testing/debugging
    def full_state(self) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Copies of the total mean x (n,), covariance P (n, n) and the mapped ids in slot
        order (landmark j occupies ``x[nv + 3j : nv + 3j + 3]``, nv = 9 or 13 with biases)."""
        x, P, slots = self._filter.full_state(0)
        return x, P, np.array(self._ids, dtype=int)[slots]

    def set_full_state(self, x: FloatArray, P: FloatArray) -> None:
        """Overwrite the total mean and covariance (same size n as :meth:`full_state`).

        Raises:
            ValueError: On a shape mismatch or non-finite values.
        """
        self._filter.set_full_state(x, P, 0)

    def stacked_measurement(self, ids: np.ndarray) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """Stacked observation model of the mapped/known landmarks ``ids`` (eq. 34 and 40).

        See :meth:`EkfSlamBatch.stacked_measurement`.

        Raises:
            KeyError: If an id is not mapped (or known).
        """
        rows = [self._index[int(i)] for i in np.asarray(ids).reshape(-1).tolist()]
        return self._filter.stacked_measurement(np.array(rows, dtype=np.int64), 0)
