"""A delayed LiDAR with the iSAM2 smoother (docs/isam2.md "A delayed LiDAR"; docs/timing.md
"Latency"): the smoother is not copied; each scan reaches it d steps late and gets a keyframe at
its own time (:class:`quadslam_env.runtime.scan_delay.LateScans`, :mod:`estimators.isam2.history`).

Two cores see the same truth, IMU and scans (open-loop torque actions, same seeds), one with
the LiDAR undelayed and one with it d steps late. The delayed smoother must reach, scan by
scan, the keyframes the undelayed one reached at the scans' own times, and where no scan is in
flight its output (the latest keyframe carried to now by the IMU) must be the undelayed one's.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from quadslam_env.config.scenario import load_scenario
from quadslam_env.core import SimCore
from quadslam_env.runtime.scan_delay import LateScans
from quadslam_env.schema import ConfigError

pytest.importorskip("gtsam")

LIDAR_EVERY = 10  # paper_ekf_figure8: 10 Hz LiDAR at 100 Hz control
STEPS = 130
UNKNOWN = {"association": "unknown", "clutter_rate": 3.0, "detection_prob": 0.9}
# The same factors reach the smoother in the same order, with the same time stamps, so its
# relinearisation and the fixed lag's marginalisation see the same sequence of updates either
# way: the two runs agree to rounding (measured: exactly; 1e-9 leaves room for a GTSAM build
# whose floating-point reductions depend on memory layout).
ATOL = 1e-9


def _core(delay: int, params: dict[str, Any], lidar: dict[str, Any] | None = None) -> SimCore:
    over = {
        "episode": {"duration_s": 2.0},
        "estimator": {"name": "isam2", "params": params},
        "lidar": {"delay_steps": delay, **(lidar or {})},
    }
    return SimCore(load_scenario("paper_ekf_figure8", over), 2)


def _open_loop(core: SimCore, seed: int) -> np.ndarray:
    """Hover actions with small noise (T, B, 4): the truth does not depend on the estimate."""
    rng = np.random.default_rng(seed)
    hover = core.action_map.hover_action
    return hover + 0.02 * rng.standard_normal((STEPS, core.num_lanes, hover.shape[0]))


def _output(core: SimCore, lane: int) -> list[np.ndarray]:
    """A lane's output: position, body velocity, attitude, pose covariance, map labels, means."""
    est = core.est
    assert est.pose_cov is not None
    ids = np.flatnonzero(est.landmark_mapped[lane])  # the map's labels, then their means
    return [
        est.position[lane], est.vel_body[lane], est.euler[lane], est.pose_cov[lane],
        ids.astype(float), est.landmark_means[lane][ids],
    ]  # fmt: skip


def _keyframe(core: SimCore, lane: int) -> tuple[int, list[np.ndarray]]:
    """A lane's latest keyframe: its index and smoothed pose (4, 4), velocity, joint marginal."""
    smoother = core.estimator.lanes[lane]  # type: ignore[attr-defined]
    state = [smoother._kf_pose.matrix(), smoother._kf_vel, smoother._kf_cov]
    return smoother.keyframes, state


def _used(core: SimCore, lane: int, unlabeled: bool) -> int:
    """Returns of a lane's scan this step that entered the graph: all with known association;
    with unknown association those paired with a mapped landmark (the others only fed a
    tentative one, which changes nothing yet)."""
    if not unlabeled:
        return int(core.n_visible[lane])
    return int((core.estimator.last_association[lane] >= 0).sum())  # type: ignore[attr-defined]


def _agree(got: list[np.ndarray], want: list[np.ndarray]) -> float:
    """Assert ``got`` equals ``want`` array by array to :data:`ATOL`; the largest difference."""
    worst = 0.0
    for g, w in zip(got, want, strict=True):
        np.testing.assert_allclose(g, w, rtol=0, atol=ATOL)
        worst = max(worst, float(np.max(np.abs(g - w), initial=0.0)))
    return worst


def _run(delay: int, params: dict[str, Any], lidar: dict[str, Any] | None = None) -> dict[str, int]:
    """Step an undelayed and a ``delay``-step core together (lane 1 reset at step 37, so the
    lanes' scan phases differ) and compare them; returns the counts of the comparisons (and,
    printed, the largest difference found where they must agree)."""
    plain, late = _core(0, params, lidar), _core(delay, params, lidar)
    buffer = late._copies
    assert isinstance(buffer, LateScans)
    actions = _open_loop(plain, seed=1)
    for core in (plain, late):
        core.reset_lanes([0, 1], [np.random.default_rng(s) for s in (10, 11)])
    keyframes: list[dict[int, tuple[int, list[np.ndarray]]]] = [{}, {}]  # at each scan step
    seen: list[dict[int, int]] = [{}, {}]  # returns the smoother used, by scan step
    counts = {"equal": 0, "keyframe": 0, "differ": 0}
    worst = 0.0
    for k in range(STEPS):
        if k == 37:
            for core in (plain, late):
                core.reset_lanes([1], [np.random.default_rng(12)])
            keyframes[1], seen[1] = {}, {}
        for core in (plain, late):
            *_, term, trunc, _ = core.step(actions[k])
            assert not (term.any() or trunc.any())
        np.testing.assert_array_equal(plain.vehicle.state, late.vehicle.state)
        assert not buffer.refreshed.any()
        arrived = [] if buffer.applied is None else buffer.applied.lanes.tolist()
        for lane in (0, 1):
            s = int(plain.steps[lane])
            if s % LIDAR_EVERY == 0:
                keyframes[lane][s] = _keyframe(plain, lane)
                seen[lane][s] = _used(plain, lane, lidar is not None)
            if lane in arrived:  # the scan of step s - d: the undelayed keyframe of then
                assert (s - delay) % LIDAR_EVERY == 0
                want_k, want = keyframes[lane][s - delay]
                got_k, got = _keyframe(late, lane)
                assert got_k == want_k
                worst = max(worst, _agree(got, want))
                counts["keyframe"] += 1
            in_flight = [m for m in range(max(1, s - delay + 1), s + 1) if m % LIDAR_EVERY == 0]
            want_out, got_out = _output(plain, lane), _output(late, lane)
            if not in_flight:
                worst = max(worst, _agree(got_out, want_out))
                counts["equal"] += 1
            elif any(seen[lane][m] > 0 for m in in_flight):
                same = all(
                    g.shape == w.shape and np.allclose(g, w, rtol=0, atol=1e-6)
                    for g, w in zip(got_out, want_out, strict=True)
                )
                assert not same, f"lane {lane} step {s}: a scan in flight changed nothing"
                counts["differ"] += 1
    print(f"d = {delay}, {params}, {lidar}: {counts}, largest difference {worst:.1e}")
    return counts


@pytest.mark.parametrize(
    ("params", "lidar"),
    [({"window_s": None}, None), ({"window_s": 0.5}, None), ({"window_s": 0.5}, UNKNOWN)],
    ids=["full-graph", "fixed-lag", "fixed-lag-unknown-association"],
)
def test_delayed_smoother_equals_the_undelayed_one_where_no_scan_is_in_flight(
    params: dict[str, Any], lidar: dict[str, Any] | None
) -> None:
    """d = 4 < L = 10: from a scan's arrival to the next scan nothing is in flight, and the
    delayed output (position, velocity, attitude, pose covariance, map) is the undelayed one;
    at each arrival the new keyframe is the undelayed smoother's of the scan's time; while a
    scan that saw landmarks is in flight the outputs differ. The 0.5 s window marginalises
    keyframes within the 1.3 s run."""
    counts = _run(4, params, lidar)
    assert counts["keyframe"] >= 15 and counts["equal"] >= 60 and counts["differ"] >= 30


def test_two_scans_in_flight_each_get_their_own_keyframe_in_order() -> None:
    """d = 13 > L = 10: a second scan is measured before the first arrives, so after the
    first scan some scan is always in flight; each arrival still makes the undelayed
    smoother's keyframe of its scan's time (the kept samples beyond it go on to the next)."""
    counts = _run(13, {"window_s": 0.5})
    assert counts["keyframe"] >= 15 and counts["differ"] >= 80


# ------------------------------------------------------------------ vector env
def _lane_rollout(kwargs: dict[str, Any], seed: int, actions: np.ndarray) -> list[np.ndarray]:
    """What a lane of the vector env must see: the scalar env seeded ``seed`` with the
    vector env's next-step autoreset (the step after an end is a reset)."""
    env = gym.make("QuadSLAM-v0", **kwargs)
    obs, _ = env.reset(seed=seed)
    out, done = [obs], False
    for a in actions:
        if done:
            obs, _ = env.reset()
            done = False
        else:
            obs, _, term, trunc, _ = env.step(a)
            done = term or trunc
        out.append(obs)
    return out


def test_vector_lanes_equal_the_scalar_env_through_an_autoreset() -> None:
    """Lane 1 rolls over its 20° tilt limit every ~20 steps (full roll torque), so it is
    reset with scans in flight and runs out of phase with lane 0."""
    kwargs: dict[str, Any] = {
        "scenario": "paper_ekf_figure8",
        "estimator": {"name": "isam2", "params": {"window_s": 0.5}},
        "lidar": {"delay_steps": 12},
        "episode": {"duration_s": 0.6, "max_tilt_deg": 20.0},
    }
    vec = gym.make_vec("QuadSLAM-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    single = gym.make("QuadSLAM-v0", **kwargs)
    hover = single.unwrapped.hover_action  # type: ignore[attr-defined]
    single.close()
    rng = np.random.default_rng(7)
    actions = (hover + 0.05 * rng.standard_normal((70, 2, hover.shape[0]))).astype(np.float32)
    actions[:, 1, 1] = 1.0
    obs, _ = vec.reset(seed=5)
    got, ends = [obs], 0
    for a in actions:
        obs, _, term, trunc, _ = vec.step(a)
        got.append(obs)
        ends += int(term[1] or trunc[1])
    assert ends >= 2
    for lane in (0, 1):
        want = _lane_rollout(kwargs, 5 + lane, actions[:, lane])
        for k, (g, w) in enumerate(zip(got, want, strict=True)):
            np.testing.assert_array_equal(g[lane], w, err_msg=f"lane {lane} step {k}")


# ------------------------------------------------------------------ the scenario check
def test_the_check_accepts_a_delayed_lidar_and_refuses_a_slow_imu() -> None:
    isam2 = {"estimator": {"name": "isam2"}}
    scenario = load_scenario("paper_ekf_figure8", {**isam2, "lidar": {"delay_steps": 12}})
    assert scenario.lidar.delay_steps == 12
    with pytest.raises(ConfigError, match=r"^imu\.rate_hz: got 10\.0 .*'isam2', which cannot"):
        load_scenario("paper_ekf_figure8", {**isam2, "imu": {"rate_hz": 10.0}})
    # Both together: the delay check names the delayed LiDAR first, for every estimator.
    with pytest.raises(ConfigError, match=r"^lidar\.delay_steps: got 2 with imu\.rate_hz"):
        load_scenario(
            "paper_ekf_figure8", {**isam2, "imu": {"rate_hz": 10.0}, "lidar": {"delay_steps": 2}}
        )
