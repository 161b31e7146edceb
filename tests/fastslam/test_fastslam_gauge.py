"""Tests of the FastSLAM gauge (estimators/fastslam/gauge.py) against independent facts."""

from __future__ import annotations

import math

import numpy as np

from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.gauge import (
    GAUGE_INDEX,
    gauge_split,
    landmark_gauge_cov,
    pose_gauge_cov,
)
from quadslam_env.estimation.measurements import LidarScan
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.integrators import state_derivative
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset

LIDAR_SIGMA = np.array([math.radians(0.1), math.radians(0.1), 0.03])
POLES = np.array([[2.0, 2.0, -1.0], [-2.0, 2.0, -1.0], [-2.0, -2.0, -1.0], [2.0, -2.0, -1.0]])


def _rz(angle: float) -> np.ndarray:
    """Rotation about n3 (NED down) by ``angle``: ``C3(angle)`` of seed 001 eq. 1."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _shift(x: np.ndarray, anchor: np.ndarray, d_rho: np.ndarray, d_psi: float) -> np.ndarray:
    """The state (12,) of a solution translated by ``d_rho`` and rotated about n3 by ``d_psi``
    around ``anchor``, as a rotation matrix (not the first-order model under test)."""
    out = x.copy()
    out[0:3] = anchor + _rz(d_psi) @ (x[0:3] - anchor) + d_rho
    C = _rz(d_psi) @ dcm_from_euler(x[6:9])
    out[6] = math.atan2(C[2, 1], C[2, 2])
    out[7] = -math.asin(C[2, 0])
    out[8] = math.atan2(C[1, 0], C[0, 0])
    return out


def test_gauge_split_is_gaussian_conditioning() -> None:
    rng = np.random.default_rng(0)
    A = rng.normal(size=(12, 12))
    P0 = A @ A.T + 0.1 * np.eye(12)
    G, Pc = gauge_split(P0)
    g = GAUGE_INDEX
    o = np.setdiff1d(np.arange(12), g)
    np.testing.assert_allclose(G, P0[np.ix_(g, g)])
    # Independent: the conditional covariance is the inverse of the precision's block.
    np.testing.assert_allclose(Pc[np.ix_(o, o)], np.linalg.inv(np.linalg.inv(P0)[np.ix_(o, o)]))
    assert np.all(Pc[g, :] == 0.0) and np.all(Pc[:, g] == 0.0)
    # A diagonal prior: the other states keep their variances, G is the gauge's diagonal.
    d = np.arange(1.0, 13.0)
    G, Pc = gauge_split(np.diag(d))
    np.testing.assert_allclose(G, np.diag(d[g]))
    np.testing.assert_allclose(np.diag(Pc)[o], d[o])


def test_measurements_and_dynamics_are_invariant_under_the_gauge() -> None:
    """The premise: a translated and yawed solution explains the same LiDAR and IMU data."""
    rng = np.random.default_rng(1)
    vehicle = vehicle_preset("sadeghzadeh2021")
    anchor = np.array([1.0, 0.0, -0.75])
    for _ in range(5):
        x = rng.normal(size=12) * 0.3
        x[0:3] += anchor
        lms = POLES + rng.normal(size=POLES.shape) * 0.2
        d_rho, d_psi = rng.normal(size=3), rng.uniform(-math.pi, math.pi)
        y = _shift(x, anchor, d_rho, d_psi)
        lms_y = anchor + (lms - anchor) @ _rz(d_psi).T + d_rho
        np.testing.assert_allclose(y[6:8], x[6:8], atol=1e-12)  # roll, pitch unchanged
        z_x = lidar_measure(x[0:3], dcm_from_euler(x[6:9]), lms)
        z_y = lidar_measure(y[0:3], dcm_from_euler(y[6:9]), lms_y)
        np.testing.assert_allclose(z_y, z_x, atol=1e-10)
        f_x = state_derivative(x, 14.0, np.array([0.01, -0.02, 0.005]), vehicle)
        f_y = state_derivative(y, 14.0, np.array([0.01, -0.02, 0.005]), vehicle)
        np.testing.assert_allclose(f_y[3:], f_x[3:], atol=1e-10)  # v̇_B, Λ̇, ω̇ (IMU) equal
        np.testing.assert_allclose(f_y[0:3], _rz(d_psi) @ f_x[0:3], atol=1e-10)  # ρ̇ rotated


def test_gauge_covariances_match_the_exact_shift_by_monte_carlo() -> None:
    rng = np.random.default_rng(2)
    anchor = np.array([1.0, 0.0, -0.75])
    x = np.r_[-0.5, 1.2, -1.0, 0.3, -0.1, 0.05, 0.05, -0.03, 2.0, 0.0, 0.0, 0.0]
    G = np.diag([4e-4, 9e-4, 1e-4, 1e-4])
    G[0, 3] = G[3, 0] = 5e-5
    draws = rng.multivariate_normal(np.zeros(4), G, size=20000)
    shifted = np.array([_shift(x, anchor, d[0:3], d[3]) for d in draws])
    pose = np.c_[shifted[:, 0:6], shifted[:, 6:9] - x[6:9]]
    np.testing.assert_allclose(
        np.cov(pose.T), pose_gauge_cov(x[0:3], anchor, G), atol=3e-5, rtol=0.05
    )
    lms = shifted[:, 0:3]  # a landmark at the vehicle's position moves the same way
    np.testing.assert_allclose(
        np.cov(lms.T), landmark_gauge_cov(x[None, 0:3], anchor, G)[0], atol=3e-5, rtol=0.05
    )


def _filter(anchor_gauge: bool, known: bool) -> DynamicFastSLAM:
    est = DynamicFastSLAM(
        vehicle_preset("sadeghzadeh2021"), n_particles=200, anchor_gauge=anchor_gauge
    )
    cov0 = np.diag([1e-3] * 3 + [1e-3] * 3 + [1e-4] * 3 + [1e-8] * 3)
    x0 = np.r_[1.0, 0.0, -0.75, np.zeros(9)]
    known_map = (np.arange(4), POLES) if known else None
    est.reset(x0, cov0, np.random.default_rng(4), known_landmarks=known_map)
    return est


def test_slam_keeps_the_gauge_prior_out_of_the_particles_and_in_the_covariance() -> None:
    est = _filter(anchor_gauge=True, known=False)
    assert np.all(np.ptp(est.state.x[:, [0, 1, 2, 8]], axis=0) == 0.0)  # pinned at the mean
    assert np.all(np.std(est.state.x[:, 3:6], axis=0) > 0.02)  # the rest keeps its prior
    e = est.estimate()
    assert e.pose_cov is not None
    np.testing.assert_allclose(np.diag(e.pose_cov[0])[[0, 1, 2, 8]], np.r_[[1e-3] * 3, 1e-4])
    z = lidar_measure(est.state.x[0, 0:3], np.eye(3), POLES)
    est.update(LidarScan(0.0, np.arange(4), z, LIDAR_SIGMA))
    e = est.estimate()
    # Each landmark: its EKF covariance plus the gauge's translation and yaw lever.
    lever = np.linalg.norm(POLES[:, 0:2] - [1.0, 0.0], axis=1)
    hor = e.mapped_landmarks()[2][:, 0, 0] + e.mapped_landmarks()[2][:, 1, 1]
    assert np.all(hor > 2e-3 + 1e-4 * lever**2 - 1e-9)


def test_known_map_and_switched_off_gauge_keep_the_prior_in_the_particles() -> None:
    for est in (_filter(anchor_gauge=True, known=True), _filter(anchor_gauge=False, known=False)):
        assert np.all(
            np.std(est.state.x[:, [0, 1, 2, 8]], axis=0) > 0.5 * np.sqrt([1e-3] * 3 + [1e-4])
        )
        e = est.estimate()
        assert e.pose_cov is not None
        dev = est.state.x[:, 0:3] - est.state.x[:, 0:3].mean(axis=0)
        np.testing.assert_allclose(e.pose_cov[0, 0:3, 0:3], dev.T @ dev / est.n_particles)
