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

from estimators.fastslam.associate import unlabeled_returns
from estimators.fastslam.gauge import add_gauge_cov, gauge_split, pin_gauge
from estimators.fastslam.landmarks import landmark_init
from estimators.fastslam.lock import LockMonitor
from estimators.fastslam.moments import landmark_mixture, state_moments
from estimators.fastslam.process import perturb_particles, wrap_euler_rows
from estimators.fastslam.progressive import Tempering, scan_update
from estimators.fastslam.resampling import (
    apply_log_likelihood,
    regularisation_bandwidth,
    regularise_pose,
    systematic_resample,
)
from estimators.fastslam.settings import AssociationSettings, FastSlamSettings, scan_noise
from estimators.fastslam.state import ParticleState
from estimators.memory import MemoryTerm, Workload, check_fastslam_map, fastslam_terms
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_angle
from quadslam_env.models.linalg import psd_sqrt
from quadslam_env.types import EUL, MEAS_DIM, POS, POSE_DIM, RATE, STATE_DIM, VEL, FloatArray


class FastSLAMBase:
    """Particles, landmark EKFs, weights, resampling and the estimate (shared machinery).

    Subclasses implement :meth:`_propagate` (motion model) and may override the hooks
    :meth:`_imu_step`, :meth:`_post_predict`, :meth:`_post_update`, :meth:`_resample_extra`.

    Unlabeled scans (``lidar.association: unknown``, ``scan.ids is None``) are associated per
    particle by maximum likelihood (:mod:`.associate`); each particle then has its own map.

    The estimated state is :attr:`state` (:class:`~.state.ParticleState`). The landmark update
    of a labeled scan (:func:`.progressive.scan_update`) and the association of an unlabeled
    one (:meth:`.associate.ParticleMaps.associate`) return each particle's log-likelihood and
    NIS; this class applies them to the weights, the loss-of-lock check and the diagnostics.
    """

    associates_unlabeled: ClassVar[bool] = True
    settings_class: ClassVar[type[FastSlamSettings]] = FastSlamSettings
    """The subclass's ``estimator.params`` (:meth:`memory_terms` validates them)."""

    def __init__(self, settings: FastSlamSettings) -> None:
        self.settings = settings
        """The validated ``estimator.params`` (:mod:`.settings`)."""
        self.n_particles = settings.n_particles
        check_fastslam_map(1, self.n_particles, 0)  # this lane's particles, before _alloc
        self.resample_threshold = settings.resample_threshold
        self.process_noise = settings.noise_density()
        self.integrator = settings.integrator
        self.known_map_sigma = settings.known_map_sigma
        self.likelihood_inflation = settings.likelihood_inflation
        self.roughening = settings.roughening
        self.anchor_gauge = settings.anchor_gauge
        self.regularisation = settings.regularisation
        self.progressive_ess = settings.progressive_ess
        self.nis_divergence = settings.nis_divergence
        self.nis_divergence_s = settings.nis_divergence_s
        self.association = AssociationSettings.of(settings)
        self._rng = np.random.default_rng(0)
        self._alloc()

    @classmethod
    def memory_terms(cls, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
        """The particles and landmark filters of ``load``'s lanes before any is built
        (:func:`estimators.memory.fastslam_terms`), with the particles of ``params``.

        Raises:
            ConfigError: Invalid ``estimator.params``.
            MemoryLimitError: They would not fit in a filter's share.
        """
        return fastslam_terms(load, cls.settings_class.from_dict(params).n_particles)

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
        self.state = ParticleState.empty(n)
        """The estimated state: particles, weights, landmark EKFs, map bookkeeping, gauge."""
        self._scratch = np.empty(n)
        self._bad = np.zeros(n, dtype=bool)
        self._draw = np.empty((n, STATE_DIM))
        self._noise_cache: tuple[float, FloatArray] | None = None
        self.n_resamples = 0
        self.n_progressive_stages = 0
        self.n_divergences = 0
        self._diverged = False
        self._nis = math.nan
        self._nis_dof = 0
        self._lock = LockMonitor(self.n_particles)
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
        s = self.state
        s.known_map = known_landmarks is not None
        n = self.n_particles
        if self.anchor_gauge and known_landmarks is None:
            # SLAM: the initial position and yaw are the gauge (:mod:`.gauge`), kept
            # analytically; the particles start from the prior given the gauge.
            gauge_cov, cov = gauge_split(cov)
            s.gauge = (gauge_cov, mean[POS].copy())
        s.x = mean + rng.standard_normal((n, STATE_DIM)) @ psd_sqrt(cov).T
        wrap_euler_rows(s.x)
        if known_landmarks is not None:
            ids = np.asarray(known_landmarks[0]).astype(int).ravel()
            pts = np.asarray(known_landmarks[1], dtype=float).reshape(-1, 3)
            if ids.shape[0] != pts.shape[0]:
                raise ValueError(
                    f"reset: known_landmarks has {ids.shape[0]} ids but {pts.shape[0]} positions"
                )
            s.slots.add(ids)
            s.mu = np.broadcast_to(pts, (n, *pts.shape)).copy()
            s.sigma = np.broadcast_to(
                self.known_map_sigma**2 * np.eye(3), (n, pts.shape[0], 3, 3)
            ).copy()
        self._reset_extra()

    def _reset_extra(self) -> None:
        """Hook: reset subclass state after the particles are drawn."""

    # ---------------------------------------------------------------- weights
    @property
    def lineage(self) -> np.ndarray:
        """(N,) int index of each particle's ancestor among the particles drawn at reset."""
        return self.state.lineage

    def particle_positions(self) -> FloatArray:
        """(N, 3) particle positions ρ in N, m (a copy; for display)."""
        return self.state.x[:, POS].copy()

    def _apply_loglik(self, loglik: FloatArray, scale: float = 1.0) -> None:
        """``log w ← log w + log p(z | particle) / scale``, normalised; flags divergence (eq. 28).

        Args:
            loglik: (N,) log-likelihoods. scale: Tempering λ ≥ 1 (1 = none).
        """
        s = self.state
        ess = apply_log_likelihood(
            s.logw, np.asarray(loglik, dtype=float), float(scale), self._scratch, s.w
        )
        if ess < 0.0:
            self._diverged = True
            self.n_divergences += 1
            return
        s.ess = float(ess)

    def _maybe_resample(self) -> None:
        if self.state.ess < self.resample_threshold * self.n_particles:
            self._resample(systematic_resample(self.state.w, self._rng))

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
        s, n = self.state, self.n_particles
        if self.roughening > 0.0:
            dev = s.x - s.w @ s.x
            dev[:, EUL] = wrap_angle(dev[:, EUL])
            spread = np.sqrt(np.maximum(s.w @ (dev * dev), 0.0))
            scale = self.roughening * spread * n ** (-1.0 / STATE_DIM)
        if self.regularisation > 0.0:
            h = min(1.0, self.regularisation * regularisation_bandwidth(n, POSE_DIM))
            s.x = regularise_pose(s.x, idx, s.w, h, self._rng)
        else:
            s.x = s.x[idx]
        if self.roughening > 0.0:
            s.x = s.x + self._rng.standard_normal(s.x.shape) * scale
            wrap_euler_rows(s.x)
        s.mu = s.mu[idx]
        s.sigma = s.sigma[idx]
        if s.maps is not None:
            s.maps.resample(idx, s.w)
        self._resample_extra(idx)
        s.lineage = s.lineage[idx]
        s.set_logw(np.full(n, -math.log(n)))
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
        self.state.time += dt
        self._nis = math.nan
        self._nis_dof = 0
        x_new = self._propagate(imu, control, dt)
        self._rng.standard_normal(out=self._draw)
        s = self.state
        n_bad = perturb_particles(x_new, s.x, self._draw, self._noise_scale(dt), self._bad)
        penalty = None
        if n_bad:
            if n_bad == self.n_particles:
                self._diverged = True
                self.n_divergences += 1
                return
            penalty = np.where(self._bad, -np.inf, 0.0)
        x_prev, s.x = s.x, x_new
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
        s = self.state
        if s.maps is not None and not s.known_map:
            raise ValueError(
                "update: a labeled scan after unlabeled ones; a FastSLAM run takes one kind"
            )
        scan_ids = np.asarray(scan.ids).astype(int).ravel()
        meas = np.asarray(scan.meas, dtype=float).reshape(-1, 3)
        if np.unique(scan_ids).size != scan_ids.size:  # repeated id: keep its first return
            _, first = np.unique(scan_ids, return_index=True)
            scan_ids, meas = scan_ids[first], meas[first]
        R = scan_noise(scan.sigma)
        slots = s.slots.of(scan_ids)
        old = slots >= 0
        idx = slots[old]
        if idx.size:
            # Each observed landmark's EKF in every particle, in place (a landmark whose update
            # broke down keeps its prior); a scan far narrower than the cloud first in stages.
            tempering = Tempering(
                self.likelihood_inflation, self.progressive_ess, self.resample_threshold,
                self._resample, self._rng,
            )  # fmt: skip
            result = scan_update(s, idx, meas[old], R, tempering)
            self.n_progressive_stages += result.stages
            self._nis = float(s.w @ result.nis)
            self._nis_dof = MEAS_DIM * int(idx.size)
            self._check_lock(result.nis / self._nis_dof)
            # Tempering (likelihood inflation λ): the weights use p(z | x)^{1/λ}, i.e. the
            # Gaussian with covariance λ·S up to a particle-independent constant; the EKFs
            # above use the true R.
            self._apply_loglik(result.loglik, self.likelihood_inflation / result.remaining)
        if not np.all(old):
            if s.gauge is not None and not s.slots.ids:  # the map is born: pin
                s.gauge = pin_gauge(s.x, s.w, *s.gauge)
            mu0, sig0 = landmark_init(s.x[:, POS], dcm_from_euler_batch(s.x[:, EUL]), meas[~old], R)
            s.mu = np.concatenate([s.mu, mu0], axis=1)
            s.sigma = np.concatenate([s.sigma, sig0], axis=1)
            s.slots.add(scan_ids[~old])
        self._maybe_resample()
        if idx.size:
            self._post_update(idx, meas[old], R)

    def _update_unlabeled(self, scan: LidarScan) -> None:
        """Per-particle ML association of an unlabeled scan, then the weights: each is
        multiplied by the likelihood of the particle's own association (λS, p0 per unpaired
        return; :meth:`.associate.ParticleMaps.associate`). :attr:`last_association` is the
        reported particle's, labeled as in :meth:`estimate`. Stage 2's ρ regeneration is not
        applied (it needs one pairing in all particles).

        Raises:
            ValueError: Malformed returns, or unlabeled scans after labeled ones in SLAM.
        """
        meas, R = unlabeled_returns(scan)
        s = self.state
        maps = s.unlabeled_maps()
        result = maps.associate(
            s.x, s.mu, s.sigma, meas, R, self.association, self.likelihood_inflation
        )
        s.mu, s.sigma = result.mu, result.sigma
        k, dof = meas.shape[0], result.dof
        if k:
            if dof.any():
                self._check_lock(np.where(dof > 0, result.nis / np.maximum(dof, 1), np.nan))
            self._apply_loglik(result.loglik)
        maps.report = best = int(np.argmax(s.w))
        self._nis = float(result.nis[best]) if dof[best] else math.nan
        self._nis_dof = int(dof[best])
        self.last_association = maps.labels(best, k)
        self._maybe_resample()

    def _post_update(self, idx: np.ndarray, meas: FloatArray, R: FloatArray) -> None:
        """Hook run after resampling in :meth:`update` with the mapped observations."""

    def _check_lock(self, nis_per_dof: FloatArray) -> None:
        """One scan's NIS per degree of freedom (N,) to the loss-of-lock check
        (:class:`.lock.LockMonitor`); a lost lock marks this step diverged."""
        t = self.state.time
        if self._lock.check(nis_per_dof, t, self.nis_divergence, self.nis_divergence_s):
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
        s = self.state
        w = s.w
        mean, vel_inertial = np.empty(STATE_DIM), np.empty(3)
        pose_cov = np.empty((POSE_DIM, POSE_DIM))
        state_moments(s.x, w, mean, pose_cov, vel_inertial)
        ids = s.slots.ids_sorted
        n_lm = len(s.slots.ids)
        lm_mean, lm_cov = np.empty((n_lm, 3)), np.empty((n_lm, 3, 3))
        if s.maps is not None and not s.known_map:
            best = s.maps.report
            n_lm = int(s.maps.size[best])
            ids = np.arange(n_lm)
            lm_mean, lm_cov = s.mu[best, :n_lm].copy(), s.sigma[best, :n_lm].copy()
        elif n_lm:
            landmark_mixture(s.mu, s.sigma, w, s.slots.order, lm_mean, lm_cov)
        if s.gauge is not None:  # the SLAM gauge's share (:mod:`.gauge`)
            add_gauge_cov(s.gauge, mean[POS], pose_cov, lm_mean, lm_cov)
        accel_bias, gyro_bias = self._bias_estimate(w)
        diagnostics = {
            "ess": s.ess,
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
