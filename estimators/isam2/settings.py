"""Validated settings of the iSAM2 estimator (``estimator.params`` with ``estimator.name: isam2``).

The keys shared with EKF-SLAM (``process_noise``, ``estimate_imu_bias`` and the four bias keys;
the five data-association keys) have the EKF's meaning, units and defaults
(:class:`estimators.ekf.settings.EkfSlamSettings`, :mod:`estimators.association_settings`), so a
scenario written for the EKF keeps its IMU model and its association rule when its estimator is
swapped (both settings classes inherit them: :class:`~estimators.imu_bias_settings.ImuBiasFields`,
:class:`~estimators.association_settings.AssociationFields`); the EKF's own iteration keys
(``imu_noise_in_q``, ``relinearise_tolerance``, ``max_iterations``) are rejected with the list
of accepted keys.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.association import chi2_threshold
from estimators.association_settings import AssociationFields
from estimators.imu_bias_settings import ImuBiasFields
from quadslam_env.schema import spec
from quadslam_env.types import POSE_DIM, FloatArray

FIXED_BIAS_SIGMA = 1e-5
"""With ``estimate_imu_bias: false`` the biases are held at zero by a prior of this std on
*every* keyframe's bias and a random walk of this density between keyframes (m/s² and
m/s²/√s for the accelerometer, rad/s and rad/s/√s for the gyro): the IMU factor of Forster
et al. (2017) always carries bias variables, and a zero-variance prior would make the
information matrix singular. The prior at every keyframe keeps the bias's variance below
this std squared for the whole flight; a prior on the first keyframe alone would let the walk
grow it as ``σ² (1 + t)`` — 7e-5 rad/s after 50 s — and the reported covariance would carry a
bias the simulated IMU does not have (on ``paper_ekf_figure8_known`` it made the attitude's
variance 25% larger; docs/isam2-validation.md, "Consistency"). Over one 0.1 s keyframe
interval a bias of this std moves the attitude by 1e-6 rad and the position by 5e-8 m, far
below the sensors' noise."""

HORIZONTAL_ACCEL_VARIANCE = 1e-8
"""With ``thrust_axis_accel`` the variance density of the horizontal specific force taken as
zero, (m/s²)²·s: what the preintegration gets instead of the samples' ``a_x, a_y`` and their
noise (small against the accelerometer's ~1e-5, above :data:`NOISE_FLOOR` so that the IMU
factor stays well conditioned)."""

NOISE_FLOOR = 1e-12
"""Smallest continuous-time variance (per axis) handed to GTSAM's preintegration (an ideal
IMU has zero noise density, which would make the IMU factor's covariance singular)."""

PRIOR_VARIANCE_FLOOR = 1e-8
"""Smallest eigenvalue of the initial prior's covariance in GTSAM's tangent space (rad², m²,
m²/s²): the scenarios' ``estimator.initial_cov_diag`` may hold zeros (a known attitude),
which a Gaussian factor cannot represent."""


FACTORIZATIONS = ("qr", "cholesky")
"""``estimator.params.factorization`` choices of iSAM2's elimination."""


@dataclass(frozen=True)
class Isam2Settings(ImuBiasFields, AssociationFields):
    """iSAM2 settings (``estimator.params`` of ``isam2``), built by :meth:`from_dict`.

    Every key, its default, what it accepts and its meaning is declared below with
    :func:`~quadslam_env.schema.spec` (the docs' ``estimator.params`` table of
    ``isam2`` is generated from these declarations); the bias and association keys are the
    EKF's (see the module docstring).

    ``window_s`` bounds the cost per scan: vehicle states (pose, velocity, biases) older than
    it are marginalised (:class:`~estimators.isam2.fixed_lag.FixedLagIsam2`, every fifth
    keyframe: the window holds ``window_s`` to ``window_s`` plus four scan periods) while
    landmarks stay in the window for the whole episode (they have no timestamp, so a landmark
    that comes back into view still has its variable); ``null`` is full iSAM2 (Kaess et al.
    2012), whose cost grows with the episode. ``relinearize_skip`` keyframes apart, the
    smoother relinearises and re-eliminates the whole window. ``process_noise`` is added to the
    preintegration's inputs: the ρ block to the integration covariance, the v_B block to the
    accelerometer's and the Λ block to the gyro's (exact for isotropic blocks in level
    flight); the simulator has no process noise beyond the IMU's, so the default is none.
    With ``estimate_imu_bias: false`` the biases are held at zero (:data:`FIXED_BIAS_SIGMA`,
    a prior at every keyframe). ``factorization: cholesky`` squares the condition number:
    after ~15 s of dead reckoning (the map out of view) the position's variance is ~1e8 times
    the held biases' and it reports an indeterminate system; QR works on the square-root
    information directly (same solution, ~15% more time per scan).

    The measurement noise (LiDAR σ per return, IMU white noise per sample) comes with the
    data, as for the EKF (:class:`~quadslam_env.estimation.measurements.LidarScan`,
    :class:`~quadslam_env.estimation.measurements.ImuSample`).
    """

    window_s: float | None = spec(
        3.0,
        lo=0.0,
        lo_open=True,
        optional=True,
        doc="smoother lag, s: older vehicle states are marginalised; null: keep every state",
    )
    process_noise: tuple[float, ...] = spec(
        (0.0,) * POSE_DIM,
        kind="vec",
        length=POSE_DIM,
        lo=0.0,
        hi=1e3,
        doc="the EKF's continuous process noise Q over (ρ, v_B, Λ), m²/s, m²/s³, rad²/s, "
        "each at most 1e3, added to the preintegration's inputs",
    )
    integration_sigma: float = spec(
        1e-4,
        lo=0.0,
        hi=1.0,
        doc="GTSAM's integration noise, m/√s, at most 1: the position error of integrating a "
        "held IMU sample (added to the ρ block of process_noise)",
    )
    relinearize_threshold: float = spec(
        0.01,
        lo=0.0,
        lo_open=True,
        doc="relinearise a variable when its tangent-space update exceeds this (rad, m, m/s)",
    )
    relinearize_skip: int = spec(
        50,
        kind="int",
        lo=1,
        hi=100,
        doc="relinearise every this many keyframes (re-eliminating the whole window)",
    )
    factorization: str = spec(
        "qr",
        kind="str",
        choices=FACTORIZATIONS,
        doc="how iSAM2 eliminates the linearised system (cholesky: faster, fails after long "
        "dead reckoning)",
    )
    iterations: int = spec(
        1,
        kind="int",
        lo=1,
        hi=20,
        doc="iSAM2 updates per keyframe (the later ones: one more Gauss–Newton step each)",
    )
    landmark_covariances: bool = spec(
        True,
        kind="bool",
        doc="recover each mapped landmark's marginal covariance when a snapshot asks for it "
        "(false: reported as zero; always on with unknown association)",
    )
    thrust_axis_accel: bool = spec(
        False,
        kind="bool",
        doc="EKF-SLAM's specific-force model (seed 001 eq. 25): use only the accelerometer's "
        "z axis, the horizontal specific force taken as zero (exact without drag) and the "
        "horizontal accelerometer biases held",
    )
    factor_per_return: bool = spec(
        False,
        kind="bool",
        doc="unknown map: one LiDAR factor per return instead of one per scan (the same "
        "likelihood, more Python calls)",
    )

    @property
    def new_gate(self) -> float:
        """The new-landmark gate ``χ²₃(new_landmark_probability)`` (≥ :attr:`gate` unless the
        association gate is off)."""
        return chi2_threshold(3, self.new_landmark_probability)

    def bias_prior_sigmas(self) -> FloatArray:
        """(6,) prior std of the (accelerometer x, y, z in m/s², gyro x, y, z in rad/s) biases
        at the first keyframe, at least :data:`FIXED_BIAS_SIGMA` (a zero std is a singular
        factor); with ``thrust_axis_accel`` the horizontal accelerometer biases are held."""
        return self._per_axis(self.accel_bias_sigma0, self.gyro_bias_sigma0)

    def bias_walks(self) -> FloatArray:
        """(6,) random-walk densities of the same biases (m/s²/√s, rad/s/√s), at least
        :data:`FIXED_BIAS_SIGMA`, held as in :meth:`bias_prior_sigmas`."""
        return self._per_axis(self.accel_bias_walk, self.gyro_bias_walk)

    def _per_axis(self, accel: float, gyro: float) -> FloatArray:
        out = np.full(6, FIXED_BIAS_SIGMA)
        if self.estimate_imu_bias:
            out[:3] = max(accel, FIXED_BIAS_SIGMA)
            out[3:] = max(gyro, FIXED_BIAS_SIGMA)
        if self.thrust_axis_accel:
            out[:2] = FIXED_BIAS_SIGMA  # EKF-SLAM's model: only b_az
        return out
