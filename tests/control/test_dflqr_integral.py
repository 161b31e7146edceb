"""DF-LQR's optional integral action: the steady offset it removes (against the analytic
offset without it), its per-lane reset and its stability bound."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401
from agents.control.dflqr import DFLQRPolicy, integral_gain_bound, lqr_gain
from quadslam_env.types import GRAVITY

MASS_SCALE = 1.2


def _hover_offset(integral_gain: float) -> np.ndarray:
    """(3,) position error (heading frame, m) after 60 s of hover on the truth with the
    vehicle 20 % heavier than the controller's model (pinned through ``reset``)."""
    # The offset without the integral (11 m) exceeds the default 10 m error limit.
    episode = {"duration_s": 60.0, "max_pos_err_m": 30.0}
    env = gym.make("QuadSLAM-Oracle-v0", scenario="hover", episode=episode)
    try:
        policy = DFLQRPolicy.from_env(env, integral_gain=integral_gain)
        obs, _ = env.reset(seed=0, options={"randomized": {"mass_scale": MASS_SCALE}})
        state, start = None, np.array([True])
        terminated = truncated = False
        while not (terminated or truncated):
            action, state = policy.predict(obs, state=state, episode_start=start)
            start = np.array([False])
            obs, _, terminated, truncated, _ = env.step(action)
        assert not terminated
        return np.asarray(obs[:3], dtype=float)
    finally:
        env.close()


def test_without_integral_a_heavy_vehicle_settles_at_the_analytic_offset() -> None:
    # Thrust m‖u‖ on a vehicle of mass 1.2 m holds hover when ‖u‖ = 1.2 g: the position loop
    # supplies Δa = 0.2 g, so it settles Δa / k_p below the reference (NED z down).
    k_p = lqr_gain()[2, 2]
    offset = _hover_offset(0.0)
    assert offset[2] == pytest.approx((MASS_SCALE - 1.0) * GRAVITY / k_p, rel=2e-3)
    assert np.abs(offset[:2]).max() < 1e-9


def test_with_integral_the_offset_goes_to_zero() -> None:
    offset = _hover_offset(0.02)
    assert np.abs(offset).max() < 0.01


def _policy(integral_gain: float) -> DFLQRPolicy:
    env = gym.make("QuadSLAM-Oracle-v0", scenario="hover")
    try:
        return DFLQRPolicy.from_env(env, integral_gain=integral_gain)
    finally:
        env.close()


def test_the_integral_is_the_state_and_resets_per_lane() -> None:
    policy = _policy(0.02)
    rng = np.random.default_rng(0)
    obs = np.zeros((3, 16))
    obs[:, 0:3] = rng.normal(size=(3, 3))
    dt = policy.control_dt
    _, state = policy.predict(obs, episode_start=np.ones(3, dtype=bool))
    # ψ̇_d = 0: one Euler step of the error from zero; the clock at one step.
    np.testing.assert_allclose(state[:, :3], obs[:, 0:3] * dt)
    np.testing.assert_allclose(state[:, 3], dt)
    action, state2 = policy.predict(obs, state=state, episode_start=np.array([False, True, False]))
    np.testing.assert_allclose(state2[[0, 2], :3], 2 * obs[[0, 2], 0:3] * dt)
    np.testing.assert_allclose(state2[:, 3], [2 * dt, dt, 2 * dt])
    np.testing.assert_allclose(state2[1, :3], obs[1, 0:3] * dt)  # lane 1 restarted from zero
    # Lane 1 flew the restarted integral: the same action as a fresh single-lane policy call,
    # and lane 0 the integral's bias: −k_i ∫ρ̃ on u_p changes its command.
    single, _ = policy.predict(obs[1], episode_start=np.array([True]))
    np.testing.assert_array_equal(action[1], single)
    fresh, _ = policy.predict(obs[0], episode_start=np.array([True]))
    assert not np.array_equal(action[0], fresh)


def test_the_integral_is_held_at_zero_after_the_start() -> None:
    env = gym.make("QuadSLAM-Oracle-v0", scenario="hover")
    try:
        policy = DFLQRPolicy.from_env(env, integral_gain=0.02, integral_hold_s=0.05)
    finally:
        env.close()
    obs = np.zeros((1, 16))
    obs[0, 0:3] = 1.0
    state: Any = None
    for step in range(1, 8):
        _, state = policy.predict(obs, state=state, episode_start=np.array([step == 1]))
        held = step <= 5  # the clock reads 0 … 0.04 s before steps 1 … 5
        assert (state[0, 0] == 0.0) == held, step
    np.testing.assert_allclose(state[0, :3], 2 * policy.control_dt)


def test_the_integral_turns_with_the_heading_frame() -> None:
    # A world-frame integral seen from a heading frame turning at ψ̇_d: its components rotate
    # by −ψ̇_d dt per step (with zero error nothing else changes).
    policy = _policy(0.02)
    obs = np.zeros((1, 16))
    obs[0, 15] = 0.5
    state = np.array([[1.0, 0.0, 0.3, 7.0]])
    _, out = policy.predict(obs, state=state, episode_start=np.array([False]))
    angle = -0.5 * policy.control_dt
    np.testing.assert_allclose(out, [[np.cos(angle), np.sin(angle), 0.3, 7.0 + policy.control_dt]])


def test_off_by_default_passes_the_state_through() -> None:
    policy = _policy(0.0)
    marker = object()
    _, state = policy.predict(np.zeros(16), state=marker)
    assert state is marker


def test_the_gain_must_be_below_the_routh_hurwitz_bound() -> None:
    bound = integral_gain_bound(lqr_gain())
    # z: s³ + K_d s² + K_p s + k_i is marginally stable at k_i = K_p K_d: roots on the axis.
    K = lqr_gain()
    roots = np.roots([1.0, K[2, 5], K[2, 2], K[2, 2] * K[2, 5]])
    assert np.abs(roots.real).min() < 1e-9 and bound == pytest.approx(K[2, 2] * K[2, 5])
    with pytest.raises(ValueError, match="integral_gain"):
        _policy(bound)
    with pytest.raises(ValueError, match="integral_gain"):
        _policy(-0.01)
    env = gym.make("QuadSLAM-Oracle-v0", scenario="hover")
    try:
        with pytest.raises(ValueError, match="integral_hold_s"):
            DFLQRPolicy.from_env(env, integral_gain=0.02, integral_hold_s=-1.0)
    finally:
        env.close()


def test_anti_windup_clamps_the_contribution_and_freezes_on_saturated_thrust() -> None:
    policy = _policy(0.02)
    cap = policy.integral_limit / policy.integral_gain
    obs = np.zeros((2, 16))
    obs[:, 0:3] = 1.0
    obs[1, 14] = -50.0  # 50 m/s² up: the thrust command saturates at its maximum
    state = np.array([[2 * cap, -2 * cap, 0.0, 20.0], [0.1, 0.2, 0.3, 20.0]])
    action, out = policy.predict(obs, state=state, episode_start=np.zeros(2, dtype=bool))
    assert action[1, 0] == 1.0
    np.testing.assert_allclose(out[0, :3], [cap, -cap, policy.control_dt])
    np.testing.assert_array_equal(out[1, :3], state[1, :3])
