"""A complementary filter written outside the package and flown through ``gymnasium.make``.

The filter implements the :class:`estimators.Estimator` protocol (``reset``, ``predict``,
``update``, ``estimate``) and registers itself under the name ``complementary``, after which
``estimator.name: complementary`` (or ``estimator_name="complementary"`` in
``gymnasium.make``) selects it like a built-in estimator.

Prediction is strapdown integration of the IMU (the kinematics of seed 001 eq. 24: ρ̇ = C_NB v,
v̇ = −ω×v + C_NBᵀ g n3 + a_m, Λ̇ = D(Λ) ω) with one Euler step per sample. Each LiDAR scan of the
known map gives a position fix per landmark, ρ = l − C_NB ϱ(y) (the inverse model, seed 001
eq. 44, solved for ρ); the filter blends the mean fix into the position and the velocity with
fixed gains. It has no covariance (``pose_cov=None``, so ``info`` carries no NEES) and no
landmark map of its own, so it needs ``estimator.known_map: true``.

Run it: ``python examples/complementary_filter.py``.
"""

from __future__ import annotations

# --8<-- [start:filter]
from typing import Any

import numpy as np

import estimators
from estimators import BatchEstimate
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models import dcm_from_euler, euler_rate_matrix, lidar_inverse
from quadslam_env.types import GRAVITY, FloatArray


@estimators.register("complementary")
class ComplementaryFilter:
    """Strapdown prediction blended with LiDAR position fixes from a known map.

    Args:
        vehicle: Vehicle parameters (passed to every estimator; unused here).
        position_gain: Share of the position residual applied per scan, in (0, 1].
        velocity_gain: Body-velocity correction per metre of position residual, per scan.
    """

    def __init__(self, vehicle: Any = None, position_gain: float = 0.2, velocity_gain: float = 0.3):
        self.k_pos, self.k_vel = float(position_gain), float(velocity_gain)
        self.x = np.zeros(9)  # (ρ, v_B, Λ)
        self.rates = np.zeros(3)
        self.row: dict[int, int] = {}
        self.landmarks = np.zeros((0, 3))

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start from the 12-state mean; the known map is required."""
        if known_landmarks is None:
            raise ValueError("estimator.known_map: got false; allowed: true (complementary)")
        ids, self.landmarks = known_landmarks
        self.row = {int(i): k for k, i in enumerate(ids)}
        self.x, self.rates = np.array(mean0[:9], dtype=float), np.array(mean0[9:12], dtype=float)

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """One Euler step of the strapdown kinematics driven by the IMU sample."""
        vel, euler, w = self.x[3:6], self.x[6:9], imu.gyro
        dcm = dcm_from_euler(euler)
        accel = -np.cross(w, vel) + dcm.T @ np.array([0.0, 0.0, GRAVITY]) + imu.accel
        self.x[0:3] += dt * (dcm @ vel)
        self.x[3:6] += dt * accel
        self.x[6:9] += dt * (euler_rate_matrix(euler) @ w)
        self.rates = np.array(w, dtype=float)

    def update(self, scan: LidarScan) -> None:
        """Blend the mean position fix of the scan's landmarks into position and velocity."""
        if scan.ids is None:  # the env refuses unknown association for this filter
            raise ValueError("ComplementaryFilter needs labeled scans (lidar.association: known)")
        if scan.count == 0:
            return
        dcm = dcm_from_euler(self.x[6:9])
        rows = [self.row[int(i)] for i in scan.ids]
        offsets = lidar_inverse(np.zeros(3), dcm, scan.meas)  # C_NB ϱ(y) per landmark
        residual = (self.landmarks[rows] - offsets).mean(axis=0) - self.x[0:3]
        self.x[0:3] += self.k_pos * residual
        self.x[3:6] += self.k_vel * (dcm.T @ residual)

    def estimate(self) -> BatchEstimate:
        """The current pose (a snapshot of one lane, of copies); no covariance, no landmark
        estimates."""
        dcm = dcm_from_euler(self.x[6:9])
        return BatchEstimate.one_lane(
            position=self.x[0:3].copy(),
            vel_body=self.x[3:6].copy(),
            vel_inertial=dcm @ self.x[3:6],
            euler=self.x[6:9].copy(),
            rates=self.rates.copy(),
            pose_cov=None,
            landmark_ids=np.zeros(0, dtype=int),
            landmark_means=np.zeros((0, 3)),
            landmark_covs=np.zeros((0, 3, 3)),
        )


# --8<-- [end:filter]


def main() -> None:
    """Fly the DF-LQR baseline on the filter's estimate for 20 s and print the errors."""
    # --8<-- [start:fly]
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.control.dflqr import DFLQRPolicy

    env = gym.make(
        "QuadSLAM-v0",
        scenario="paper_ekf_figure8_known",
        estimator_name="complementary",
        episode={"duration_s": 20.0},
    )
    policy = DFLQRPolicy.from_env(env)
    obs, info = env.reset(seed=0)
    done, errors = False, []
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
        errors.append(info["est_pos_err_m"])
        done = terminated or truncated
    rmse = float(np.sqrt(np.mean(np.square(errors))))
    print(f"{len(errors)} steps, estimate position RMSE {rmse:.3f} m, ", end="")
    print(f"tracking error at the end {info['track_pos_err_m']:.3f} m")
    # --8<-- [end:fly]


if __name__ == "__main__":
    main()
