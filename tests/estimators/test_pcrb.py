"""The posterior Cramér–Rao bound (estimators/pcrb.py) against closed forms.

(a) Linear-Gaussian: the PCRB recursion in information form equals the Kalman filter's
covariance recursion, and converges to the discrete algebraic Riccati equation's solution.
(b) A hovering vehicle (static truth) seeing fixed landmarks: with no process noise the bound
is the information sum ``J0 + Σ Φ_kᵀ Hᵀ R⁻¹ H Φ_k`` mapped to the final time, for a known map
and — with zero prior information on the landmarks — for an unknown one.
(c) The Jacobians factored out of the EKF's prediction (transition, noise input, discrete Q)
and the error transforms vs finite differences.
"""

from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.linalg import solve_discrete_are

from estimators.ekf.kernels import propagate_covariance, transition_matrices
from estimators.ekf.settings import EkfSlamSettings
from estimators.pcrb import (
    BoundModel,
    TruthRecord,
    augment_without_prior,
    covariance_predict,
    covariance_update,
    error_bounds,
    error_transforms,
    information_step,
    slam_bound,
)
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.strapdown import strapdown_rk4
from quadslam_env.types import GRAVITY


# ----------------------------------------------------------------------- (a) linear case
def _double_integrator(dt: float = 0.1, q: float = 0.5, r: float = 0.04):
    F = np.array([[1.0, dt], [0.0, 1.0]])
    Q = q * np.array([[dt**3 / 3, dt**2 / 2], [dt**2 / 2, dt]])
    H = np.array([[1.0, 0.0]])
    R = np.array([[r]])
    return F, Q, H, R


def test_information_recursion_equals_kalman_covariance() -> None:
    F, Q, H, R = _double_integrator()
    P0 = np.diag([2.0, 0.5])
    J = np.linalg.inv(P0)
    P = P0.copy()  # textbook Kalman filter, written out here
    B = P0.copy()  # the bound's covariance form
    for _ in range(60):
        J = information_step(J, F, Q, H, R)
        Pm = F @ P @ F.T + Q
        K = Pm @ H.T @ np.linalg.inv(H @ Pm @ H.T + R)
        P = (np.eye(2) - K @ H) @ Pm
        B = covariance_update(covariance_predict(B, F, Q), H, R)
        np.testing.assert_allclose(np.linalg.inv(J), P, rtol=1e-10, atol=1e-14)
        np.testing.assert_allclose(B, P, rtol=1e-10, atol=1e-14)
    # Steady state: the filtered covariance of the DARE's predicted solution.
    Pm = solve_discrete_are(F.T, H.T, Q, R)
    P_inf = Pm - Pm @ H.T @ np.linalg.inv(H @ Pm @ H.T + R) @ H @ Pm
    np.testing.assert_allclose(np.linalg.inv(J), P_inf, rtol=1e-8)


def test_information_step_without_measurement_is_the_prediction() -> None:
    F, Q, _, _ = _double_integrator()
    P0 = np.array([[1.0, 0.2], [0.2, 0.3]])
    J = information_step(np.linalg.inv(P0), F, Q, None, None)
    np.testing.assert_allclose(np.linalg.inv(J), F @ P0 @ F.T + Q, rtol=1e-12)


def test_augment_without_prior_is_the_limit_of_a_flat_prior() -> None:
    rng = np.random.default_rng(3)
    A = rng.standard_normal((4, 4))
    P = A @ A.T + 0.1 * np.eye(4)
    rows = np.array([0, 2, 3])
    H_x = rng.standard_normal((3, 3))
    H_l = rng.standard_normal((3, 3)) + 3.0 * np.eye(3)
    R = np.diag([0.1, 0.2, 0.05])
    out = augment_without_prior(P, rows, H_x, H_l, R)
    # The joint information with zero prior information on l, inverted.
    H = np.zeros((3, 7))
    H[:, rows] = H_x
    H[:, 4:] = H_l
    J = np.zeros((7, 7))
    J[:4, :4] = np.linalg.inv(P)
    J += H.T @ np.linalg.inv(R) @ H
    np.testing.assert_allclose(out, np.linalg.inv(J), rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(out[:4, :4], P)  # a first sighting says nothing about x


# --------------------------------------------------------------- (b) static vehicle, map
_HOVER = np.array([0.5, -0.3, -2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.3, 0.0, 0.0, 0.0])
_LANDMARKS = np.array([[8.0, 1.0, -2.5], [7.0, -2.0, -1.0], [9.0, 3.0, -3.0]])
_SIGMA = np.array([0.006, 0.005, 0.1])
_DT, _STEPS, _EVERY = 0.01, 60, 10


def _hover_jacobian() -> np.ndarray:
    """∂f/∂s of seed 001 eq. 24 at a level hover at rest (written out independently):
    ρ̇ = C_NB v gives C_NB(ψ) on the velocity; v̇ = C_NBᵀ g n3 gives −g on θ and +g on φ."""
    F = np.zeros((9, 9))
    F[0:3, 3:6] = dcm_from_euler(_HOVER[6:9])
    F[3, 7] = -GRAVITY
    F[4, 6] = GRAVITY
    return F


def _measurement_jacobian(landmarks: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Central differences of the LiDAR measurement w.r.t. the pose (9) and the landmarks."""

    def h(s: np.ndarray, lms: np.ndarray) -> np.ndarray:
        return lidar_measure(s[None, 0:3], dcm_from_euler(s[6:9])[None], lms).ravel()

    s0, eps = _HOVER[:9], 1e-6
    k = landmarks.shape[0]
    H_s = np.zeros((3 * k, 9))
    H_l = np.zeros((3 * k, 3 * k))
    for i in range(9):
        d = np.zeros(9)
        d[i] = eps
        H_s[:, i] = (h(s0 + d, landmarks) - h(s0 - d, landmarks)) / (2 * eps)
    flat = landmarks.ravel()
    for i in range(3 * k):
        d = np.zeros(3 * k)
        d[i] = eps
        up, down = (flat + d).reshape(-1, 3), (flat - d).reshape(-1, 3)
        H_l[:, i] = (h(s0, up) - h(s0, down)) / (2 * eps)
    return H_s, H_l


def _hover_bound(known_map: bool, P0: np.ndarray):
    record = TruthRecord(
        dt=_DT,
        state=np.tile(_HOVER, (_STEPS + 1, 1)),
        rates=np.zeros((_STEPS, 3)),
        landmarks=_LANDMARKS,
        scan_steps=np.arange(_EVERY, _STEPS + 1, _EVERY),
        scan_ids=[np.arange(3)] * (_STEPS // _EVERY),
    )
    model = BoundModel(
        settings=EkfSlamSettings.from_dict({"process_noise": [0.0] * 9}),
        accel_sigma=0.0,
        gyro_sigma=0.0,
        lidar_sigma=_SIGMA,
        cov0=P0,
        known_map=known_map,
    )
    return slam_bound(record, model)


def _phi(t: float) -> np.ndarray:
    """exp(F t) = I + F t + F² t²/2 exactly: F is nilpotent (position ← velocity ← tilt)."""
    F = _hover_jacobian()
    return np.eye(9) + F * t + F @ F * (t * t / 2.0)


def test_static_vehicle_known_map_bound_is_the_information_sum() -> None:
    P0 = np.diag([0.01] * 3 + [0.01] * 3 + [0.001] * 3)
    result = _hover_bound(True, P0)
    H_s, _ = _measurement_jacobian(_LANDMARKS)
    Rinv = np.diag(np.tile(1.0 / _SIGMA**2, 3))
    J0 = np.linalg.inv(P0)  # information of the initial state, then of every scan
    for k in range(_EVERY, _STEPS + 1, _EVERY):
        Phi = _phi(k * _DT)
        J0 = J0 + Phi.T @ H_s.T @ Rinv @ H_s @ Phi
    T = _phi(_STEPS * _DT)
    expected = T @ np.linalg.inv(J0) @ T.T
    np.testing.assert_allclose(result.pose_cov[-1], expected, rtol=1e-6, atol=1e-12)
    assert result.n_landmarks[-1] == 0
    # Between scans the bound only moves with the dynamics.
    P5 = result.pose_cov[5]
    np.testing.assert_allclose(P5, _phi(5 * _DT) @ P0 @ _phi(5 * _DT).T, rtol=1e-9, atol=1e-15)


def test_static_vehicle_unknown_map_bound_is_the_joint_information_sum() -> None:
    P0 = np.diag([0.01] * 3 + [0.01] * 3 + [0.001] * 3)
    result = _hover_bound(False, P0)
    H_s, H_l = _measurement_jacobian(_LANDMARKS)
    H = np.hstack([H_s, H_l])
    Rinv = np.diag(np.tile(1.0 / _SIGMA**2, 3))
    J = np.zeros((18, 18))
    J[:9, :9] = np.linalg.inv(P0)  # the landmarks start with no information at all
    for k in range(_EVERY, _STEPS + 1, _EVERY):
        Phi = np.eye(18)
        Phi[:9, :9] = _phi(k * _DT)
        J = J + Phi.T @ H.T @ Rinv @ H @ Phi
    T = np.eye(18)
    T[:9, :9] = _phi(_STEPS * _DT)
    expected = (T @ np.linalg.inv(J) @ T.T)[:9, :9]
    np.testing.assert_allclose(result.pose_cov[-1], expected, rtol=1e-6, atol=1e-12)
    assert result.n_landmarks[-1] == 3
    # The landmarks carry no absolute information: the position bound cannot drop below the
    # prior's position block (shifting vehicle and map together changes no measurement).
    known = _hover_bound(True, P0).pose_cov[-1]
    assert np.trace(result.pose_cov[-1][:3, :3]) > np.trace(known[:3, :3])
    assert np.trace(result.pose_cov[-1][:3, :3]) >= 0.999 * np.trace(P0[:3, :3])


# ------------------------------------------------------------- (c) Jacobians vs FD
_STATE = np.array([0.3, -1.2, -2.0, 1.5, -0.4, 0.3, 0.12, -0.2, 0.9])
_RATES = np.array([0.3, -0.2, 0.5])
_AZ = -9.3


def _rk4(s: np.ndarray, az: float, rates: np.ndarray, dt: float) -> np.ndarray:
    y = np.concatenate([s, rates])
    strapdown_rk4(y, 0.0, 0.0, az, dt, np.empty((6, 12)))
    return y[:9]


def _transition(dt: float, nv: int = 13, sa: float = 0.0, sg: float = 0.0):
    F, G = np.empty((9, 9)), np.empty((9, 4))
    A, M, Phi = (np.empty((nv, nv)) for _ in range(3))
    Gam = np.empty((nv, 4))
    xb = np.zeros(nv)
    xb[:9] = _STATE
    transition_matrices(xb, nv, *_RATES, sa, sg, dt, F, G, A, M, Phi, Gam)
    return Phi, Gam


def _fd_step_jacobian(dt: float) -> np.ndarray:
    """∂(one RK4 step)/∂(s, b_ω, b_az) by central differences, λ = λ̃ − b."""
    eps = 1e-6
    out = np.zeros((9, 13))
    for i in range(13):
        d = np.zeros(13)
        d[i] = eps

        def step(delta: np.ndarray) -> np.ndarray:
            return _rk4(_STATE + delta[:9], _AZ - delta[12], _RATES - delta[9:12], dt)

        out[:, i] = (step(d) - step(-d)) / (2 * eps)
    return out


def test_transition_matches_the_rk4_step_to_second_order() -> None:
    errors = []
    for dt in (0.02, 0.01):
        Phi, _ = _transition(dt)
        fd = _fd_step_jacobian(dt)
        errors.append(np.abs(Phi[:9, :] - fd).max())
        np.testing.assert_allclose(Phi[9:, :], np.hstack([np.zeros((4, 9)), np.eye(4)]))
        assert errors[-1] < 5e-4
    # Φ = I + A + ½A² omits the change of F along the step: a local error O(dt²).
    assert 3.0 < errors[0] / errors[1] < 5.0


def test_noise_input_matches_the_step_jacobian_of_the_imu_input() -> None:
    dt, sa, sg = 0.01, 0.03, 0.002
    _, Gam = _transition(dt, sa=sa * dt, sg=sg * dt)
    fd = _fd_step_jacobian(dt)  # ∂step/∂λ = −∂step/∂b (columns 9–12: b_ω, b_az)
    expected = np.column_stack([-fd[:, 12] * sa, -fd[:, 9:12] * sg])
    # Γ = (I + ½A) G σ dt is the step's input Jacobian to second order: 1% per column.
    assert np.all(np.abs(Gam[:9] - expected) <= 0.01 * np.abs(expected).max(axis=0))
    np.testing.assert_array_equal(Gam[9:], 0.0)


def test_discrete_noise_is_gamma_gamma_t_plus_q_dt() -> None:
    dt, nv = 0.01, 13
    _, Gam = _transition(dt, nv, 0.03 * dt, 0.002 * dt)
    Phi = np.eye(nv)
    qc = np.arange(1.0, nv + 1.0) * 1e-3
    P = np.zeros((nv, nv))
    T, Pvv = np.empty((nv, nv)), np.empty((nv, nv))
    assert propagate_covariance(P, nv, nv, Phi, Gam, qc, dt, T, Pvv)
    np.testing.assert_allclose(Pvv, Gam @ Gam.T + np.diag(qc) * dt, rtol=1e-12, atol=1e-20)


def test_error_transforms_vs_finite_differences() -> None:
    T_v, T_a = error_transforms(_STATE)
    eps = 1e-6

    def vel_n(x: np.ndarray) -> np.ndarray:
        return dcm_from_euler(x[3:6]) @ x[0:3]

    x0 = _STATE[3:9]
    fd_v = np.column_stack(
        [(vel_n(x0 + eps * e) - vel_n(x0 - eps * e)) / (2 * eps) for e in np.eye(6)]
    )
    np.testing.assert_allclose(T_v, fd_v, atol=1e-7)
    C0 = dcm_from_euler(_STATE[6:9])

    def rot_vec(delta: np.ndarray) -> np.ndarray:  # small rotation C_trueᵀ C_est ≈ I + [r×]
        M = C0.T @ dcm_from_euler(_STATE[6:9] + delta)
        S = 0.5 * (M - M.T)
        return np.array([S[2, 1], S[0, 2], S[1, 0]])

    fd_a = np.column_stack([(rot_vec(eps * e) - rot_vec(-eps * e)) / (2 * eps) for e in np.eye(3)])
    np.testing.assert_allclose(T_a, fd_a, atol=1e-7)
    # The attitude bound is then a bound on the squared rotation angle the metrics report.
    P = np.zeros((1, 9, 9))
    P[0, 6:9, 6:9] = np.diag([1e-4, 2e-4, 3e-4])
    b = error_bounds(_STATE[None], P)
    assert b["att_rad2"][0] == pytest.approx(np.trace(T_a @ P[0, 6:9, 6:9] @ T_a.T))
    assert math.isclose(b["pos_m2"][0], 0.0)


def test_no_estimator_imports_the_bound() -> None:
    """The bound evaluates models at the truth: estimators must never use it (DESIGN §1)."""
    root = Path(__file__).resolve().parents[2] / "estimators"
    for path in root.rglob("*.py"):
        if path.name == "pcrb.py":
            continue
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            names = []
            if isinstance(node, ast.ImportFrom):
                names = [node.module or ""] + [f"{node.module}.{a.name}" for a in node.names]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            assert not any(n.startswith("estimators.pcrb") for n in names), path
