"""The iSAM2 estimator's sliding window (:class:`estimators.isam2.fixed_lag.FixedLagIsam2`): on
linear-Gaussian problems marginalisation is exact, so the window's newest state and the landmarks
equal the full graph's batch solution after every update (a state marginalised while it is not a
leaf of the Bayes tree would break this, or GTSAM's memory); the window holds ``lag`` seconds; in
flight the landmarks never leave it."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import quadslam_env  # noqa: F401  (registers the env ids)
from estimators.isam2 import fixed_lag
from estimators.isam2.fixed_lag import FixedLagIsam2
from estimators.isam2.team import VEHICLE_STRIDE

gtsam = pytest.importorskip("gtsam")

PERIOD = 0.1  # s between keyframes


def _chain(rng: np.random.Generator, steps: int) -> list[tuple[Any, Any, dict[int, float]]]:
    """A linear-Gaussian chain: points p_k (Point3) with odometry between them, a landmark l
    seen from every one (unstamped: it stays, as the estimator's landmarks), a prior on p_0.

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
        out.append((graph, values, {pk: k * PERIOD}))
    return out


@pytest.fixture(params=[1, 5], ids=["marginalise_each", "marginalise_5"])
def marginalise_every(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> int:
    """Marginalise after every update (the leaf check every time) or every fifth (the default)."""
    monkeypatch.setattr(fixed_lag, "MARGINALIZE_EVERY", request.param)
    return int(request.param)


def _first_kept(k: int, lag_steps: int, every: int) -> int:
    """The oldest state index still in the window after update k (states are p_0 … p_k, one
    per update): the marginalisation after update u (u = k + 1 counted from one, a multiple of
    ``every``) drops the states more than ``lag_steps`` periods older than p_{u-1}."""
    last = (k + 1) // every * every - 1  # the newest state at the last marginalisation
    return max(0, last - lag_steps) if last >= 0 else 0


@pytest.mark.parametrize("every", [1, 3, 7])
def test_window_newest_state_and_landmark_equal_the_full_batch_solution(
    every: int, marginalise_every: int
) -> None:
    """Linear factors: the marginal a marginalisation leaves is exact, so after every update
    the newest point and the landmark (means and marginal covariances) are the full graph's
    batch least-squares solution (relinearised every ``every`` updates, a no-op on linear
    factors but another elimination), and the window holds the last ``lag`` seconds of states."""
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
        assert kept[0] == _first_kept(k, 4, marginalise_every)  # stamps ≥ newest − 0.45 s


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_window_equals_batch_with_landmarks_seen_at_random(
    seed: int, marginalise_every: int
) -> None:
    """Linear factors with the structure of landmark SLAM: states p_k with odometry, six
    landmarks (unstamped) each seen from a random subset of the states, and sightings added
    late to states still in the window (as a confirmed landmark's earlier sightings are).
    After every update the newest state and every landmark equal the full graph's batch
    solution, with relinearisation every third update."""
    rng = np.random.default_rng(seed)
    steps, lag, n_lm = 40, 0.55, 6
    odo = gtsam.noiseModel.Isotropic.Sigma(3, 0.05)
    seen = gtsam.noiseModel.Isotropic.Sigma(3, 0.2)
    truth = np.cumsum(rng.normal(0.0, 0.3, (steps, 3)), axis=0)
    landmarks = rng.normal(0.0, 5.0, (n_lm, 3))
    lm = [gtsam.symbol("l", j) for j in range(n_lm)]
    window = FixedLagIsam2(gtsam, lag, gtsam.ISAM2Params(), 3)
    full_graph, full_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    mapped: set[int] = set()

    def sighting(graph: Any, k: int, j: int) -> None:
        z = landmarks[j] - truth[k] + rng.normal(0.0, 0.2, 3)
        graph.add(gtsam.BetweenFactorPoint3(gtsam.symbol("x", k), lm[j], z, seen))

    for k in range(steps):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        pk = gtsam.symbol("x", k)
        if k == 0:
            prior = gtsam.noiseModel.Isotropic.Sigma(3, 0.5)
            graph.add(gtsam.PriorFactorPoint3(pk, truth[0], prior))
        else:
            step = truth[k] - truth[k - 1] + rng.normal(0.0, 0.05, 3)
            graph.add(gtsam.BetweenFactorPoint3(gtsam.symbol("x", k - 1), pk, step, odo))
        values.insertPoint3(pk, truth[k] + rng.normal(0.0, 0.3, 3))
        for j in np.flatnonzero(rng.random(n_lm) < 0.4).tolist():
            if j not in mapped:
                values.insertPoint3(lm[j], landmarks[j] + rng.normal(0.0, 1.0, 3))
                mapped.add(j)
            sighting(graph, k, j)
        if k >= 3 and mapped and rng.random() < 0.3:  # a late sighting from a state in the window
            sighting(graph, k - int(rng.integers(1, 4)), int(rng.choice(sorted(mapped))))
        full_graph.push_back(graph)
        full_values.insert(values)
        window.update(graph, values, {pk: k * PERIOD})
        batch = gtsam.GaussNewtonOptimizer(full_graph, full_values).optimize()
        marginals = gtsam.Marginals(full_graph, batch)
        est = window.calculateEstimate()
        isam = window.getISAM2()
        for key in [pk] + [lm[j] for j in sorted(mapped)]:
            np.testing.assert_allclose(est.atPoint3(key), batch.atPoint3(key), atol=1e-8)
            np.testing.assert_allclose(
                isam.marginalCovariance(key), marginals.marginalCovariance(key), atol=1e-10
            )
        kept = [j for j in range(k + 1) if est.exists(gtsam.symbol("x", j))]
        assert kept == list(range(_first_kept(k, 5, marginalise_every), k + 1))  # 0.55 s lag


def test_a_state_that_is_not_a_leaf_is_seen_and_the_order_restored(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """After a batch step (the eighth update) the states older than the lag are leaves;
    re-eliminated with the oldest last (the root of the Bayes tree) they are not: the leaf
    check says so, the marginalisation re-eliminates the window in time order first, and the
    window then equals the full graph's batch solution."""
    monkeypatch.setattr(fixed_lag, "MARGINALIZE_EVERY", 100)  # marginalised by hand below
    chain = _chain(np.random.default_rng(5), 8)
    window = FixedLagIsam2(gtsam, 0.45, gtsam.ISAM2Params(), 8)
    full_graph, full_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for graph, values, stamps in chain:
        full_graph.push_back(graph)
        full_values.insert(values)
        window.update(graph, values, stamps)
    isam = window.getISAM2()
    old = [gtsam.symbol("x", k) for k in range(3)]  # stamps 0–0.2 s < 0.7 − 0.45 s
    assert window._are_leaves(old)
    everything = gtsam.KeyList()
    groups = gtsam.KeyGroupMap()
    keys = isam.getLinearizationPoint().keys()
    for key in keys:
        everything.push_back(key)
        groups.insert2(key, 1 if key == old[0] else 0)
    isam.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), [], groups, None, everything)
    assert not window._are_leaves(old)
    window._marginalize()
    assert window.repairs == 1
    assert [isam.valueExists(key) for key in old] == [False] * 3
    batch = gtsam.GaussNewtonOptimizer(full_graph, full_values).optimize()
    est = window.calculateEstimate()
    for key in (gtsam.symbol("x", 7), gtsam.symbol("l", 0)):
        np.testing.assert_allclose(est.atPoint3(key), batch.atPoint3(key), atol=1e-9)


def test_two_vehicles_chains_interleaved_by_time_leave_the_window_exactly() -> None:
    """A team's graph (``team.fusion: centralised``): two chains of states, the second's keys
    offset as a team's vehicle 1's, both seeing one landmark, added one vehicle at a time at
    the same stamps. Ordered by time, the two chains' old states are leaves of the Bayes tree
    together: after every update each vehicle's newest state and the landmark equal the full
    graph's batch solution, no marginalisation needs a repair, and the window holds the lag."""
    steps, lag = 40, 0.45
    shift = VEHICLE_STRIDE
    chains = [_chain(np.random.default_rng(seed), steps) for seed in (11, 12)]
    window = FixedLagIsam2(gtsam, lag, gtsam.ISAM2Params(), 3)
    full_graph, full_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    lm = gtsam.symbol("l", 0)
    for k in range(steps):
        for vehicle, chain in enumerate(chains):
            graph, values, stamps = chain[k]
            if vehicle:  # vehicle 1's states: its keys shifted, the landmark shared
                graph, values, stamps = _shifted(graph, values, stamps, shift, lm, k)
            full_graph.push_back(graph)
            full_values.insert(values)
            window.update(graph, values, stamps)
            batch = gtsam.GaussNewtonOptimizer(full_graph, full_values).optimize()
            est = window.calculateEstimate()
            for key in (gtsam.symbol("x", k), gtsam.symbol("x", k + shift), lm):
                if est.exists(key):
                    np.testing.assert_allclose(est.atPoint3(key), batch.atPoint3(key), atol=1e-8)
    est = window.calculateEstimate()
    kept = [j for j in range(steps) if est.exists(gtsam.symbol("x", j))]
    assert window.repairs == 0
    assert kept == list(range(35, steps))  # the 80th update marginalised those before 3.45 s


def _shifted(
    graph: Any, values: Any, stamps: dict[int, float], shift: int, lm: int, k: int
) -> tuple[Any, Any, dict[int, float]]:
    """Vehicle 1's copy of one step of :func:`_chain`: every state key shifted by ``shift``;
    the landmark shared (its initial value inserted once, by vehicle 0)."""

    def move(key: int) -> int:
        return key if key == lm else key + shift

    out_graph, out_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for i in range(graph.size()):
        factor = graph.at(i)
        keys = [move(key) for key in factor.keys()]  # noqa: SIM118 (a KeyVector)
        if isinstance(factor, gtsam.PriorFactorPoint3):
            out_graph.add(gtsam.PriorFactorPoint3(keys[0], factor.prior(), factor.noiseModel()))
        else:
            out_graph.add(
                gtsam.BetweenFactorPoint3(keys[0], keys[1], factor.measured(), factor.noiseModel())
            )
    for key in values.keys():  # noqa: SIM118 (gtsam.Values)
        if key != lm:
            out_values.insertPoint3(move(key), values.atPoint3(key))
    return out_graph, out_values, {move(key): t for key, t in stamps.items()}


def test_a_state_keeps_its_stamp() -> None:
    """Re-stamping a state would let it sink below newer states in the Bayes tree (and be
    marginalised while not a leaf): refused, naming the key."""
    window = FixedLagIsam2(gtsam, 1.0, gtsam.ISAM2Params(), 1)
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    p0 = gtsam.symbol("x", 0)
    graph.add(gtsam.PriorFactorPoint3(p0, np.zeros(3), gtsam.noiseModel.Isotropic.Sigma(3, 1.0)))
    values.insertPoint3(p0, np.zeros(3))
    window.update(graph, values, {p0: 0.0})
    with pytest.raises(ValueError, match=f"key {p0} already has a stamp"):
        window.update(gtsam.NonlinearFactorGraph(), gtsam.Values(), {p0: 0.1})


def test_landmarks_stay_and_old_keyframes_leave_in_flight() -> None:
    """SLAM on the paper's map, 1 s window, relinearised every 4 keyframes: at the end every
    mapped landmark is still a variable and only the last 1 s to 1.4 s of keyframes are."""
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
    assert 9 <= kept[-1] - kept[0] <= 14  # marginalised every 5th; float stamps
