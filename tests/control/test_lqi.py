"""The LQI baseline: its gain against an independent solve of the augmented Riccati equation,
zero steady-state error under a constant disturbance (final-value theorem, and flown), DF-LQR
bit for bit with no integral weight, conditional integration, lanes equal to the scalar env,
and its bad weights."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401
from agents.control.dflqr import Q_TILDE, R_TILDE, DFLQRPolicy, lqr_gain
from agents.control.lqi import INTEGRAL_WEIGHTS, STATE_WEIGHTS, LQIPolicy, lqi_gain
from agents.control.named import build_controller
from quadslam_env.schema import ConfigError


def _hamiltonian_care(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: np.ndarray) -> np.ndarray:
    """P of ``AᵀP + PA − PBR⁻¹BᵀP + Q = 0`` from the stable invariant subspace of the
    Hamiltonian (Laub's method, written out with numpy's eigenvectors: not scipy's solver)."""
    n = A.shape[0]
    H = np.block([[A, -B @ np.linalg.solve(R, B.T)], [-Q, -A.T]])
    w, V = np.linalg.eig(H)
    stable = V[:, w.real < 0.0]
    assert stable.shape[1] == n
    U, W = stable[:n], stable[n:]
    return np.real(W @ np.linalg.inv(U))


def _augmented() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The 11-state LQI system written out by hand: z = (∫x̃, ∫ỹ, ∫z̃, ∫ψ̃, x̃, ỹ, z̃, ẋ̃, ẏ̃,
    ż̃, ψ̃), inputs (a_x, a_y, a_z, ψ̇)."""
    A = np.zeros((11, 11))
    A[0, 4] = A[1, 5] = A[2, 6] = A[3, 10] = 1.0  # ξ̇ = (ρ̃, ψ̃)
    A[4, 7] = A[5, 8] = A[6, 9] = 1.0  # ρ̃̇ = velocity error
    B = np.zeros((11, 4))
    B[7, 0] = B[8, 1] = B[9, 2] = B[10, 3] = 1.0
    Q = np.zeros((11, 11))
    Q[:4, :4] = np.diag(INTEGRAL_WEIGHTS)
    Q[4:, 4:] = STATE_WEIGHTS
    return A, B, Q


def test_gain_matches_an_independent_solve_of_the_augmented_riccati_equation() -> None:
    A, B, Q = _augmented()
    P = _hamiltonian_care(A, B, Q, R_TILDE)
    K = np.linalg.solve(R_TILDE, B.T @ P)
    K_r, K_xi, poles = lqi_gain()
    np.testing.assert_allclose(K_xi, K[:, :4], atol=1e-8)
    np.testing.assert_allclose(K_r, K[:, 4:], atol=1e-8)
    np.testing.assert_allclose(
        np.sort_complex(poles), np.sort_complex(np.linalg.eigvals(A - B @ K)), atol=1e-8
    )


def test_a_constant_disturbance_leaves_no_steady_error_final_value_theorem() -> None:
    # ż = (A − BK) z + B d: the equilibrium z* = −(A − BK)⁻¹ B d (the final value of a step
    # disturbance) has r̃ = 0 on every axis; only the integrals hold the disturbance (K_ξ ξ* = d).
    A, B, _ = _augmented()
    K_r, K_xi, _ = lqi_gain()
    K = np.hstack([K_xi, K_r])
    d = np.array([0.7, -0.4, 1.9, 0.05])
    z = -np.linalg.solve(A - B @ K, B @ d)
    np.testing.assert_allclose(z[4:], 0.0, atol=1e-12)
    np.testing.assert_allclose(K_xi @ z[:4], d, rtol=1e-10)
    # DF-LQR's equilibrium keeps the analytic offset d / K_p on each position axis.
    A7, B7 = A[4:, 4:], B[4:]
    r = -np.linalg.solve(A7 - B7 @ lqr_gain(), B7 @ d)
    np.testing.assert_allclose(r[:3], d[:3] / np.diag(lqr_gain())[:3], rtol=1e-10)


def _hover_in_wind(policy_name: str) -> np.ndarray:
    """(3,) position error after 40 s of hover on the truth in a steady 2 m/s wind (linear
    rotor drag 0.3 s⁻¹: a drag of 0.6 m/s² along n1), heading frame, m."""
    episode = {"duration_s": 40.0, "max_pos_err_m": 30.0}
    wind = {"steady_mps": [2.0, 0.0, 0.0]}
    env = gym.make("QuadSLAM-Oracle-v0", scenario="hover", episode=episode, wind=wind,
                   vehicle={"drag_per_s": 0.3})  # fmt: skip
    try:
        policy = build_controller(policy_name, env)
        obs, _ = env.reset(seed=0)
        state, start = None, np.array([True])
        done = False
        while not done:
            action, state = policy.predict(obs, state=state, episode_start=start)
            start = np.array([False])
            obs, _, terminated, truncated, _ = env.step(action)
            done = terminated or truncated
        assert not terminated
        return np.asarray(obs[:3], dtype=float)
    finally:
        env.close()


def test_flown_in_a_steady_wind_lqi_removes_the_offset_dflqr_keeps() -> None:
    # The wind blows along n1 at hover heading 0, so the drag acts on the heading frame's x.
    dflqr = _hover_in_wind("dflqr")
    assert dflqr[0] == pytest.approx(0.3 * 2.0 / lqr_gain()[0, 0], rel=0.02)
    lqi = _hover_in_wind("lqi")
    assert np.abs(lqi).max() < 0.005


def _random_obs(rng: np.random.Generator, n: int) -> np.ndarray:
    obs = rng.normal(0.0, 0.3, size=(n, 16))
    obs[:, 14] = rng.normal(0.0, 0.5, size=n)
    return obs


def _oracle_env(**kwargs: Any) -> gym.Env:
    return gym.make("QuadSLAM-Oracle-v0", **kwargs)


def test_without_integral_weight_it_is_dflqr_bit_for_bit() -> None:
    env = _oracle_env()
    try:
        lqi = LQIPolicy.from_env(env, state_weights=Q_TILDE, integral_weights=np.zeros(4),
                                 max_tilt_deg=90.0)  # fmt: skip
        dflqr = DFLQRPolicy.from_env(env)
        obs = _random_obs(np.random.default_rng(3), 64)
        a, state = lqi.predict(obs)
        assert state is None
        assert np.array_equal(a, dflqr.predict(obs)[0])
        # and along a flight of the paper scenario's start (climb included)
        o_l, _ = env.reset(seed=5)
        for _ in range(300):
            act_l, _ = lqi.predict(o_l)
            assert np.array_equal(act_l, dflqr.predict(o_l)[0])
            o_l, *_ = env.step(act_l)
    finally:
        env.close()


def test_saturated_lanes_do_not_integrate() -> None:
    env = _oracle_env()
    try:
        policy = LQIPolicy.from_env(env)
    finally:
        env.close()
    obs = np.zeros((2, 16))
    obs[:, 14] = 0.0
    obs[0, 2] = -0.05  # a small error: within the actuators' range
    obs[1, 2] = -50.0  # 50 m below: the thrust saturates
    xi0 = np.array([[0.1, 0.0, 0.2, 0.0], [0.1, 0.0, 0.2, 0.0]])
    act, xi = policy.predict(obs, state=xi0, episode_start=np.array([False, False]))
    assert abs(act[0, 0]) < 1.0 and act[1, 0] == 1.0
    np.testing.assert_allclose(xi[0, :3], xi0[0, :3] + obs[0, :3] * policy.control_dt)
    np.testing.assert_array_equal(xi[1], xi0[1])
    # episode_start zeroes a lane's integrals before it acts
    _, xi2 = policy.predict(obs, state=xi0, episode_start=np.array([True, False]))
    np.testing.assert_allclose(xi2[0, :3], obs[0, :3] * policy.control_dt)


def test_vector_lanes_equal_the_scalar_env() -> None:
    kwargs = {"wind": {"steady_mps": [1.5, -1.0, 0.0]}, "vehicle": {"drag_per_s": 0.3}}
    seeds = [11, 12, 13]
    vec = gym.make_vec("QuadSLAM-Oracle-v0", num_envs=3, vectorization_mode="vector_entry_point",
                       **kwargs)  # fmt: skip
    try:
        policy = LQIPolicy.from_env(vec)
        obs, _ = vec.reset(seed=seeds[0])
        state, start = None, np.ones(3, dtype=bool)
        lanes = [obs]
        for _ in range(200):
            act, state = policy.predict(obs, state=state, episode_start=start)
            start = np.zeros(3, dtype=bool)
            obs, *_ = vec.step(act)
            lanes.append(obs)
    finally:
        vec.close()
    for i, seed in enumerate(seeds):
        env = _oracle_env(**kwargs)
        try:
            policy = LQIPolicy.from_env(env)
            o, _ = env.reset(seed=seed)
            state, start = None, np.array([True])
            np.testing.assert_array_equal(o, lanes[0][i])
            for k in range(200):
                a, state = policy.predict(o, state=state, episode_start=start)
                start = np.array([False])
                o, *_ = env.step(a)
                np.testing.assert_array_equal(o, lanes[k + 1][i])
        finally:
            env.close()


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"integral_weights": [-1.0, 1.0, 1.0, 0.0]}, "integral weights >= 0"),
        ({"integral_weights": [np.nan, 1.0, 1.0, 0.0]}, "lqi.integral_weights"),
        ({"integral_weights": [1.0, 1.0]}, "shape"),
        ({"state_weights": np.diag([-1.0] * 7)}, "positive semidefinite"),
        ({"input_weights": np.zeros(4)}, "positive definite"),
        ({"state_weights": np.diag([1e6] * 3 + [0.0] * 3 + [0.04])}, "fastest pole"),
    ],
)
def test_bad_weights_are_refused(kwargs: dict[str, Any], match: str) -> None:
    env = _oracle_env()
    try:
        with pytest.raises(ConfigError, match=match):
            LQIPolicy.from_env(env, **kwargs)
    finally:
        env.close()


def test_an_unknown_controller_name_is_refused() -> None:
    env = _oracle_env()
    try:
        with pytest.raises(ValueError, match=r"--policy: got 'pid'; allowed: one of \['dflqr'"):
            build_controller("pid", env)
    finally:
        env.close()


def test_as_a_residual_base_a_zero_residual_flies_lqi_across_autoresets() -> None:
    from agents.rl.wrappers import ResidualDFLQRVectorWrapper

    kwargs = {"episode": {"duration_s": 1.0}, "wind": {"steady_mps": [2.0, 0.0, 0.0]},
              "vehicle": {"drag_per_s": 0.3}}  # fmt: skip

    def make() -> Any:
        return gym.make_vec("QuadSLAM-Oracle-v0", num_envs=2,
                            vectorization_mode="vector_entry_point", **kwargs)  # fmt: skip

    wrapped, plain = ResidualDFLQRVectorWrapper(make(), base="lqi"), make()
    try:
        policy = LQIPolicy.from_env(plain)
        o_w, _ = wrapped.reset(seed=4)
        o_p, _ = plain.reset(seed=4)
        state, start = None, np.ones(2, dtype=bool)
        ends = 0
        for _ in range(250):  # two and a half episodes of 100 steps
            o_w, *_ = wrapped.step(np.zeros((2, 4), np.float32))
            act, state = policy.predict(o_p, state=state, episode_start=start)
            o_p, _, term, trunc, _ = plain.step(act)
            start = term | trunc
            ends += int(start.sum())
            np.testing.assert_array_equal(o_w, o_p)
        assert ends == 4
    finally:
        wrapped.close()
        plain.close()


def test_the_tilt_limit_scales_the_horizontal_command_only() -> None:
    from agents.control.dflqr import limit_tilt

    tan30 = np.tan(np.radians(30.0))
    ux, uy, uz, limited = limit_tilt(3.0, 4.0, -5.0, tan30)
    assert limited and uz == -5.0
    assert np.hypot(ux, uy) == pytest.approx(5.0 * tan30, rel=1e-12)
    assert ux / uy == pytest.approx(0.75, rel=1e-12)  # the direction kept
    assert limit_tilt(1.0, 1.0, -9.81, tan30) == (1.0, 1.0, -9.81, False)
    assert limit_tilt(30.0, 40.0, -5.0, np.inf) == (30.0, 40.0, -5.0, False)
    # a lane whose command is tilt-limited does not integrate
    env = _oracle_env()
    try:
        policy = LQIPolicy.from_env(env)
    finally:
        env.close()
    obs = np.zeros((1, 16))
    obs[0, 0] = 5.0  # 5 m behind: a command of ~34 m/s² sideways, far beyond 30°
    xi0 = np.zeros((1, 4))
    _, xi = policy.predict(obs, state=xi0, episode_start=np.array([False]))
    np.testing.assert_array_equal(xi, xi0)
