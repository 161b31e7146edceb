"""SB3 adapter over the batched core, vector residual wrapper, lane-parallel evaluation."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO
from stable_baselines3.common.vec_env import DummyVecEnv, VecCheckNan, VecMonitor, VecNormalize

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import EPISODE_KEYS, Trace, run_episode, run_episodes
from agents.rl.vec_adapter import QuadSLAMVecEnv, _merge_arrays
from agents.rl.wrappers import ResidualDFLQRVectorWrapper, ResidualDFLQRWrapper
from quadslam_env.episode.actions import ActionError
from quadslam_env.schema import ConfigError

SHORT = {"episode": {"duration_s": 0.3}}
ORACLE = "QuadSLAM-Oracle-v0"
EKF = "QuadSLAM-EKF-v0"
VOLATILE = {"est_step_time_ms"}  # wall-clock timing: differs between any two runs
ROOT = Path(__file__).resolve().parents[2]


def noisy_hover(env_id: str, lanes: int, steps: int, seed: int = 3) -> np.ndarray:
    """(steps, lanes, 4) hover actions with noise; lane 1 rolls hard and crashes early."""
    env = gym.make(env_id, **SHORT)
    hover = env.unwrapped.hover_action
    env.close()
    acts = hover + 0.05 * np.random.default_rng(seed).standard_normal((steps, lanes, 4))
    acts[:, 1 % lanes, 1] = 0.6
    return acts.astype(np.float32)


def dummy_vec(env_id: str, lanes: int, seed: int, wrap: bool = False) -> DummyVecEnv:
    """SB3's reference semantics: DummyVecEnv over the scalar env (lane i seeded seed + i)."""

    def make() -> gym.Env:
        env = gym.make(env_id, **SHORT)
        return ResidualDFLQRWrapper(env) if wrap else env

    venv = DummyVecEnv([make] * lanes)
    venv.seed(seed)
    return venv


def assert_info_equal(got: dict, want: dict, where: str) -> None:
    assert set(got) == set(want), where
    for key, value in want.items():
        if key in VOLATILE:
            continue
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(got[key], value, err_msg=f"{where} {key}")
        elif isinstance(value, float):
            assert got[key] == pytest.approx(value, rel=1e-6, abs=1e-9), f"{where} {key}"
        else:
            assert got[key] == value, f"{where} {key}"


def assert_same_rollout(a, b, actions: np.ndarray) -> int:
    """Step two SB3 VecEnvs with the same actions; return the number of episode ends seen."""
    np.testing.assert_array_equal(a.reset(), b.reset())
    for lane, (ga, gb) in enumerate(zip(a.reset_infos, b.reset_infos, strict=True)):
        assert_info_equal(ga, gb, f"reset lane {lane}")
    ends = 0
    for k, act in enumerate(actions):
        obs_a, rew_a, done_a, infos_a = a.step(act)
        obs_b, rew_b, done_b, infos_b = b.step(act)
        np.testing.assert_array_equal(obs_a, obs_b, err_msg=f"step {k}")
        np.testing.assert_allclose(rew_a, rew_b, rtol=1e-6, atol=1e-9)
        np.testing.assert_array_equal(done_a, done_b)
        assert rew_a.dtype == rew_b.dtype and done_a.dtype == done_b.dtype
        for lane, (ia, ib) in enumerate(zip(infos_a, infos_b, strict=True)):
            assert_info_equal(ia, ib, f"step {k} lane {lane}")
            if done_b[lane]:
                assert_info_equal(a.reset_infos[lane], b.reset_infos[lane], f"reset {k} {lane}")
        ends += int(done_b.sum())
    return ends


@pytest.mark.parametrize("env_id", [ORACLE, EKF])
def test_lane_i_equals_dummy_vec_env_of_scalar_env_seeded_s_plus_i(env_id):
    lanes, steps, seed = 3, 70, 11
    acts = noisy_hover(env_id, lanes, steps)
    adapter = QuadSLAMVecEnv(env_id, lanes, seed=seed, **SHORT)
    reference = dummy_vec(env_id, lanes, seed)
    ends = assert_same_rollout(adapter, reference, acts)
    assert ends >= lanes + 1  # every lane went through an autoreset, one of them crashed
    adapter.close()
    reference.close()


def test_n_workers_2_equals_n_workers_1():
    lanes, steps = 3, 40
    acts = noisy_hover(EKF, lanes, steps, seed=5)
    one = QuadSLAMVecEnv(EKF, lanes, n_workers=1, **SHORT)
    two = QuadSLAMVecEnv(EKF, lanes, n_workers=2, **SHORT)
    one.seed(21)
    two.seed(21)
    assert assert_same_rollout(two, one, acts) >= 1
    assert two.get_attr("t") == one.get_attr("t")
    assert two.get_attr("steps", indices=[2]) == one.get_attr("steps", indices=[2])
    np.testing.assert_array_equal(two.get_attr("true_state")[2], one.get_attr("true_state")[2])
    one.close()
    two.close()
    with pytest.raises(ConfigError, match="duration_s"):  # a worker's error reaches the caller
        QuadSLAMVecEnv(EKF, 2, n_workers=2, episode={"duration_s": -1.0})


def apart_actions(env_id: str, steps: int, seed: int = 0) -> np.ndarray:
    """(steps, 4, 4) actions whose lanes end at different steps: lane 0 rolls left and lane 3
    rolls right (tilt terminations at different periods), lane 2 flies random actions, lane 1
    hovers with noise (truncations)."""
    env = gym.make(env_id)
    hover = env.unwrapped.hover_action
    env.close()
    rng = np.random.default_rng(seed)
    acts = hover + 0.05 * rng.standard_normal((steps, 4, 4))
    acts[:, 0, 1] = -0.7
    acts[:, 2] = rng.uniform(-1.0, 1.0, (steps, 4))
    acts[:, 3, 1] = 1.0
    return acts.astype(np.float32)


@pytest.mark.parametrize("stagger", [False, True])
def test_n_workers_2_equals_n_workers_1_with_lanes_ending_apart(stagger):
    lanes, steps, max_steps = 4, 320, 60
    episode = {"episode": {"duration_s": 0.6}}
    acts = apart_actions(EKF, steps)
    one = QuadSLAMVecEnv(EKF, lanes, seed=8, n_workers=1, stagger=stagger, **episode)
    two = QuadSLAMVecEnv(EKF, lanes, seed=8, n_workers=2, stagger=stagger, **episode)
    np.testing.assert_array_equal(two.reset(), one.reset())
    for lane in range(lanes):
        assert_info_equal(two.reset_infos[lane], one.reset_infos[lane], f"reset lane {lane}")
    # Stagger cuts the first episode of lanes 0..2 outside the core; every end, cut or not,
    # must carry the lane's summary, and a cut says so.
    cuts = {lane: math.ceil(max_steps * (lane + 1) / lanes) for lane in range(lanes - 1)}
    cuts = cuts if stagger else {}
    ends = np.zeros(lanes, dtype=int)
    alone = [0, 0]  # steps on which only worker 0's (resp. worker 1's) lanes ended
    crashes = 0
    for k, act in enumerate(acts):
        obs_2, rew_2, done_2, infos_2 = two.step(act)
        obs_1, rew_1, done_1, infos_1 = one.step(act)
        np.testing.assert_array_equal(obs_2, obs_1, err_msg=f"step {k}")
        np.testing.assert_array_equal(rew_2, rew_1, err_msg=f"step {k}")
        np.testing.assert_array_equal(done_2, done_1, err_msg=f"step {k}")
        assert list(two.step_info) == list(one.step_info), f"step {k}"
        for key, value in one.step_info.items():
            if key not in VOLATILE:
                got = two.step_info[key]
                assert got.shape == (lanes,) and got.dtype == value.dtype, f"step {k} {key}"
                np.testing.assert_array_equal(got, value, err_msg=f"step {k} {key}")
        for lane in range(lanes):
            where = f"step {k} lane {lane}"
            info = infos_2[lane]
            assert_info_equal(info, infos_1[lane], where)
            done = bool(done_2[lane])
            assert ("terminal_observation" in info) == done, where
            if done:
                assert_info_equal(two.reset_infos[lane], one.reset_infos[lane], f"reset {where}")
                ends[lane] += 1
                crashes += bool(info["termination_reason"])
            cut = done and ends[lane] == 1 and cuts.get(lane) == k + 1
            assert ("episode_steps" in info) == done, where
            assert ("stagger_cut" in info) == cut, where
            summary = two.step_info.get("episode_steps", np.full(lanes, np.nan))[lane]
            assert summary == info.get("episode_steps", np.nan) or math.isnan(summary), where
        ended = [bool(done_2[:2].any()), bool(done_2[2:].any())]
        if ended[0] != ended[1]:
            alone[int(ended[1])] += 1
    assert (ends >= 4).all() and crashes >= 6, (ends, crashes)
    assert min(alone) >= 3, alone  # both workers had ends the other did not share
    one.close()
    two.close()


def test_a_stagger_cut_ends_the_episode_with_its_summary():
    """A staggered first episode cut short ends like any other: its info has the episode
    summary (which matches the step terms it covers), the truncation marks, and VecMonitor
    counts it; a lane that crashed before its cut runs its next episode in full."""
    lanes, max_steps = 3, 100
    env = VecMonitor(QuadSLAMVecEnv(ORACLE, lanes, seed=0, stagger=True,
                                    episode={"duration_s": 1.0}))  # fmt: skip
    hover = np.tile(gym.make(ORACLE).unwrapped.hover_action, (lanes, 1)).astype(np.float32)
    env.reset()
    track: list[list[float]] = [[] for _ in range(lanes)]
    ends: list[list[tuple[int, dict]]] = [[] for _ in range(lanes)]
    for k in range(1, 2 * max_steps + 1):
        act = hover.copy()
        if not ends[1]:
            act[1, 1] = 0.9  # lane 1 rolls until it crashes (before its cut at 67 steps)
        _, _, dones, infos = env.step(act)
        step_info = env.venv.step_info
        for lane in range(lanes):
            track[lane].append(float(step_info["track_pos_err_m"][lane]))
            if dones[lane]:
                ends[lane].append((k, infos[lane]))
                info = infos[lane]
                assert info["episode_steps"] == step_info["episode_steps"][lane]
                assert info["episode"]["l"] == info["episode_steps"]  # VecMonitor's count
                assert info["TimeLimit.truncated"] == (not info["termination_reason"])
    cut_at = math.ceil(max_steps / lanes)  # lane 0's first episode: ceil(100 · 1 / 3) steps
    (first, info), *later = ends[0]
    assert first == cut_at and info["stagger_cut"] is True and info["termination_reason"] == ""
    assert info["episode_steps"] == cut_at and info["TimeLimit.truncated"] is True
    rmse = math.sqrt(np.mean(np.square(track[0][:cut_at])))
    assert info["episode_track_pos_rmse_m"] == pytest.approx(rmse, rel=1e-12)
    assert [k - first for k, _ in later] == [max_steps]  # the next one is not cut
    (crash, info), (second, info_2), *_ = ends[1]
    assert info["termination_reason"] and "stagger_cut" not in info and crash < 67
    assert second - crash == max_steps and "stagger_cut" not in info_2
    assert [k for k, _ in ends[2]] == [max_steps, 2 * max_steps]  # the last lane: no cut
    env.close()


def test_merge_arrays_fills_keys_a_share_lacks():
    slices = [slice(0, 2), slice(2, 5)]
    parts = [
        {"a": np.array([1.0, 2.0]), "n": np.array([3, 4]), "s": ["x", ""]},
        {"a": np.array([5.0, 6.0, 7.0]), "e": np.array([np.nan, 8.0, np.nan])},
    ]
    merged = _merge_arrays(parts, slices)
    assert list(merged) == ["a", "n", "s", "e"]
    np.testing.assert_array_equal(merged["a"], [1.0, 2.0, 5.0, 6.0, 7.0])
    np.testing.assert_array_equal(merged["e"], [np.nan] * 3 + [8.0, np.nan])
    np.testing.assert_array_equal(merged["n"], [3.0, 4.0] + [np.nan] * 3)
    assert merged["a"].dtype == merged["e"].dtype == merged["n"].dtype == np.float64
    assert merged["s"].dtype == object and merged["s"].tolist() == ["x", "", "", "", ""]
    assert _merge_arrays(parts[:1], [slice(0, 2)]) is parts[0]


def test_script_without_main_guard_gets_a_clear_error(tmp_path):
    script = tmp_path / "unguarded.py"
    script.write_text(
        "from agents.rl.vec_adapter import QuadSLAMVecEnv\n"
        f"QuadSLAMVecEnv({ORACLE!r}, 2, n_workers=2)\n"
    )
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, env=env, timeout=600
    )
    assert run.returncode != 0
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("RuntimeError: QuadSLAMVecEnv: worker process"), run.stderr
    assert 'if __name__ == "__main__":' in last
    assert "EOFError" in run.stderr  # the broken pipe, chained


def test_info_keys_limit_the_copied_terms():
    adapter = QuadSLAMVecEnv(ORACLE, 2, seed=0, info_keys=["t", "reward_pos"], **SHORT)
    adapter.reset()
    assert set(adapter.reset_infos[0]) == {"t"}  # a reset has no reward terms
    hover = adapter.get_attr("hover_action")[0]
    _, _, _, infos = adapter.step(np.tile(hover, (2, 1)))
    assert set(infos[1]) == {"t", "reward_pos", "TimeLimit.truncated"}
    assert infos[1]["t"] == pytest.approx(adapter.get_attr("dt")[0])
    adapter.close()


def test_attributes_methods_and_bad_input():
    adapter = QuadSLAMVecEnv(ORACLE, 3, seed=0, n_workers=2, **SHORT)
    assert adapter.get_attr("render_mode") == [None] * 3
    spec = adapter.get_attr("spec", indices=1)[0]
    assert spec.id == ORACLE and spec.kwargs["episode"] == SHORT["episode"]
    assert adapter.observation_space.shape == (16,) and adapter.action_space.shape == (4,)
    assert adapter.get_attr("max_steps") == [30] * 3
    assert not adapter.has_attr("no_such_attribute")
    assert adapter.env_is_wrapped(ResidualDFLQRWrapper) == [False] * 3
    adapter.reset()
    assert adapter.env_method("render", indices=[0, 2]) == [None, None]  # no render_mode
    adapter.set_attr("hover_action", np.zeros(4))
    assert adapter.get_attr("hover_action", indices=2)[0].tolist() == [0.0] * 4
    with pytest.raises(ValueError, match="indices=None"):
        adapter.set_attr("hover_action", np.zeros(4), indices=[0])
    bad = np.zeros((3, 4))
    bad[2, 0] = np.nan
    with pytest.raises(ActionError, match=r"lane\(s\) \[2\]"):
        adapter.step(bad)
    with pytest.raises(ActionError, match="shape"):
        adapter.step(np.zeros((2, 4)))
    adapter.close()
    with pytest.raises(ConfigError, match="n_workers"):
        QuadSLAMVecEnv(ORACLE, 2, n_workers=3)


def test_render_returns_lane_0_frame():
    adapter = QuadSLAMVecEnv(ORACLE, 2, seed=0, render_mode="rgb_array", **SHORT)
    adapter.reset()
    frame = adapter.render()
    assert frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype == np.uint8
    adapter.close()


def test_vec_normalize_vec_monitor_and_vec_check_nan_wrap_and_step():
    adapter = QuadSLAMVecEnv(ORACLE, 2, seed=0, **SHORT)
    venv = VecNormalize(VecCheckNan(VecMonitor(adapter), raise_exception=True))
    obs = venv.reset()
    assert obs.shape == (2, 16)
    acts = noisy_hover(ORACLE, 2, 40)
    episodes = []
    for act in acts:
        obs, rew, done, infos = venv.step(act)
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rew))
        episodes += [info["episode"] for info in infos if "episode" in info]
        for info, d in zip(infos, done, strict=True):
            assert ("terminal_observation" in info) == bool(d)
    assert len(episodes) >= 2 and {"r", "l", "t"} <= set(episodes[0])
    assert venv.obs_rms.count > 40
    venv.close()


def test_ppo_learns_on_lanes():
    venv = VecNormalize(VecMonitor(QuadSLAMVecEnv(ORACLE, 4, seed=0, wrapper="residual_dflqr")))
    model = PPO("MlpPolicy", venv, n_steps=8, batch_size=16, n_epochs=1, seed=0, device="cpu")
    model.learn(total_timesteps=64)
    assert model.num_timesteps == 64
    venv.close()


def test_residual_adapter_equals_scalar_residual_wrapper_per_lane():
    lanes, steps, seed = 2, 40, 7
    residuals = np.random.default_rng(1).uniform(-1, 1, (steps, lanes, 4)).astype(np.float32)
    adapter = QuadSLAMVecEnv(ORACLE, lanes, seed=seed, wrapper={"name": "residual_dflqr"}, **SHORT)
    assert adapter.env_is_wrapped(ResidualDFLQRWrapper) == [True] * lanes
    reference = dummy_vec(ORACLE, lanes, seed, wrap=True)
    assert assert_same_rollout(adapter, reference, residuals) >= lanes
    adapter.close()
    reference.close()


def test_residual_vector_wrapper_equals_scalar_residual_wrapper_per_lane():
    lanes, steps, seed = 2, 40, 4
    residuals = np.random.default_rng(2).uniform(-1, 1, (steps, lanes, 4)).astype(np.float32)
    vec = gym.make_vec(ORACLE, num_envs=lanes, vectorization_mode="vector_entry_point", **SHORT)
    wrapped = ResidualDFLQRVectorWrapper(vec, scale=0.3)
    got = [wrapped.reset(seed=seed)[0]] + [wrapped.step(r)[0] for r in residuals]
    with pytest.raises(ValueError, match="residual action"):
        wrapped.step(np.zeros(4))
    wrapped.close()
    for lane in range(lanes):
        env = ResidualDFLQRWrapper(gym.make(ORACLE, **SHORT), scale=0.3)
        want, done = [env.reset(seed=seed + lane)[0]], False
        for r in residuals[:, lane]:  # next-step autoreset, as the native vector env
            if done:
                want.append(env.reset()[0])
                done = False
                continue
            obs, _, term, trunc, _ = env.step(r)
            want.append(obs)
            done = term or trunc
        np.testing.assert_array_equal(np.array(got)[:, lane], np.array(want))


def test_run_episodes_as_lanes_equals_sequential_scalar_runs():
    env = gym.make(EKF, **SHORT)
    policy = DFLQRPolicy.from_env(env)
    seeds = [3, 4, 5]
    sequential = [run_episode(env, policy, s) for s in seeds]
    trace_seq, trace_vec = Trace(), Trace()
    run_episode(env, policy, seeds[0], trace=trace_seq)
    counts: list[int] = []
    lanes = run_episodes(env, policy, seeds, trace=trace_vec, on_step=counts.append, max_lanes=2)
    assert sum(counts) == env.unwrapped.max_steps * len(seeds)
    for want, got in zip(sequential, lanes, strict=True):
        assert list(got) == list(want) == [k for k in EPISODE_KEYS if k in got]
        for key in got:
            if key == "steps_per_s":
                assert got[key] > 0
            else:  # same seeds, same numbers
                assert got[key] == want[key], key
    np.testing.assert_array_equal(np.array(trace_vec.est_pos), np.array(trace_seq.est_pos))
    np.testing.assert_array_equal(trace_vec.landmarks, trace_seq.landmarks)
    env.close()
