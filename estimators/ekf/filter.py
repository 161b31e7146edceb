"""EKF-SLAM of seed 001 §2.3 over a leading batch axis of B lanes (DESIGN.md §5, §9).

State of lane b (seed 001 eq. 21–23), in fixed-capacity arrays::

    x[b] = (s, b_imu, m)                                      (nmax,), first n[b] entries used
    s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])         9 vehicle states (eq. 21)
    b_imu = (b_ω [rad/s, B], b_az [m/s²])                     4 IMU biases (only with
                                                              ``estimate_imu_bias``)
    m = (l_slot0, l_slot1, …) [m, N]                          3 per mapped landmark
    P[b]                                                      (nmax, nmax), eq. 23

with ``nmax = nv + 3 Lmax`` (nv = 9 or 13). Landmarks are identified by their id
``0 … Lmax-1``; ``slot_of_id`` / ``id_of_slot`` map ids to map slots, which are filled in
registration order (ascending id within a scan). Known-map mode is chosen per lane at reset.

The numerical work runs in numba kernels that loop over lanes (:mod:`estimators.ekf.kernels`
for the prediction, :mod:`estimators.ekf.update` for the correction); this class validates,
allocates, grows and hands out results.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.special import gammaincinv

from estimators.base import POSE_DIM, Estimate, check_kwargs
from estimators.batch import BatchEstimate, IntArray, KnownMaps, register_batch
from estimators.ekf.kernels import (
    D_NIS,
    DIAGNOSTIC_NAMES,
    fill_outputs,
    predict_lanes,
    sync_lane,
    wrap_state_angle,
)
from estimators.ekf.update import first_nonfinite_lane, predicted_measurements, update_lanes
from quadslam_env.models.rotations import FloatArray, dcm_from_euler

BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated."""

PAPER_Q_UNKNOWN = (0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2)
"""Seed 001 Table 7: diagonal of Q over (ρ, v_B, Λ) for the unknown-map case."""

_AR3 = np.arange(3)


def _check_nonneg(key: str, value: float) -> float:
    value = float(value)
    if not (math.isfinite(value) and value >= 0.0):
        raise ValueError(f"estimator.params.{key}: got {value!r}; allowed: a finite number >= 0")
    return value


@register_batch("ekf_slam")
class EkfSlamBatch:
    """EKF-SLAM of seed 001 §2.3 with known data association, for B lanes.

    Implements :class:`estimators.batch.BatchEstimator`. Lane b behaves exactly like a scalar
    :class:`~estimators.ekf.scalar.EkfSlam` fed the same inputs.

    Args:
        num_lanes: B ≥ 1.
        landmark_capacity: Lmax, the number of landmark ids (and map slots) allocated; grows
            (by reallocation) when a known map or a scan brings larger ids.
        vehicle: Nominal vehicle parameters (unused: the process model is driven by the IMU).
        **params: Settings (all optional):

            ``process_noise`` (list of 9 floats ≥ 0, default seed 001 Table 7
            ``[0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2]``): diagonal of the
            continuous-time process-noise spectral density Q over (ρ, v_B, Λ), in m²/s,
            m²/s³, rad²/s. Table 6 (known landmarks) uses ``[0.01]*6 + [0.02]*3``.

            Known-map mode (localisation only, the paper's known-landmarks case) is selected
            per lane by passing a known map to :meth:`reset_lanes` (the env does so when the
            scenario sets ``estimator.known_map: true``); those positions are exact and are
            not states.

            ``estimate_imu_bias`` (bool, default False): augment the state with the gyro bias
            b_ω (3) and the accelerometer z bias b_az (1); these are the only IMU axes the
            model uses (λ = (ã_z, ω̃), seed 001 eq. 25). Random walks with the settings below.

            ``gyro_bias_sigma0`` (float ≥ 0, default 0.01 rad/s): initial bias std per axis.

            ``accel_bias_sigma0`` (float ≥ 0, default 0.05 m/s²): initial z-bias std.

            ``gyro_bias_walk`` (float ≥ 0, default 1e-4 rad/s/√s): random-walk density.

            ``accel_bias_walk`` (float ≥ 0, default 1e-3 m/s²/√s): random-walk density.

            ``gate_probability`` (float in (0, 1], default 0.99): per-landmark χ² gate
            (3 DOF; 0.99 → NIS threshold 11.345). 1.0 disables gating.

            ``imu_noise_in_q`` (bool, default True): add the IMU white noise mapped through
            ``∂f/∂λ`` to the discrete process noise (needed for consistency; False reproduces
            the paper, which only uses Q).

    Raises:
        ValueError: Unknown key, wrong type or out-of-range value (the message names the key,
            the value and what is allowed).
    """

    uses_truth = False

    def __init__(
        self, num_lanes: int, landmark_capacity: int, vehicle: Any = None, **params: Any
    ) -> None:
        check_kwargs(
            "estimator.params",
            params,
            {
                "process_noise": (list, tuple, np.ndarray),
                "estimate_imu_bias": bool,
                "gyro_bias_sigma0": (float, int),
                "accel_bias_sigma0": (float, int),
                "gyro_bias_walk": (float, int),
                "accel_bias_walk": (float, int),
                "gate_probability": (float, int),
                "imu_noise_in_q": bool,
            },
        )
        if int(num_lanes) < 1:
            raise ValueError(f"num_lanes: got {num_lanes!r}; allowed: an integer >= 1")
        self.vehicle = vehicle
        q = params.get("process_noise", PAPER_Q_UNKNOWN)
        if len(q) != POSE_DIM or not all(
            isinstance(e, float | int) and not isinstance(e, bool) for e in q
        ):
            raise ValueError(
                f"estimator.params.process_noise: got {q!r}; allowed: a list of 9 numbers >= 0"
            )
        q_diag = [_check_nonneg("process_noise", e) for e in q]
        self.estimate_imu_bias = bool(params.get("estimate_imu_bias", False))
        self.imu_noise_in_q = bool(params.get("imu_noise_in_q", True))
        self.gyro_bias_sigma0 = _check_nonneg(
            "gyro_bias_sigma0", params.get("gyro_bias_sigma0", 0.01)
        )
        self.accel_bias_sigma0 = _check_nonneg(
            "accel_bias_sigma0", params.get("accel_bias_sigma0", 0.05)
        )
        gyro_walk = _check_nonneg("gyro_bias_walk", params.get("gyro_bias_walk", 1e-4))
        accel_walk = _check_nonneg("accel_bias_walk", params.get("accel_bias_walk", 1e-3))
        prob = float(params.get("gate_probability", 0.99))
        if not 0.0 < prob <= 1.0:
            raise ValueError(
                f"estimator.params.gate_probability: got {prob!r}; allowed: 0 < p <= 1"
            )
        self.gate_probability = prob
        self.gate_threshold = math.inf if prob >= 1.0 else float(2.0 * gammaincinv(1.5, prob))
        self.nv = POSE_DIM + (BIAS_DIM if self.estimate_imu_bias else 0)
        qc = q_diag + ([gyro_walk**2] * 3 + [accel_walk**2] if self.estimate_imu_bias else [])
        self._qc = np.array(qc)
        self.num_lanes = b = int(num_lanes)
        self._n = np.full(b, self.nv, dtype=np.int64)
        self._stale = np.zeros(b, dtype=bool)
        self._known = np.zeros(b, dtype=bool)
        self._rates = np.zeros((b, 3))
        self._diag = np.zeros((len(DIAGNOSTIC_NAMES), b))
        self._diag[D_NIS] = math.nan
        self._vel_inertial = np.zeros((b, 3))
        self._accel_bias = np.zeros((b, 3))
        self._allocate(max(int(landmark_capacity), 0))

    # ------------------------------------------------------------------ storage
    def _allocate(self, lmax: int, keep: bool = False) -> None:
        """(Re)allocate the per-lane arrays for ``lmax`` landmarks, copying the old content."""
        b, nv = self.num_lanes, self.nv
        nmax = nv + 3 * lmax
        x = np.zeros((b, nmax))
        P = np.zeros((b, nmax, nmax))
        slot_of_id = np.full((b, lmax), -1, dtype=np.int64)
        id_of_slot = np.full((b, lmax), -1, dtype=np.int64)
        mapped = np.zeros((b, lmax), dtype=bool)
        known_pos = np.zeros((b, lmax, 3))
        if keep:
            m, L = self._x.shape[1], self._mapped.shape[1]
            x[:, :m] = self._x
            P[:, :m, :m] = self._P
            slot_of_id[:, :L] = self._slot_of_id
            id_of_slot[:, :L] = self._id_of_slot
            mapped[:, :L] = self._mapped
            known_pos[:, :L] = self._known_pos
        self._x, self._P = x, P
        self._slot_of_id, self._id_of_slot = slot_of_id, id_of_slot
        self._mapped, self._known_pos = mapped, known_pos
        self._landmark_means = np.zeros((b, lmax, 3))
        self._batch_estimate: BatchEstimate | None = None

    def _ensure_ids(self, count: int) -> None:
        """Grow so that ids ``0 … count-1`` fit: at least double the state buffer length."""
        lmax = self.landmark_capacity
        if count <= lmax:
            return
        doubled = -(-(2 * (self.nv + 3 * lmax) - self.nv) // 3)  # ceil
        self._allocate(max(count, doubled), keep=True)

    @property
    def landmark_capacity(self) -> int:
        """Lmax: landmark ids (and map slots) currently allocated per lane."""
        return int(self._mapped.shape[1])

    @property
    def state_capacity(self) -> int:
        """nmax = nv + 3 Lmax, the length of each lane's state buffer."""
        return int(self._x.shape[1])

    @property
    def state_dim(self) -> np.ndarray:
        """(B,) int, current size n of each lane's total state x = (s, b, m) (read only)."""
        out = self._n.view()
        out.flags.writeable = False
        return out

    @property
    def known_map(self) -> np.ndarray:
        """(B,) bool, lanes localising against a known map (read only)."""
        out = self._known.view()
        out.flags.writeable = False
        return out

    # ------------------------------------------------------------------ reset
    def reset_lanes(
        self,
        lanes: IntArray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Start new runs in ``lanes`` (seed 001 §2.3.1: no landmarks are mapped at the start).

        Args:
            lanes: (k,) lane indices.
            mean0: (k, 12) initial means (ρ [m, N], v_B [m/s], Λ [rad], ω [rad/s]); the first
                9 entries become ŝ, ω is reported until the first IMU sample arrives.
            cov0: (k, 12, 12) initial covariances; the (9, 9) top-left block becomes ``P_ss``.
            rngs: Unused (the EKF is deterministic); accepted for the protocol.
            known_landmarks: Per lane ``(ids (L,), positions (L, 3) [m, N])`` to localise
                against a known map (no landmark states), or ``None`` (for that lane or all)
                for full SLAM. Ids are non-negative integers.

        Raises:
            ValueError: Wrong shapes, non-finite values or negative known ids (nothing is
                changed then).
        """
        del rngs
        lanes = np.asarray(lanes, dtype=np.int64).reshape(-1)
        mean0 = np.asarray(mean0, dtype=float).reshape(lanes.shape[0], -1)
        cov0 = np.asarray(cov0, dtype=float)
        maps: list[tuple[np.ndarray, FloatArray] | None] = []
        for j in range(lanes.shape[0]):
            if mean0[j].shape != (12,) or not np.isfinite(mean0[j]).all():
                raise ValueError(
                    f"reset: mean0 must be a finite (12,) array, got shape {mean0[j].shape}"
                )
            if cov0[j].shape != (12, 12) or not np.isfinite(cov0[j]).all():
                raise ValueError(
                    f"reset: cov0 must be a finite (12, 12) array, got shape {cov0[j].shape}"
                )
            known = None if known_landmarks is None else known_landmarks[j]
            maps.append(None if known is None else self._check_known(known))
        need = max((int(m[0].max()) + 1 for m in maps if m is not None and m[0].size), default=0)
        self._ensure_ids(need)
        nv = self.nv
        for j, lane in enumerate(lanes.tolist()):
            x, P = self._x[lane], self._P[lane]
            x[:] = 0.0
            P[:] = 0.0
            x[:POSE_DIM] = mean0[j, :POSE_DIM]
            x[6] = wrap_state_angle(float(x[6]))
            x[8] = wrap_state_angle(float(x[8]))
            P0 = cov0[j, :POSE_DIM, :POSE_DIM]
            P[:POSE_DIM, :POSE_DIM] = 0.5 * (P0 + P0.T)
            if self.estimate_imu_bias:
                b_var = [self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2]
                P[POSE_DIM:nv, POSE_DIM:nv] = np.diag(b_var)
            self._n[lane] = nv
            self._stale[lane] = False
            self._rates[lane] = mean0[j, 9:12]
            self._diag[:, lane] = 0.0
            self._diag[D_NIS, lane] = math.nan
            self._slot_of_id[lane] = -1
            self._id_of_slot[lane] = -1
            self._mapped[lane] = False
            self._known_pos[lane] = 0.0
            known = maps[j]
            self._known[lane] = known is not None
            if known is not None:
                self._known_pos[lane, known[0]] = known[1]
                self._mapped[lane, known[0]] = True

    @staticmethod
    def _check_known(known: tuple[np.ndarray, FloatArray]) -> tuple[np.ndarray, FloatArray]:
        ids = np.asarray(known[0]).astype(np.int64).reshape(-1)
        pos = np.asarray(known[1], dtype=float).reshape(-1, 3)
        if ids.shape[0] != pos.shape[0] or not np.isfinite(pos).all():
            raise ValueError(
                "reset: known_landmarks must be (ids (L,), finite positions (L, 3)), got "
                f"{ids.shape[0]} ids and {pos.shape[0]} positions"
            )
        if ids.size and int(ids.min()) < 0:
            raise ValueError(f"reset: known landmark ids must be >= 0, got {int(ids.min())}")
        return ids, pos

    # ------------------------------------------------------------------ predict / update
    def predict(
        self,
        t: FloatArray,
        accel: FloatArray,
        gyro: FloatArray,
        accel_sigma: float,
        gyro_sigma: float,
        thrust: FloatArray,
        torque: FloatArray,
        dt: float,
        active: np.ndarray,
    ) -> None:
        """Propagate the ``active`` lanes over one IMU sample period (seed 001 eq. 24–29).

        Mean: RK4 with the input ``λ = (ã_z, ω̃) - b̂`` held over ``dt`` (eq. 26).
        Covariance: ``Φ = I + A + ½A²`` with ``A = F dt`` (eq. 27–28),
        ``P_vv ← Φ P_vv Φᵀ + Q_d`` and ``P_vm ← Φ P_vm`` (eq. 29), ``P_mm`` untouched, with
        ``Q_d = Q dt + Γ R_λ Γᵀ``, ``Γ = (I dt + ½F dt²) ∂f/∂λ``: the IMU white noise
        (per-sample std held over the sample period) mapped into the state.

        Args:
            t: (B,) sample times in s (unused).
            accel: (B, 3) measured specific force [m/s², B]; only the z column is used (eq. 25).
            gyro: (B, 3) measured body rates [rad/s, B].
            accel_sigma: Accelerometer white-noise std per sample in m/s².
            gyro_sigma: Gyro white-noise std per sample in rad/s.
            thrust: (B,) applied thrust in N (unused: the process is driven by the IMU).
            torque: (B, 3) applied torque in N·m (unused).
            dt: Sample period in s (> 0).
            active: (B,) bool, lanes to propagate.

        Raises:
            ValueError: If ``dt`` is not a positive finite number.
        """
        del t, thrust, torque
        if not 0.0 < dt < math.inf:
            raise ValueError(f"predict: dt must be a positive finite number of seconds, got {dt}")
        sa = accel_sigma * dt if self.imu_noise_in_q else 0.0
        sg = gyro_sigma * dt if self.imu_noise_in_q else 0.0
        predict_lanes(
            self._x,
            self._P,
            self._n,
            self.nv,
            self._stale,
            self._rates,
            self._diag,
            np.ascontiguousarray(active, dtype=bool),
            np.ascontiguousarray(accel, dtype=float),
            np.ascontiguousarray(gyro, dtype=float),
            float(sa),
            float(sg),
            float(dt),
            self._qc,
        )

    def update(
        self,
        t: FloatArray,
        lanes: IntArray,
        visible: np.ndarray,
        meas: FloatArray,
        sigma: FloatArray,
    ) -> None:
        """Correct ``lanes`` with their scans, then register new landmarks (eq. 37–53).

        Per lane: the observed mapped (known) landmarks are gated one by one on their 3-DOF
        NIS (rejections counted in ``n_rejected``) and the accepted ones form one stacked
        update over the columns ``[s, m_κ]`` (Cholesky of S, azimuth/elevation innovations
        wrapped, ``P -= W Wᵀ`` kept exactly symmetric); a step that fails (S not positive
        definite, non-finite result) is skipped and sets ``diverged``. Unmapped ids are then
        registered in ascending id order (ignored in known-map lanes). See
        :mod:`estimators.ekf.update`.

        Args:
            t: (B,) scan times in s (unused).
            lanes: (k,) int, lanes that scan.
            visible: (B, L) bool, returned landmark ids per lane.
            meas: (B, L, 3) measurements (α rad, β rad, δ m); only visible entries are read.
            sigma: (3,) measurement noise stds (σ_α rad, σ_β rad, σ_δ m).

        Raises:
            ValueError: On a non-finite visible measurement (nothing is changed then).
        """
        del t
        lanes = np.ascontiguousarray(lanes, dtype=np.int64).reshape(-1)
        if lanes.size == 0:
            return
        visible = np.ascontiguousarray(visible, dtype=bool)
        meas = np.ascontiguousarray(meas, dtype=float)
        bad = first_nonfinite_lane(lanes, visible, meas)
        if bad >= 0:
            raise ValueError(f"update: lane {bad}: scan measurements must be finite")
        self._ensure_ids(visible.shape[1])
        r_diag = np.asarray(sigma, dtype=float).reshape(3) ** 2
        update_lanes(
            self._x,
            self._P,
            self._n,
            self.nv,
            self._stale,
            self._slot_of_id,
            self._id_of_slot,
            self._mapped,
            self._known,
            self._known_pos,
            self._diag,
            lanes,
            visible,
            meas,
            r_diag,
            self.gate_threshold,
        )

    # ------------------------------------------------------------------ output
    def estimate(self) -> BatchEstimate:
        """The belief of every lane as views into the filter's buffers (read, don't keep).

        Returns:
            :class:`BatchEstimate` with ``pose_cov`` (B, 9, 9), ``landmark_means``
            (B, Lmax, 3) by id, ``landmark_mapped`` (B, Lmax) (mapped, or known in known-map
            lanes), the biases when estimated (``accel_bias = (0, 0, b̂_az)``) and the
            diagnostics ``nis`` (NaN before a lane's first update), ``nis_dof``,
            ``n_rejected``, ``n_rejected_last``, ``n_updates``, ``n_mapped``, ``diverged``
            as (B,) float arrays.
        """
        x = self._x
        fill_outputs(
            x,
            self.nv,
            self._slot_of_id,
            self._mapped,
            self._known,
            self._known_pos,
            self._vel_inertial,
            self._landmark_means,
        )
        out = self._batch_estimate
        if out is None:  # views stay valid until the buffers are reallocated
            gyro_bias = accel_bias = None
            if self.estimate_imu_bias:
                gyro_bias = x[:, 9:12]
                accel_bias = self._accel_bias
            out = BatchEstimate(
                position=x[:, 0:3],
                vel_body=x[:, 3:6],
                vel_inertial=self._vel_inertial,
                euler=x[:, 6:9],
                rates=self._rates,
                pose_cov=self._P[:, :POSE_DIM, :POSE_DIM],
                landmark_means=self._landmark_means,
                landmark_mapped=self._mapped,
                accel_bias=accel_bias,
                gyro_bias=gyro_bias,
                diagnostics={k: self._diag[i] for i, k in enumerate(DIAGNOSTIC_NAMES)},
            )
            self._batch_estimate = out
        if self.estimate_imu_bias:
            self._accel_bias[:, 2] = x[:, 12]
        return out

    def lane_estimate(self, lane: int) -> Estimate:
        """Snapshot (copies) of one lane's belief.

        Returns:
            :class:`Estimate` with the pose mean, ``pose_cov`` (9, 9) over (ρ, v_B, Λ),
            ``rates`` = last gyro minus bias estimate, landmarks sorted by id (in known-map
            mode the known map with zero covariance), biases when estimated and the
            diagnostics of :meth:`estimate` as floats.
        """
        x, P, nv = self._x[lane], self._P[lane], self.nv
        lm_ids = np.flatnonzero(self._mapped[lane])
        if self._known[lane]:
            lm_means = self._known_pos[lane, lm_ids]
            lm_covs = np.zeros((lm_ids.shape[0], 3, 3))
        else:
            idx = nv + 3 * self._slot_of_id[lane, lm_ids]
            lm_means = x[idx[:, None] + _AR3]
            lm_covs = P[idx[:, None, None] + _AR3[:, None], idx[:, None, None] + _AR3]
        gyro_bias = accel_bias = None
        if self.estimate_imu_bias:
            gyro_bias = x[9:12].copy()
            accel_bias = np.array([0.0, 0.0, x[12]])
        return Estimate(
            position=x[0:3].copy(),
            vel_body=x[3:6].copy(),
            vel_inertial=dcm_from_euler(x[6:9]) @ x[3:6],
            euler=x[6:9].copy(),
            rates=self._rates[lane].copy(),
            pose_cov=P[:POSE_DIM, :POSE_DIM].copy(),
            landmark_ids=lm_ids,
            landmark_means=lm_means,
            landmark_covs=lm_covs,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics={k: float(self._diag[i, lane]) for i, k in enumerate(DIAGNOSTIC_NAMES)},
        )

    # ------------------------------------------------------------------ testing/debugging
    def lane_full_state(self, lane: int) -> tuple[FloatArray, FloatArray, np.ndarray]:
        """Copies of one lane's total mean x (n,), covariance P (n, n) and the mapped ids in
        slot order (landmark slot j occupies ``x[nv + 3j : nv + 3j + 3]``)."""
        n = int(self._n[lane])
        self._sync(lane)
        n_mapped = (n - self.nv) // 3
        return (
            self._x[lane, :n].copy(),
            self._P[lane, :n, :n].copy(),
            self._id_of_slot[lane, :n_mapped].copy(),
        )

    def set_lane_full_state(self, lane: int, x: FloatArray, P: FloatArray) -> None:
        """Overwrite one lane's total mean and covariance (same size n as the current state).

        Raises:
            ValueError: On a shape mismatch or non-finite values.
        """
        n = int(self._n[lane])
        x = np.asarray(x, dtype=float)
        P = np.asarray(P, dtype=float)
        if x.shape != (n,) or P.shape != (n, n):
            raise ValueError(f"set_full_state: expected x ({n},) and P ({n}, {n})")
        if not (np.isfinite(x).all() and np.isfinite(P).all()):
            raise ValueError("set_full_state: x and P must be finite")
        self._x[lane, :n] = x
        self._P[lane, :n, :n] = P
        self._stale[lane] = False

    def stacked_measurement(
        self, lane: int, ids: np.ndarray
    ) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """Stacked observation model of one lane's mapped/known landmarks ``ids`` (eq. 34, 40).

        Args:
            lane: Lane index.
            ids: (k,) landmark ids; all must be mapped (or in the known map).

        Returns:
            ``(cols, h, H)``: ``cols`` (d,) the columns of x the model depends on
            (``[s, m_κ]``, d = 9 + 3k; only s in known-map mode), ``h`` (3k,) the predicted
            measurements (α, β, δ per landmark) and ``H`` (3k, d) = ``∂h/∂x[cols]``.

        Raises:
            KeyError: If an id is not mapped (or known).
        """
        ids = np.asarray(ids, dtype=np.int64).reshape(-1)
        for i in ids.tolist():
            if not (0 <= i < self.landmark_capacity and self._mapped[lane, i]):
                raise KeyError(i)
        x = self._x[lane]
        k = ids.shape[0]
        known = bool(self._known[lane])
        if known:
            lms = self._known_pos[lane, ids]
            cols = np.arange(POSE_DIM)
        else:
            lm_cols = (self.nv + 3 * self._slot_of_id[lane, ids][:, None] + _AR3).ravel()
            lms = x[lm_cols].reshape(k, 3)
            cols = np.concatenate((np.arange(POSE_DIM), lm_cols))
        h = np.empty((k, 3))
        blocks = np.empty((k, 3, 9))
        predicted_measurements(x, np.ascontiguousarray(lms), h, blocks)
        H = np.zeros((k, 3, cols.shape[0]))
        H[:, :, 0:3] = blocks[:, :, 0:3]
        H[:, :, 6:9] = blocks[:, :, 3:6]
        if not known:
            for i in range(k):
                H[i, :, POSE_DIM + 3 * i : POSE_DIM + 3 * i + 3] = blocks[i, :, 6:9]
        return cols, h.ravel(), H.reshape(3 * k, -1)

    def _sync(self, lane: int) -> None:
        """Make one lane's P fully symmetric again (see :func:`predict_lanes`)."""
        if self._stale[lane]:
            sync_lane(self._P[lane], int(self._n[lane]), self.nv)
            self._stale[lane] = False
