"""Map fusion of the team (estimators.ekf.fusion, quadslam_env.team.comms): covariance
intersection against its closed form and a brute-force ω, its consistency under an unknown
correlation against the naive update's, and the team env's messages (independent unchanged, ci
changing the maps deterministically, drops, bad settings)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.ekf.fusion import ci_trace, ci_weight, fuse_lane, fused_trace, message_noise
from quadslam_env.schema import ConfigError

pytest.importorskip("pettingzoo")
from quadslam_env.team.env import parallel_env

SHORT = {"duration_s": 3.0}
"""300 steps: 30 scans, enough for maps to overlap."""
TWO = {"time_offsets_s": [0.0, 6.25]}
"""Two vehicles a quarter period apart on the default figure-8 (never at the crossing together)."""


def _spd(rng: np.random.Generator, m: int) -> np.ndarray:
    A = rng.standard_normal((m, m))
    return A @ A.T + 0.2 * np.eye(m)


def _closed_form(A: np.ndarray, B: np.ndarray, w: float) -> np.ndarray:
    """CI of two estimates: ``(ω A⁻¹ + (1 − ω) B⁻¹)⁻¹``."""
    return np.linalg.inv(w * np.linalg.inv(A) + (1.0 - w) * np.linalg.inv(B))


@pytest.mark.parametrize("seed", range(4))
def test_ci_of_two_estimates_is_the_closed_form_at_the_minimum_trace(seed: int) -> None:
    """The whole state is one 3-vector, estimated by a (the prior) and b (the message): the
    update gives P⁻¹ = ωA⁻¹ + (1−ω)B⁻¹ and x = P(ωA⁻¹a + (1−ω)B⁻¹b), with ω the grid's
    minimiser of the trace."""
    rng = np.random.default_rng(seed)
    A, B = _spd(rng, 3), _spd(rng, 3)
    a, b = rng.standard_normal(3), rng.standard_normal(3)
    grid = np.linspace(1e-4, 1 - 1e-4, 20001)
    traces = [np.trace(_closed_form(A, B, w)) for w in grid]
    best = float(grid[int(np.argmin(traces))])
    w = ci_weight(A, np.arange(3), B)
    assert w == pytest.approx(best, abs=2e-4)
    assert np.trace(_closed_form(A, B, w)) <= min(traces) + 1e-9
    T, g, d, _ = ci_trace(A, np.arange(3), B)
    for v in (0.1, 0.5, w, 0.9):
        assert fused_trace(v, T, g, d) == pytest.approx(np.trace(_closed_form(A, B, v)), rel=1e-9)
    x, P = a.copy(), A.copy()
    got = fuse_lane(x, P, 3, np.array([0]), b[None], B, "ci")
    assert got == pytest.approx(w, abs=1e-12)
    want_P = _closed_form(A, B, w)
    want_x = want_P @ (w * np.linalg.solve(A, a) + (1 - w) * np.linalg.solve(B, b))
    np.testing.assert_allclose(P, want_P, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(x, want_x, rtol=1e-9, atol=1e-12)
    x, P = a.copy(), A.copy()
    assert fuse_lane(x, P, 3, np.array([0]), b[None], B, "naive") == 1.0
    np.testing.assert_allclose(P, np.linalg.inv(np.linalg.inv(A) + np.linalg.inv(B)), rtol=1e-9)


def test_ci_on_a_joint_state_minimises_the_whole_trace() -> None:
    """A 9-state (vehicle 3 + two landmarks) receiving one landmark: the ω used is the grid's
    minimiser of the trace of the whole fused covariance, and the other states move through
    their correlations (the fused P is the information-form CI)."""
    rng = np.random.default_rng(7)
    P0, Q = _spd(rng, 9), _spd(rng, 3)
    x0, y = rng.standard_normal(9), rng.standard_normal(3)
    H = np.zeros((3, 9))
    H[:, 6:9] = np.eye(3)

    def info(w: float) -> np.ndarray:
        return np.linalg.inv(w * np.linalg.inv(P0) + (1 - w) * H.T @ np.linalg.inv(Q) @ H)

    grid = np.linspace(1e-4, 1 - 1e-4, 20001)
    best = float(grid[int(np.argmin([np.trace(info(w)) for w in grid]))])
    x, P = x0.copy(), P0.copy()
    w = fuse_lane(x, P, 9, np.array([6]), y[None], Q, "ci")
    assert w == pytest.approx(best, abs=2e-4)
    np.testing.assert_allclose(P, info(w), rtol=1e-8, atol=1e-12)
    assert np.trace(P) <= np.trace(P0) + 1e-12


def test_ci_is_consistent_under_an_unknown_correlation_and_naive_is_not() -> None:
    """Two estimates of one 3-vector whose errors are correlated (ρ = 0.8, unknown to the
    fusion): the mean NEES of CI's result is at most 3 within the 99% χ² bound of 2000 runs,
    the naive update's well above."""
    rng = np.random.default_rng(3)
    A, B = np.diag([1.0, 2.0, 0.5]), np.diag([1.5, 1.0, 0.8])
    rho, n = 0.8, 2000
    La, Lb = np.linalg.cholesky(A), np.linalg.cholesky(B)
    nees = {"ci": 0.0, "naive": 0.0}
    for _ in range(n):
        u = rng.standard_normal(3)
        v = rho * u + math.sqrt(1 - rho**2) * rng.standard_normal(3)
        ea, eb = La @ u, Lb @ v  # errors of the two estimates of a true value 0
        for mode in nees:
            x, P = ea.copy(), A.copy()
            fuse_lane(x, P, 3, np.array([0]), eb[None], B, mode)
            nees[mode] += float(x @ np.linalg.solve(P, x)) / n
    upper = chi2.ppf(0.99, 3 * n) / n
    assert nees["ci"] <= upper
    assert nees["naive"] > upper


def test_the_message_noise_is_the_joint_block_or_k_times_the_block_diagonal() -> None:
    rng = np.random.default_rng(5)
    Q = _spd(rng, 9)  # three landmarks' joint covariance
    blocks = np.stack([Q[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] for j in range(3)])
    keep = np.array([True, False, True])
    rows = [0, 1, 2, 6, 7, 8]
    np.testing.assert_array_equal(message_noise(Q, keep, "ci"), Q[np.ix_(rows, rows)])
    np.testing.assert_array_equal(message_noise(Q, keep, "naive"), Q[np.ix_(rows, rows)])
    diag = np.zeros((6, 6))
    diag[:3, :3], diag[3:, 3:] = blocks[0], blocks[2]
    np.testing.assert_array_equal(message_noise(blocks, keep, "naive"), diag)
    np.testing.assert_array_equal(message_noise(blocks, keep, "ci"), 2 * diag)
    # The bound: 2 · blockdiag − Q_sub is positive semi-definite.
    assert np.linalg.eigvalsh(2 * diag - Q[np.ix_(rows, rows)]).min() >= -1e-12


def test_ci_with_the_joint_covariance_of_a_common_error_is_consistent_and_beats_the_blocks() -> (
    None
):
    """Two vehicles' maps of k = 4 landmarks, each with its own common offset (the unobservable
    start error, σ = 0.05 m) and a small error per landmark (0.01 m), independent between the
    vehicles: CI with the sender's joint covariance stays consistent (mean NEES within the 99%
    χ² bound of 1000 runs) and takes out over a fifth of the squared error, while CI with the
    block bound, whose k · blockdiag spreads the common offset over every landmark, takes out
    under a tenth."""
    rng = np.random.default_rng(11)
    k, n = 4, 1000
    common = np.kron(np.ones((k, k)), 0.05**2 * np.eye(3))
    P0 = common + 0.01**2 * np.eye(3 * k)
    L = np.linalg.cholesky(P0)
    blocks = np.stack([P0[3 * j : 3 * j + 3, 3 * j : 3 * j + 3] for j in range(k)])
    cols, keep = 3 * np.arange(k), np.ones(k, dtype=bool)
    nees, sq = {"joint": 0.0, "blocks": 0.0}, {"joint": 0.0, "blocks": 0.0}
    for _ in range(n):
        mine, theirs = L @ rng.standard_normal(3 * k), L @ rng.standard_normal(3 * k)
        for name, covs in (("joint", P0), ("blocks", blocks)):
            x, P = mine.copy(), P0.copy()
            R = message_noise(covs, keep, "ci")
            fuse_lane(x, P, 3 * k, cols, theirs.reshape(k, 3), R, "ci")
            nees[name] += float(x @ np.linalg.solve(P, x)) / n
            sq[name] += float(x @ x) / n
    upper = chi2.ppf(0.99, 3 * k * n) / n
    assert nees["joint"] <= upper and nees["blocks"] <= upper
    prior = np.trace(P0)  # the receiver's mean squared error before the fusion
    assert sq["joint"] < 0.8 * prior and sq["blocks"] > 0.9 * prior


def _flown(team: dict[str, Any], n: int = 2, steps: int = 300, seed: int = 4) -> Any:
    """A team of n hovering with small noise for ``steps``; returns the env and last infos."""
    env = parallel_env(n_vehicles=n, team={**TWO, **team}, episode=SHORT)
    env.reset(seed=seed)
    hover, rng, infos = env.core.action_map.hover_action, np.random.default_rng(1), {}
    for _ in range(steps):
        if not env.agents:
            break
        acts = {a: np.clip(hover + 0.02 * rng.standard_normal(4), -1, 1) for a in env.agents}
        _, _, _, _, step_infos = env.step(acts)
        infos.update(step_infos)
    return env, infos


def _maps(env: Any) -> list[np.ndarray]:
    return [env.core.estimator.full_state(i)[0] for i in range(env.n_vehicles)]


@pytest.fixture(scope="module")
def independent() -> tuple[Any, dict[str, Any]]:
    return _flown({"fusion": "independent"})


def test_ci_changes_the_maps_finitely_and_repeats_with_the_seed(independent: Any) -> None:
    env0, infos0 = independent
    blocks = {"fusion": "ci", "landmarks_per_message": 4, "message_covariance": "blocks",
              "message_rate_hz": None}  # fmt: skip
    env, infos = _flown(blocks)
    again, _ = _flown(blocks)
    for a, b, c in zip(_maps(env), _maps(again), _maps(env0), strict=True):
        assert np.isfinite(a).all()
        np.testing.assert_array_equal(a, b)
        assert not np.array_equal(a, c)
    info = infos["vehicle_1"]
    # A message after each scan but the last (the episode ends on it), each fused on the next
    # step, of at most 4 landmarks of 10 floats of 8 bytes.
    assert info["team_messages_sent"] == 2 * 29 and info["team_messages_delivered"] == 58
    assert 0 < info["team_bytes_sent"] <= 58 * 4 * 80 and info["team_bytes_sent"] % 80 == 0
    for key in ("team_episode_map_rmse_m", "team_episode_landmark_anees", "est_landmark_anees"):
        assert math.isfinite(info[key]), key
    assert "team_messages_sent" not in infos0["vehicle_1"]  # independent: no messages


def test_joint_messages_carry_the_senders_covariance_and_count_its_bytes() -> None:
    env, infos = _flown({"fusion": "ci", "landmarks_per_message": 4, "message_rate_hz": None})
    info = infos["vehicle_1"]
    # 58 messages of 4 landmarks once both have mapped 4: 16 + 78 floats of 8 bytes each.
    assert info["team_messages_sent"] == 58
    assert 0 < info["team_bytes_sent"] <= 58 * 8 * (16 + 78)
    est = env.core.estimator
    ids, _, covs = est.lane_estimate(0).mapped_landmarks(0)
    joint = est.landmark_covariance(0, ids[::-1])
    for j, c in enumerate(covs[::-1]):  # its diagonal blocks are the snapshot's, in ids' order
        np.testing.assert_allclose(joint[3 * j : 3 * j + 3, 3 * j : 3 * j + 3], c, atol=1e-15)
    np.testing.assert_array_equal(joint, joint.T)
    assert np.linalg.eigvalsh(joint).min() > 0


def test_drop_probability_one_delivers_nothing_and_changes_nothing(independent: Any) -> None:
    env0, infos0 = independent
    env, infos = _flown({"fusion": "ci", "drop_probability": 1.0, "message_rate_hz": None})
    for a, b in zip(_maps(env), _maps(env0), strict=True):
        np.testing.assert_array_equal(a, b)
    info = infos["vehicle_0"]
    assert info["team_messages_delivered"] == 0
    assert info["team_messages_dropped"] == info["team_messages_sent"] == 58
    assert info["team_episode_map_rmse_m"] == infos0["vehicle_0"]["team_episode_map_rmse_m"]


def test_a_receiver_out_of_radio_range_hears_nothing(independent: Any) -> None:
    """The vehicles a quarter period apart (metres) and a 0.5 m radio: every message is out of
    range, so nothing is fused and the maps are independent's, bit for bit."""
    env0, _ = independent
    env, infos = _flown({"fusion": "ci", "comm_range_m": 0.5, "message_rate_hz": None})
    for a, b in zip(_maps(env), _maps(env0), strict=True):
        np.testing.assert_array_equal(a, b)
    info = infos["vehicle_0"]
    assert info["team_min_separation_m"] > 0.5
    assert info["team_messages_delivered"] == info["team_messages_dropped"] == 0
    assert info["team_messages_out_of_range"] == info["team_messages_sent"] == 58


def test_a_radio_range_beyond_the_team_changes_nothing() -> None:
    """A range no two vehicles reach is the unlimited radio, bit for bit (it draws nothing)."""
    team = {"fusion": "ci", "landmarks_per_message": 4, "message_rate_hz": None}
    env, _ = _flown(team)
    far, far_infos = _flown({**team, "comm_range_m": 1e5})
    for a, b in zip(_maps(env), _maps(far), strict=True):
        np.testing.assert_array_equal(a, b)
    assert far_infos["vehicle_1"]["team_messages_out_of_range"] == 0
    assert far_infos["vehicle_1"]["team_messages_delivered"] == 58


def test_latency_and_rate_time_the_messages() -> None:
    _, infos = _flown({"fusion": "naive", "message_rate_hz": 2.0, "latency_steps": 60})
    info = infos["vehicle_0"]
    assert info["team_messages_sent"] == 2 * 5  # t = 0.5, …, 2.5 s (not at the end, 3.0 s)
    assert info["team_messages_delivered"] == 2 * 4  # 2.5 s + 60 steps: after the end


def test_team_map_terms_are_their_definitions(independent: Any) -> None:
    env, infos = independent
    truth = env.core.landmarks[0, : env.core.n_landmarks[0]]
    union, rmse = {}, []
    for i in range(env.n_vehicles):
        ids, means, covs = env.core.estimator.lane_estimate(i).mapped_landmarks(0)
        err = means - truth[ids]
        rmse.append(math.sqrt(float(np.mean(np.sum(err**2, axis=1)))))
        nees = [e @ np.linalg.solve(c, e) for e, c in zip(err, covs, strict=True)]
        assert infos[f"vehicle_{i}"]["est_landmark_anees"] == pytest.approx(np.mean(nees))
        assert infos[f"vehicle_{i}"]["est_map_rmse_m"] == pytest.approx(rmse[-1], rel=1e-12)
        for j, m in zip(ids.tolist(), means, strict=True):
            union.setdefault(j, m)
    info = infos["vehicle_0"]
    assert info["team_map_rmse_m"] == pytest.approx(np.mean(rmse), rel=1e-12)
    ids = np.array(list(union))
    err = np.stack(list(union.values())) - truth[ids]
    want = math.sqrt(float(np.mean(np.sum(err**2, axis=1))))
    assert info["team_union_map_rmse_m"] == pytest.approx(want, rel=1e-12)
    assert info["team_n_mapped"] == len(union)


class _SnapshotsOnly:
    """The estimator seen through its lane snapshots only (no batched covariances)."""

    def __init__(self, estimator: Any) -> None:
        self.lane_estimate = estimator.lane_estimate


def test_batched_map_terms_equal_those_of_the_lane_snapshots() -> None:
    from quadslam_env.team.map_metrics import MapMetrics

    env, _ = _flown({"fusion": "ci", "time_offsets_s": [0.0, 6.25, 12.5]}, n=3, steps=150)
    truth, count = env.core.landmarks[0], int(env.core.n_landmarks[0])
    lanes = np.array([True, False, True])
    fast, slow = MapMetrics(3), MapMetrics(3)
    got = fast.observe(env.core.estimator, truth, count, lanes)
    want = slow.observe(_SnapshotsOnly(env.core.estimator), truth, count, lanes)  # type: ignore[arg-type]
    np.testing.assert_allclose(got, want, rtol=1e-12)
    assert np.isnan(got[1]) and np.isfinite(got[[0, 2]]).all()
    for key, value in fast.terms(truth, lanes).items():
        assert value == pytest.approx(slow.terms(truth, lanes)[key], rel=1e-12), key


@pytest.mark.parametrize(
    ("kwargs", "fragment"),
    [
        (
            {"team": {"fusion": "centralised"}},
            "team.fusion: got 'centralised' with estimator.name = 'ekf_slam', which cannot be one",
        ),
        ({"team": {"fusion": "mean"}}, "team.fusion: got 'mean'; allowed: one of"),
        ({"team": {"drop_probability": 0.5}}, "team.drop_probability: got 0.5, which team.fusion"),
        ({"team": {"fusion": "ci", "drop_probability": 1.5}}, "team.drop_probability: got 1.5"),
        ({"team": {"fusion": "ci", "latency_steps": -1}}, "team.latency_steps: got -1"),
        ({"team": {"fusion": "ci", "landmarks_per_message": 0}}, "landmarks_per_message: got 0"),
        (
            {"team": {"fusion": "ci", "message_covariance": "full"}},
            "team.message_covariance: got 'full'; allowed: one of",
        ),
        (
            {"team": {"fusion": "ci", "message_every_scans": 2, "message_rate_hz": 1.0}},
            "team.message_every_scans: got 2 with team.message_rate_hz = 1.0",
        ),
        (
            {"team": {"fusion": "ci", "message_every_scans": 2}},
            "team.message_every_scans: got 2 with team.message_rate_hz = 0.2 (its default is "
            "0.2); allowed: message_rate_hz null",
        ),
        (
            {"team": {"fusion": "ci", "message_rate_hz": 500.0}},
            "team.message_rate_hz: got 500.0; allowed: at most episode.control_hz",
        ),
        (
            {"team": {"fusion": "ci"}, "estimator": {"name": "fastslam"}},
            "team.fusion: got 'ci' with estimator.name = 'fastslam', which cannot fuse",
        ),
        (
            {"team": {"fusion": "ci"}, "lidar": {"association": "unknown"}},
            "team.fusion: got 'ci' with lidar.association = 'unknown'",
        ),
        (
            {"team": {"fusion": "naive"}, "lidar": {"delay_steps": 2}},
            "team.fusion: got 'naive' with lidar.delay_steps set",
        ),
    ],
)
def test_bad_fusion_settings_name_the_key_the_value_and_what_is_allowed(
    kwargs: dict[str, Any], fragment: str
) -> None:
    with pytest.raises(ConfigError) as err:
        parallel_env(n_vehicles=2, **kwargs)
    assert fragment in str(err.value)
