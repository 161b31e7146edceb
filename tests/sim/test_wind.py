"""Wind: Dryden turbulence, drag on the air-relative velocity, settings (docs/physics.md "Wind").

Independent facts: the standard's low-altitude formulas, the filter's transition and noise
covariance against Van Loan's matrix exponential, the simulated gust's variance and its
power spectral density (Welch) against the analytic Dryden PSD folded at the sampling rate,
closed-form drag transients in a steady wind, the drag force against a NumPy transcription of
the equation, and the lane contract (vector lane = scalar env) with gusts on.
"""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import gymnasium as gym
import lane_cases as tve
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from scipy.linalg import expm
from scipy.signal import welch

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.hardware import ImuConfig
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams
from quadslam_env.models.rigid_body import rigid_body_derivative
from quadslam_env.models.wind import (
    FOOT,
    KNOT,
    W20_MPS,
    dryden_filter,
    dryden_low_altitude,
    dryden_psd,
    dryden_series,
)
from quadslam_env.schema import ConfigError
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.vehicle import VehicleBatch
from quadslam_env.sim.wind import WIND_KEYS
from quadslam_env.types import GRAVITY

SIGMA = np.array([1.5, 1.2, 0.8])
LENGTH = np.array([10.0, 10.0, 5.0])
SPEED, PERIOD = 20.0, 0.05  # a = V/L = 2 and 4 1/s, sampled at 20 Hz
GUSTS = {
    "wind": {"preset": "moderate", "steady_mps": [3.0, -2.0, 0.0]},
    "vehicle": {"drag_per_s": 0.2, "drag_quadratic_per_m": [0.05, 0.05, 0.1]},
}


def _gusts(n_chunks: int, chunk: int, seed: int = 11) -> np.ndarray:
    """(n_chunks · chunk, 3) gust samples (u, v, w) of the test filter, stationary start."""
    f = dryden_filter(SIGMA, LENGTH, SPEED, PERIOD)
    rng = np.random.default_rng(seed)
    x = f.stationary @ rng.standard_normal(5)
    out = np.empty((n_chunks * chunk, 3))
    for k in range(n_chunks):
        dryden_series(x, rng.standard_normal((chunk, 5)), f.phi, f.chol, f.output, out[k * chunk :])
    return out


def test_low_altitude_intensities_and_scales_are_mil_f_8785c_in_feet_and_knots() -> None:
    # h = 100 ft, W20 = 30 kt: σ_w = 3 kt, σ_u = σ_v = 3/(0.177 + 0.0823)^0.4 kt, L_w = 100 ft,
    # L_u = L_v = 100/(0.2593)^1.2 ft.
    sigma, length = dryden_low_altitude(100 * FOOT, 30 * KNOT)
    d = 0.177 + 0.000823 * 100
    np.testing.assert_allclose(sigma / KNOT, [3 / d**0.4, 3 / d**0.4, 3.0], rtol=1e-12)
    np.testing.assert_allclose(length / FOOT, [100 / d**1.2, 100 / d**1.2, 100.0], rtol=1e-12)
    assert W20_MPS["moderate"] == pytest.approx(15.433, abs=1e-3)
    below = dryden_low_altitude(1.0, 30 * KNOT)  # under 10 ft: the 10 ft values
    at_10ft = dryden_low_altitude(10 * FOOT, 30 * KNOT)
    np.testing.assert_array_equal(below[0], at_10ft[0])
    np.testing.assert_array_equal(below[1], at_10ft[1])


@pytest.mark.parametrize("a_t", [1e-5, 0.05, 0.9, 1.1, 30.0])
def test_discretisation_equals_van_loan(a_t: float) -> None:
    period = 0.01
    speed = a_t / period * 7.0  # L = 7 m for every axis
    f = dryden_filter(SIGMA, [7.0, 7.0, 7.0], speed, period)
    a = speed / 7.0
    A = np.zeros((5, 5))
    A[0, 0] = -a
    for j in (1, 3):
        A[j, j + 1], A[j + 1, j], A[j + 1, j + 1] = 1.0, -a * a, -2.0 * a
    B = np.zeros((5, 3))
    B[0, 0], B[2, 1], B[4, 2] = 1.0, 1.0, 1.0
    M = expm(np.block([[-A, B @ B.T], [np.zeros((5, 5)), A.T]]) * period)
    phi = M[5:, 5:].T
    q = phi @ M[:5, 5:]
    np.testing.assert_allclose(f.phi, phi, rtol=1e-9, atol=1e-15)
    np.testing.assert_allclose(f.chol @ f.chol.T, q, rtol=1e-7, atol=1e-14 * np.abs(q).max())
    p = f.stationary @ f.stationary.T  # stationary: P = Φ P Φᵀ + Q_d, and C P Cᵀ = σ²
    np.testing.assert_allclose(phi @ p @ phi.T + q, p, rtol=1e-9, atol=1e-12 * p.max())
    np.testing.assert_allclose(np.diag(f.output @ p @ f.output.T), SIGMA**2, rtol=1e-12)


def test_gust_variance_and_psd_match_the_dryden_model() -> None:
    gust = _gusts(8, 2**17)  # 2^20 samples, 14.6 h at 20 Hz: ≥ 1e5 correlation times
    # Variance within 5% of σ² (the estimate's own std is < 0.5% here).
    np.testing.assert_allclose(gust.var(axis=0), SIGMA**2, rtol=0.05)
    assert np.abs(gust.mean(axis=0)).max() < 0.02
    fs = 1.0 / PERIOD
    freq, est = welch(gust.T, fs=fs, nperseg=4096, axis=-1)
    # The sampled process has the one-sided PSD Σ_k S(|f + k fs|) (aliasing; images past
    # ±200 would add < 0.3%).
    images = np.abs(freq[:, None] + fs * np.arange(-200, 201)[None, :])
    folded = dryden_psd(images.ravel(), SIGMA, LENGTH, SPEED).reshape(3, *images.shape).sum(-1)
    edges = np.geomspace(0.1, 0.45 * fs, 12)
    for lo, hi in itertools.pairwise(edges):
        band = (freq >= lo) & (freq < hi)
        ratio = est[:, band].mean(axis=1) / folded[:, band].mean(axis=1)
        np.testing.assert_allclose(ratio, 1.0, atol=0.08, err_msg=f"band {lo:.3f}-{hi:.3f} Hz")
    # Below fs/20 the folding changes the PSD by < 2%: there the estimate is the Dryden PSD.
    low = (freq >= 0.05) & (freq < fs / 20)
    ratio = est[:, low].mean(axis=1) / dryden_psd(freq[low], SIGMA, LENGTH, SPEED).mean(axis=1)
    np.testing.assert_allclose(ratio, 1.0, atol=0.05)


def _aero_case(wind_n: np.ndarray, k: float, c: float, yaw: float, seconds: float) -> np.ndarray:
    """Hovering body (thrust m g, level, heading ``yaw``) from rest in a steady wind: its
    velocity in N (T, 3) at every 0.01 s."""
    params = VEHICLE_PRESETS["rauniyar2023"]
    params = VehicleParams(
        "custom", params.mass, params.inertia, params.max_thrust, params.max_torque,
        drag=k, drag_quadratic=(c, c, 0.5),
    )  # fmt: skip
    batch = VehicleBatch(params, 0.002, 1)
    x0 = np.zeros((1, 12))
    x0[0, 8] = yaw
    batch.reset([0], x0)
    batch.wind_n = wind_n.reshape(1, 3).copy()
    dcm = dcm_from_euler([0.0, 0.0, yaw])
    out = []
    for _ in range(round(seconds / 0.01)):
        batch.step(np.array([params.hover_thrust]), np.zeros((1, 3)), 0.01)
        out.append(dcm @ batch.state[0, 3:6])
    return np.array(out)


@pytest.mark.parametrize(("k", "c"), [(0.0, 0.3), (0.4, 0.2), (0.5, 0.0)])
def test_drag_in_a_steady_wind_follows_the_closed_form_and_settles_at_the_wind(
    k: float, c: float
) -> None:
    # Along the wind, r = |w| − speed obeys ṙ = −(k r + c r²): r(t) = k r0 e^{−kt} / (k + c r0
    # (1 − e^{−kt})), and r0/(1 + c r0 t) for k = 0. Isotropic horizontally, so any heading.
    w = np.array([3.0 * math.cos(0.5), 3.0 * math.sin(0.5), 0.0])
    vel = _aero_case(w, k, c, yaw=1.1, seconds=4.0)
    t = 0.01 * np.arange(1, vel.shape[0] + 1)
    r0 = 3.0
    if k == 0.0:
        r = r0 / (1.0 + c * r0 * t)
    else:
        e = np.exp(-k * t)
        r = k * r0 * e / (k + c * r0 * (1.0 - e))
    np.testing.assert_allclose(vel, np.outer(1.0 - r / r0, w), atol=1e-9)
    settled = _aero_case(w, 2.0, c, yaw=-0.4, seconds=12.0)[-1]
    np.testing.assert_allclose(settled, w, atol=1e-9)  # at rest relative to the air


def test_drag_force_is_the_equation_on_the_air_relative_velocity() -> None:
    rng = np.random.default_rng(4)
    x = rng.normal(size=12) * 0.5
    wind, cq = np.array([2.0, -1.0, 0.5]), np.array([0.1, 0.2, 0.3])
    mass, drag, thrust = 1.3, 0.25, 11.0
    body = np.zeros(20)
    body[0], body[1] = mass, drag
    body[2:11], body[11:20] = np.eye(3).ravel(), np.eye(3).ravel()
    u = np.zeros(7)
    u[0] = thrust
    out = np.zeros(12)
    rigid_body_derivative(x, u, body, False, out, (*wind, *cq), True)
    dcm = dcm_from_euler(x[6:9])
    v, w_rate = x[3:6], x[9:12]
    va = v - dcm.T @ wind
    f_b = -drag * va - cq * np.linalg.norm(va) * va - np.array([0.0, 0.0, thrust / mass])
    vdot = -np.cross(w_rate, v) + dcm.T @ np.array([0.0, 0.0, GRAVITY]) + f_b
    np.testing.assert_allclose(out[3:6], vdot, rtol=1e-12, atol=1e-12)
    # The accelerometer senses the same specific force (noise-free IMU, same air velocity).
    params = VehicleParams(
        "custom", mass, np.eye(3), 30.0, np.ones(3), drag=drag, drag_quadratic=cq
    )
    imu = ImuBatch(ImuConfig.from_dict({"preset": "ideal"}), params, 100.0, 1)
    imu.reset([0], [np.random.default_rng(0)])
    accel, _ = imu.sample(0.0, va[None], w_rate[None], np.array([thrust]))
    np.testing.assert_allclose(accel[0], f_b, rtol=1e-12, atol=1e-12)


def test_a_zero_wind_on_the_aerodynamic_path_equals_still_air_exactly() -> None:
    params = VEHICLE_PRESETS["sadeghzadeh2021"]
    x0 = np.random.default_rng(5).normal(size=(3, 12)) * 0.3
    still, calm = VehicleBatch(params, 0.002, 3), VehicleBatch(params, 0.002, 3)
    still.reset(np.arange(3), x0)
    calm.reset(np.arange(3), x0)
    calm.wind_n = np.zeros((3, 3))
    for _ in range(20):
        thrust, torque = np.full(3, 15.0), np.full((3, 3), 0.05)
        np.testing.assert_array_equal(
            still.step(thrust, torque, 0.01), calm.step(thrust, torque, 0.01)
        )
        np.testing.assert_array_equal(still.state, calm.state)


def _rollout(seed: int, steps: int = 30, **kw: dict) -> list[tuple]:
    env = gym.make("QuadSLAM-EKF-v0", episode={"duration_s": 1.0}, **kw)
    obs, info = env.reset(seed=seed)
    out = [(obs, info, env.unwrapped.landmarks.copy())]
    for _ in range(steps):
        obs, _, _, _, info = env.step(env.unwrapped.hover_action)
        out.append((obs, info, env.unwrapped.true_state))
    obs, info = env.reset()  # a second episode from the same generator
    out.append((obs, info, env.unwrapped.landmarks.copy()))
    env.close()
    return out


def test_same_seed_same_gusts_and_the_wind_changes_no_other_stream() -> None:
    a, b, other = _rollout(3, **GUSTS), _rollout(3, **GUSTS), _rollout(4, **GUSTS)
    wind = [[info[key] for key in WIND_KEYS] for _, info, _ in a]
    for (obs_a, info_a, x_a), (obs_b, info_b, x_b) in zip(a, b, strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        np.testing.assert_array_equal(x_a, x_b)
        assert info_a == info_b
    assert wind[0] == wind[1]  # the reset reports the wind the first step flies in
    assert len({tuple(w) for w in wind[1:]}) == len(wind) - 1  # gusts change every step
    assert a[1][1]["wind_n_mps"] != other[1][1]["wind_n_mps"]
    calm = _rollout(3, steps=2, vehicle=GUSTS["vehicle"])
    assert "wind_n_mps" not in calm[1][1]  # terms defined where they apply
    np.testing.assert_array_equal(a[0][2], calm[0][2])  # same landmarks, both episodes
    np.testing.assert_array_equal(a[-1][2], calm[-1][2])


@pytest.mark.parametrize(
    "mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP], ids=lambda m: m.value
)
def test_vector_lanes_with_gusts_equal_the_scalar_env(monkeypatch, mode) -> None:
    case = {
        **tve.SHORT,
        **GUSTS,
        "vehicle": {"drag_per_s": 0.2, "drag_quadratic_per_m": [0.05, 0.05, 0.1]},
        "imu": {"rate_hz": 10.0},  # the slower IMU's first sample takes the air velocity too
    }
    monkeypatch.setitem(tve.CASES, "QuadSLAM-EKF-v0-wind", case)
    tve.assert_lanes_equal_scalar_rollouts("QuadSLAM-EKF-v0-wind", mode)


def test_defaults_leave_the_air_still() -> None:
    cfg = load_scenario("paper_ekf_figure8")
    assert not cfg.wind.enabled and cfg.wind.turbulence == "none"
    assert not cfg.vehicle.params().drag_quadratic.any()


@pytest.mark.parametrize(
    ("section", "value", "key"),
    [
        ("wind", {"turbulence": "dryden", "w20_mps": -1.0, "steady_mps": [1, 0, 0]}, "w20_mps"),
        ("wind", {"steady_mps": [1.0, 2.0]}, "wind.steady_mps"),
        ("wind", {"steady_mps": [float("nan"), 0.0, 0.0]}, "wind.steady_mps[0]"),
        ("wind", {"steady_mps": [0.0, float("inf"), 0.0]}, "wind.steady_mps[1]"),
        ("wind", {"turbulence": "gusty"}, "wind.turbulence"),
        ("wind", {"preset": "hurricane"}, "wind.preset"),
        ("wind", {"turbulence": "dryden"}, "wind.airspeed_mps"),
        ("wind", {"preset": "light", "airspeed_mps": -2.0}, "wind.airspeed_mps"),
        ("wind", {"preset": "light", "steady_mps": [2, 0, 0], "altitude_m": 0.0}, "altitude_m"),
        ("wind", {"w20_mps": 20.0}, "wind.w20_mps"),  # read only with turbulence: dryden
        ("wind", {"gust": 1.0}, "wind.gust"),
        ("wind", {"steady_mps": [2.0, 0.0, 0.0]}, "vehicle.drag_per_s"),  # no drag: no effect
        ("vehicle", {"drag_quadratic_per_m": [0.1, -0.1, 0.0]}, "drag_quadratic_per_m[1]"),
        ("vehicle", {"drag_quadratic_per_m": 0.1}, "vehicle.drag_quadratic_per_m"),
    ],
)
def test_bad_wind_settings_name_the_key_before_the_episode(section, value, key) -> None:
    with pytest.raises(ConfigError, match=r"allowed") as err:
        gym.make("QuadSLAM-EKF-v0", **{section: value})
    assert key in str(err.value)


def test_wind_info_keys_are_documented_with_a_unit() -> None:
    page = (Path(__file__).resolve().parents[2] / "docs" / "env.md").read_text()
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    for key in WIND_KEYS:
        row = next((r for r in rows if f"`{key}`" in r.split("|")[1]), None)
        assert row is not None and row.rstrip(" |").rsplit("|", 1)[1].strip() == "m/s", key
