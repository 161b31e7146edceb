"""DF-LQR baseline: gain, inverse mapping, and closed-loop tracking on the oracle estimate."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

import quadslam_env  # noqa: F401
from agents.control.dflqr import Q_TILDE, R_TILDE, DFLQRPolicy, lqr_gain
from quadslam_env.models.flatness import inverse_mapping
from quadslam_env.models.frames import rot1, rot2, rot3
from quadslam_env.types import GRAVITY


def test_lqr_gain_matches_closed_form_riccati_solution() -> None:
    # The flat system decouples into three double integrators (ρ_i, ρ̇_i) and one single
    # integrator (ψ). For ẍ = u with Q = diag(q1, q2), R = r the CARE gives
    # K = [√(q1/r), √(q2/r + 2√(q1/r))]; for ẋ = u, K = √(q/r).
    K = lqr_gain()
    assert K.shape == (4, 7)
    q = np.diag(Q_TILDE)
    r = np.diag(R_TILDE)
    expected = np.zeros((4, 7))
    for i in range(3):
        kp = math.sqrt(q[i] / r[i])
        expected[i, i] = kp
        expected[i, 3 + i] = math.sqrt(q[3 + i] / r[i] + 2.0 * kp)
    expected[3, 6] = math.sqrt(q[6] / r[3])
    np.testing.assert_allclose(K, expected, atol=1e-9)


def test_lqr_gain_matches_steady_state_of_riccati_differential_equation() -> None:
    # A second independent solution: integrate the Riccati ODE Ṗ = A'P + PA - PBR⁻¹B'P + Q
    # from P = 0 to steady state (no scipy CARE involved) and compare the gains.
    A = np.zeros((7, 7))
    A[0:3, 3:6] = np.eye(3)
    B = np.zeros((7, 4))
    B[3:7, :] = np.eye(4)
    P = np.zeros((7, 7))
    Rinv = np.linalg.inv(R_TILDE)
    dt = 0.01
    for _ in range(20000):
        P = P + dt * (A.T @ P + P @ A - P @ B @ Rinv @ B.T @ P + Q_TILDE)
    np.testing.assert_allclose(lqr_gain(), Rinv @ B.T @ P, atol=1e-4)


@pytest.mark.parametrize("seed", range(5))
def test_inverse_mapping_rebuilds_u_p_through_forward_model(seed: int) -> None:
    rng = np.random.default_rng(seed)
    mass = 1.56
    u_p = np.array([rng.uniform(-4, 4), rng.uniform(-4, 4), rng.uniform(-15, -5)])
    psi_d = rng.uniform(-math.pi, math.pi)
    u_heading = rot3(psi_d).T @ u_p
    u_psi = rng.uniform(-1, 1)
    thrust, phi_d, theta_d, r_d = inverse_mapping(np.array([[*u_heading, u_psi]]), mass)
    # Forward model (seed 001 eq. 9): u_p = (1/m) C_NB f_T with f_T = -f_T b3.
    c_nb = rot3(psi_d) @ rot2(theta_d[0]) @ rot1(phi_d[0])
    rebuilt = c_nb @ np.array([0.0, 0.0, -thrust[0]]) / mass
    np.testing.assert_allclose(rebuilt, u_p, atol=1e-10)
    # ψ̇ = (q sin φ + r cos φ)/cos θ with q_d = 0 gives back u_ψ (eq. 18-19).
    assert r_d[0] * math.cos(phi_d[0]) / math.cos(theta_d[0]) == pytest.approx(u_psi)


def test_hover_observation_gives_hover_command() -> None:
    env = gym.make("QuadSLAM-Oracle-v0")
    policy = DFLQRPolicy.from_env(env)
    thrust, torque = policy.command(np.zeros((1, 16)))
    assert thrust[0] == pytest.approx(env.unwrapped.vehicle_params.mass * GRAVITY)
    np.testing.assert_allclose(torque, 0.0, atol=1e-12)


def test_oracle_tracking_of_figure8_after_climb() -> None:
    env = gym.make("QuadSLAM-Oracle-v0")
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    errors = []
    while True:
        action, _ = policy.predict(obs)
        obs, _, terminated, truncated, info = env.step(action)
        errors.append(info["track_pos_err_m"])
        if terminated or truncated:
            break
    assert not terminated
    after_climb = np.array(errors[int(15.0 / env.unwrapped.dt) :])
    assert math.sqrt(np.mean(after_climb**2)) < 0.06


def test_works_with_sb3_evaluate_policy() -> None:
    env = Monitor(gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 2.0}))
    policy = DFLQRPolicy.from_env(env)
    mean, std = evaluate_policy(policy, env, n_eval_episodes=2, deterministic=True)
    assert np.isfinite(mean) and np.isfinite(std)


def test_batched_predict_equals_single() -> None:
    env = gym.make("QuadSLAM-Oracle-v0")
    policy = DFLQRPolicy.from_env(env)
    rng = np.random.default_rng(3)
    obs = rng.normal(scale=0.3, size=(5, 16)).astype(np.float32)
    batch, _ = policy.predict(obs)
    for i in range(5):
        single, _ = policy.predict(obs[i])
        np.testing.assert_allclose(single, batch[i])


def test_rejects_rate_action_mode() -> None:
    env = gym.make("QuadSLAM-Oracle-v0", action={"mode": "thrust_rates"})
    with pytest.raises(ValueError, match=r"action\.mode"):
        DFLQRPolicy.from_env(env)
