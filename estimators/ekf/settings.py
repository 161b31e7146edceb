"""Validated settings of the EKF-SLAM estimator (``estimator.params`` in a scenario)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from estimators.association_settings import AssociationFields
from estimators.imu_bias_settings import ImuBiasFields
from quadslam_env.config_schema import spec
from quadslam_env.types import POSE_DIM, FloatArray

BIAS_DIM = 4
"""Size of the bias block b = (b_ω (3), b_az (1)) when biases are estimated."""

GYRO_BIAS, ACCEL_BIAS_Z = slice(POSE_DIM, POSE_DIM + 3), POSE_DIM + 3
"""Where b_ω (rad/s) and b_az (m/s²) sit in the filter's state ``x = (s, b, m)``: after the pose
``s = (ρ, v_B, Λ)``, whose entries sit as in the vehicle's 12-state
(:data:`~quadslam_env.types.POS`, ``VEL``, ``EUL``), but where the vehicle state has ω."""

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

    process_noise: tuple[float, ...] = spec(
        PAPER_Q_UNKNOWN,
        kind="vec",
        length=POSE_DIM,
        lo=0.0,
        doc="diagonal of the continuous process-noise density Q over (ρ, v_B, Λ), m²/s, "
        "m²/s³, rad²/s (default: seed 001 Table 7)",
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
    def nv(self) -> int:
        """Vehicle-state size: 9, or 13 with bias states."""
        return POSE_DIM + (BIAS_DIM if self.estimate_imu_bias else 0)

    def continuous_noise(self) -> FloatArray:
        """(nv,) diagonal of the continuous process-noise density over (s, b)."""
        walks = [self.gyro_bias_walk**2] * 3 + [self.accel_bias_walk**2]
        return np.array(list(self.process_noise) + (walks if self.estimate_imu_bias else []))

    def initial_bias_variances(self) -> FloatArray:
        """(4,) initial variances of (b_ω, b_az)."""
        return np.array([self.gyro_bias_sigma0**2] * 3 + [self.accel_bias_sigma0**2])
