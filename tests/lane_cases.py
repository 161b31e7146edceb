"""The lane-versus-scalar cases of the native vector env, shared by the tests of every feature
that must keep lane i of a vector env equal to the scalar env seeded s + i through autoresets
(``tests/env/test_vector_env.py`` and the feature tests that add a case with
``monkeypatch.setitem(CASES, ...)``; docs/design.md §9)."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import quadslam_env  # noqa: F401  (registers the ids)

SHORT = {"episode": {"duration_s": 0.35}}
FAST_FASTSLAM = {
    "episode": {"duration_s": 0.25},
    "estimator": {"params": {"n_particles": 30}},
}
UNKNOWN_LIDAR = {"association": "unknown", "clutter_rate": 3.0, "detection_prob": 0.9}
CASES = {
    "QuadSLAM-Oracle-v0": SHORT,
    "QuadSLAM-EKF-v0": SHORT,
    "QuadSLAM-EKF-v0-known": {**SHORT, "scenario": "paper_ekf_figure8_known"},
    "QuadSLAM-FastSLAM-v0": FAST_FASTSLAM,
    "QuadSLAM-EKF-v0-unknown": {
        "episode": {"duration_s": 0.45},
        "lidar": UNKNOWN_LIDAR,
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
    # The wind states with the estimated wind and air velocity appended to the observation.
    "QuadSLAM-EKF-v0-wind-observation": {
        **SHORT,
        "scenario": "ekf_figure8_wind_states",
        "observation": {"estimated_wind": True, "air_velocity": True},
    },
    "QuadSLAM-EKF-v0-crazyflie-rotors": {
        **SHORT,
        "vehicle": {"preset": "crazyflie2"},
        "action": {"mode": "rotor_thrust"},
    },
    # A LiDAR and actions delayed by whole steps (docs/timing.md "Latency"): the filter copy
    # lags each lane by its own phase; a delay longer than the scan interval and a fast IMU.
    "QuadSLAM-EKF-v0-latency": {
        **SHORT,
        "lidar": {"delay_steps": 3},
        "action": {"delay_steps": 2, "mode": "thrust_rates"},
    },
    "QuadSLAM-FastSLAM-v0-latency-imu1000": {
        **FAST_FASTSLAM,
        "imu": {"rate_hz": 1000.0},
        "lidar": {"delay_steps": 12},
        "action": {"delay_steps": 1},
    },
    # Unlabeled scans that arrive late: the lagging filter associates them at their own time.
    "QuadSLAM-EKF-v0-unknown-latency": {
        "episode": {"duration_s": 0.45},
        "lidar": {**UNKNOWN_LIDAR, "delay_steps": 4},
        "estimator": {"params": {"confirm_hits": 2, "confirm_window": 3}},
    },
    "QuadSLAM-FastSLAM-v0-unknown-latency": {
        **FAST_FASTSLAM,
        "lidar": {**UNKNOWN_LIDAR, "delay_steps": 3},
    },
    "QuadSLAM-EKF-v0-unknown-imu5": {
        "episode": {"duration_s": 0.45},
        "imu": {"rate_hz": 5.0},
        "lidar": UNKNOWN_LIDAR,
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
    """The make kwargs of a case; a 20° tilt limit ends lane 1 (full roll torque, see
    :func:`lane_actions`) every ~20 steps, so lanes end, and are reset, at different steps."""
    kwargs = dict(CASES[env_id])
    kwargs["episode"] = {**kwargs.get("episode", {}), "max_tilt_deg": 20.0}
    return kwargs


MODES = [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP, AutoresetMode.DISABLED]


def scalar_rollout(
    env_id: str, seed: int, actions: np.ndarray, mode: AutoresetMode = AutoresetMode.NEXT_STEP
) -> tuple[list[tuple], int]:
    """What a lane must produce, from the scalar env reset as the vector env's ``mode`` resets
    the lane, and how many times it was reset after an episode end.

    Entries ``(obs, reward, terminated, truncated, info, final)``, ``final`` the ending step's
    ``(obs, info)`` where SAME_STEP put the reset in that step's entry, else ``None``.
    NEXT_STEP resets on the step after an end (its action unused); SAME_STEP in the ending
    step; DISABLED right after it, as an entry of its own (a ``reset_mask`` reset).
    """
    env = gym.make(_id(env_id), **_kwargs(env_id))
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, False, False, info, None)]
    done = False
    n_resets = 0
    for a in actions:
        if done:  # NEXT_STEP only: the other modes reset below, right after the end
            obs, info = env.reset()
            out.append((obs, 0.0, False, False, info, None))
            done = False
            n_resets += 1
            continue
        obs, reward, term, trunc, info = env.step(a)
        done = term or trunc
        if done and mode == AutoresetMode.SAME_STEP:
            final = (obs, info)
            obs, info = env.reset()
            out.append((obs, reward, term, trunc, info, final))
        else:
            out.append((obs, reward, term, trunc, info, None))
        if done and mode != AutoresetMode.NEXT_STEP:
            if mode == AutoresetMode.DISABLED:
                obs, info = env.reset()
                out.append((obs, 0.0, False, False, info, None))
            done = False
            n_resets += 1
    env.close()
    return out, n_resets


def vector_rollout(
    vec: gym.vector.VectorEnv, seed: int, actions: np.ndarray
) -> list[tuple[tuple, np.ndarray, int]]:
    """Events ``(reset or step result, lanes (B,) bool it applies to, steps taken)`` of ``vec``
    reset with ``seed`` and stepped with ``actions`` (T, B, 4); with DISABLED the lanes that
    end are reset with ``reset_mask`` right after the step."""
    b = vec.num_envs
    every = np.ones(b, dtype=bool)
    obs, info = vec.reset(seed=seed)
    events = [((obs, np.zeros(b), np.zeros(b, bool), np.zeros(b, bool), info), every, 0)]
    for k, act in enumerate(actions, start=1):
        result = vec.step(act)
        events.append((result, every, k))
        ended = result[2] | result[3]
        if vec.metadata["autoreset_mode"] == AutoresetMode.DISABLED and ended.any():
            obs, info = vec.reset(options={"reset_mask": ended})
            reset = (obs, np.zeros(b), np.zeros(b, bool), np.zeros(b, bool), info)
            events.append((reset, ended, k))
    return events


def assert_lane_info(got: dict, lane: int, want: dict, where: str) -> None:
    """Lane ``lane`` of the vector info ``got`` holds exactly the scalar env's ``want``."""
    want = dict(want)
    keys = {
        key
        for key in got
        if not key.startswith("_") and key not in ("final_obs", "final_info")
        and got[f"_{key}"][lane]
    }  # fmt: skip
    reason = want.pop("termination_reason", "")
    assert keys - {"termination_reason"} == set(want), where
    got_reason = got["termination_reason"][lane] if "termination_reason" in keys else ""
    assert got_reason == reason, where
    for key, value in want.items():
        if key != "est_step_time_ms":
            assert got[key][lane] == pytest.approx(value, rel=1e-6, abs=1e-9), f"{where} {key}"


def assert_lanes_equal_scalar_rollouts(env_id: str, mode: AutoresetMode) -> None:
    """Lane i of the vector env of the case ``env_id`` (a key of :data:`CASES`) equals the
    scalar env seeded 100 + i, event for event, through several autoresets in ``mode``."""
    lanes, steps, seed = 3, 80, 100
    acts = lane_actions(env_id, lanes, steps)
    vec = gym.make_vec(
        _id(env_id),
        num_envs=lanes,
        vectorization_mode="vector_entry_point",
        autoreset_mode=mode,
        **_kwargs(env_id),
    )
    assert vec.metadata["autoreset_mode"] == mode
    events = vector_rollout(vec, seed, acts)
    vec.close()
    end_steps = []
    for lane in range(lanes):
        want, n_resets = scalar_rollout(env_id, seed + lane, acts[:, lane], mode)
        assert n_resets >= 1  # the comparison went through at least one reset after an end
        got = [(event, step) for event, applies, step in events if applies[lane]]
        ends = []
        for k, (w, (g, step)) in enumerate(zip(want, got, strict=True)):
            w_obs, w_rew, w_term, w_trunc, w_info, w_final = w
            g_obs, g_rew, g_term, g_trunc, g_info = g
            where = f"lane {lane} event {k}"
            np.testing.assert_array_equal(g_obs[lane], w_obs, err_msg=where)
            assert g_rew[lane] == pytest.approx(w_rew, rel=1e-6, abs=1e-9)
            assert (bool(g_term[lane]), bool(g_trunc[lane])) == (w_term, w_trunc)
            assert_lane_info(g_info, lane, w_info, where)
            has_final = "final_obs" in g_info and g_info["_final_obs"][lane]
            assert has_final == (w_final is not None), where
            assert bool("final_info" in g_info and g_info["_final_info"][lane]) == has_final
            if has_final:
                np.testing.assert_array_equal(g_info["final_obs"][lane], w_final[0])
                assert_lane_info(g_info["final_info"], lane, w_final[1], f"{where} final")
            if w_term or w_trunc:
                ends.append(step)
        end_steps.append(ends)
    # Several episode ends, not at the same steps in every lane.
    assert max(map(len, end_steps)) >= 3 and len(set(map(tuple, end_steps))) > 1
