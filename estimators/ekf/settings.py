"""Validated settings of the EKF-SLAM estimator (``estimator.params`` in a scenario)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.association_settings import AssociationFields
from estimators.imu_bias_settings import ImuBiasFields
from quadslam_env.config_schema import spec
from quadslam_env.types import POSE_DIM, FloatArray

BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated with the thrust-axis
model; the whole specific force adds (b_ax, b_ay) (:attr:`EkfSlamSettings.bias_dim`)."""

GYRO_BIAS, ACCEL_BIAS_Z = slice(POSE_DIM, POSE_DIM + 3), POSE_DIM + 3
"""Where b_ω (rad/s) and b_az (m/s²) sit in the filter's state ``x = (s, b, m)``: after the pose
``s = (ρ, v_B, Λ)``, whose entries sit as in the vehicle's 12-state
(:data:`~quadslam_env.types.POS`, ``VEL``, ``EUL``), but where the vehicle state has ω."""
ACCEL_BIAS_XY = slice(POSE_DIM + 4, POSE_DIM + 6)
"""Where (b_ax, b_ay) (m/s²) sit with ``specific_force: full``: after b_az, so the thrust-axis
layout is the leading part of the full one."""
SPECIFIC_FORCE = ("thrust_axis", "full")

PAPER_Q_UNKNOWN = (0.2, 0.2, 0.05, 0.01, 0.01, 0.01, 0.02, 0.2, 0.2)
"""Seed 001 Table 7: diagonal of Q over (ρ, v_B, Λ) for the unknown-map case."""


@dataclass(frozen=True)
class EkfSlamSettings(ImuBiasFields, AssociationFields):
    """EKF-SLAM settings (``estimator.params`` of ``ekf_slam``), built by :meth:`from_dict`.

    Every key, its default, what it accepts and its meaning is declared below with
    :func:`~quadslam_env.config_schema.spec` (the docs' ``estimator.params`` table of
    ``ekf_slam`` is generated from these declarations). The bias keys come from
    :class:`~estimators.imu_bias_settings.ImuBiasFields` (b_ω (3) and b_az (1): the only IMU
    axes the model uses, λ = (ã_z, ω̃), seed 001 eq. 25) and the association keys, read with
    ``lidar.association: unknown`` (:mod:`estimators.ekf.associate`), from
    :class:`~estimators.association_settings.AssociationFields`.

    ``process_noise`` defaults to seed 001 Table 7 (unknown landmarks); Table 6 (known
    landmarks) uses ``[0.01]*6 + [0.02]*3``. ``imu_noise_in_q: false`` reproduces the paper,
    which only uses Q. ``relinearise_tolerance`` iterates an update (Gauss–Newton
    relinearisation, :mod:`estimators.ekf.correction`) after a long gap without landmarks,
    when the returning scan corrects metres; an ordinary update is far below it and is the
    first-order update bit for bit.

    Known-map mode (localisation only, the paper's known-landmarks case) is not a setting: it
    is chosen per run by passing a known map at reset (the env does so when the scenario sets
    ``estimator.known_map: true``).
    """

    specific_force: str = spec(
        "thrust_axis",
        kind="str",
        choices=SPECIFIC_FORCE,
        doc="thrust_axis: the accelerometer's z axis only (seed 001 eq. 25; a horizontal "
        "specific force such as drag reads as tilt); full: all three axes, the textbook "
        "strapdown mechanisation (with estimate_imu_bias, all three accelerometer biases)",
    )
    process_noise: tuple[float, ...] = spec(
        PAPER_Q_UNKNOWN,
        kind="vec",
        length=POSE_DIM,
        lo=0.0,
        hi=1e3,
        doc="diagonal of the continuous process-noise density Q over (ρ, v_B, Λ), m²/s, "
        "m²/s³, rad²/s, each at most 1e3 (default: seed 001 Table 7)",
    )
    imu_noise_in_q: bool = spec(
        True,
        kind="bool",
        doc="add the IMU white noise mapped through ∂f/∂λ to the discrete process noise "
        "(needed for consistency)",
    )
    relinearise_tolerance: float = spec(
        2.0,
        lo=0.0,
        lo_open=True,
        allow_inf=True,
        doc="iterate an update when the first-order update's linearisation error exceeds "
        "this many measurement noise stds on some channel; .inf: never",
    )
    max_iterations: int = spec(
        10, kind="int", lo=1, hi=100, doc="most iterations of such an update"
    )

    @property
    def full_specific_force(self) -> bool:
        """All three accelerometer axes drive the model (``specific_force: full``)."""
        return self.specific_force == "full"

    @property
    def bias_dim(self) -> int:
        """Bias states: 0 without ``estimate_imu_bias``; 4 (b_ω, b_az), or 6 (b_ω, b_az, b_ax,
        b_ay) with the whole specific force."""
        if not self.estimate_imu_bias:
            return 0
        return BIAS_DIM + (2 if self.full_specific_force else 0)

    @property
    def input_dim(self) -> int:
        """nλ, the IMU inputs of the model: 4 (a_z, ω), or 6 (a_z, ω, a_x, a_y)."""
        return 6 if self.full_specific_force else 4

    @property
    def nv(self) -> int:
        """Vehicle-state size: 9, 13 with bias states, 15 with the whole specific force's."""
        return POSE_DIM + self.bias_dim

    def continuous_noise(self) -> FloatArray:
        """(nv,) diagonal of the continuous process-noise density over (s, b)."""
        n_accel = self.bias_dim - 3
        walks = [self.gyro_bias_walk**2] * 3 + [self.accel_bias_walk**2] * n_accel
        return np.array(list(self.process_noise) + (walks if self.estimate_imu_bias else []))

    def initial_bias_variances(self) -> FloatArray:
        """(bias_dim,) initial variances of (b_ω, b_az[, b_ax, b_ay])."""
        n_accel = self.bias_dim - 3
        return np.array([self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2] * n_accel)
