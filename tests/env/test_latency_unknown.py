"""A delayed LiDAR with unknown data association (docs/timing.md "Latency"): the lagging filter
associates and applies each unlabeled scan at its own time (:mod:`quadslam_env.runtime.scan_delay`),
and the association's counts score the scan that arrived (``EstimatorCopies.applied``).
Lane-versus-scalar equality through autoresets is in tests/env/test_vector_env.py (the
``-unknown-latency`` cases)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from quadslam_env.config.scenario import load_scenario
from quadslam_env.core import SimCore
from quadslam_env.env import QuadSLAMEnv
from quadslam_env.metrics.association import ASSOCIATION_KEYS
from quadslam_env.runtime.scan_delay import ScanDelay

LIDAR_EVERY = 10  # paper_ekf_figure8: 10 Hz LiDAR at 100 Hz control
STEPS = 130
UNKNOWN = {"association": "unknown", "clutter_rate": 3.0, "detection_prob": 0.9}
ESTIMATORS = {
    "ekf_slam": {"name": "ekf_slam", "params": {"confirm_hits": 2, "confirm_window": 3}},
    "fastslam": {"name": "fastslam", "params": {"n_particles": 30}},
}


def _core(name: str, delay: int) -> SimCore:
    over = {
        "episode": {"duration_s": 2.0},
        "lidar": {**UNKNOWN, "delay_steps": delay},
        "estimator": ESTIMATORS[name],
    }
    return SimCore(load_scenario("paper_ekf_figure8", over), 2)


def _belief(estimator: Any, lane: int) -> list[np.ndarray]:
    """A lane's belief: its snapshot (pose, covariance, the mapped labels' means; the rows of
    unmapped labels are unused), and the EKF's total mean, covariance and slot ids or
    FastSLAM's particles, log-weights and landmark EKFs."""
    est = estimator.estimate()
    mapped = est.landmark_mapped[lane].copy()
    snapshot = [est.position[lane], est.euler[lane], est.pose_cov[lane], mapped]
    snapshot = [np.array(a) for a in snapshot] + [est.landmark_means[lane][mapped]]
    if hasattr(estimator, "full_state"):
        return snapshot + list(estimator.full_state(lane))
    state = estimator.lanes[lane].state
    arrays = (state.x, state.logw, state.mu, state.sigma, state.lineage)
    return snapshot + [a.copy() for a in arrays]


def _assert_same(got: list[np.ndarray], want: list[np.ndarray], where: str) -> None:
    for g, w in zip(got, want, strict=True):
        np.testing.assert_array_equal(g, w, err_msg=where)


@pytest.mark.parametrize("delay", [3, 12])
@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_delayed_unlabeled_scans_do_the_undelayed_filters_operations(name: str, delay: int) -> None:
    """Two cores see the same truth, IMU and unlabeled scans (clutter, missed detections;
    open-loop hover actions, same seeds); lane 1 is reset at step 37 so the lanes' scan phases
    differ. Where no scan of a lane is in flight the delayed output is the undelayed filter bit
    for bit (its own association included: the same belief pairs the returns the same way);
    the lagging filter is the undelayed filter of the scan's time at every delivery; and the
    association counts reported at a delivery are those the undelayed env reported when the
    scan was measured (the same labels of the same returns)."""
    plain, late = _core(name, 0), _core(name, delay)
    pipeline = late._copies
    assert isinstance(pipeline, ScanDelay)
    rng = np.random.default_rng(1)
    hover = plain.action_map.hover_action
    actions = hover + 0.02 * rng.standard_normal((STEPS, 2, hover.shape[0]))
    for core in (plain, late):
        core.reset_lanes([0, 1], [np.random.default_rng(s) for s in (10, 11)])
    history: list[list[list[np.ndarray]]] = [[], []]  # undelayed belief per lane step
    counts: list[dict[int, dict[str, float]]] = [{}, {}]  # undelayed counts per scan step
    compared = {"equal": 0, "filter": 0, "counts": 0, "missed": 0}
    for k in range(STEPS):
        if k == 37:
            for core in (plain, late):
                core.reset_lanes([1], [np.random.default_rng(12)])
            history[1], counts[1] = [], {}
        *_, term, trunc, want_info = plain.step(actions[k])
        *_, term2, trunc2, got_info = late.step(actions[k])
        assert not (term.any() or trunc.any() or term2.any() or trunc2.any())
        np.testing.assert_array_equal(plain.vehicle.state, late.vehicle.state)
        for lane in (0, 1):
            s = int(plain.steps[lane])
            want = _belief(plain.estimator, lane)
            history[lane].append(want)
            if s % LIDAR_EVERY == 0:
                counts[lane][s] = {key: float(want_info[key][lane]) for key in ASSOCIATION_KEYS}
            in_flight = [m for m in range(max(1, s - delay + 1), s + 1) if m % LIDAR_EVERY == 0]
            if not in_flight:
                _assert_same(_belief(late.estimator, lane), want, f"lane {lane} step {s}")
                compared["equal"] += 1
            got = {key: float(got_info[key][lane]) for key in ASSOCIATION_KEYS}
            if pipeline.refreshed[lane]:
                f = int(pipeline.filter_step[lane])
                assert f == s - delay
                _assert_same(_belief(pipeline.filter, lane), history[lane][f - 1], f"filter {s}")
                compared["filter"] += 1
                for key in ("assoc_n_returns", "assoc_n_associated", "assoc_n_true"):
                    assert got[key] == counts[lane][f][key], f"lane {lane} step {s} {key}"
                assert got["assoc_n_missed"] == counts[lane][f]["assoc_n_missed"]
                assert got["assoc_n_wrong"] <= got["assoc_n_associated"]
                compared["counts"] += 1
                compared["missed"] += got["assoc_n_missed"] > 0
            else:  # nothing arrived: nothing was associated
                assert all(value == 0.0 for value in got.values()), f"lane {lane} step {s}"
    assert compared["filter"] >= 8 and compared["counts"] == compared["filter"]
    assert compared["equal"] >= (20 if delay < LIDAR_EVERY else 10)
    assert compared["missed"] >= 1  # detection_prob 0.9: some return was missed


def _episode(name: str, delay: int, seed: int, steps: int = 200) -> list[tuple]:
    """(obs, info) of every step of a scalar env with unlabeled, ``delay``-step-late scans,
    flown open loop on hover actions with seeded noise."""
    env = QuadSLAMEnv(
        "paper_ekf_figure8",
        episode={"duration_s": 2.0},
        lidar={**UNKNOWN, "delay_steps": delay},
        estimator=ESTIMATORS[name],
    )
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    rng = np.random.default_rng(seed)
    hover = env.hover_action
    for _ in range(steps):
        action = hover + 0.02 * rng.standard_normal(hover.shape)
        obs, _, term, trunc, info = env.step(action.astype(np.float32))
        out.append((obs, info))
        if term or trunc:
            break
    return out


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_association_terms_stay_consistent_with_a_delay(name: str) -> None:
    """With d = 4 the counts are finite and nested (wrong ≤ associated ≤ returns, missed ≤
    true ≤ returns), non-zero only at deliveries (4 steps after each 10th step), where the
    returns counted are those the LiDAR took d steps earlier (``est_n_visible`` then); the
    mapped and spurious counts are finite, the map ends non-empty, and the episode's rates are
    the ratios of the summed counts (the last scan, still in flight, is dropped)."""
    delay = 4
    run = _episode(name, delay, seed=3)
    assert len(run) == 201  # reset and the 2 s episode's 200 steps
    delivered = 0
    for s, (_, info) in enumerate(run):
        c = {key: float(info[key]) for key in ASSOCIATION_KEYS}
        assert all(math.isfinite(v) and v >= 0 for v in c.values()), (s, c)
        assert c["assoc_n_wrong"] <= c["assoc_n_associated"] <= c["assoc_n_returns"]
        assert c["assoc_n_missed"] <= c["assoc_n_true"] <= c["assoc_n_returns"]
        assert math.isfinite(info["est_n_mapped"]) and math.isfinite(info["spurious_landmarks"])
        measured = s - delay
        if s > delay and measured % LIDAR_EVERY == 0:
            assert c["assoc_n_returns"] == run[measured][1]["est_n_visible"], s
            delivered += c["assoc_n_returns"] > 0
        else:
            assert c["assoc_n_returns"] == 0.0, s
    assert delivered >= 10
    last = run[-1][1]
    assert last["est_n_mapped"] > 0 and last["episode_n_mapped"] == last["est_n_mapped"]
    total = {key: sum(float(info[key]) for _, info in run[1:]) for key in ASSOCIATION_KEYS}
    assert total["assoc_n_associated"] > 0 and total["assoc_n_true"] > 0
    wrong = total["assoc_n_wrong"] / total["assoc_n_associated"]
    missed = total["assoc_n_missed"] / total["assoc_n_true"]
    assert last["episode_assoc_wrong_rate"] == pytest.approx(wrong, rel=1e-12, abs=1e-15)
    assert last["episode_assoc_missed_rate"] == pytest.approx(missed, rel=1e-12, abs=1e-15)


@pytest.mark.parametrize("name", sorted(ESTIMATORS))
def test_a_delayed_unknown_association_run_is_determined_by_its_seed(name: str) -> None:
    """Same seed, same observations and info bit for bit; another seed, another run."""
    first, again, other = (_episode(name, 5, seed, steps=60) for seed in (7, 7, 8))
    for (obs_a, info_a), (obs_b, info_b) in zip(first, again, strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert info_a.keys() == info_b.keys()
        for key, value in info_a.items():
            np.testing.assert_array_equal(value, info_b[key], err_msg=key)
    assert not np.array_equal(first[-1][0], other[-1][0])
