"""Simulated sensors: the biased, drifting IMU and the FOV-limited LiDAR (DESIGN.md §3).

Each sensor owns one ``numpy.random.Generator`` handed to it at reset by the env (a child of the
env's ``np_random``), so the same seed gives the same measurements.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.config import ImuConfig, LidarConfig
from quadslam_env.measurements import ImuSample, LidarScan
from quadslam_env.models.dynamics import VehicleParams, specific_force
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.rotations import FloatArray, wrap_angle

_DEG = math.pi / 180.0


class Imu:
    """Accelerometer + gyro with constant bias, Gauss–Markov drift and white noise.

    Seed 000 eq. 5–11 with a physical accelerometer (DESIGN.md §3):
    ``a_m = f_B + b0_a + b1_a + v_a``, ``ω_m = ω + b0_ω + b1_ω + v_ω``, where ``f_B`` is the
    specific force. The drift is first-order Gauss–Markov, discretised exactly:
    ``b1 ← e^{-T/τ} b1 + N(0, σ_b1² (1 - e^{-2T/τ}))`` (so its stationary std is σ_b1). White
    noise per sample has std ``ND · √f_s`` for noise density ND and sample rate f_s.

    Args:
        cfg: IMU settings.
        vehicle: Vehicle parameters (mass and drag enter the specific force).
        rate_hz: Sample rate f_s in Hz (the control rate).
    """

    def __init__(self, cfg: ImuConfig, vehicle: VehicleParams, rate_hz: float) -> None:
        self.cfg = cfg
        self.vehicle = vehicle
        self.period = 1.0 / rate_hz
        self.accel_sigma = cfg.accel_noise_density * math.sqrt(rate_hz)
        self.gyro_sigma = cfg.gyro_noise_density * math.sqrt(rate_hz)
        self._decay = math.exp(-self.period / cfg.drift_tau_s)
        self._drift_scale = math.sqrt(1.0 - self._decay**2)
        self._drift_sigma = np.array([cfg.accel_drift_sigma] * 3 + [cfg.gyro_drift_sigma] * 3)
        self.bias0 = np.zeros(6)
        self.drift = np.zeros(6)
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> None:
        """Draw the episode's constant bias signs (if random) and a stationary initial drift."""
        self._rng = rng
        bias = np.array(self.cfg.accel_bias + self.cfg.gyro_bias, dtype=float)
        if self.cfg.random_bias_sign:
            bias *= rng.choice([-1.0, 1.0], size=6)
        self.bias0 = bias
        self.drift = self._drift_sigma * rng.standard_normal(6)

    @property
    def total_bias(self) -> FloatArray:
        """(6,) current total bias ``b0 + b1`` (accel m/s², then gyro rad/s): truth for metrics."""
        return self.bias0 + self.drift

    def sample(self, t: float, vel_body: FloatArray, rates: FloatArray, thrust: float) -> ImuSample:
        """Measure, then advance the drift by one sample period.

        Args:
            t: Sample time in s.
            vel_body: (3,) true body velocity in m/s (enters the drag specific force).
            rates: (3,) true body rates in rad/s.
            thrust: Applied thrust in N.
        """
        noise = self._rng.standard_normal(6)
        bias = self.bias0 + self.drift
        accel = (
            specific_force(vel_body, thrust, self.vehicle) + bias[:3] + self.accel_sigma * noise[:3]
        )
        gyro = np.asarray(rates, dtype=float) + bias[3:] + self.gyro_sigma * noise[3:]
        self.drift = self._decay * self.drift + self._drift_scale * self._drift_sigma * (
            self._rng.standard_normal(6)
        )
        return ImuSample(
            t=t, accel=accel, gyro=gyro, accel_sigma=self.accel_sigma, gyro_sigma=self.gyro_sigma
        )


class Lidar:
    """FOV-limited LiDAR returning (azimuth, elevation, range) of point landmarks.

    A landmark is returned iff its *true* ``|α| ≤ α_max``, ``|β| ≤ β_max`` and
    ``δ_min ≤ δ ≤ δ_max`` (seed 001 Table 4); Gaussian noise is then added per channel and the
    azimuth wrapped. Identities are known (perfect data association, as in both papers).
    """

    def __init__(self, cfg: LidarConfig) -> None:
        self.cfg = cfg
        self.sigma = np.array(
            [cfg.sigma_azimuth_deg * _DEG, cfg.sigma_elevation_deg * _DEG, cfg.sigma_range_m]
        )
        self._az_max = cfg.azimuth_fov_deg * _DEG
        self._el_max = cfg.elevation_fov_deg * _DEG
        self._rng = np.random.default_rng(0)

    def reset(self, rng: np.random.Generator) -> None:
        """Take the generator for this episode."""
        self._rng = rng

    def visible(self, meas: FloatArray) -> np.ndarray:
        """Boolean mask (k,) of noise-free measurements inside the FOV and range limits."""
        return (
            (np.abs(meas[:, 0]) <= self._az_max)
            & (np.abs(meas[:, 1]) <= self._el_max)
            & (meas[:, 2] >= self.cfg.range_min_m)
            & (meas[:, 2] <= self.cfg.range_max_m)
        )

    def scan(
        self,
        t: float,
        pos: FloatArray,
        dcm: FloatArray,
        landmark_ids: np.ndarray,
        landmarks: FloatArray,
    ) -> LidarScan:
        """One scan from the true pose.

        Args:
            t: Scan time in s.
            pos: (3,) true position in N, m.
            dcm: (3, 3) true ``C_NB``.
            landmark_ids: (L,) sorted landmark ids.
            landmarks: (L, 3) true landmark positions in N, m.
        """
        true_meas = lidar_measure(pos, dcm, landmarks)
        mask = self.visible(true_meas)
        meas = true_meas[mask] + self.sigma * self._rng.standard_normal((int(mask.sum()), 3))
        meas[:, 0] = wrap_angle(meas[:, 0])
        return LidarScan(t=t, ids=landmark_ids[mask], meas=meas, sigma=self.sigma)
