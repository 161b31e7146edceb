"""The map block of the posterior Cramér–Rao bound (estimators/pcrb.py) against closed forms.

(a) A hovering vehicle (static truth) with no process noise: the bound of each landmark is
the landmark block of the inverse joint information ``J0 + Σ Φ_kᵀ Hᵀ R⁻¹ H Φ_k``.
(b) The same hover driven by the IMU noise, one landmark entering late: a linear-Gaussian
system, whose Kalman filter written here in information form (which holds the landmarks'
zero prior information exactly) has the bound's landmark covariances at every scan.
(c) Monte Carlo: with the pose known but for a position prior, the landmarks estimated from
noisy scans of the nonlinear LiDAR model have the bound as error covariance (χ² on the NEES).
(d) The map RMSE's bound, eq. (2), over the mapped landmarks.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.ekf.kernels import transition_matrices
from estimators.ekf.settings import EkfSlamSettings
from estimators.pcrb import BoundModel, TruthRecord, map_error_bound, slam_bound
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_inverse, lidar_measure

_HOVER = np.array([0.5, -0.3, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
_LANDMARKS = np.array([[8.0, 1.0, -2.5], [7.0, -2.0, -1.0], [9.0, 3.0, -3.0]])
_SIGMA = np.array([0.006, 0.005, 0.1])
_DT, _STEPS, _EVERY = 0.01, 80, 10
_P0 = np.diag([0.01] * 3 + [0.01] * 3 + [0.001] * 3)


def _record(scan_ids: list[np.ndarray]) -> TruthRecord:
    return TruthRecord(
        dt=_DT,
        state=np.tile(_HOVER, (_STEPS + 1, 1)),
        rates=np.zeros((_STEPS, 3)),
        landmarks=_LANDMARKS,
        scan_steps=np.arange(_EVERY, _STEPS + 1, _EVERY),
        scan_ids=scan_ids,
    )


def _model(P0: np.ndarray, accel_sigma: float = 0.0, gyro_sigma: float = 0.0) -> BoundModel:
    return BoundModel(
        settings=EkfSlamSettings.from_dict({"process_noise": [0.0] * 9}),
        accel_sigma=accel_sigma,
        gyro_sigma=gyro_sigma,
        lidar_sigma=_SIGMA,
        cov0=P0,
        known_map=False,
    )


def _jacobians(landmarks: np.ndarray) -> np.ndarray:
    """Central differences of the LiDAR measurement w.r.t. (pose (9), landmarks (3k))."""

    def h(x: np.ndarray) -> np.ndarray:
        lms = x[9:].reshape(-1, 3)
        return lidar_measure(x[None, 0:3], dcm_from_euler(x[6:9])[None], lms).ravel()

    x0, eps = np.concatenate([_HOVER[:9], landmarks.ravel()]), 1e-6
    cols = [(h(x0 + eps * e) - h(x0 - eps * e)) / (2 * eps) for e in np.eye(x0.size)]
    return np.column_stack(cols)


def _phi(t: float) -> np.ndarray:
    """exp(F t) at the level hover, exactly I + F t + F² t²/2 (F nilpotent: position ←
    velocity ← tilt; ρ̇ = C_NB v, v̇ = C_NBᵀ g n3 written out)."""
    F = np.zeros((9, 9))
    F[0:3, 3:6] = dcm_from_euler(_HOVER[6:9])
    F[3, 7], F[4, 6] = -9.81, 9.81
    return np.eye(9) + F * t + F @ F * (t * t / 2.0)


def _landmark_block(P: np.ndarray, j: int) -> np.ndarray:
    return P[9 + 3 * j : 12 + 3 * j, 9 + 3 * j : 12 + 3 * j]


# ------------------------------------------------------------ (a) no process noise
def test_static_vehicle_landmark_bound_is_the_joint_information_sum() -> None:
    result = slam_bound(_record([np.arange(3)] * (_STEPS // _EVERY)), _model(_P0))
    H = _jacobians(_LANDMARKS)
    Rinv = np.diag(np.tile(1.0 / _SIGMA**2, 3))
    J = np.zeros((18, 18))
    J[:9, :9] = np.linalg.inv(_P0)  # the landmarks start with no information at all
    for k in range(_EVERY, _STEPS + 1, _EVERY):
        Phi = np.eye(18)
        Phi[:9, :9] = _phi(k * _DT)
        J = J + Phi.T @ H.T @ Rinv @ H @ Phi
    T = np.eye(18)
    T[:9, :9] = _phi(_STEPS * _DT)
    expected = T @ np.linalg.inv(J) @ T.T
    assert result.landmark_cov is not None and result.landmark_var is not None
    for j in range(3):
        block = _landmark_block(expected, j)
        np.testing.assert_allclose(result.landmark_cov[j], block, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(result.landmark_var[-1, j], np.diag(block), rtol=1e-6)
    # Before the first scan no landmark has a bound; between scans the map block is constant.
    assert np.isnan(result.landmark_var[_EVERY - 1]).all()
    np.testing.assert_array_equal(result.landmark_var[_EVERY + 5], result.landmark_var[_EVERY])
    # The gauge: no landmark is known better than the prior knows the vehicle's position.
    assert np.all(np.trace(result.landmark_cov, axis1=1, axis2=2) > np.trace(_P0[:3, :3]))


# ---------------------------------------------------- (b) IMU noise, linear Kalman case
def _information_predict(Y: np.ndarray, Phi: np.ndarray, Gam: np.ndarray) -> np.ndarray:
    """Textbook information-filter prediction, valid for a singular ``Y`` (zero information
    on the unseen landmarks): with ``M = Φ⁻ᵀ Y Φ⁻¹``, ``Y⁻ = M − M Γ (I + Γᵀ M Γ)⁻¹ Γᵀ M``."""
    Phi_inv = np.linalg.inv(Phi)
    M = Phi_inv.T @ Y @ Phi_inv
    S = np.eye(Gam.shape[1]) + Gam.T @ M @ Gam
    out = M - M @ Gam @ np.linalg.solve(S, Gam.T @ M)
    return 0.5 * (out + out.T)


def test_landmark_bound_is_the_kalman_covariance_with_process_noise() -> None:
    sa, sg = 0.05, 0.004  # accelerometer m/s², gyro rad/s per sample
    late = 3  # landmark 2 is first seen at the third scan
    scans = [np.arange(3) if i + 1 >= late else np.arange(2) for i in range(_STEPS // _EVERY)]
    result = slam_bound(_record(scans), _model(_P0, sa, sg))
    # The hover's transition (the filter's, checked against finite differences in
    # test_pcrb.py), extended over the static landmarks.
    F, G = np.empty((9, 9)), np.empty((9, 4))
    A, M, Phi9 = (np.empty((9, 9)) for _ in range(3))
    Gam9 = np.empty((9, 4))
    transition_matrices(_HOVER[:9].copy(), 9, 0.0, 0.0, 0.0, sa * _DT, sg * _DT, _DT,
                        F, G, A, M, Phi9, Gam9)  # fmt: skip
    Phi, Gam = np.eye(18), np.zeros((18, 4))
    Phi[:9, :9], Gam[:9] = Phi9, Gam9
    H = _jacobians(_LANDMARKS)
    Y = np.zeros((18, 18))
    Y[:9, :9] = np.linalg.inv(_P0)
    assert result.landmark_var is not None
    for k in range(1, _STEPS + 1):
        Y = _information_predict(Y, Phi, Gam)
        if k % _EVERY:
            continue
        rows = np.concatenate([np.arange(3 * j, 3 * j + 3) for j in scans[k // _EVERY - 1]])
        Y = Y + H[rows].T @ np.diag(np.tile(1.0 / _SIGMA**2, rows.size // 3)) @ H[rows]
        if k // _EVERY < late:  # landmark 2 still has no information: no finite bound
            assert np.isnan(result.landmark_var[k, 2]).all()
            continue
        P = np.linalg.inv(Y)
        for j in range(3):
            np.testing.assert_allclose(
                result.landmark_var[k, j], np.diag(_landmark_block(P, j)), rtol=1e-6
            )
    assert result.landmark_cov is not None
    np.testing.assert_allclose(result.landmark_cov[2], _landmark_block(P, 2), rtol=1e-6)


# ------------------------------------------------------------------- (c) Monte Carlo
def test_monte_carlo_landmark_errors_have_the_bound_as_covariance() -> None:
    """Pose known but for a position prior (attitude and velocity exact, no process noise):
    each landmark's efficient estimate is the estimated position plus the mean of the
    inverse-model points of its scans (seed 001 eq. 44), and its error covariance is the
    bound, ``P0_ρ + H_l⁻¹ R H_l⁻ᵀ / N`` to first order."""
    P0 = np.zeros((9, 9))
    P0[:3, :3] = np.diag([4e-4, 9e-4, 1e-3])
    result = slam_bound(_record([np.arange(3)] * (_STEPS // _EVERY)), _model(P0))
    assert result.landmark_cov is not None
    runs, scans = 4000, _STEPS // _EVERY
    rng = np.random.default_rng(7)
    pos, C = _HOVER[:3], dcm_from_euler(_HOVER[6:9])
    clean = lidar_measure(pos[None], C[None], _LANDMARKS)  # (3, 3): landmark × (α, β, δ)
    noisy = clean + _SIGMA * rng.standard_normal((runs, scans, 3, 3))
    pos_est = pos + rng.multivariate_normal(np.zeros(3), P0[:3, :3], size=runs)  # (runs, 3)
    points = lidar_inverse(pos[None, None, None], C, noisy) - pos  # relative, (runs, scans, 3, 3)
    est = pos_est[:, None, :] + points.mean(axis=1)  # (runs, 3 landmarks, 3)
    err = est - _LANDMARKS
    for j in range(3):
        nees = np.einsum("ri,ij,rj->r", err[:, j], np.linalg.inv(result.landmark_cov[j]), err[:, j])
        lo, hi = chi2.ppf([0.0005, 0.9995], 3 * runs) / runs
        assert lo < nees.mean() < hi, (j, nees.mean(), lo, hi)


# ------------------------------------------------------------- (d) the map RMSE bound
def test_map_error_bound_averages_the_traces_of_the_mapped_landmarks() -> None:
    var = np.full((3, 3, 3), np.nan)
    var[1, 0] = [1.0, 2.0, 3.0]  # landmark 0 seen at step 1
    var[2, :2] = [[1.0, 1.0, 1.0], [4.0, 4.0, 4.0]]
    np.testing.assert_allclose(map_error_bound(var), [np.nan, 6.0, 7.5])
    mapped = np.array([[False] * 3, [True, False, False], [False, True, True]])
    np.testing.assert_allclose(map_error_bound(var, mapped), [np.nan, 6.0, 12.0])
    assert map_error_bound(var, mapped)[2] == pytest.approx(12.0)
