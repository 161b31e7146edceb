"""The native vector env: lane i equals the scalar env seeded s + i (DESIGN.md §9)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import quadslam_env  # noqa: F401  (registers the ids)
from agents.dflqr import DFLQRPolicy
from quadslam_env.actions import ActionError

SHORT = {"episode": {"duration_s": 0.35}}
FAST_FASTSLAM = {
    "episode": {"duration_s": 0.25},
    "estimator": {"params": {"n_particles": 30}},
}
CASES = {
    "QuadSLAM-Oracle-v0": SHORT,
    "QuadSLAM-EKF-v0": SHORT,
    "QuadSLAM-EKF-v0-known": {**SHORT, "scenario": "paper_ekf_figure8_known"},
    "QuadSLAM-FastSLAM-v0": FAST_FASTSLAM,
    "QuadSLAM-EKF-v0-unknown": {
        "episode": {"duration_s": 0.45},
        "lidar": {"association": "unknown", "clutter_rate": 3.0, "detection_prob": 0.9},
        "estimator": {"params": {"confirm_hits": 2, "confirm_window": 3}},
    },
    # imu.rate_hz: a slower IMU (filter replayed at its instants, lanes out of phase after
    # the autoresets; at 5 Hz the 10 Hz scans fall between instants) and a faster one.
    "QuadSLAM-EKF-v0-imu10": {**SHORT, "imu": {"rate_hz": 10.0}},
    "QuadSLAM-EKF-v0-imu1000": {**SHORT, "imu": {"rate_hz": 1000.0}},
    "QuadSLAM-FastSLAM-v0-imu10": {**FAST_FASTSLAM, "imu": {"rate_hz": 10.0}},
    # A free heading turned by a fifth action, the nearest-landmark observation and the
    # reward on the filter's own position uncertainty.
    "QuadSLAM-ActivePerception-v0": {
        "episode": {"duration_s": 0.35, "settle_s": 0.2},
        "reward": {"pos_std_weight": 0.5},
    },
    "QuadSLAM-EKF-v0-unknown-imu5": {
        "episode": {"duration_s": 0.45},
        "imu": {"rate_hz": 5.0},
        "lidar": {"association": "unknown", "clutter_rate": 3.0, "detection_prob": 0.9},
        "estimator": {"params": {"confirm_hits": 2, "confirm_window": 3}},
    },
}


def _id(case: str) -> str:
    """The registered id of a test case (``QuadSLAM-EKF-v0-known`` → ``QuadSLAM-EKF-v0``)."""
    return case[: case.index("-v0") + 3]


def lane_actions(env_id: str, lanes: int, steps: int) -> np.ndarray:
    """DF-LQR-like hover actions with per-lane noise; lane 1 crashes early (tilt)."""
    rng = np.random.default_rng(7)
    single = gym.make(_id(env_id), **_kwargs(env_id))
    hover = single.unwrapped.hover_action
    single.close()
    acts = hover + 0.05 * rng.standard_normal((steps, lanes, hover.shape[0]))
    if hover.shape[0] == 5:  # the heading channel: turns of either sign
        acts[:, :, 4] = rng.uniform(-1.0, 1.0, (steps, lanes))
    if lanes > 1:
        acts[:, 1, 1] = 1.0  # full roll torque: ends lane 1 on the tilt limit
    return acts.astype(np.float32)


def _kwargs(env_id: str) -> dict:
    return dict(CASES[env_id])


def scalar_rollout(env_id: str, seed: int, actions: np.ndarray) -> tuple[list[tuple], int]:
    """What a lane must produce, from the scalar env (reset the step after an episode ends),
    and how many times it was reset after an episode end."""
    env = gym.make(_id(env_id), **_kwargs(env_id))
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, False, False, info)]
    done = False
    n_resets = 0
    for a in actions:
        if done:
            obs, info = env.reset()
            out.append((obs, 0.0, False, False, info))
            done = False
            n_resets += 1
            continue
        obs, reward, term, trunc, info = env.step(a)
        out.append((obs, reward, term, trunc, info))
        done = term or trunc
    env.close()
    return out, n_resets


@pytest.mark.parametrize("env_id", sorted(CASES))
def test_lane_i_equals_the_scalar_env_seeded_s_plus_i_through_autoresets(env_id):
    lanes, steps, seed = 3, 80, 100
    acts = lane_actions(env_id, lanes, steps)
    vec = gym.make_vec(
        _id(env_id),
        num_envs=lanes,
        vectorization_mode="vector_entry_point",
        **_kwargs(env_id),
    )
    obs, info = vec.reset(seed=seed)
    got = [(obs, np.zeros(lanes), np.zeros(lanes, bool), np.zeros(lanes, bool), info)]
    for k in range(steps):
        got.append(vec.step(acts[k]))
    vec.close()
    for lane in range(lanes):
        want, n_resets = scalar_rollout(env_id, seed + lane, acts[:, lane])
        assert n_resets >= 1  # the comparison went through at least one autoreset
        for k, (w, g) in enumerate(zip(want, got, strict=True)):
            w_obs, w_rew, w_term, w_trunc, w_info = w
            g_obs, g_rew, g_term, g_trunc, g_info = g
            np.testing.assert_array_equal(g_obs[lane], w_obs, err_msg=f"lane {lane} step {k}")
            assert g_rew[lane] == pytest.approx(w_rew, rel=1e-6, abs=1e-9)
            assert (bool(g_term[lane]), bool(g_trunc[lane])) == (w_term, w_trunc)
            keys = {key for key in g_info if not key.startswith("_") and g_info[f"_{key}"][lane]}
            reason = w_info.pop("termination_reason", "")
            assert keys - {"termination_reason"} == set(w_info), f"lane {lane} step {k}"
            got_reason = g_info["termination_reason"][lane] if "termination_reason" in keys else ""
            assert got_reason == reason
            for key, value in w_info.items():
                if key != "est_step_time_ms":
                    assert g_info[key][lane] == pytest.approx(value, rel=1e-6, abs=1e-9), key


def test_vector_conventions():
    vec = gym.make_vec("QuadSLAM-Oracle-v0", num_envs=4, vectorization_mode="vector_entry_point")
    assert vec.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    assert vec.single_action_space.shape == (4,) and vec.action_space.shape == (4, 4)
    assert vec.observation_space.shape == (4, *vec.single_observation_space.shape)
    obs, info = vec.reset(seed=[1, 2, 3, 4])
    assert obs.shape == (4, 16) and obs.dtype == np.float32
    assert vec.observation_space.contains(obs)
    obs, reward, term, trunc, info = vec.step(vec.action_space.sample())
    assert reward.shape == term.shape == trunc.shape == (4,)
    assert info["_reward_pos"].all() and info["reward_pos"].shape == (4,)
    assert "est_nees_pose" not in info  # the oracle has no covariance: the term never applies
    vec.close()


def test_make_vec_takes_the_kwargs_of_make():
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=2, scenario="paper_ekf_figure8_known")
    assert vec.unwrapped.scenario.estimator.known_map
    vec.close()


@pytest.mark.parametrize(
    ("bad", "fragment"),
    [
        (np.zeros((3, 4)), "shape"),
        (np.zeros(4), "shape"),
        ("up", "actions"),
    ],
)
def test_bad_batch_actions_raise_and_change_no_lane(bad, fragment):
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=2)
    vec.reset(seed=0)
    core = vec.unwrapped.core
    before = core.vehicle.state.copy(), core.t.copy()
    with pytest.raises(ActionError, match=fragment):
        vec.step(bad)
    np.testing.assert_array_equal(core.vehicle.state, before[0])
    np.testing.assert_array_equal(core.t, before[1])
    vec.close()


def test_non_finite_action_names_the_lane():
    vec = gym.make_vec("QuadSLAM-Oracle-v0", num_envs=3)
    vec.reset(seed=0)
    acts = np.tile(vec.unwrapped.hover_action, (3, 1))
    acts[2, 1] = math.nan
    with pytest.raises(ActionError, match=r"lane\(s\) \[2\]"):
        vec.step(acts)
    vec.close()


def test_batched_dflqr_flies_every_lane():
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=3, episode={"duration_s": 10.0})
    policy = DFLQRPolicy.from_env(vec)
    obs, _ = vec.reset(seed=0)
    for _ in range(vec.unwrapped.core.max_steps - 1):
        act, _ = policy.predict(obs)
        assert act.shape == (3, 4)
        for lane in range(3):  # the batch is the per-lane policy, row by row
            np.testing.assert_array_equal(act[lane], policy.predict(obs[lane])[0])
        obs, _, term, trunc, info = vec.step(act)
        assert not (term.any() or trunc.any())
    # The vehicle starts 2 m from the reference; DF-LQR on the EKF estimate closes the gap.
    assert (info["track_pos_err_m"] < 0.3).all()
    vec.close()


class _CorruptLane:
    """Wraps a batch estimator; from the 6th estimate on, lane ``lane``'s position is NaN."""

    def __init__(self, inner, lane):
        self.inner, self.lane, self.calls = inner, lane, 0
        self.num_lanes, self.uses_truth = inner.num_lanes, inner.uses_truth

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def estimate(self):
        import dataclasses

        self.calls += 1
        est = self.inner.estimate()
        if self.calls <= 6:
            return est
        position = est.position.copy()
        position[self.lane] = math.nan
        return dataclasses.replace(est, position=position)


def test_a_diverging_lane_ends_alone_with_its_reason_and_autoresets():
    vec = gym.make_vec("QuadSLAM-EKF-v0", num_envs=3)
    clean = gym.make_vec("QuadSLAM-EKF-v0", num_envs=3)
    core = vec.unwrapped.core
    core.estimator = _CorruptLane(core.estimator, lane=1)
    obs, _ = vec.reset(seed=5)
    clean_obs, _ = clean.reset(seed=5)
    hover = np.tile(vec.unwrapped.hover_action, (3, 1)).astype(np.float32)
    for _ in range(5):
        obs, _, term, _, info = vec.step(hover)
        clean_obs, *_ = clean.step(hover)
        assert not term.any()
    obs, reward, term, trunc, info = vec.step(hover)
    clean_obs, *_ = clean.step(hover)
    assert term.tolist() == [False, True, False] and not trunc.any()
    assert info["_termination_reason"].tolist() == [False, True, False]
    assert info["termination_reason"][1] == "estimator_diverged: non-finite position"
    assert np.isfinite(obs).all() and np.isfinite(reward).all()
    for lane in (0, 2):  # the healthy lanes are untouched by lane 1's failure
        np.testing.assert_array_equal(obs[lane], clean_obs[lane])
    obs, reward, term, trunc, info = vec.step(hover)  # next step: lane 1 autoresets
    assert reward[1] == 0.0 and not term[1] and info["t"][1] == 0.0
    vec.close()
    clean.close()
