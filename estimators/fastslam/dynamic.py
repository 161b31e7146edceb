"""Seed 000's self-calibrating, dynamics-based FastSLAM (``fastslam``, Table 2)."""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np

from estimators.fastslam.bias_kf import (
    BIAS_DIM,
    H_BIAS,
    bias_transition,
    imu_bias_step,
)
from estimators.fastslam.landmarks import inverse_model_cov, offset_in_inertial
from estimators.fastslam.moments import weighted_mean
from estimators.fastslam.particles import FastSLAMBase
from estimators.fastslam.process import DynamicsModel
from estimators.fastslam.settings import SIGMA_FLOOR, DynamicFastSlamSettings
from estimators.fastslam.state import BiasKFState
from estimators.inertia import GyroTorqueRegression
from quadslam_env.estimation.measurements import Control, ImuSample
from quadslam_env.estimation.registry import register
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.models.linalg import chol3, inv3_sym, mv
from quadslam_env.models.params import VehicleParams
from quadslam_env.models.rigid_body import NO_AIR, AirTuple
from quadslam_env.schema import ConfigError
from quadslam_env.types import EUL, POS, RATE, FloatArray


@register("fastslam")
class DynamicFastSLAM(FastSLAMBase):
    """Dynamics-based FastSLAM with joint IMU bias/drift estimation (seed 000 Table 2).

    Its model is the vehicle's (mass, inertia, drag): :meth:`set_vehicle` replaces the vehicle
    (``randomize.inform_estimator``) and :meth:`set_wind` gives the drag a known wind
    (``wind.inform_estimator``; ``models_drag``).

    Parameters: ``estimator.params``, validated by :class:`~.settings.DynamicFastSlamSettings`
    (unknown keys, wrong types or out-of-range values raise a ``ConfigError`` naming the key);
    the docs' generated ``estimator.params`` table of ``fastslam`` lists every key.

    Unknown data association (``lidar.association: unknown``, :mod:`.associate`): every
    particle associates the unlabeled returns with its own landmarks by maximum likelihood
    and keeps its own map; returns no landmark explains become tentative landmarks, mapped
    after M sightings in N scans.

    Robustness tuning (paper_fastslam_helix, DF-LQR on the estimate, 4 poles, VLP-16 noise
    3 cm / 0.1°, N = 500, seeds 0–9, 30 s): with the raw FastSLAM 1.0 weight the LiDAR
    likelihood is far narrower than the particle cloud, the weights collapse onto a few
    particles each scan, position σ collapses to millimetres and ~half the seeds lose lock
    (seed 004 §3: degeneracy / sample impoverishment of SIR). Tempering the LiDAR weight with
    λ = 30 (the per-particle NIS ~ 3 then costs ~0.05 in log-weight, so ESS stays high and
    resampling is rare) keeps lock on 10/10 seeds (position RMSE median 0.05 m vs 0.09 m and
    3/10 lost at λ = 30 with the old noise; λ = 10, 100 worse). A larger attitude noise
    (0.003 rad/√s) lets particles absorb attitude errors the LiDAR reveals. Roughening
    (K = 0.2) together with λ = 10 was worse and is off by default; larger velocity noise (0.3)
    was worse.

    Gyro-bias identification (same runs): the gyro pins each particle's ``ω^i + b̂_ω^i`` to
    ``ω_m``; what separates ω from the bias is the dynamics, which predict ω from the applied
    torque *given the initial ω*. An ω offset is not damped by the dynamics and is otherwise
    seen only through its integral, the attitude, by the LiDAR. So the bias is identified
    only if (a) the initial ω is known — the helix scenarios start at rest with a 1e-4 rad/s
    ω prior — and (b) the ω process noise is small enough that ω does not random-walk away
    from the dynamics: a density q_ω wanders by q_ω √T, i.e. 1e-3 rad/s in 30 s at the old
    2e-4. Measured gyro-bias error (median of 10 seeds, biases 0.005): 35 % with a 1e-3 rad/s
    ω prior and q_ω = 2e-4; 17 % with the 1e-4 prior and q_ω = 2e-4; 4–6 % with the 1e-4 prior
    and q_ω ∈ [1e-5, 5e-5] (default 2e-5), at unchanged position accuracy.

    Model mismatch (``inertia_scale=2.5``, seed 000 Fig. 14; measured in docs/reproducing.md).
    With a fixed model the dynamics predict ω wrongly during the controller's initial transient, the
    gyro-bias KF absorbs that model error as "bias" while its prior is still wide, and the
    ω/bias split is never undone; the IMU likelihood, computed through the wrong model, then
    favours the wrong particles (0.26 m median, 2/10 seeds lost; 0.074 m with LiDAR-only
    weights, the gyro bias still wrong). Seed 000 §IV names online inertia estimation as the
    remedy; ``estimate_inertia`` (on by default) implements it: the inertia is identified to
    ~1 % within about a second of flight, and under mismatch the filter keeps lock on every
    seed with the paper's full IMU × LiDAR weights (0.067 vs 0.053 m median for the matched
    model).

    * Stage 2's ω regeneration makes the next KF innovation independent of the bias
      (``ω_m,k+1 − ω^i_{k+1} − b̂`` is pure noise once ``ω^i_k = ω_m,k − b̂``), so the bias is
      then learnt only through resampling. Stage 2's ρ regeneration replaces the dynamic
      position by a LiDAR fix and can leave the velocity uncorrected (large velocity errors
      in some runs); ``stage2_position=False`` keeps only the ω part. Measured on the helix
      at biases 0.005: both variants end every run early (attitude errors 6–8°), so stage 2
      is off by default.
    * Consistency (docs/filter-consistency.md, "FastSLAM consistency"): resampling makes one initial
      particle the ancestor of all within seconds, so the unobservable initial position and yaw
      (the SLAM gauge) left the particle spread while the error kept it (pose ANEES 53.9 at
      N = 500). ``anchor_gauge`` keeps the gauge out of the particles and adds it analytically
      (:mod:`.gauge`); ``regularisation`` keeps the cloud's spread through resampling and
      ``progressive_ess`` lets a scan far narrower than the cloud (after landmarks were out of
      view) be absorbed in stages (:mod:`.progressive`). Pose ANEES now 8.2 (seeds 0–9).

    Args:
        vehicle: Nominal vehicle parameters given by the env (required).
        **params: ``estimator.params`` (:class:`~.settings.DynamicFastSlamSettings`).

    Raises:
        ValueError: If ``vehicle`` is missing or a setting is invalid (``ConfigError``).
    """

    models_drag: ClassVar[bool] = True
    settings_class = DynamicFastSlamSettings

    def __init__(self, vehicle: VehicleParams | None = None, **params: Any) -> None:
        if vehicle is None:
            raise ValueError(
                "estimator 'fastslam' needs the nominal vehicle parameters: pass "
                "vehicle=VehicleParams (the env does this from its vehicle config)"
            )
        if not isinstance(vehicle, VehicleParams):
            raise ValueError(
                f"estimator 'fastslam': vehicle must be a VehicleParams, got {vehicle!r}"
            )
        settings = DynamicFastSlamSettings.from_dict(params)
        super().__init__(settings)
        self.bias_tau_s = settings.bias_tau_s
        self.accel_drift_sigma = settings.accel_drift_sigma
        self.gyro_drift_sigma = settings.gyro_drift_sigma
        self.accel_bias_sigma = settings.accel_bias_sigma
        self.gyro_bias_sigma = settings.gyro_bias_sigma
        self._scales = (settings.mass_scale, settings.inertia_scale)
        self.use_imu_likelihood = settings.use_imu_likelihood
        self.stage2 = settings.stage2
        self.stage2_position = settings.stage2_position
        self._estimate_inertia = settings.estimate_inertia
        self._inertia_rel_sigma = settings.inertia_prior_rel_sigma
        self._use_vehicle(vehicle)
        self._air: AirTuple | None = None  # a known wind (set_wind), else still air
        self._bias_cache: tuple[float, FloatArray, FloatArray] | None = None
        self._imu_R: tuple[float, float, FloatArray] | None = None
        m, n = H_BIAS.shape  # imu_bias_step's K, L, their sparsity and the innovations
        self._kf_buffers = (
            np.empty((n, m)),
            np.empty((m, m)),
            np.empty((n, m), dtype=np.int64),
            np.empty(n, dtype=np.int64),
            np.empty((m, m), dtype=np.int64),
            np.empty(m, dtype=np.int64),
            np.empty((self.n_particles, m)),
        )
        self._bias_mean = np.empty(BIAS_DIM)
        self._imu_loglik = np.empty(self.n_particles)  # the IMU step's (N,) log-likelihoods
        self._reset_extra()

    def _use_vehicle(self, vehicle: VehicleParams) -> None:
        """Build everything taken from the vehicle: the dynamics model (mass and inertia times
        ``mass_scale`` and ``inertia_scale``, the drag) and the inertia identification's prior.

        Raises:
            ValueError: ``estimate_inertia`` with products of inertia.
        """
        mass_scale, inertia_scale = self._scales
        self.vehicle = vehicle
        self.model = DynamicsModel(vehicle, mass_scale=mass_scale, inertia_scale=inertia_scale)
        self._inertia0 = np.diag(self.model.inertia).copy()
        diagonal = bool(np.allclose(self.model.inertia, np.diag(self._inertia0)))
        wanted = self._estimate_inertia
        self.estimate_inertia = diagonal if wanted is None else bool(wanted)
        if self.estimate_inertia and not diagonal:
            raise ConfigError(
                "estimator.params.estimate_inertia: got True; allowed: false or null for a "
                "vehicle whose inertia has products of inertia (the identification models "
                "principal moments only)"
            )
        self.inertia_id = GyroTorqueRegression(
            self._inertia0,
            self._inertia_rel_sigma,
            bias_sigma=math.hypot(self.gyro_bias_sigma, self.gyro_drift_sigma),
            # Random walk with the Gauss–Markov drift's short-term variance growth 2σ²/τ.
            bias_rate_sigma=self.gyro_drift_sigma * math.sqrt(2.0 / self.bias_tau_s),
        )

    def set_vehicle(self, vehicle: VehicleParams) -> None:
        """Model ``vehicle`` from now on; the env calls it just before a :meth:`reset`
        (:class:`~quadslam_env.estimation.protocol.UsesVehicle`; ``randomize.inform_estimator``).
        The model's mass, inertia and drag and the inertia identification's prior are rebuilt
        from it (times ``mass_scale`` and ``inertia_scale``); the same object is a no-op.

        Raises:
            ValueError: Not a :class:`VehicleParams`, or ``estimate_inertia`` with products of
                inertia.
        """
        if not isinstance(vehicle, VehicleParams):
            raise ValueError(
                f"estimator 'fastslam': vehicle must be a VehicleParams, got {vehicle!r}"
            )
        if vehicle is not self.vehicle:
            self._use_vehicle(vehicle)

    def set_wind(self, wind: FloatArray) -> None:
        """Fly the model in the known wind ``wind`` (3,) N, m/s over the next predictions
        (:class:`~quadslam_env.estimation.protocol.ModelsDrag`; ``wind.inform_estimator``): the
        drag of the dynamics and of the IMU model acts on the air-relative velocity, with the
        vehicle's quadratic drag, as in the simulator."""
        w = np.asarray(wind, dtype=float).reshape(3)
        if not np.isfinite(w).all():
            raise ValueError(f"estimator 'fastslam': wind must be 3 finite numbers, got {wind!r}")
        cq = self.vehicle.drag_quadratic
        wn, we, wd = (float(v) for v in w)
        self._air = (wn, we, wd, float(cq[0]), float(cq[1]), float(cq[2]))

    def _reset_extra(self) -> None:
        self.inertia_id.reset()
        self.model.set_inertia(self._inertia0)
        self.bias = BiasKFState(
            xb=np.zeros((self.n_particles, BIAS_DIM)),
            P=np.diag(
                np.r_[
                    np.full(3, self.accel_bias_sigma**2),
                    np.full(3, self.gyro_bias_sigma**2),
                    np.full(3, self.accel_drift_sigma**2),
                    np.full(3, self.gyro_drift_sigma**2),
                ]
            ),
        )
        """The particles' IMU bias Kalman filter (means and the shared covariance)."""

    def _resample_extra(self, idx: np.ndarray) -> None:
        self.bias.xb = self.bias.xb[idx]

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        torque = np.asarray(control.torque, dtype=float).reshape(3)
        return self.model.propagate(
            self.state.x, float(control.thrust), torque, dt, method=self.integrator, air=self._air
        )

    def _transition(self, dt: float) -> tuple[FloatArray, FloatArray]:
        """The diagonal ``a`` (12,) of A and Q (12, 12) over ``dt`` s (cached for the last dt)."""
        if self._bias_cache is None or self._bias_cache[0] != dt:
            A, Q = bias_transition(
                dt, self.bias_tau_s, self.accel_drift_sigma, self.gyro_drift_sigma
            )
            self._bias_cache = (dt, np.diag(A).copy(), Q)
        return self._bias_cache[1], self._bias_cache[2]

    def _imu_noise(self, imu: ImuSample) -> FloatArray:
        """(6, 6) IMU noise covariance ``R^I`` (cached for the last pair of σ)."""
        sa = max(float(imu.accel_sigma), SIGMA_FLOOR)
        sg = max(float(imu.gyro_sigma), SIGMA_FLOOR)
        if self._imu_R is None or self._imu_R[:2] != (sa, sg):
            self._imu_R = (sa, sg, np.diag([sa * sa] * 3 + [sg * sg] * 3))
        return self._imu_R[2]

    def _imu_step(
        self, imu: ImuSample, control: Control, dt: float, x_prev: FloatArray
    ) -> FloatArray | None:
        """Table 2 steps 2–4: bias KF predict, IMU likelihood (eq. 26), bias KF update.

        One kernel (:func:`~estimators.fastslam.bias_kf.imu_bias_step`): the shared covariance
        is predicted and updated once, then every particle's bias mean is predicted, compared
        with the IMU (``z − h^d(x^{D,i}) − H x̂^B``) and updated.
        """
        if self.estimate_inertia:
            self._identify_inertia(imu, control, dt)
        a, Q = self._transition(dt)
        model = self.model
        loglik = self._imu_loglik
        imu_bias_step(
            self.state.x,
            x_prev,
            self.bias.xb,
            self.bias.P,
            a,
            Q,
            self._imu_noise(imu),
            np.asarray(imu.accel, dtype=float),
            np.asarray(imu.gyro, dtype=float),
            float(control.thrust),
            model.mass,
            model.drag,
            NO_AIR if self._air is None else self._air,
            self._air is not None,
            *self._kf_buffers,
            loglik,
        )
        return loglik if self.use_imu_likelihood else None

    def _identify_inertia(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Update the inertia identification and move the model and the particles to it.

        The particles' ω were integrated with the old θ̂; under the new one the same torque
        history gives another ω (:meth:`~.process.DynamicsModel.retune`), and that shift is
        applied to every particle before the IMU step compares ω with the
        gyro. Without it, the model error made while θ̂ was still wrong would stay in the
        particles' ω and be absorbed by the gyro-bias KF. The model follows the estimate only
        while it explains the data (:attr:`GyroTorqueRegression.usable`), else the nominal.
        """
        reg = self.inertia_id
        reg.update(imu.gyro, float(imu.gyro_sigma), control.torque, dt)
        # While the data contradict the rigid-body model, fall back to the nominal inertia.
        theta = reg.theta if reg.usable else 1.0 / self._inertia0
        self.model.retune(self.state.x, theta, reg.integrals, reg.gyro_bias)

    def _post_predict(self, imu: ImuSample) -> None:
        """Stage 2 (Table 2 step 8, eq. 32–34): ``ω^i ~ N(ω_m − b̂_ω^i, σ_g² I)``."""
        if not self.stage2:
            return
        xb = self.bias.xb
        bias = xb[:, 3:6] + xb[:, 9:12]
        sg = float(imu.gyro_sigma)
        self.state.x[:, RATE] = (
            np.asarray(imu.gyro, dtype=float)
            - bias
            + sg * self._rng.standard_normal((self.n_particles, 3))
        )

    def _post_update(self, idx: np.ndarray, meas: FloatArray, R: FloatArray) -> None:
        """Stage 2 (Table 2 step 8): regenerate ρ from the LiDAR inverse model.

        Each mapped observation j gives ``ρ_j = μ_j^i − C_NB^i ϱ(z_j)`` with covariance
        ``Σ_j^i + C_NB^i (∂ϱ/∂z) R (∂ϱ/∂z)ᵀ C_NB^iᵀ``; the per-landmark estimates are fused by
        their information and ``ρ^i`` is drawn from the fused Gaussian.
        """
        if not (self.stage2 and self.stage2_position):
            return
        s = self.state
        dcm = dcm_from_euler_batch(s.x[:, EUL])
        rho = s.mu[:, idx] - offset_in_inertial(dcm, meas)  # (N, m, 3)
        cov = s.sigma[:, idx] + inverse_model_cov(dcm, meas, R)
        info, _ = inv3_sym(cov)  # (N, m, 3, 3)
        info_sum = info.sum(axis=1)
        eta = np.einsum("nkij,nkj->ni", info, rho)
        fused_cov, _ = inv3_sym(info_sum)
        fused = np.einsum("nij,nj->ni", fused_cov, eta)
        draw = mv(chol3(fused_cov), self._rng.standard_normal((self.n_particles, 3)))
        s.x[:, POS] = fused + draw

    def _extra_diagnostics(self) -> dict[str, float]:
        """The model's principal moments of inertia in kg·m² (identified or nominal)."""
        jx, jy, jz = self.model.inertia.diagonal().tolist()
        return {"inertia_x": jx, "inertia_y": jy, "inertia_z": jz}

    def _bias_estimate(self, w: FloatArray) -> tuple[FloatArray | None, FloatArray | None]:
        total = self._bias_mean
        weighted_mean(self.bias.xb, w, total)
        return total[0:3] + total[6:9], total[3:6] + total[9:12]
