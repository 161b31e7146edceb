"""The iSAM2 estimator's sliding window (:class:`estimators.isam2.fixed_lag.FixedLagIsam2`): on a
linear-Gaussian chain marginalisation is exact, so the window's newest state and the landmark
equal the full graph's batch solution; the window's length stays bounded; in flight the
landmarks never leave it."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import quadslam_env  # noqa: F401  (registers the env ids)
from estimators.isam2.fixed_lag import FixedLagIsam2

gtsam = pytest.importorskip("gtsam")

PERIOD = 0.1  # s between keyframes


def _chain(rng: np.random.Generator, steps: int) -> list[tuple[Any, Any, dict[int, float]]]:
    """A linear-Gaussian chain: points p_k (Point3) with odometry between them, a landmark l
    seen from every one (each sighting re-stamps l, as the estimator does), a prior on p_0.

    Returns:
        Per step, the new factors, the new values and the stamps, as the estimator passes them.
    """
    lm = gtsam.symbol("l", 0)
    odo = gtsam.noiseModel.Isotropic.Sigma(3, 0.05)
    seen = gtsam.noiseModel.Isotropic.Sigma(3, 0.2)
    truth = np.cumsum(rng.normal(0.0, 0.3, (steps, 3)), axis=0)
    landmark = np.array([4.0, -2.0, 1.0])
    out = []
    for k in range(steps):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pk = gtsam.symbol("x", k)
        if k == 0:
            prior = gtsam.noiseModel.Isotropic.Sigma(3, 0.5)
            graph.add(gtsam.PriorFactorPoint3(pk, truth[0] + rng.normal(0, 0.5, 3), prior))
            values.insertPoint3(lm, landmark + rng.normal(0.0, 1.0, 3))
        else:
            step = truth[k] - truth[k - 1] + rng.normal(0.0, 0.05, 3)
            graph.add(gtsam.BetweenFactorPoint3(gtsam.symbol("x", k - 1), pk, step, odo))
        values.insertPoint3(pk, truth[k] + rng.normal(0.0, 0.3, 3))
        sighting = landmark - truth[k] + rng.normal(0.0, 0.2, 3)
        graph.add(gtsam.BetweenFactorPoint3(pk, lm, sighting, seen))
        out.append((graph, values, {pk: k * PERIOD, lm: k * PERIOD}))
    return out


@pytest.mark.parametrize("every", [1, 3, 7])
def test_window_newest_state_and_landmark_equal_the_full_batch_solution(every: int) -> None:
    """Linear factors: the marginal a marginalisation leaves is exact, so after every update
    the newest point and the landmark (means and marginal covariances) are the full graph's
    batch least-squares solution, and the window holds at most ``lag`` plus ``every − 1``
    keyframe periods of states."""
    steps, lag = 30, 0.45
    chain = _chain(np.random.default_rng(3), steps)
    window = FixedLagIsam2(gtsam, lag, gtsam.ISAM2Params(), every)
    full_graph, full_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    lm = gtsam.symbol("l", 0)
    for k, (graph, values, stamps) in enumerate(chain):
        full_graph.push_back(graph)
        full_values.insert(values)
        window.update(graph, values, stamps)
        batch = gtsam.GaussNewtonOptimizer(full_graph, full_values).optimize()
        marginals = gtsam.Marginals(full_graph, batch)
        est = window.calculateEstimate()
        isam = window.getISAM2()
        for key in (gtsam.symbol("x", k), lm):
            np.testing.assert_allclose(est.atPoint3(key), batch.atPoint3(key), atol=1e-9)
            np.testing.assert_allclose(
                isam.marginalCovariance(key), marginals.marginalCovariance(key), atol=1e-12
            )
        kept = [j for j in range(k + 1) if est.exists(gtsam.symbol("x", j))]
        assert kept == list(range(kept[0], k + 1))  # the newest ones, without a gap
        held = (k - kept[0]) * PERIOD
        assert held <= lag + (every - 1) * PERIOD + 1e-9
        assert held >= min(k * PERIOD, lag - PERIOD) - 1e-9  # stamps ≥ newest − lag kept


def test_landmarks_stay_and_old_keyframes_leave_in_flight() -> None:
    """SLAM on the paper's map, 1 s window, marginalised every 4 keyframes: at the end every
    mapped landmark is still a variable and only the last 1 s to 1.3 s of keyframes are."""
    env = gym.make(
        "QuadSLAM-v0",
        scenario="paper_ekf_figure8",
        estimator={"name": "isam2", "params": {"window_s": 1.0, "relinearize_skip": 4}},
        episode={"duration_s": 4.0},
    )
    infos, terminated = fly_dflqr(env, 0, None)
    assert not terminated, infos[-1]["termination_reason"]
    est = env.unwrapped.estimator.lanes[0]
    values = est._smoother.calculateEstimate()
    snap = est.estimate()
    assert snap.landmark_ids().size > 5
    for i in snap.landmark_ids().tolist():
        assert values.exists(gtsam.symbol("l", i))
    kept = [k for k in range(est.keyframes + 1) if values.exists(gtsam.symbol("x", k))]
    assert kept[-1] == est.keyframes
    assert 10 <= kept[-1] - kept[0] <= 13
