"""FastSLAM 1.0 on IMU strapdown kinematics (``fastslam_kinematic``, seed 000 §IV-B)."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.fastslam.particles import FastSLAMBase
from estimators.fastslam.settings import KinematicFastSlamSettings
from quadslam_env.estimation.measurements import Control, ImuSample
from quadslam_env.estimation.registry import register
from quadslam_env.models.integrators import kinematic_propagate
from quadslam_env.models.params import VehicleParams
from quadslam_env.types import RATE, FloatArray


@register("fastslam_kinematic")
class KinematicFastSLAM(FastSLAMBase):
    """FastSLAM 1.0 driven by IMU strapdown kinematics, no bias calibration (seed 000 §IV-B).

    Each particle is propagated with ``v̇ = −ω×v + C_NBᵀ g n3 + a``, ``Λ̇ = D(Λ) ω``,
    ``ρ̇ = C_NB v`` where ``a = a_m + ε_a`` and ``ω = ω_m + ε_ω`` are the IMU readings perturbed by
    the sample's white noise (σ × ``imu_noise_scale``), i.e. samples from the motion model with
    noisy inputs. The ω slot of each particle holds its input ω. Weights use the LiDAR only.

    Parameters: ``estimator.params``, validated by
    :class:`~.settings.KinematicFastSlamSettings`; the docs' generated ``estimator.params``
    table of ``fastslam_kinematic`` lists every key.

    Args:
        vehicle: Accepted for a uniform interface; not used (kinematics need no parameters).
        **params: ``estimator.params`` (:class:`~.settings.KinematicFastSlamSettings`).
    """

    settings_class = KinematicFastSlamSettings

    def __init__(self, vehicle: VehicleParams | None = None, **params: Any) -> None:
        settings = KinematicFastSlamSettings.from_dict(params)
        super().__init__(settings)
        self.imu_noise_scale = settings.imu_noise_scale
        self.vehicle = vehicle

    def _propagate(self, imu: ImuSample, control: Control, dt: float) -> FloatArray:
        n = self.n_particles
        noise = self._rng.standard_normal((n, 6))
        accel = (
            np.asarray(imu.accel, dtype=float)
            + (float(imu.accel_sigma) * self.imu_noise_scale) * noise[:, 0:3]
        )
        x = self.state.x.copy()
        x[:, RATE] = (
            np.asarray(imu.gyro, dtype=float)
            + (float(imu.gyro_sigma) * self.imu_noise_scale) * noise[:, 3:6]
        )
        # The simulator's rigid-body kinematics with a_m as the specific force and ω held.
        # quadslam_env.models.strapdown (the EKF's eq. 24 model) takes only a_z, so it cannot
        # serve this full-3-axis strapdown.
        return kinematic_propagate(x, accel, dt, self.integrator)
