"""Shared particle machinery of the FastSLAM filters (seed 000 §III, Table 2; seed 004 §3).

Particles, per-particle landmark EKFs, log-weights, resampling, the NIS loss-of-lock check and
the estimate. Subclasses supply the motion model and the IMU step. The per-particle loops are
numba kernels (:mod:`.process`, :mod:`.resampling`, :mod:`.landmarks`, :mod:`.moments`); the
normalised weights and the ESS are kept in step with the log-weights, so each is computed once
per change.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from estimators.fastslam.associate import ParticleMaps, update_unlabeled
from estimators.fastslam.gauge import add_gauge_cov, gauge_split, pin_gauge
from estimators.fastslam.landmarks import landmark_init
from estimators.fastslam.lock import LockMonitor
from estimators.fastslam.moments import landmark_mixture, state_moments
from estimators.fastslam.process import perturb_particles, wrap_euler_rows
from estimators.fastslam.progressive import scan_update
from estimators.fastslam.resampling import (
    apply_log_likelihood,
    ess_of,
    regularisation_bandwidth,
    regularise_pose,
    systematic_resample,
)
from estimators.fastslam.settings import (
    FLOAT,
    OWNER,
    SIGMA_FLOOR,
    VECTOR,
    AssociationSettings,
    fail,
    fraction,
    parse_process_noise,
    positive,
)
from estimators.memory import check_fastslam_map
from estimators.settings_check import check_kwargs
from quadslam_env.estimation import BatchEstimate
from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_angle
from quadslam_env.models.linalg import psd_sqrt
from quadslam_env.types import EUL, MEAS_DIM, POS, POSE_DIM, RATE, STATE_DIM, VEL, FloatArray


class FastSLAMBase:
    """Particles, landmark EKFs, weights, resampling and the estimate (shared machinery).

    Subclasses implement :meth:`_propagate` (motion model) and may override the hooks
    :meth:`_imu_step`, :meth:`_post_predict`, :meth:`_post_update`, :meth:`_resample_extra`.

    Unlabeled scans (``lidar.association: unknown``, ``scan.ids is None``) are associated per
    particle by maximum likelihood (:mod:`.associate`); each particle then has its own map.
    """

    associates_unlabeled: ClassVar[bool] = True

    _COMMON: ClassVar[dict[str, type | tuple[type, ...]]] = {
        "n_particles": int,
        "resample_threshold": FLOAT,
        "process_noise": VECTOR,
        "integrator": str,
        "known_map_sigma": FLOAT,
        "likelihood_inflation": FLOAT,
        "roughening": FLOAT,
        "anchor_gauge": bool,
        "regularisation": FLOAT,
        "progressive_ess": FLOAT,
        "nis_divergence": FLOAT,
        "nis_divergence_s": FLOAT,
        "gate_probability": FLOAT,
        "new_landmark_likelihood": FLOAT,
        "confirm_hits": int,
        "confirm_window": int,
    }
    _DEFAULT_NOISE: ClassVar[tuple[float, float, float, float]] = (0.0, 0.0, 0.0, 0.0)
    _DEFAULT_INFLATION: ClassVar[float] = 1.0
    _DEFAULT_ROUGHENING: ClassVar[float] = 0.0

    def __init__(self, params: dict[str, Any], extra: dict[str, type | tuple[type, ...]]) -> None:
        allowed = {**self._COMMON, **extra}
        check_kwargs(OWNER, params, allowed)
        self.n_particles = int(params.get("n_particles", 500))
        if self.n_particles < 1:
            raise fail("n_particles", self.n_particles, "an int >= 1")
        check_fastslam_map(1, self.n_particles, 0)  # this lane's particles, before _alloc
        self.resample_threshold = fraction(
            "resample_threshold", params.get("resample_threshold", 0.5)
        )
        self.process_noise = parse_process_noise(
            "process_noise", params.get("process_noise", self._DEFAULT_NOISE)
        )
        self.integrator = params.get("integrator", "rk4")
        if self.integrator not in ("rk4", "euler"):
            raise fail("integrator", self.integrator, "'rk4' or 'euler'")
        self.known_map_sigma = positive("known_map_sigma", params.get("known_map_sigma", 1e-3))
        self.likelihood_inflation = positive(
            "likelihood_inflation", params.get("likelihood_inflation", self._DEFAULT_INFLATION)
        )
        if self.likelihood_inflation < 1.0:
            raise fail(
                "likelihood_inflation", params["likelihood_inflation"], "a finite number >= 1"
            )
        self.roughening = positive(
            "roughening", params.get("roughening", self._DEFAULT_ROUGHENING), strict=False
        )
        self.anchor_gauge = bool(params.get("anchor_gauge", True))
        self.regularisation = positive(
            "regularisation", params.get("regularisation", 1.0), strict=False
        )
        self.progressive_ess = fraction("progressive_ess", params.get("progressive_ess", 0.1))
        self.nis_divergence = positive(
            "nis_divergence", params.get("nis_divergence", 1000.0), strict=False
        )
        self.nis_divergence_s = positive(
            "nis_divergence_s", params.get("nis_divergence_s", 2.0), strict=False
        )
        self.association = AssociationSettings.from_params(params)
        self._rng = np.random.default_rng(0)
        self._alloc()

    # ---------------------------------------------------------------- state
    def check_memory(self, num_lanes: int, landmark_capacity: int) -> None:
        """Reject, before the other lanes are built, particles and landmark filters for
        ``landmark_capacity`` landmarks on ``num_lanes`` lanes that would not fit in memory
        (:func:`estimators.memory.check_fastslam_map`).

        Raises:
            ValueError: Names the sizes and what would fit.
        """
        check_fastslam_map(num_lanes, self.n_particles, landmark_capacity)

    def _alloc(self) -> None:
        n = self.n_particles
        self.x = np.zeros((n, STATE_DIM))
        self._w = np.empty(n)  # exp(logw), kept in step with the log-weights
        self._scratch = np.empty(n)
        self._loglik = np.empty(n)
        self._nis_sum = np.empty(n)
        self._bad = np.zeros(n, dtype=bool)
        self._draw = np.empty((n, STATE_DIM))
        self._noise_cache: tuple[float, FloatArray] | None = None
        self.logw = np.full(n, -math.log(n))
        self.mu = np.zeros((n, 0, 3))
        self.sigma = np.zeros((n, 0, 3, 3))
        self._slot: dict[int, int] = {}
        self._slot_ids: list[int] = []
        self._ids_sorted = np.zeros(0, dtype=int)
        self._order = np.zeros(0, dtype=int)
        self.n_resamples = 0
        self.n_progressive_stages = 0
        self.lineage = np.arange(n)
        """(N,) index of each particle's ancestor among the particles drawn at reset."""
        self.n_divergences = 0
        self._diverged = False
        self._nis = math.nan
        self._nis_dof = 0
        self._time = 0.0
        self._lock = LockMonitor(self.n_particles)
        self._known_map = False
        self._maps: ParticleMaps | None = None  # per-particle maps (unlabeled scans)
        self._gauge: tuple[FloatArray, FloatArray] | None = None  # (G (4, 4), anchor ρ_a (3,))
        self.last_association = np.zeros(0, dtype=np.int64)
        """(k,) label of each return of the last unlabeled scan in the reported map (-1)."""

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Draw N particles from ``N(mean0, cov0)`` and clear the map.

        Args:
            mean0: (12,) initial state mean ``(ρ, v_B, Λ, ω)``.
            cov0: (12, 12) initial covariance (PSD; singular allowed).
            rng: The only source of randomness of this estimator.
            known_landmarks: Optional ``(ids (L,), positions (L, 3))``: the landmarks start
                mapped at these positions with covariance ``known_map_sigma² I`` in every
                particle (known-map mode); they are still EKF-updated (negligibly).

        Raises:
            ValueError: On wrong shapes or non-finite values.
        """
        mean = np.asarray(mean0, dtype=float)
        cov = np.asarray(cov0, dtype=float)
        if mean.shape != (STATE_DIM,) or not np.all(np.isfinite(mean)):
            raise ValueError(f"reset: mean0 must be a finite (12,) array, got shape {mean.shape}")
        if cov.shape != (STATE_DIM, STATE_DIM) or not np.all(np.isfinite(cov)):
            raise ValueError(f"reset: cov0 must be a finite (12, 12) array, got shape {cov.shape}")
        self._rng = rng
        self._alloc()
        self._known_map = known_landmarks is not None
        n = self.n_particles
        if self.anchor_gauge and known_landmarks is None:
            # SLAM: the initial position and yaw are the gauge (:mod:`.gauge`), kept
            # analytically; the particles start from the prior given the gauge.
            gauge_cov, cov = gauge_split(cov)
            self._gauge = (gauge_cov, mean[POS].copy())
        self.x = mean + rng.standard_normal((n, STATE_DIM)) @ psd_sqrt(cov).T
        wrap_euler_rows(self.x)
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(int).ravel()
            pts = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            if ids.shape[0] != pts.shape[0]:
                raise ValueError(
                    f"reset: known_landmarks has {ids.shape[0]} ids but {pts.shape[0]} positions"
                )
            self._add_slots(ids)
            self.mu = np.broadcast_to(pts, (n, *pts.shape)).copy()
            self.sigma = np.broadcast_to(
                self.known_map_sigma**2 * np.eye(3), (n, pts.shape[0], 3, 3)
            ).copy()
        self._reset_extra()

    def _reset_extra(self) -> None:
        """Hook: reset subclass state after the particles are drawn."""

    def _add_slots(self, ids: np.ndarray) -> None:
        for lid in ids.tolist():
            self._slot[int(lid)] = len(self._slot_ids)
            self._slot_ids.append(int(lid))
        ids_all = np.array(self._slot_ids, dtype=int)
        self._order = np.argsort(ids_all, kind="stable")
        self._ids_sorted = ids_all[self._order]

    # ---------------------------------------------------------------- weights
    @property
    def logw(self) -> FloatArray:
        """(N,) normalised log-weights (assigning new ones updates the weights and the ESS)."""
        return self._logw

    @logw.setter
    def logw(self, value: FloatArray) -> None:
        self._logw = np.array(value, dtype=float).reshape(self.n_particles)
        np.exp(self._logw, out=self._w)
        self._ess = float(ess_of(self._w))

    @property
    def weights(self) -> FloatArray:
        """(N,) normalised weights ``exp(logw)`` (a copy)."""
        return self._w.copy()

    def particle_positions(self) -> FloatArray:
        """(N, 3) particle positions ρ in N, m (a copy; for display)."""
        return self.x[:, POS].copy()

    def _apply_loglik(self, loglik: FloatArray, scale: float = 1.0) -> None:
        """``log w ← log w + log p(z | particle) / scale``, normalised; flags divergence (eq. 28).

        Args:
            loglik: (N,) log-likelihoods. scale: Tempering λ ≥ 1 (1 = none).
        """
        ess = apply_log_likelihood(
            self._logw, np.asarray(loglik, dtype=float), float(scale), self._scratch, self._w
        )
        if ess < 0.0:
            self._diverged = True
            self.n_divergences += 1
            return
        self._ess = float(ess)

    def _maybe_resample(self) -> None:
        if self._ess < self.resample_threshold * self.n_particles:
            self._resample(systematic_resample(self._w, self._rng))

    def _resample(self, idx: np.ndarray) -> None:
        """Copy the selected particles (fancy indexing: fresh arrays, no shared views).

        With ``roughening = K > 0`` every copied vehicle state is then jittered (Gordon et al.
        1993 "roughening", the standard remedy for sample impoverishment after SIR resampling,
        cf. seed 004 §3 on degeneracy/impoverishment): state j gets ``N(0, σ_j²)`` with
        ``σ_j = K E_j N^{−1/d}``, ``E_j`` the weighted standard deviation of state j *before*
        resampling and d = 12. The jitter scales with the current spread, so it re-diversifies
        the duplicates without adding a fixed noise floor; landmark EKFs are not jittered.

        With ``regularisation = c > 0`` the copies' poses ``(ρ, v_B, Λ)`` are moved by the shrunk
        kernel of :func:`.resampling.regularise_pose` (bandwidth ``min(1, c·h_opt)``, d = 9).
        """
        if self.roughening > 0.0:
            w = self._w
            mean = w @ self.x
            dev = self.x - mean
            dev[:, EUL] = wrap_angle(dev[:, EUL])
            spread = np.sqrt(np.maximum(w @ (dev * dev), 0.0))
            scale = self.roughening * spread * self.n_particles ** (-1.0 / STATE_DIM)
        if self.regularisation > 0.0:
            h = min(1.0, self.regularisation * regularisation_bandwidth(self.n_particles, POSE_DIM))
            self.x = regularise_pose(self.x, idx, self._w, h, self._rng)
        else:
            self.x = self.x[idx]
        if self.roughening > 0.0:
            self.x = self.x + self._rng.standard_normal(self.x.shape) * scale
            wrap_euler_rows(self.x)
        self.mu = self.mu[idx]
        self.sigma = self.sigma[idx]
        if self._maps is not None:
            self._maps.resample(idx, self._w)
        self._resample_extra(idx)
        self.lineage = self.lineage[idx]
        self.logw = np.full(self.n_particles, -math.log(self.n_particles))
        self.n_resamples += 1

    def _resample_extra(self, idx: np.ndarray) -> None:
        """Hook: resample per-particle subclass arrays."""

    # ---------------------------------------------------------------- predict
    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Table 2 steps 1–4 and 6 for one IMU/control period of ``dt`` s.

        Propagates every particle, runs the subclass IMU step (bias KF and IMU likelihood for
        the dynamic filter), resamples if the ESS fell below the threshold, then applies the
        stage-2 hook.
        """
        dt = float(dt)
        if not (math.isfinite(dt) and dt > 0.0):
            raise ValueError(f"predict: dt must be a finite number > 0, got {dt!r}")
        self._diverged = self._lock.lost
        self._time += dt
        self._nis = math.nan
        self._nis_dof = 0
        x_new = self._propagate(imu, control, dt)
        self._rng.standard_normal(out=self._draw)
        n_bad = perturb_particles(x_new, self.x, self._draw, self._noise_scale(dt), self._bad)
        penalty = None
        if n_bad:
            if n_bad == self.n_particles:
                self._diverged = True
                self.n_divergences += 1
                return
            penalty = np.where(self._bad, -np.inf, 0.0)
        x_prev, self.x = self.x, x_new
        loglik = self._imu_step(imu, control, dt, x_prev)
        if penalty is not None:
            loglik = penalty if loglik is None else loglik + penalty
        if loglik is not None:
            self._apply_loglik(loglik)
        self._maybe_resample()
        self._post_predict(imu)

    def _noise_scale(self, dt: float) -> FloatArray:
        """(12,) process-noise std over ``dt`` s: density × √dt (cached for the last dt)."""
        if self._noise_cache is None or self._noise_cache[0] != dt:
            self._noise_cache = (dt, self.process_noise * math.sqrt(dt))
        return self._noise_cache[1]

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        """Motion model without process noise: (N, 12) new states (a fresh array)."""
        raise NotImplementedError

    def _imu_step(
        self, imu: ImuSample, control: Control, dt: float, x_prev: FloatArray
    ) -> FloatArray | None:
        """Hook: IMU log-likelihood (N,) after propagation (``x_prev`` (N, 12): the particles
        before it), or ``None`` for no weighting."""
        return None

    def _post_predict(self, imu: ImuSample) -> None:
        """Hook run after resampling in :meth:`predict` (stage 2)."""

    # ---------------------------------------------------------------- update
    def update(self, scan: LidarScan) -> None:
        """Weight with the LiDAR likelihood, update/initialise landmark EKFs, resample.

        Table 2 steps 3, 5, 6 (and the stage-2 hook) for one scan; an empty labeled scan is
        a no-op. An unlabeled scan (``scan.ids is None``) goes to :meth:`_update_unlabeled`;
        a run takes labeled or unlabeled scans, not both (known-map runs excepted).

        Raises:
            ValueError: A malformed unlabeled scan, or labeled and unlabeled scans mixed.
        """
        if scan.ids is None:
            self._update_unlabeled(scan)
            return
        if scan.count == 0:
            return
        if self._maps is not None and not self._known_map:
            raise ValueError(
                "update: a labeled scan after unlabeled ones; a FastSLAM run takes one kind"
            )
        scan_ids = np.asarray(scan.ids).astype(int).ravel()
        meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3)
        if np.unique(scan_ids).size != scan_ids.size:  # repeated id: keep its first return
            _, first = np.unique(scan_ids, return_index=True)
            scan_ids, meas = scan_ids[first], meas[first]
        sig = np.maximum(np.asarray(scan.sigma, dtype=float).reshape(3), SIGMA_FLOOR)
        R = np.diag(sig * sig)
        slots = np.array([self._slot.get(i, -1) for i in scan_ids.tolist()])
        old = slots >= 0
        idx = slots[old]
        if idx.size:
            # Each observed landmark's EKF in every particle, in place (a landmark whose update
            # broke down keeps its prior); a scan far narrower than the cloud first in stages.
            nis = self._nis_sum
            remaining = scan_update(self, idx, meas[old], R)
            self._nis = float(self._w @ nis)
            self._nis_dof = MEAS_DIM * int(idx.size)
            self._check_lock(nis / self._nis_dof)
            # Tempering (likelihood inflation λ): the weights use p(z | x)^{1/λ}, i.e. the
            # Gaussian with covariance λ·S up to a particle-independent constant; the EKFs
            # above use the true R.
            self._apply_loglik(self._loglik, self.likelihood_inflation / remaining)
        if not np.all(old):
            if self._gauge is not None and not self._slot_ids:  # the map is born: pin
                self._gauge = pin_gauge(self.x, self._w, *self._gauge)
            new_ids = scan_ids[~old]
            pos = self.x[:, POS]
            dcm = dcm_from_euler_batch(self.x[:, EUL])
            mu0, sig0 = landmark_init(pos, dcm, meas[~old], R)
            self.mu = np.concatenate([self.mu, mu0], axis=1)
            self.sigma = np.concatenate([self.sigma, sig0], axis=1)
            self._add_slots(new_ids)
        self._maybe_resample()
        if idx.size:
            self._post_update(idx, meas[old], R)

    def _update_unlabeled(self, scan: LidarScan) -> None:
        """An unlabeled scan: :func:`.associate.update_unlabeled`."""
        update_unlabeled(self, scan)

    def _post_update(self, idx: np.ndarray, meas: FloatArray, R: FloatArray) -> None:
        """Hook run after resampling in :meth:`update` with the mapped observations."""

    def _check_lock(self, nis_per_dof: FloatArray) -> None:
        """One scan's NIS per degree of freedom (N,) to the loss-of-lock check
        (:class:`.lock.LockMonitor`); a lost lock marks this step diverged."""
        if self._lock.check(nis_per_dof, self._time, self.nis_divergence, self.nis_divergence_s):
            self.n_divergences += 1
        self._diverged = self._diverged or self._lock.lost

    # ---------------------------------------------------------------- estimate
    def _bias_estimate(self, w: FloatArray) -> tuple[FloatArray | None, FloatArray | None]:
        return None, None

    def _extra_diagnostics(self) -> dict[str, float]:
        """Hook: subclass diagnostics added to :attr:`BatchEstimate.diagnostics`."""
        return {}

    def estimate(self) -> BatchEstimate:
        """Weighted particle mean and covariance, and the map (a snapshot with B = 1).

        Euler angles use the weighted circular mean; the (9, 9) pose covariance of
        ``(ρ, v_B, Λ)`` uses wrapped angle deviations. With labels shared by all particles
        (known association, or a known map) the map is the mixture over the particles, with
        covariances ``Σ_i w_i (Σ^i + (μ^i − μ̄)(μ^i − μ̄)ᵀ)``; under unknown association in
        SLAM every particle has its own map, and the map of the reported particle (the
        highest-weight one after the last scan) is given, labeled by its slots ``0, 1, …``.
        """
        w = self._w
        mean, vel_inertial = np.empty(STATE_DIM), np.empty(3)
        pose_cov = np.empty((POSE_DIM, POSE_DIM))
        state_moments(self.x, w, mean, pose_cov, vel_inertial)
        ids = self._ids_sorted
        n_lm = len(self._slot_ids)
        lm_mean, lm_cov = np.empty((n_lm, 3)), np.empty((n_lm, 3, 3))
        if self._maps is not None and not self._known_map:
            best = self._maps.report
            n_lm = int(self._maps.size[best])
            ids = np.arange(n_lm)
            lm_mean, lm_cov = self.mu[best, :n_lm].copy(), self.sigma[best, :n_lm].copy()
        elif n_lm:
            landmark_mixture(self.mu, self.sigma, w, self._order, lm_mean, lm_cov)
        if self._gauge is not None:  # the SLAM gauge's share (:mod:`.gauge`)
            add_gauge_cov(self._gauge, mean[POS], pose_cov, lm_mean, lm_cov)
        accel_bias, gyro_bias = self._bias_estimate(w)
        diagnostics = {
            "ess": self._ess,
            "n_resamples": float(self.n_resamples),
            "n_progressive_stages": float(self.n_progressive_stages),
            "nis": self._nis,
            "nis_dof": float(self._nis_dof),
            "diverged": 1.0 if (self._diverged or self._lock.lost) else 0.0,
            "best_nis_per_dof": self._lock.best_nis,
            "n_divergences": float(self.n_divergences),
            **self._extra_diagnostics(),
        }
        return BatchEstimate.one_lane(
            position=mean[POS],  # views of this call's fresh array
            vel_body=mean[VEL],
            vel_inertial=vel_inertial,
            euler=mean[EUL],
            rates=mean[RATE],
            pose_cov=pose_cov,
            landmark_ids=ids,
            landmark_means=lm_mean,
            landmark_covs=lm_cov,
            accel_bias=accel_bias,
            gyro_bias=gyro_bias,
            diagnostics=diagnostics,
        )
