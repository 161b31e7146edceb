"""The native vector env: lane i equals the scalar env seeded s + i (docs/design.md §9)."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from gymnasium.wrappers import vector as vector_wrappers
from lane_cases import (
    CASES,
    MODES,
    _kwargs,
    assert_lanes_equal_scalar_rollouts,
    lane_actions,
)

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from quadslam_env.episode.actions import ActionError
from quadslam_env.schema import ConfigError

# Every case in the default mode; the other modes, whose bookkeeping is the vector env's and
# not the estimator's, on one case per kind of core path (no estimator covariance, EKF with
# labelled and unlabelled scans, a slower IMU, the heading channel).
OTHER_MODE_CASES = (
    "QuadSLAM-Oracle-v0",
    "QuadSLAM-EKF-v0",
    "QuadSLAM-EKF-v0-unknown",
    "QuadSLAM-EKF-v0-imu10",
    "QuadSLAM-ActivePerception-v0",
)
LANE_CASES = [(case, MODES[0]) for case in sorted(CASES)] + [
    (case, mode) for mode in MODES[1:] for case in OTHER_MODE_CASES
]


@pytest.mark.parametrize(
    ("env_id", "mode"), LANE_CASES, ids=[f"{c}-{m.value}" for c, m in LANE_CASES]
)
def test_lane_i_equals_the_scalar_env_seeded_s_plus_i_through_autoresets(env_id, mode):
    assert_lanes_equal_scalar_rollouts(env_id, mode)


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


# ----------------------------------------------------------------------------- autoreset modes
ORACLE = "QuadSLAM-Oracle-v0"
TINY = {"episode": {"duration_s": 0.05}}  # 5 steps


def _vec(mode: AutoresetMode | str, lanes: int = 2, **kwargs) -> gym.vector.VectorEnv:
    return gym.make_vec(
        ORACLE,
        num_envs=lanes,
        vectorization_mode="vector_entry_point",
        autoreset_mode=mode,
        **kwargs,
    )


@pytest.mark.parametrize("mode", MODES, ids=[m.value for m in MODES])
def test_autoreset_mode_takes_the_enum_or_its_value_and_is_in_the_metadata(mode):
    for value in (mode, mode.value):
        vec = _vec(value)
        assert vec.metadata["autoreset_mode"] is mode
        vec.close()
    assert _vec(AutoresetMode.NEXT_STEP).metadata == gym.make_vec(ORACLE, num_envs=2).metadata


@pytest.mark.parametrize("bad", ["same_step", "SAME_STEP", 1, None])
def test_unknown_autoreset_mode_names_the_key_the_value_and_the_allowed_values(bad):
    with pytest.raises(ConfigError, match=r"^autoreset_mode: got .+; allowed: .*") as err:
        _vec(bad)
    assert repr(bad) in str(err.value) and "'NextStep', 'SameStep', 'Disabled'" in str(err.value)


def test_cleanrl_style_same_step_loop_counts_every_episode_once():
    lanes, steps = 3, 80
    acts = lane_actions(ORACLE, lanes, steps)  # lane 1 ends on the tilt limit, see _kwargs
    vec = vector_wrappers.RecordEpisodeStatistics(
        _vec(AutoresetMode.SAME_STEP, lanes, **_kwargs(ORACLE))
    )
    vec.reset(seed=0)
    ends = finals = 0
    for act in acts:
        _, _, terminated, truncated, infos = vec.step(act)
        done = terminated | truncated
        ends += int(done.sum())
        assert ("final_info" in infos) == done.any() == ("episode" in infos)
        if not done.any():
            continue
        final = infos["final_info"]
        np.testing.assert_array_equal(infos["_final_info"], done)
        np.testing.assert_array_equal(infos["_final_obs"], done)
        for i in np.flatnonzero(infos["_final_info"]):  # as CleanRL reads them
            finals += 1
            assert vec.single_observation_space.contains(infos["final_obs"][i])
            assert all(final[f"_{key}"][i] for key in ("episode_steps", "episode_est_pos_rmse_m"))
            # Every step counts in same-step mode: the statistics wrapper agrees.
            assert final["episode_steps"][i] == infos["episode"]["l"][i]
            assert infos["t"][i] == 0.0  # the lane was reset in the same step
        assert not final["_episode_steps"][~done].any()
    assert finals == ends and ends >= 6
    vec.close()


def test_disabled_autoreset_raises_on_an_ended_lane_and_reset_mask_resets_only_those():
    acts = lane_actions(ORACLE, 3, 40)
    vec = _vec(AutoresetMode.DISABLED, 3, **_kwargs(ORACLE))
    core = vec.unwrapped.core
    with pytest.raises(gym.error.ResetNeeded, match=r"call reset\(\)"):
        vec.step(acts[0])
    with pytest.raises(gym.error.ResetNeeded, match="reset_mask"):
        vec.reset(options={"reset_mask": np.array([True, False, False])})
    obs, _ = vec.reset(seed=3)
    for act in acts:
        obs, _, terminated, truncated, info = vec.step(act)
        if (terminated | truncated).any():
            break
    ended = terminated | truncated
    assert ended.tolist() == [False, True, False]  # lane 1 on the tilt limit
    assert "final_obs" not in info and info["t"][1] > 0.0  # nothing was reset
    before = core.vehicle.state.copy(), core.t.copy()
    with pytest.raises(gym.error.ResetNeeded, match=r"lane\(s\) \[1\] ended.*reset_mask"):
        vec.step(act)
    np.testing.assert_array_equal(core.vehicle.state, before[0])  # no lane moved
    start = core.vehicle.state[0].copy()  # lane 0's upright state: the other options apply
    options = {"reset_mask": ended, "initial_state": start.tolist()}
    r_obs, r_info = vec.reset(options=options)
    assert "reset_mask" in options  # the caller's options are left as they were
    np.testing.assert_array_equal(core.vehicle.state[1], start)
    np.testing.assert_array_equal(r_obs[[0, 2]], obs[[0, 2]])  # the last observations
    np.testing.assert_array_equal(core.vehicle.state[[0, 2]], before[0][[0, 2]])
    assert core.t.tolist() == [before[1][0], 0.0, before[1][2]]
    assert r_info["_t"].tolist() == [False, True, False]
    vec.step(act)  # every lane is running again
    assert core.t.tolist() == pytest.approx([before[1][0] + 0.01, 0.01, before[1][2] + 0.01])
    vec.close()


@pytest.mark.parametrize(
    "mask",
    [
        [1, 0],
        np.array([0, 1]),
        np.array([True, False, True]),
        np.array([False, False]),
        "all",
    ],
)
def test_bad_reset_mask_is_a_config_error(mask):
    vec = _vec(AutoresetMode.DISABLED)
    vec.reset(seed=0)
    with pytest.raises(ConfigError, match=r"reset options\.reset_mask: got .*; allowed: a \(2,\)"):
        vec.reset(options={"reset_mask": mask})
    vec.close()


@pytest.mark.parametrize("mode", MODES, ids=[m.value for m in MODES])
def test_gymnasium_vector_wrappers_and_render_in_every_mode(mode):
    wrappers = vector_wrappers
    base = _vec(mode, render_mode="rgb_array", **TINY)
    env = wrappers.RecordEpisodeStatistics(base)
    env = wrappers.NormalizeReward(wrappers.ClipAction(env))
    if mode == AutoresetMode.NEXT_STEP:  # Gymnasium's observation wrappers: next-step only
        env = wrappers.NormalizeObservation(env)
    env = wrappers.DictInfoToList(env)
    history = base.unwrapped._renderer.history
    env.reset(seed=0)
    action = np.tile(1.5 * base.unwrapped.hover_action, (2, 1))  # clipped to [-1, 1]
    lengths = []
    for _ in range(12):
        obs, _, terminated, truncated, infos = env.step(action)
        done = terminated | truncated
        if mode == AutoresetMode.DISABLED and done.any():
            env.reset(options={"reset_mask": done})
        lengths += [info["episode"]["l"] for info in infos if "episode" in info]
        for info in infos:
            if "final_obs" in info:
                assert info["final_obs"].shape == obs.shape[1:]
                assert "episode_steps" in info["final_info"]
    assert lengths == [5] * 4  # two episodes in each lane, counted once each
    assert history.episode == 3  # lane 0's frames follow its resets
    assert base.render().shape == (480, 640, 3)
    env.close()


@pytest.mark.parametrize(
    ("seed", "fragment"),
    [
        (1.5, r"seed: got 1\.5; allowed: None, an integer >= 0 .* or a list of 3 seeds"),
        ("3", r"seed: got '3'; allowed: None, an integer >= 0"),
        (True, r"seed: got True; allowed"),
        (-1, r"seed: got -1; allowed"),
        ([1, 2], r"seed: got \[1, 2\] \(a list of 2\); allowed: a list of 3 seeds"),
        ([0, 1, 2.5], r"seed\[2\]: got 2\.5; allowed: None or an integer >= 0"),
        ([0, -1, 2], r"seed\[1\]: got -1"),
        ((0, np.True_, 2), r"seed\[1\]: got "),
    ],
)
def test_bad_seeds_name_the_key_the_value_and_what_is_allowed(seed, fragment):
    vec = _vec(AutoresetMode.NEXT_STEP, 3)
    with pytest.raises(ConfigError, match=fragment) as err:
        vec.reset(seed=seed)
    assert "\n" not in str(err.value)
    vec.close()


def test_numpy_integer_seeds_equal_python_ones():
    vec = _vec(AutoresetMode.NEXT_STEP, 3)
    want, _ = vec.reset(seed=4)
    for seed in (np.int64(4), np.uint8(4), [4, np.int32(5), 6], np.arange(4, 7)):
        np.testing.assert_array_equal(vec.reset(seed=seed)[0], want)
    vec.close()
