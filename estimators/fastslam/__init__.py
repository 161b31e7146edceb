"""FastSLAM estimators (docs/design.md §5; seed 000 §III, Tables 2–4).

Two Rao-Blackwellised particle filters share one implementation
(:class:`~estimators.fastslam.particles.FastSLAMBase`):

``fastslam`` (:class:`DynamicFastSLAM`)
    Seed 000's self-calibrating FastSLAM. Each particle i carries the 12-state
    ``x^D = (ρ [m, N], v [m/s, B], Λ [rad], ω [rad/s, B])`` propagated through the quadcopter
    **dynamics** (seed 001 eq. 2 = seed 000 eq. 1–4) with the applied control, a Kalman filter
    over the IMU bias/drift state ``x^B = (b0_a, b0_ω, b1_a, b1_ω)`` (seed 000 eq. 8–12,
    Table 4) and one EKF per landmark (Table 3). Weights multiply the LiDAR and the IMU
    likelihoods (eq. 28). Optional stage 2 (Table 2, step 8) regenerates ω from the gyro inverse
    model and ρ from the LiDAR inverse model.

``fastslam_kinematic`` (:class:`KinematicFastSLAM`)
    FastSLAM 1.0 driven by IMU strapdown kinematics ``v̇ = −ω_m×v + C_NBᵀ g n3 + a_m``,
    ``Λ̇ = D(Λ) ω_m`` with no bias calibration and LiDAR-only weights — seed 000's comparison
    baseline (Fig. 10–14).

State (all particle work is batched; there is no Python loop over particles — the
per-particle loops are numba kernels, docs/design.md §9). The filter's ``state`` is a
:class:`~.state.ParticleState`; the functions of the other modules take it (or its arrays) and
return their results (log-likelihoods, NIS, stage counts), which the filter applies:

* ``x``      (N, 12) particle states ``x^D``;
* ``logw``   (N,) normalised log-weights, with ``w = exp(logw)`` and the ESS kept in step;
* ``mu``     (N, L, 3) landmark means ``μ_j^i`` in N, m; ``sigma`` (N, L, 3, 3) their
  covariances ``Σ_j^i`` in m². With known association L grows when a landmark id is seen for
  the first time and the id → slot map is shared by all particles (docs/design.md §3). With
  unknown association (unlabeled scans, :mod:`.associate`) every particle associates by
  maximum likelihood and owns its map: particle i's landmarks are slots ``0 … n_i − 1``
  (``ParticleMaps.size``), L is a capacity, and the estimate reports the map of the
  highest-weight particle.
* dynamic filter only: ``bias`` (:class:`~.state.BiasKFState`), ``xb`` (N, 12) bias-KF means
  and ONE shared (12, 12) covariance ``P``.
  The bias subsystem is linear with the same ``A, H, Q, R`` for every particle (seed 000
  eq. 11–12); the particles only differ in the innovation ``z̄ = z^I − h^d(x^{D,i})``, which
  enters the mean but not the covariance. So ``P`` is particle-independent and is stored once.

Resampling (systematic, when ESS < ``resample_threshold``·N, seed 004 Table 3-2) uses fancy
indexing, so every resampled array is a fresh copy: particles never share memory.

Choices not fixed by the papers (documented here and in the parameter table):

* Particle propagation uses one classical RK4 step per IMU/control period by default
  (``integrator="rk4"``), with the simulator's compiled rigid-body kernels
  (:mod:`quadslam_env.models.integrators`) looped over the particles. At 100 Hz and for the
  rates of a quadcopter the RK4 truncation error (O(h⁵) per step) is many orders below the
  process noise. ``integrator="euler"`` is 4× cheaper with an O(h²) local
  error (~1e-4 m/s per step at g-level accelerations), offered for very large N.
* Process noise is a white-noise *density*: each step adds ``N(0, σ² dt)`` per state, so the
  filter behaves the same at any control rate.
* The bias drift is discretised exactly, ``b1 ← e^{−T/τ} b1 + N(0, σ_b1²(1 − e^{−2T/τ}))``, with
  σ_b1 the stationary standard deviation (docs/design.md §3, matching the simulated IMU). Seed 000
  eq. 11 uses the first-order ``1 − T/τ`` and ``Q = T²σ²``; the two agree to O(T/τ).
* The IMU likelihood (eq. 26) is evaluated exactly: with the Gaussian bias prediction the
  integral in eq. 26 is ``N(z̄; H x̂^B_{k|k−1}, H P Hᵀ + R^I)``, which the paper approximates
  by a delta at ``x̂^B`` (i.e. drops ``H P Hᵀ``). Seed 000's ``k = 1`` re-initialisation of
  Table 4 is not used: ``HᵀH`` is singular (b0 and b1 enter the measurement only as a sum), so
  its least-squares re-initialisation is ill-posed; the prior ``P0`` plays its role.
* The LiDAR likelihood of an already-mapped landmark is ``N(z; h(x^{D,i}, μ_j^i), S)`` with
  ``S = H Σ Hᵀ + R`` (the standard FastSLAM 1.0 weight); new landmarks add the same constant
  to every particle and are ignored. Angle residuals are wrapped.
* The IMU sample passed to :meth:`predict` is taken to describe the vehicle at the *end* of
  the period (after the physics step), so it is compared with the propagated particles.
* Not in seed 000's filter, but named there (§IV) as the remedy for model mismatch: the
  principal moments of inertia are identified online from the gyro and the applied torque
  (:mod:`estimators.inertia`, ``estimate_inertia``), and the model and the particles' ω follow
  the estimate. Set ``estimate_inertia=False`` for the paper's fixed-model filter.

Modules: :mod:`.particles` (the shared particle machinery), :mod:`.dynamic` and
:mod:`.kinematic` (the two filters), :mod:`.state` (the state containers), :mod:`.process`
(motion models, process noise), :mod:`.bias_kf`, :mod:`.landmarks`, :mod:`.associate`
(per-particle data association), :mod:`.progressive` (progressive correction),
:mod:`.resampling`, :mod:`.moments` (the estimate's weighted moments), :mod:`.settings`
(parameter validation).

Kernels (``quadslam_env.models.jit.kernel``, no ``fastmath``) loop over the particles for the hot
paths: process noise and angle wrapping (:func:`.process.perturb_particles`), the IMU step
(:func:`.bias_kf.imu_bias_step`: the shared bias covariance once, then every particle's
innovation, likelihood and bias-mean update), the weights (:mod:`.resampling`), the landmark
EKFs (:func:`.landmarks.landmark_ekf_particles`, on the LiDAR model's kernels) and the estimate
(:mod:`.moments`). The normalised weights and the ESS are kept with the log-weights. Random
draws stay outside the kernels, in the same order as before, so a seed gives the same stream.
"""

# Importing the filter modules registers "fastslam" and "fastslam_kinematic".
from estimators.fastslam.bias_kf import (
    BIAS_DIM,
    H_BIAS,
    bias_kf_predict,
    bias_kf_update,
    bias_transition,
)
from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.kinematic import KinematicFastSLAM
from estimators.fastslam.landmarks import landmark_ekf_update, landmark_init
from estimators.fastslam.process import (
    DynamicsModel,
    dynamics_derivative_batch,
    kinematic_derivative_batch,
)
from estimators.fastslam.resampling import (
    effective_sample_size,
    normalise_log_weights,
    systematic_resample,
)

__all__ = [
    "BIAS_DIM",
    "H_BIAS",
    "DynamicFastSLAM",
    "DynamicsModel",
    "KinematicFastSLAM",
    "bias_kf_predict",
    "bias_kf_update",
    "bias_transition",
    "dynamics_derivative_batch",
    "effective_sample_size",
    "kinematic_derivative_batch",
    "landmark_ekf_update",
    "landmark_init",
    "normalise_log_weights",
    "systematic_resample",
]
