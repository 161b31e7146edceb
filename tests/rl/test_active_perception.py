"""The active-perception pieces: the free heading and its action channel, the nearest-landmark
observation, the reward on the filter's own uncertainty and the look-at baseline."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401
from agents.control.dflqr import DFLQRPolicy
from agents.control.lookat import LookAtPolicy, aim_azimuth
from quadslam_env.config.scenario import load_scenario
from quadslam_env.episode.observation import nearest_landmarks
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.schema import ConfigError

AP = "QuadSLAM-ActivePerception-v0"
SHORT = {"episode": {"duration_s": 3.0, "settle_s": 1.0}}


def _rot(euler: np.ndarray) -> np.ndarray:
    """C_NB = C3(ψ) C2(θ) C1(φ), written out here independently of the package."""
    phi, theta, psi = euler
    c1 = np.array(
        [[1, 0, 0], [0, math.cos(phi), -math.sin(phi)], [0, math.sin(phi), math.cos(phi)]]
    )
    c2 = np.array(
        [[math.cos(theta), 0, math.sin(theta)], [0, 1, 0], [-math.sin(theta), 0, math.cos(theta)]]
    )
    c3 = np.array(
        [[math.cos(psi), -math.sin(psi), 0], [math.sin(psi), math.cos(psi), 0], [0, 0, 1]]
    )
    return c3 @ c2 @ c1


def test_the_heading_channel_turns_the_reference_at_the_commanded_rate() -> None:
    env = gym.make(AP, **SHORT)
    env.reset(seed=0)
    policy = DFLQRPolicy.from_env(env)
    assert env.action_space.shape == (5,)
    base = env.unwrapped
    obs = None
    for k in range(1, 101):
        obs, *_ = env.step(np.zeros(5, np.float32)) if obs is None else env.step(_turn(policy, obs))
        if k == 1:
            assert base.reference().yaw == 0.0  # a4 = 0 holds the start heading
    # 99 steps of a4 = 0.5 at 90°/s: ψ_d = 0.5 · 90°/s · 0.99 s.
    ref = base.reference()
    assert ref.yaw == pytest.approx(math.radians(0.5 * 90.0 * 0.99))
    assert ref.yaw_rate == pytest.approx(math.radians(45.0))
    assert obs[15] == pytest.approx(math.radians(45.0), rel=1e-6)  # ψ̇_d in the observation
    env.close()


def _turn(policy: DFLQRPolicy, obs: np.ndarray) -> np.ndarray:
    action, _ = policy.predict(obs)
    action[4] = 0.5
    return action


def test_dflqr_tracks_the_commanded_heading() -> None:
    env = gym.make(
        "QuadSLAM-Oracle-v0",
        scenario="active_perception",
        observation={"landmarks_nearest": 0},
        episode={"duration_s": 8.0},
    )
    obs, _ = env.reset(seed=0)
    policy = DFLQRPolicy.from_env(env)
    for _ in range(600):  # 6 s of a 30°/s turn
        obs, _, terminated, _, info = env.step(_command(policy, obs, 1.0 / 3.0))
        assert not terminated
    base = env.unwrapped
    err = (base.true_state[8] - base.reference().yaw + math.pi) % (2 * math.pi) - math.pi
    assert abs(err) < math.radians(3.0)
    assert info["track_pos_err_m"] < 0.1  # the position loop holds the circle while turning
    env.close()


def _command(policy: DFLQRPolicy, obs: np.ndarray, a4: float) -> np.ndarray:
    action, _ = policy.predict(obs)
    action[4] = a4
    return action


@pytest.mark.parametrize(
    ("overrides", "key"),
    [
        ({"trajectory": {"yaw_mode": "tangent"}}, "action.heading"),
        ({"action": {"heading": False}}, "trajectory.yaw_mode"),
        ({"estimator": {"name": "oracle", "params": {}}}, "observation.landmarks_nearest"),
    ],
)
def test_inconsistent_heading_settings_name_the_key(overrides: dict, key: str) -> None:
    with pytest.raises(ConfigError, match="allowed") as err:
        load_scenario("active_perception", overrides)
    assert str(err.value).startswith(key)


def test_nearest_landmarks_are_the_lidar_view_of_the_estimated_map() -> None:
    rng = np.random.default_rng(4)
    b, lmax, k = 3, 7, 5
    euler = rng.uniform(-0.3, 0.3, (b, 3))
    position = rng.normal(size=(b, 3))
    means = rng.normal(scale=5.0, size=(b, lmax, 3))
    mapped = rng.random((b, lmax)) < 0.6
    mapped[2] = [True, False, False, False, False, False, False]  # fewer than k: padding
    est = BatchEstimate(
        position=position,
        vel_body=np.zeros((b, 3)),
        vel_inertial=np.zeros((b, 3)),
        euler=euler,
        rates=np.zeros((b, 3)),
        pose_cov=None,
        landmark_means=means,
        landmark_mapped=mapped,
        diagnostics={},
    )
    got = nearest_landmarks(est, k)
    for lane in range(b):
        c = (means[lane] - position[lane]) @ _rot(euler[lane])  # rows: C_NBᵀ (l − ρ)
        rng_m = np.linalg.norm(c, axis=1)
        ids = [i for i in np.argsort(rng_m) if mapped[lane, i]][:k]
        for j in range(k):
            if j < len(ids):
                x, y, z = c[ids[j]]
                want = [math.atan2(y, x), math.atan2(z, math.hypot(x, y)), rng_m[ids[j]], 1.0]
                np.testing.assert_allclose(got[lane, j], want, atol=1e-12)
            else:
                assert not got[lane, j].any()


def test_position_std_reward_is_the_filters_own_uncertainty() -> None:
    env = gym.make(AP, reward={"pos_std_weight": 2.0}, **SHORT)
    obs, _ = env.reset(seed=1)
    policy = DFLQRPolicy.from_env(env)
    for _ in range(30):
        obs, reward, _, _, info = env.step(policy.predict(obs)[0])
        cov = env.unwrapped.last_estimate.pose_cov[0]
        assert info["reward_pos_std"] == pytest.approx(-2.0 * math.sqrt(np.trace(cov[:3, :3])))
        terms = sum(v for key, v in info.items() if key.startswith("reward_"))
        assert reward == pytest.approx(terms)
    env.close()


def test_aim_azimuth_picks_the_fullest_window_by_enumeration() -> None:
    half = math.radians(30.0)
    alpha = np.array([-1.0, -0.9, -0.8, 0.5, 2.0, 0.0])
    mask = np.array([1, 1, 1, 1, 1, 0.0])  # the last is padding
    assert aim_azimuth(alpha, mask, half) == pytest.approx(-0.9)  # three within ±30° of -0.9
    # A tie (one each) goes to the smallest turn.
    assert aim_azimuth(np.array([2.0, -0.4]), np.ones(2), half) == pytest.approx(-0.4)
    # Across ±π: the window wraps and the aim is the circular mean.
    wrapped = aim_azimuth(np.array([math.pi - 0.1, -math.pi + 0.1]), np.ones(2), half)
    assert abs(abs(wrapped) - math.pi) < 1e-12
    assert aim_azimuth(alpha, np.zeros(6), half) is None


def test_look_at_keeps_landmarks_in_view_where_a_fixed_heading_sees_none() -> None:
    def visible(policy_of) -> float:
        env = gym.make(AP, episode={"duration_s": 12.0})
        obs, _ = env.reset(seed=3)
        policy = policy_of(env)
        seen = []
        for _ in range(1200):
            obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
            seen.append(info["est_n_visible"])
            if terminated or truncated:
                break
        env.close()
        return float(np.mean(seen[600:]))  # the second half: after the search

    assert visible(DFLQRPolicy.from_env) == 0.0  # the landmarks are behind the start heading
    assert visible(LookAtPolicy) >= 3.0
