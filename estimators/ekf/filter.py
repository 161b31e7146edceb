"""EKF-SLAM of seed 001 §2.3 over a leading batch axis of B lanes (docs/design.md §5, §9).

State of lane b (seed 001 eq. 21–23), in fixed-capacity arrays::

    x[b] = (s, b_imu, m)                                      (nmax,), first n[b] entries used
    s = (ρ [m, N], v_B [m/s, B], Λ = (φ, θ, ψ) [rad])         9 vehicle states (eq. 21)
    b_imu = (b_ω [rad/s, B], b_az [m/s²][, b_ax, b_ay])       4 IMU biases (only with
                                                              ``estimate_imu_bias``), 6 with
                                                              ``specific_force: full`` or
                                                              ``wind: estimate``
    w = (w_N, w_E) [m/s, N]                                   2 wind states (only with
                                                              ``wind: estimate``)
    m = (l_slot0, l_slot1, …) [m, N]                          3 per mapped landmark
    P[b]                                                      (nmax, nmax), eq. 23

with ``nmax = nv + 3 Lmax`` (nv = 9, 13 or 15; 11 or 17 with the wind). Landmarks are
identified by their id ``0 … Lmax-1``; ``slot_of_id`` / ``id_of_slot`` map ids to map slots,
which are filled in registration order (ascending id within a scan). Known-map mode is
chosen per lane at reset.

The numerical work runs in numba kernels that loop over lanes (:mod:`estimators.ekf.kernels`
for the prediction, :mod:`estimators.ekf.wind` for the prediction with the wind states and the
accelerometer update, :mod:`estimators.ekf.update` for the correction); this class validates,
allocates, grows and hands out results.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from estimators.association import UNASSOCIATED, joint_thresholds
from estimators.ekf import warmup
from estimators.ekf.associate import UnlabeledScans
from estimators.ekf.fde import IntegrityMonitor
from estimators.ekf.fusion import LandmarkFusion
from estimators.ekf.inspection import FilterInspection
from estimators.ekf.kernels import (
    D_NIS,
    DIAGNOSTIC_NAMES,
    fill_outputs,
    predict_lanes,
)
from estimators.ekf.ranging import RangeFusion
from estimators.ekf.settings import (
    ACCEL_BIAS_XY,
    ACCEL_BIAS_Z,
    BIAS_DIM,
    GYRO_BIAS,
    EkfSlamSettings,
    MemorySizing,
    WindStates,
)
from estimators.ekf.state import EkfState
from estimators.ekf.update import first_nonfinite_lane, update_lanes
from estimators.ekf.wind import predict_wind
from estimators.memory import check_ekf_map
from quadslam_env.estimation.protocol import IntArray, KnownMaps
from quadslam_env.estimation.registry import register
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.frames import dcm_from_euler, wrap_pi
from quadslam_env.types import EUL, POS, POSE_DIM, RATE, VEL, FloatArray

_AR3 = np.arange(3)


@register("ekf_slam")
class EkfSlamBatch(
    UnlabeledScans,
    FilterInspection,
    MemorySizing,
    WindStates,
    IntegrityMonitor,
    LandmarkFusion,
    RangeFusion,
):
    """EKF-SLAM of seed 001 §2.3 with known data association, for B lanes.

    Implements :class:`~quadslam_env.estimation.protocol.BatchEstimator`. Lanes are
    independent: lane b behaves exactly like the one lane of a filter with B = 1 fed the same
    inputs.

    Args:
        num_lanes: B ≥ 1.
        landmark_capacity: Lmax, the number of landmark ids (and map slots) allocated; grows
            (by reallocation) when a known map or a scan brings larger ids.
        vehicle: Nominal vehicle parameters: their drag with ``wind: estimate`` (otherwise
            unused: the process model is driven by the IMU).
        **params: ``estimator.params``, see :class:`~estimators.ekf.settings.EkfSlamSettings`.
            Known-map mode (localisation only) is chosen per lane by passing a known map to
            :meth:`reset_lanes`.

    Raises:
        ValueError: Unknown key, wrong type or out-of-range value, or ``wind: estimate``
            without a vehicle with drag (a ``ConfigError`` naming the key, the value and what
            is allowed).
    """

    uses_truth = False
    associates_unlabeled = True

    def __init__(
        self, num_lanes: int, landmark_capacity: int, vehicle: Any = None, **params: Any
    ) -> None:
        self.settings = settings = EkfSlamSettings.from_dict(params)
        if int(num_lanes) < 1:
            raise ValueError(f"num_lanes: got {num_lanes!r}; allowed: an integer >= 1")
        self.vehicle = vehicle
        self._drag = settings.drag_model(vehicle) if settings.estimates_wind else None
        self.estimate_imu_bias = settings.estimate_imu_bias
        self.gate_threshold = settings.gate
        self.nv = settings.nv
        self._qc = settings.continuous_noise()
        self._relinearise = settings.relinearise_tolerance
        self.num_lanes = b = int(num_lanes)
        self.state = EkfState.empty(b, self.nv, len(DIAGNOSTIC_NAMES))
        self.state.diag[D_NIS] = math.nan
        self._vel_inertial = np.zeros((b, 3))
        self._accel_bias = np.zeros((b, 3))
        self._thresholds = joint_thresholds(0, settings.gate_probability)
        self._allocate(max(int(landmark_capacity), 0))
        warmup.start()  # a cold cache: compile the update in parallel (estimators.ekf.warmup)

    def __getstate__(self) -> dict[str, Any]:
        # The cached BatchEstimate holds views into the buffers: a copy builds its own.
        state = self.__dict__.copy()
        state["_batch_estimate"] = None
        return state

    # ------------------------------------------------------------------ storage
    def _allocate(self, lmax: int, slots: int | None = None) -> None:
        """(Re)allocate the per-lane arrays for ``lmax`` landmark ids and ``slots`` landmark
        states (default ``lmax``), keeping the content that fits."""
        slots = lmax if slots is None else slots
        check_ekf_map(self.num_lanes, self.nv, slots)  # before allocating (B, n, n)
        self.state.resize(lmax, slots, self.nv)
        # Outputs by id (estimate()); the cached BatchEstimate's views die with the buffers.
        self._reported = np.zeros((self.num_lanes, lmax), dtype=bool)
        self._landmark_means = np.zeros((self.num_lanes, lmax, 3))
        self._batch_estimate: BatchEstimate | None = None

    def _fit_state_slots(self) -> None:
        """Landmark states only where a lane runs SLAM: when every lane localises against a
        known map, x and P shrink to the nv vehicle states (the filter then touches no more
        memory than it needs); a SLAM lane brings the slots back, one per landmark id."""
        want = self.landmark_capacity if not self.state.known.all() else 0
        if want != (self.state_capacity - self.nv) // 3:
            self._allocate(self.landmark_capacity, slots=want)

    def _ensure_ids(self, count: int) -> None:
        """Grow so that ids ``0 … count-1`` fit: at least double the state buffer length."""
        lmax = self.landmark_capacity
        if count <= lmax:
            return
        doubled = -(-(2 * (self.nv + 3 * lmax) - self.nv) // 3)  # ceil
        grown = max(count, doubled)
        self._allocate(grown, slots=0 if self.state.known.all() else grown)

    def reserve_landmarks(self, count: int) -> None:
        """Make room for landmark ids ``0 … count-1`` now (the env calls it at reset, so that
        a map brought by a reset option that cannot fit in memory fails there, not at the
        first scan).

        Raises:
            ValueError: The map would not fit (see :mod:`estimators.memory`).
        """
        self._ensure_ids(count)

    @property
    def landmark_capacity(self) -> int:
        """Lmax: landmark ids (and map slots) currently allocated per lane."""
        return self.state.landmark_capacity

    @property
    def state_capacity(self) -> int:
        """nmax = nv + 3 Lmax, the length of each lane's state buffer."""
        return int(self.state.x.shape[1])

    @property
    def state_dim(self) -> np.ndarray:
        """(B,) int, current size n of each lane's total state x = (s, b, m) (read only)."""
        out = self.state.n.view()
        out.flags.writeable = False
        return out

    @property
    def known_map(self) -> np.ndarray:
        """(B,) bool, lanes localising against a known map (read only)."""
        out = self.state.known.view()
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
            x, P = self.state.x[lane], self.state.P[lane]
            x[:] = 0.0
            P[:] = 0.0
            x[:POSE_DIM] = mean0[j, :POSE_DIM]
            x[6] = wrap_pi(float(x[6]))
            x[8] = wrap_pi(float(x[8]))
            P0 = cov0[j, :POSE_DIM, :POSE_DIM]
            P[:POSE_DIM, :POSE_DIM] = 0.5 * (P0 + P0.T)
            if nv > POSE_DIM:  # the biases, then the wind, start at zero with their priors
                P[POSE_DIM:nv, POSE_DIM:nv] = np.diag(self.settings.initial_extra_variances())
            self.state.clear_lane(lane, nv, UNASSOCIATED)
            self.state.rates[lane] = mean0[j, RATE]
            known = maps[j]
            self.state.known[lane] = known is not None
            if known is not None:
                self.state.known_pos[lane, known[0]] = known[1]
                self.state.mapped[lane, known[0]] = True
        self._fit_state_slots()

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
        (per-sample std held over the sample period) mapped into the state. With
        ``wind: estimate`` the model has the drag and the wind states, and the sample's
        horizontal accelerometer axes then update the lane (:mod:`estimators.ekf.wind`).

        Args:
            t: (B,) sample times in s (unused).
            accel: (B, 3) measured specific force [m/s², B]; only the z column is used (eq. 25)
                unless ``specific_force: full`` (the input) or ``wind: estimate`` (x and y
                are the wind's measurement).
            gyro: (B, 3) measured body rates [rad/s, B].
            accel_sigma: Accelerometer white-noise std per step of ``dt`` (ND/√dt) in m/s².
            gyro_sigma: Gyro white-noise std per step of ``dt`` in rad/s.
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
        sa = accel_sigma * dt if self.settings.imu_noise_in_q else 0.0
        sg = gyro_sigma * dt if self.settings.imu_noise_in_q else 0.0
        if self._drag is not None:
            noise = (float(sa), float(sg), float(dt))
            predict_wind(self.state, self.nv, active, accel, gyro, self._drag, noise,
                         float(accel_sigma) ** 2, self._qc)  # fmt: skip
            return
        predict_lanes(
            self.state.x,
            self.state.P,
            self.state.n,
            self.nv,
            self.state.stale,
            self.state.rates,
            self.state.diag,
            np.ascontiguousarray(active, dtype=bool),
            np.ascontiguousarray(accel, dtype=float),
            np.ascontiguousarray(gyro, dtype=float),
            self.settings.full_specific_force,
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
            t: (B,) scan times in s (the integrity monitor's readmission clock).
            lanes: (k,) int, lanes that scan.
            visible: (B, L) bool, returned landmark ids per lane.
            meas: (B, L, 3) measurements (α rad, β rad, δ m); only visible entries are read.
            sigma: (3,) measurement noise stds (σ_α rad, σ_β rad, σ_δ m).

        Raises:
            ValueError: On a non-finite visible measurement (nothing is changed then).
        """
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
        warmup.wait()
        st = self.state
        update_lanes(
            st.x, st.P, st.n, self.nv, st.stale, st.slot_of_id, st.id_of_slot, st.mapped,
            st.known, st.known_pos, st.diag, lanes, visible, meas, r_diag, self.gate_threshold,
            np.ascontiguousarray(t, dtype=float).reshape(-1),
            *self.monitor_arguments(st.landmark_capacity), st.readmit_at, st.seq_stats,
            st.seq_count,
            self._relinearise, self.settings.max_iterations,
        )  # fmt: skip

    def update_unlabeled(self, *args: Any) -> None:
        """:meth:`UnlabeledScans.update_unlabeled` with first-order updates only: when the
        pairing is itself a guess, a large linearisation error is as often a wrong pairing,
        which the iterated update would follow all the way (docs/ekf-slam.md)."""
        self._relinearise = math.inf
        try:
            super().update_unlabeled(*args)
        finally:
            self._relinearise = self.settings.relinearise_tolerance

    # ------------------------------------------------------------------ output
    def estimate(self) -> BatchEstimate:
        """The belief of every lane as views into the filter's buffers (read, don't keep).

        Returns:
            :class:`BatchEstimate` with ``pose_cov`` (B, 9, 9), ``landmark_means``
            (B, Lmax, 3) by id, ``landmark_mapped`` (B, Lmax) (mapped, or known in known-map
            lanes), the biases when estimated (``accel_bias = (0, 0, b̂_az)``), the wind
            ``(ŵ_N, ŵ_E)`` (B, 2) with ``wind: estimate`` and the diagnostics ``nis`` (NaN
            before a lane's first update), ``nis_dof``, ``n_rejected``, ``n_rejected_last``,
            ``n_updates``, ``n_mapped``, ``diverged`` as (B,) float arrays.
        """
        x = self.state.x
        fill_outputs(
            x,
            self.nv,
            self.state.slot_of_id,
            self.state.mapped,
            self.state.known,
            self.state.known_pos,
            self._vel_inertial,
            self._landmark_means,
        )
        out = self._batch_estimate
        if out is None:  # views stay valid until the buffers are reallocated
            gyro_bias = accel_bias = None
            if self.estimate_imu_bias:
                gyro_bias = x[:, GYRO_BIAS]
                accel_bias = self._accel_bias
            out = BatchEstimate(
                position=x[:, POS],
                vel_body=x[:, VEL],
                vel_inertial=self._vel_inertial,
                euler=x[:, EUL],
                rates=self.state.rates,
                pose_cov=self.state.P[:, :POSE_DIM, :POSE_DIM],
                landmark_means=self._landmark_means,
                landmark_mapped=self._reported,
                accel_bias=accel_bias,
                gyro_bias=gyro_bias,
                diagnostics={k: self.state.diag[i] for i, k in enumerate(DIAGNOSTIC_NAMES)},
                wind=x[:, self.settings.wind_slice] if self._drag is not None else None,
            )
            self._batch_estimate = out
        if self.estimate_imu_bias:
            self._accel_bias[:, 2] = x[:, ACCEL_BIAS_Z]
            if self.settings.bias_dim > BIAS_DIM:
                self._accel_bias[:, :2] = x[:, ACCEL_BIAS_XY]
        np.logical_and(self.state.mapped, ~self.state.tentative, out=self._reported)
        return out

    def lane_estimate(self, lane: int) -> BatchEstimate:
        """Snapshot (B = 1, copies) of one lane's belief.

        Returns:
            :class:`BatchEstimate` of one lane with the pose mean, ``pose_cov`` (9, 9) over
            (ρ, v_B, Λ), ``rates`` = last gyro minus bias estimate, the landmarks by id with
            their covariances (in known-map mode the known map with zero covariance), biases
            when estimated and the diagnostics of :meth:`estimate`.
        """
        x, P, nv = self.state.x[lane], self.state.P[lane], self.nv
        lm_ids = np.flatnonzero(self.state.mapped[lane] & ~self.state.tentative[lane])
        if self.state.known[lane]:
            lm_means = self.state.known_pos[lane, lm_ids]
            lm_covs = np.zeros((lm_ids.shape[0], 3, 3))
        else:
            idx = nv + 3 * self.state.slot_of_id[lane, lm_ids]
            lm_means = x[idx[:, None] + _AR3]
            lm_covs = P[idx[:, None, None] + _AR3[:, None], idx[:, None, None] + _AR3]
        gyro_bias = accel_bias = None
        if self.estimate_imu_bias:
            gyro_bias = x[GYRO_BIAS].copy()
            accel_bias = np.array([0.0, 0.0, x[ACCEL_BIAS_Z]])
            if self.settings.bias_dim > BIAS_DIM:
                accel_bias[:2] = x[ACCEL_BIAS_XY]
        return BatchEstimate.one_lane(
            position=x[POS].copy(),
            vel_body=x[VEL].copy(),
            vel_inertial=dcm_from_euler(x[EUL]) @ x[VEL],
            euler=x[EUL].copy(),
            rates=self.state.rates[lane].copy(),
            pose_cov=P[:POSE_DIM, :POSE_DIM].copy(),
            landmark_ids=lm_ids,
            landmark_means=lm_means,
            landmark_covs=lm_covs,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics={
                k: float(self.state.diag[i, lane]) for i, k in enumerate(DIAGNOSTIC_NAMES)
            },
            wind=x[self.settings.wind_slice].copy() if self._drag is not None else None,
        )
