"""Sensor and action latency (docs/timing.md "Latency"): a delayed scan updates the belief of its
own time and the output is re-propagated (:mod:`quadslam_env.runtime.scan_delay`); a delayed action
is applied d steps after the agent gave it (``SimCore``). Lane-versus-scalar equality with both
delays through autoresets is in tests/env/test_vector_env.py (the ``-latency`` cases)."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from agents.control.dflqr import DFLQRPolicy
from quadslam_env.config.scenario import load_scenario
from quadslam_env.core import SimCore
from quadslam_env.env import QuadSLAMEnv
from quadslam_env.metrics.step import METRIC_KEYS, metric_columns
from quadslam_env.runtime.period_log import predict_samples
from quadslam_env.runtime.scan_delay import ScanDelay
from quadslam_env.schema import ConfigError

LIDAR_EVERY = 10  # paper_ekf_figure8: 10 Hz LiDAR at 100 Hz control
STEPS = 130


def _core(lidar_delay: int = 0, action_delay: int = 0, lanes: int = 2, **over: Any) -> SimCore:
    over = {
        "episode": {"duration_s": 2.0},
        "lidar": {"delay_steps": lidar_delay},
        "action": {"delay_steps": action_delay, **over.pop("action", {})},
        **over,
    }
    return SimCore(load_scenario("paper_ekf_figure8", over), lanes)


def _open_loop(core: SimCore, steps: int, seed: int) -> np.ndarray:
    """Hover actions with small noise (T, B, 4): open loop, so that with torque actions the
    truth, the IMU and the scans do not depend on the estimate."""
    rng = np.random.default_rng(seed)
    hover = core.action_map.hover_action
    return hover + 0.02 * rng.standard_normal((steps, core.num_lanes, hover.shape[0]))


def _full(core: SimCore, lane: int) -> tuple[np.ndarray, np.ndarray]:
    """The EKF's total mean and covariance (pose, rates, biases and map) of a lane."""
    x, P, _ = core.estimator.full_state(lane)  # type: ignore[attr-defined]
    return x, P


# ------------------------------------------------------------------ re-propagation
@pytest.mark.parametrize("delay", [5, 12])
def test_delayed_pipeline_does_the_undelayed_filters_operations(delay: int) -> None:
    """Two cores see the same truth, IMU and scans (open-loop torque actions, same seeds); lane
    1 is reset at step 37 so the lanes' scan phases differ. Where no scan of a lane is in
    flight (d < L: the steps from a delivery until the next scan; always before the first
    scan) the delayed output equals the undelayed filter, mean and covariance; the lagging
    filter equals the undelayed filter of the scan's time at every delivery; and where a scan
    that saw landmarks is in flight the output differs."""
    plain, late = _core(), _core(lidar_delay=delay)
    pipeline = late._copies
    assert isinstance(pipeline, ScanDelay)
    actions = _open_loop(plain, STEPS, seed=1)
    history: list[list[tuple[np.ndarray, np.ndarray]]] = [[], []]  # undelayed, per lane step
    for core in (plain, late):
        core.reset_lanes([0, 1], [np.random.default_rng(s) for s in (10, 11)])
    seen: list[dict[int, int]] = [{}, {}]  # landmarks seen by each lane's scan of a step
    compared = {"equal": 0, "filter": 0, "differ": 0}
    for k in range(STEPS):
        if k == 37:
            for core in (plain, late):
                core.reset_lanes([1], [np.random.default_rng(12)])
            history[1], seen[1] = [], {}
        for core in (plain, late):
            *_, term, trunc, _ = core.step(actions[k])
            assert not (term.any() or trunc.any())
        np.testing.assert_array_equal(plain.vehicle.state, late.vehicle.state)
        for lane in (0, 1):
            s = int(plain.steps[lane])
            want = _full(plain, lane)
            history[lane].append(want)
            if s % LIDAR_EVERY == 0:
                seen[lane][s] = int(plain.n_visible[lane])
            got = _full(late, lane)
            in_flight = [m for m in range(max(1, s - delay + 1), s + 1) if m % LIDAR_EVERY == 0]
            if not in_flight:
                for g, w in zip(got, want, strict=True):
                    np.testing.assert_allclose(g, w, rtol=0, atol=1e-10)
                compared["equal"] += 1
            elif any(seen[lane][m] > 0 for m in in_flight):
                same = got[0].shape == want[0].shape and np.allclose(got[0], want[0], atol=1e-6)
                assert not same, f"lane {lane} step {s}: a scan in flight changed nothing"
                compared["differ"] += 1
            if pipeline.refreshed[lane]:
                f = pipeline.filter_step[lane]
                assert f == s - delay
                x, P, _ = pipeline.filter.full_state(lane)  # type: ignore[attr-defined]
                np.testing.assert_allclose(x, history[lane][f - 1][0], rtol=0, atol=1e-10)
                np.testing.assert_allclose(P, history[lane][f - 1][1], rtol=0, atol=1e-10)
                compared["filter"] += 1
    assert compared["filter"] >= 4 and compared["differ"] >= 10
    assert compared["equal"] >= (20 if delay < LIDAR_EVERY else 10)


# ------------------------------------------------------------------ action delay
@pytest.mark.parametrize("mode", ["thrust_torque", "thrust_rates"])
def test_delayed_actions_fly_the_shifted_sequence(mode: str) -> None:
    """With d steps of action delay the truth under a sequence equals the undelayed truth
    under the sequence shifted by d with the hover action in front (Oracle: the rate loop's
    estimated rates are the true ones at application time in both runs)."""
    d = 3
    est: dict[str, Any] = {"estimator": {"name": "oracle"}, "action": {"mode": mode}}
    late, plain = _core(action_delay=d, **est), _core(**est)
    actions = _open_loop(plain, 60, seed=2)
    hover = np.broadcast_to(plain.action_map.hover_action, (d, *actions.shape[1:]))
    shifted = np.concatenate([hover, actions[:-d]])
    for core in (plain, late):
        core.reset_lanes([0, 1], [np.random.default_rng(s) for s in (3, 4)])
    for k in range(actions.shape[0]):
        late.step(actions[k])
        plain.step(shifted[k])
        np.testing.assert_array_equal(late.vehicle.state, plain.vehicle.state)
    # And it is a delay: the unshifted sequence flies another trajectory.
    other = _core(**est)
    other.reset_lanes([0, 1], [np.random.default_rng(s) for s in (3, 4)])
    for k in range(actions.shape[0]):
        other.step(actions[k])
    assert not np.allclose(other.vehicle.state, late.vehicle.state)


def test_a_reset_refills_the_action_queue_with_hover() -> None:
    """A lane reset mid-way applies hover over its first d steps, not its old commands."""
    d = 4
    core = _core(action_delay=d, estimator={"name": "oracle"})
    core.reset_lanes([0, 1], [np.random.default_rng(s) for s in (5, 6)])
    full = np.tile(np.array([1.0, 0.3, -0.3, 0.1]), (2, 1))
    for _ in range(d):
        core.step(full)
    core.reset_lanes([1], [np.random.default_rng(7)])
    ref = _core(estimator={"name": "oracle"})
    ref.reset_lanes([0, 1], [np.random.default_rng(s) for s in (5, 7)])
    hover = np.tile(core.action_map.hover_action, (2, 1))
    for _ in range(d):
        core.step(full)
        ref.step(hover)
        np.testing.assert_array_equal(core.vehicle.state[1], ref.vehicle.state[1])


# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("key", ["action", "lidar"])
@pytest.mark.parametrize(
    ("value", "fragment"),
    [(-1, ">= 0"), (2.5, "an integer"), ("3", "an integer"), (True, "an integer"),
     (200, "from 0 to 199"), (250, "from 0 to 199")],
)  # fmt: skip
def test_bad_delays_name_the_key_the_value_and_the_range(
    key: str, value: Any, fragment: str
) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario(
            "paper_ekf_figure8", {"episode": {"duration_s": 2.0}, key: {"delay_steps": value}}
        )
    message = str(err.value)
    assert message.startswith(f"{key}.delay_steps: got {value!r}") and fragment in message


def test_delayed_lidar_refuses_what_it_cannot_run() -> None:
    """A slow IMU (iSAM2, which cannot be copied but takes late scans itself, is accepted:
    tests/isam2/test_isam2_latency.py)."""
    with pytest.raises(ConfigError, match=r"lidar\.delay_steps: got 2") as err:
        load_scenario("paper_ekf_figure8", {"imu": {"rate_hz": 10.0}, "lidar": {"delay_steps": 2}})
    assert "imu.rate_hz" in str(err.value)


# ------------------------------------------------------------------ consistency
def _nees_correct_and_stale(seed: int, delay: int) -> tuple[float, float]:
    """Mean pose NEES over the second half of a 10 s DF-LQR figure-8 flight on EKF-SLAM with
    the LiDAR ``delay`` steps late: of the env's estimate (re-propagated), and of a plain
    filter fed the same IMU samples and scans with each scan applied on arrival as if current.
    Both are scored against the same true state with the env's own NEES."""
    env = QuadSLAMEnv(
        "paper_ekf_figure8", episode={"duration_s": 10.0}, lidar={"delay_steps": delay}
    )
    core = env._core
    obs, _ = env.reset(seed=seed)
    pipeline = core._copies
    assert isinstance(pipeline, ScanDelay)
    stale = copy.deepcopy(pipeline.filter)  # the belief at reset
    stream: list[tuple] = []
    step = pipeline.step

    def record(*args: Any) -> Any:  # (output, steps, active, samples, sigma, scan, σ_LiDAR)
        stream.append((copy.deepcopy(args[3]), copy.deepcopy(args[5]), args[4], args[6]))
        return step(*args)

    pipeline.step = record  # type: ignore[method-assign,assignment]
    policy = DFLQRPolicy.from_env(env)
    values = np.empty((len(METRIC_KEYS), 1))
    row = METRIC_KEYS.index("est_nees_pose")
    correct, naive = [], []
    done = False
    while not done:
        obs, _, term, trunc, info = env.step(policy.predict(obs)[0])
        done = term or trunc
        samples, _, sigma, lidar_sigma = stream[-1]
        predict_samples(stale, samples, sigma, core.dt, np.ones(1, dtype=bool))
        late = stream[-1 - delay][1] if len(stream) > delay else None
        if late is not None:
            late.apply(stale, samples[-1][0], lidar_sigma)
        truth = (core.vehicle.state, core.landmarks, core.imu.total_bias)
        metric_columns(truth[0], stale.estimate(), truth[1], truth[2], values)
        correct.append(float(info["est_nees_pose"]))
        naive.append(values[row, 0])
    assert len(correct) == 1000
    return float(np.mean(correct[500:])), float(np.mean(naive[500:]))


def test_a_delayed_scan_applied_at_its_own_time_keeps_the_pose_nees_consistent() -> None:
    """d = 5 (0.05 s at 100 Hz control, 10 Hz LiDAR), four seeds: the re-propagated estimate's
    pose ANEES (9 DOF) stays near the undelayed filter's (4–12 on these flights), while the
    same scans applied as if current make it several times larger (pose moved, covariance
    unaware)."""
    runs = np.array([_nees_correct_and_stale(seed, delay=5) for seed in range(4)])
    correct, naive = runs.mean(axis=0)
    assert correct < 15.0
    assert naive > 4.0 * correct
