"""Ranges between the team's vehicles (estimators.ekf.ranging, quadslam_env.team.ranging): the
range model's Jacobian against finite differences, its CI update against the closed form on a
linear-Gaussian toy, the ranges' noise and dropout, the team unchanged without them and with
``range_fusion: none``, the fused ranges deterministic and counted, and bad settings."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.ekf.fusion import ci_trace, ci_weight, fused_trace
from estimators.ekf.ranging import fuse_range, range_model, range_noise
from quadslam_env.schema import ConfigError

pytest.importorskip("pettingzoo")
from quadslam_env.team.config import TeamConfig
from quadslam_env.team.env import parallel_env
from quadslam_env.team.ranging import Ranges

SHORT = {"duration_s": 2.0}
"""200 steps: 20 range epochs at the default 10 Hz."""


def _spd(rng: np.random.Generator, m: int) -> np.ndarray:
    A = rng.standard_normal((m, m))
    return A @ A.T + 0.2 * np.eye(m)


def test_range_jacobian_is_the_finite_difference() -> None:
    rng = np.random.default_rng(0)
    for _ in range(5):
        rho, b = rng.normal(size=3) * 5.0, rng.normal(size=3) * 5.0
        h, u = range_model(rho, b)
        assert h == pytest.approx(np.linalg.norm(rho - b), rel=1e-15)
        eps = 1e-6
        for axis in range(3):
            e = np.eye(3)[axis] * eps
            d_rho = (range_model(rho + e, b)[0] - range_model(rho - e, b)[0]) / (2 * eps)
            d_b = (range_model(rho, b + e)[0] - range_model(rho, b - e)[0]) / (2 * eps)
            assert d_rho == pytest.approx(u[axis], abs=1e-8)
            assert d_b == pytest.approx(-u[axis], abs=1e-8)  # ∂h/∂b = −uᵀ: R's beacon term
        P_b = _spd(rng, 3)
        assert range_noise(u, 0.3, P_b) == pytest.approx(0.09 + u @ P_b @ u)


@pytest.mark.parametrize("seed", range(3))
def test_ci_trace_with_a_measurement_jacobian_is_the_dense_closed_form(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 7
    P = _spd(rng, n)
    idx, A = np.array([0, 1, 2]), rng.normal(size=(2, 3))
    R = _spd(rng, 2)
    H = np.zeros((2, n))
    H[:, idx] = A
    T, g, d, _ = ci_trace(P, idx, R, A)
    for w in (0.05, 0.4, 0.9):
        dense = np.linalg.inv(w * np.linalg.inv(P) + (1 - w) * H.T @ np.linalg.inv(R) @ H)
        assert fused_trace(w, T, g, d) == pytest.approx(np.trace(dense), rel=1e-9)


def test_ci_range_update_is_the_closed_form_on_a_linear_gaussian_toy() -> None:
    """A state of the position and two landmarks (9), a beacon on the x axis: the CI update
    is ``P⁺ = (ω P⁻¹ + (1 − ω) Hᵀ R⁻¹ H)⁻¹``, ``x⁺ = P⁺ (ω P⁻¹ x + (1 − ω) Hᵀ R⁻¹ z̃)``
    with ``z̃ = r − h(x) + H x`` (the linearised measurement), at the ω of the smallest trace
    on a grid; here the range is informative enough for ω inside (0, 1)."""
    rng = np.random.default_rng(3)
    n = 9
    P = 0.05 * _spd(rng, n)
    P[:3, :3] += np.eye(3)  # a position far less certain than the range
    x = rng.normal(size=n)
    x[:3] = [10.0, 0.5, -0.3]
    beacon, P_b, sigma, r = np.zeros(3), 0.01 * np.eye(3), 0.1, 9.2
    xb, Pb = x.copy(), P.copy()
    omega, nu = fuse_range(xb, Pb, n, beacon, P_b, r, sigma)
    h, u = range_model(x[:3], beacon)
    H = np.zeros((1, n))
    H[0, :3] = u
    R = np.array([[sigma**2 + u @ P_b @ u]])
    assert nu == pytest.approx(r - h)
    grid = np.linspace(1e-3, 1 - 1e-3, 2001)

    def fused(w: float) -> np.ndarray:
        return np.linalg.inv(w * np.linalg.inv(P) + (1 - w) * H.T @ np.linalg.inv(R) @ H)

    best = grid[np.argmin([np.trace(fused(w)) for w in grid])]
    assert 0.01 < omega < 0.99
    assert omega == pytest.approx(best, abs=1e-3)
    assert omega == pytest.approx(ci_weight(P, np.arange(3), R, u[None, :]))
    P_plus = fused(omega)
    z_lin = r - h + H @ x
    x_plus = P_plus @ (
        omega * np.linalg.solve(P, x) + (1 - omega) * H.T @ np.linalg.solve(R, z_lin)
    )
    np.testing.assert_allclose(Pb, P_plus, rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(xb, x_plus, rtol=1e-8, atol=1e-10)
    np.testing.assert_array_equal(Pb, Pb.T)


def _measure(ranges: Ranges, positions: np.ndarray, epochs: int) -> np.ndarray:
    """(epochs, N, N) the ranges of ``epochs`` epochs between fixed ``positions`` (N, 3)."""
    n = positions.shape[0]
    est = SimpleNamespace(position=positions, pose_cov=np.tile(np.eye(9), (n, 1, 1)))
    live = np.ones(n, dtype=bool)
    out = np.empty((epochs, n, n))
    for e in range(epochs):
        ranges.measure(positions, est, live, 10 * (e + 1))  # type: ignore[arg-type]
        out[e] = ranges.ranges_m
    return out


def test_range_noise_std_is_sigma_within_a_chi2_bound() -> None:
    team = TeamConfig.from_dict({"ranges": True, "range_sigma_m": 0.25})
    ranges = Ranges(team, 3, 100.0)
    ranges.reset([np.random.default_rng(s) for s in range(3)])
    positions = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, -20.0]])
    got = _measure(ranges, positions, 4000)
    truth = np.linalg.norm(positions[:, None] - positions[None], axis=2)
    for i, j in ((0, 1), (0, 2), (1, 2)):
        err = got[:, i, j] - truth[i, j]
        np.testing.assert_array_equal(got[:, i, j], got[:, j, i])
        k = err.size - 1
        stat = k * np.var(err, ddof=1) / 0.25**2
        assert chi2.ppf(0.0005, k) < stat < chi2.ppf(0.9995, k), (i, j, np.std(err))
        assert abs(np.mean(err)) < 4 * 0.25 / np.sqrt(err.size)


def test_dropout_one_and_pairs_out_of_range_get_no_range() -> None:
    positions = np.array([[0.0, 0.0, 0.0], [3.0, 4.0, 0.0], [0.0, 0.0, -60.0]])
    lost = Ranges(TeamConfig.from_dict({"ranges": True, "range_dropout": 1.0}), 3, 100.0)
    lost.reset([np.random.default_rng(s) for s in range(3)])
    assert np.isnan(_measure(lost, positions, 50)).all()
    far = Ranges(TeamConfig.from_dict({"ranges": True, "range_max_m": 50.0}), 3, 100.0)
    far.reset([np.random.default_rng(s) for s in range(3)])
    got = _measure(far, positions, 5)
    assert np.isfinite(got[:, 0, 1]).all()
    assert np.isnan(got[:, 0, 2]).all() and np.isnan(got[:, 1, 2]).all()  # 60 m and 60.2 m


def _run(team: dict[str, Any], n: int = 3, seed: int = 4) -> tuple[list[Any], list[Any]]:
    """Every step's observations and infos of a hover-plus-noise rollout."""
    env = parallel_env(n_vehicles=n, team=team, episode=SHORT)
    obs, infos = env.reset(seed=seed)
    hover = env.core.action_map.hover_action
    rng = np.random.default_rng(1)
    all_obs, all_infos = [obs], [infos]
    while env.agents:
        act = {
            a: np.clip(hover + 0.02 * rng.standard_normal(hover.shape), -1, 1).astype(np.float32)
            for a in env.agents
        }
        obs, _, _, _, infos = env.step(act)
        all_obs.append(obs)
        all_infos.append(infos)
    return all_obs, all_infos


def _without_ranges(info: dict[str, Any]) -> dict[str, Any]:
    return {k: v for k, v in info.items() if not k.startswith(("team_range", "team_ranges"))}


@pytest.mark.parametrize("fusion", ["independent", "ci"])
def test_ranges_without_fusion_only_reach_the_info(fusion: str) -> None:
    """With ``range_fusion: none`` every vehicle's observations and every other info term,
    the messages' drop counts among them, are those without ranges, bit for bit."""
    comms = {"drop_probability": 0.4, "message_rate_hz": None} if fusion == "ci" else {}
    off_obs, off_infos = _run({"fusion": fusion, **comms})
    on_obs, on_infos = _run({"fusion": fusion, **comms, "ranges": True, "range_dropout": 0.2})
    assert len(off_obs) == len(on_obs)
    for a, b in zip(off_obs, on_obs, strict=True):
        for agent in a:
            np.testing.assert_array_equal(a[agent], b[agent])
    for a, b in zip(off_infos, on_infos, strict=True):
        for agent in a:
            assert _without_ranges(b[agent]) == a[agent]
    measured = sum(info["vehicle_0"]["team_ranges_measured"] for info in on_infos)
    assert 0 < measured < 2 * 19  # two other vehicles, 19 epochs, some lost
    if fusion == "ci":
        assert on_infos[-1]["vehicle_0"]["team_episode_messages_dropped"] > 0
    epoch = on_infos[10]["vehicle_1"]
    assert epoch["team_ranges_measured"] >= 1 and "team_range_residual_rms_m" in epoch
    assert "team_range_to_vehicle_1_m" not in epoch


def test_fused_ranges_move_the_estimates_repeat_with_the_seed_and_count_bytes() -> None:
    team = {"ranges": True, "range_fusion": "ci"}
    obs, infos = _run(team, n=2)
    obs2, _ = _run(team, n=2)
    off, _ = _run({}, n=2)
    for a, b in zip(obs, obs2, strict=True):
        np.testing.assert_array_equal(a["vehicle_1"], b["vehicle_1"])
    assert any(
        not np.array_equal(a["vehicle_1"], b["vehicle_1"]) for a, b in zip(obs, off, strict=True)
    )
    fused = sum(info["vehicle_0"].get("team_ranges_fused", 0.0) for info in infos)
    epochs = sum(info["vehicle_0"]["team_ranges_measured"] for info in infos)
    assert epochs == 19 and fused == 19  # at steps 10 … 190: none after the last step (200)
    weights = [
        i["vehicle_0"]["team_range_ci_weight"]
        for i in infos
        if "team_range_ci_weight" in i["vehicle_0"]
    ]
    assert len(weights) == 19 and all(0.0 < w < 1.0 for w in weights)
    assert infos[-1]["vehicle_0"]["team_episode_bytes_sent"] == 19 * 2 * 9 * 8


@pytest.mark.parametrize(
    ("team", "extra", "fragment"),
    [
        (
            {"ranges": True, "range_sigma_m": 0.0},
            {},
            "team.range_sigma_m: got 0.0; allowed: a number > 0.0",
        ),
        (
            {"ranges": True, "range_dropout": 1.5},
            {},
            "team.range_dropout: got 1.5; allowed: a number >= 0.0 and <= 1.0",
        ),
        (
            {"ranges": True, "range_fusion": "ekf"},
            {},
            "team.range_fusion: got 'ekf'; allowed: one of ['none', 'ci', 'factor']",
        ),
        ({"ranges": "yes"}, {}, "team.ranges: got 'yes'"),
        ({"ranges": True, "range_max_m": -1.0}, {}, "team.range_max_m: got -1.0"),
        (
            {"range_sigma_m": 0.5},
            {},
            "team.range_sigma_m: got 0.5, which team.ranges False ignores",
        ),
        (
            {"ranges": True, "range_rate_hz": 200.0},
            {},
            "team.range_rate_hz: got 200.0; allowed: at most episode.control_hz = 100.0",
        ),
        (
            {"ranges": True, "range_fusion": "ci"},
            {"estimator": {"name": "fastslam"}},
            "with estimator.name = 'fastslam', which cannot fuse ranges",
        ),
        (
            {"ranges": True, "range_fusion": "ci"},
            {"lidar": {"delay_steps": 2}},
            "team.range_fusion: got 'ci' with lidar.delay_steps set",
        ),
    ],
)
def test_bad_range_settings_name_the_key_the_value_and_what_is_allowed(
    team: dict[str, Any], extra: dict[str, Any], fragment: str
) -> None:
    with pytest.raises(ConfigError) as err:
        parallel_env(n_vehicles=2, team=team, **extra)
    assert fragment in str(err.value)
