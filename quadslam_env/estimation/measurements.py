"""Plain data passed from the simulator to the estimators: IMU samples, LiDAR scans, controls.

These are the only things an estimator receives (docs/design.md §1: estimators never see the truth).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from quadslam_env.types import FloatArray


@dataclass(frozen=True)
class ImuSample:
    """One IMU sample, body frame (FRD).

    Attributes:
        t: Sample time in s.
        accel: (3,) measured specific force ``a_m`` in m/s² (reads ``(0, 0, -g)`` in hover).
        gyro: (3,) measured body rates ``ω_m`` in rad/s.
        accel_sigma: White-noise standard deviation per axis of ``accel`` in m/s².
        gyro_sigma: White-noise standard deviation per axis of ``gyro`` in rad/s.
    """

    t: float
    accel: FloatArray
    gyro: FloatArray
    accel_sigma: float
    gyro_sigma: float


@dataclass(frozen=True)
class Control:
    """Inputs applied to the vehicle over the last control period (after saturation).

    Attributes:
        thrust: Collective thrust f_T in N.
        torque: (3,) body torque τ in N·m.
    """

    thrust: float
    torque: FloatArray


@dataclass(frozen=True)
class LidarScan:
    """One LiDAR scan, with known or unknown data association.

    Attributes:
        t: Scan time in s.
        ids: (k,) int landmark identities, sorted ascending; ``None`` when the association is
            unknown (``lidar.association: unknown``): the returns are then unlabeled, in random
            order, and may include false returns (clutter).
        meas: (k, 3) measurements (azimuth α rad, elevation β rad, range δ m).
        sigma: (3,) noise standard deviations (σ_α rad, σ_β rad, σ_δ m).
    """

    t: float
    ids: np.ndarray | None
    meas: FloatArray
    sigma: FloatArray

    @property
    def count(self) -> int:
        """Number of returns in the scan."""
        return int(self.meas.shape[0])

    @property
    def labeled(self) -> bool:
        """Whether the returns carry landmark ids (known data association)."""
        return self.ids is not None


@dataclass
class ScanReturns:
    """Unlabeled LiDAR returns of B lanes (``lidar.association: unknown``).

    Attributes:
        count: (B,) int returns per lane (0 for lanes that did not scan).
        meas: (B, R, 3) returns (α rad, β rad, δ m), rows ``≥ count[b]`` unused; R grows with
            the largest scan seen.
        truth: (B, R) int true landmark id of each return, -1 for a false return. The
            simulator keeps it for the association metrics; estimators never receive it.
    """

    count: np.ndarray
    meas: FloatArray
    truth: np.ndarray
