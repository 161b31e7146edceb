"""The iSAM2 estimator's snapshots: its GTSAM state as the env's one-lane
:class:`~quadslam_env.estimation.snapshot.BatchEstimate`.

The smoothed (or IMU-predicted) ``Pose3`` and velocity in N and their covariance over GTSAM's
tangent (δθ, δt, δv_N) become (ρ, v_B, Λ) and their (9, 9) covariance
(:func:`~estimators.isam2.tangent.state_covariance`); the landmarks are reported sorted by id.
"""

from __future__ import annotations

import copy

import numpy as np

from estimators.isam2.tangent import state_covariance
from quadslam_env.estimation.snapshot import BatchEstimate, LaneMap
from quadslam_env.models.frames import euler_from_dcm
from quadslam_env.types import POSE_DIM, FloatArray


def landmark_map(means: dict[int, FloatArray], covs: dict[int, FloatArray] | None) -> LaneMap:
    """The landmarks by id in a snapshot's layout, read-only (shared by the snapshots until the
    next keyframe; a missing covariance is reported as zero, ``covs`` None leaves them out).

    Args:
        means: id → (3,) position in N, m.
        covs: id → (3, 3) covariance in m², or ``None``.
    """
    ids = np.array(sorted(means), dtype=np.int64)
    out_means = np.array([means[i] for i in ids.tolist()]).reshape(-1, 3)
    out_covs = None
    if covs is not None:
        out_covs = np.array([covs.get(i, np.zeros((3, 3))) for i in ids.tolist()])
        out_covs = out_covs.reshape(-1, 3, 3)
    return LaneMap.of(ids, out_means, out_covs, shared=True)


def snapshot(
    position: FloatArray,
    dcm: FloatArray,
    vel_n: FloatArray,
    cov_t: FloatArray,
    rates: FloatArray,
    landmarks: LaneMap,
    biases: tuple[FloatArray, FloatArray] | None,
    diagnostics: dict[str, float],
) -> BatchEstimate:
    """The estimate of one state (B = 1).

    Args:
        position: (3,) ρ in N, m (the snapshot keeps this array).
        dcm: (3, 3) ``C_NB``.
        vel_n: (3,) velocity in N, m/s.
        cov_t: (9, 9) covariance over (δθ rad, δt m, δv_N m/s).
        rates: (3,) body rates, rad/s.
        landmarks: :func:`landmark_map`.
        biases: ``(accelerometer (3,) m/s², gyro (3,) rad/s)`` to report, or ``None`` (biases
            not estimated).
        diagnostics: The estimator's diagnostics.

    Raises:
        FloatingPointError: A non-finite state or covariance.
    """
    euler = euler_from_dcm(dcm)
    vel_body = dcm.T @ vel_n
    pose_cov = state_covariance(cov_t, dcm, vel_body, euler)
    if not np.isfinite(np.concatenate((position, vel_n, euler, pose_cov.ravel()))).all():
        raise FloatingPointError("isam2: non-finite prediction")
    return BatchEstimate.on_map(
        landmarks,
        position=position,
        vel_body=vel_body,
        vel_inertial=np.array(vel_n, dtype=float),
        euler=euler,
        rates=np.array(rates, dtype=float),
        pose_cov=pose_cov,
        accel_bias=None if biases is None else biases[0].copy(),
        gyro_bias=None if biases is None else biases[1].copy(),
        diagnostics=diagnostics,
    )


def neutral(diagnostics: dict[str, float]) -> BatchEstimate:
    """Zero state and covariance, no landmarks (before the first reset, as the EKF)."""
    return BatchEstimate.one_lane(
        position=np.zeros(3),
        vel_body=np.zeros(3),
        vel_inertial=np.zeros(3),
        euler=np.zeros(3),
        rates=np.zeros(3),
        pose_cov=np.zeros((POSE_DIM, POSE_DIM)),
        landmark_ids=np.zeros(0, dtype=np.int64),
        landmark_means=np.zeros((0, 3)),
        landmark_covs=np.zeros((0, 3, 3)),
        diagnostics=diagnostics,
    )


def flagged(last: BatchEstimate) -> BatchEstimate:
    """A copy of ``last`` (the last finite estimate) with ``diagnostics["diverged"] = 1``."""
    out = copy.deepcopy(last)
    out.diagnostics["diverged"] = np.ones(1)
    return out
