"""FastSLAM 1.0 on IMU strapdown kinematics (``fastslam_kinematic``, seed 000 §IV-B)."""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.fastslam.particles import FastSLAMBase
from estimators.fastslam.settings import FLOAT, positive
from quadslam_env.estimation import register
from quadslam_env.measurements import Control, ImuSample
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

    Parameters: ``n_particles`` (500), ``resample_threshold`` (0.5), ``process_noise`` (white-
    noise density per state, default (0.02, 0.05, 0.005, 0.0); the ω group is unused since ω is
    the input), ``integrator`` (``"rk4"``), ``imu_noise_scale`` (1.0, factor on the IMU sample
    σ used as input noise), ``known_map_sigma`` (0.001 m), and the robustness settings shared
    with ``fastslam`` (``likelihood_inflation`` default 1.0 here — the unmodified FastSLAM 1.0
    baseline —, ``roughening`` 0.0, ``regularisation`` 1.0, ``progressive_ess`` 0.1,
    ``anchor_gauge`` True,
    ``nis_divergence`` 1000.0, ``nis_divergence_s`` 2.0) and
    its unknown-association settings (``gate_probability`` 0.99, ``new_landmark_likelihood``
    0.001, ``confirm_hits`` 3, ``confirm_window`` 5).

    Args:
        vehicle: Accepted for a uniform interface; not used (kinematics need no parameters).
        **params: The settings above.
    """

    _DEFAULT_NOISE = (0.02, 0.05, 0.005, 0.0)

    def __init__(self, vehicle: VehicleParams | None = None, **params: Any) -> None:
        super().__init__(params, {"imu_noise_scale": FLOAT})
        self.imu_noise_scale = positive(
            "imu_noise_scale", params.get("imu_noise_scale", 1.0), strict=False
        )
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
