"""Simulated sensors (docs/design.md §3): noise-free values exactly, noise statistics within χ²
sampling bounds, Gauss–Markov drift stationary variance and autocorrelation, LiDAR FOV limits."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2

from quadslam_env.config.hardware import ImuConfig, LidarConfig
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.sim.imu import Imu
from quadslam_env.sim.lidar import Lidar
from quadslam_env.types import GRAVITY

VEHICLE = VEHICLE_PRESETS["rauniyar2023"]
HOVER = VEHICLE.mass * GRAVITY
ZERO_NOISE = {
    "accel_noise_density": 0.0,
    "gyro_noise_density": 0.0,
    "accel_drift_sigma": 0.0,
    "gyro_drift_sigma": 0.0,
}
P_FAIL = 1e-6  # two-sided false-alarm probability of each statistical bound


def assert_variance(samples: np.ndarray, sigma: float) -> None:
    """Zero-mean Gaussian samples: Σx²/σ² ~ χ²(n); two-sided bound at P_FAIL."""
    x = np.ravel(samples)
    n = x.size
    stat = float(np.sum(x * x)) / sigma**2
    lo, hi = chi2.ppf(P_FAIL / 2, n), chi2.ppf(1 - P_FAIL / 2, n)
    assert lo < stat < hi, f"Σx²/σ² = {stat:.1f} outside χ²({n}) bounds [{lo:.1f}, {hi:.1f}]"


def assert_zero_mean(samples: np.ndarray, sigma: float) -> None:
    x = np.ravel(samples)
    assert abs(x.mean()) < 5.0 * sigma / math.sqrt(x.size)


def lidar_point(pos, dcm, az_deg, el_deg, rng_m) -> np.ndarray:
    """Inertial point at body azimuth/elevation/range (elevation positive below, FRD)."""
    a, e = math.radians(az_deg), math.radians(el_deg)
    body = rng_m * np.array([math.cos(e) * math.cos(a), math.cos(e) * math.sin(a), math.sin(e)])
    return np.asarray(pos) + dcm @ body


def c3c2c1(phi, theta, psi) -> np.ndarray:
    cf, sf, ct, st, cp, sp = (
        math.cos(phi),
        math.sin(phi),
        math.cos(theta),
        math.sin(theta),
        math.cos(psi),
        math.sin(psi),
    )
    r3 = np.array([[cp, -sp, 0], [sp, cp, 0], [0, 0, 1.0]])
    r2 = np.array([[ct, 0, st], [0, 1.0, 0], [-st, 0, ct]])
    r1 = np.array([[1.0, 0, 0], [0, cf, -sf], [0, sf, cf]])
    return r3 @ r2 @ r1


# ----------------------------------------------------------------------------- IMU
def test_noise_free_imu_reads_specific_force_plus_bias():
    accel_bias, gyro_bias = [0.01, -0.02, 0.03], [0.001, 0.002, -0.003]
    cfg = ImuConfig.from_dict({**ZERO_NOISE, "accel_bias": accel_bias, "gyro_bias": gyro_bias})
    imu = Imu(cfg, VEHICLE, rate_hz=100.0)
    imu.reset(np.random.default_rng(0))
    for k in range(50):
        s = imu.sample(0.01 * k, np.zeros(3), np.zeros(3), HOVER)
        np.testing.assert_allclose(
            s.accel, np.array([0.0, 0.0, -GRAVITY]) + accel_bias, rtol=0, atol=1e-12
        )
        np.testing.assert_allclose(s.gyro, gyro_bias, rtol=0, atol=1e-15)
    # Away from hover: f_B = −(f_T/m) b3 whatever the velocity (no drag); ω_m = ω + b.
    rates = np.array([0.3, -0.2, 1.0])
    s = imu.sample(1.0, np.array([3.0, -1.0, 0.5]), rates, 5.0)
    np.testing.assert_allclose(s.accel, np.array([0, 0, -5.0 / VEHICLE.mass]) + accel_bias)
    np.testing.assert_allclose(s.gyro, rates + gyro_bias, atol=1e-15)
    np.testing.assert_allclose(imu.total_bias, accel_bias + gyro_bias, atol=0)


def test_random_bias_sign_keeps_magnitude_and_flips_both_ways():
    bias = [0.005, 0.005, 0.005]
    cfg = ImuConfig.from_dict(
        {**ZERO_NOISE, "accel_bias": bias, "gyro_bias": bias, "random_bias_sign": True}
    )
    imu = Imu(cfg, VEHICLE, 100.0)
    signs = []
    for child in np.random.default_rng(1).spawn(200):
        imu.reset(child)
        np.testing.assert_allclose(np.abs(imu.total_bias), 0.005, atol=0)
        signs.append(np.sign(imu.total_bias))
    frac_pos = np.mean(np.array(signs) > 0)
    assert 0.4 < frac_pos < 0.6  # Binomial(1200, 0.5): std 0.014


def test_white_noise_std_is_density_times_sqrt_rate():
    nd_a, nd_g, rate = 0.01, 0.002, 200.0
    cfg = ImuConfig.from_dict(
        {**ZERO_NOISE, "accel_noise_density": nd_a, "gyro_noise_density": nd_g}
    )
    imu = Imu(cfg, VEHICLE, rate_hz=rate)
    imu.reset(np.random.default_rng(2))
    n = 5000
    acc = np.empty((n, 3))
    gyr = np.empty((n, 3))
    for k in range(n):
        s = imu.sample(k / rate, np.zeros(3), np.zeros(3), HOVER)
        acc[k] = s.accel - [0.0, 0.0, -GRAVITY]
        gyr[k] = s.gyro
    sig_a, sig_g = nd_a * math.sqrt(rate), nd_g * math.sqrt(rate)
    assert s.accel_sigma == pytest.approx(sig_a) and s.gyro_sigma == pytest.approx(sig_g)
    assert_zero_mean(acc, sig_a)
    assert_zero_mean(gyr, sig_g)
    assert_variance(acc, sig_a)
    assert_variance(gyr, sig_g)
    # Consecutive samples are white: lag-1 correlation ~ N(0, 1/n).
    lag1 = np.sum(acc[1:] * acc[:-1]) / np.sum(acc * acc)
    assert abs(lag1) < 5.0 / math.sqrt(3 * n)


def test_drift_is_stationary_gauss_markov():
    """2000 independent IMUs: drift variance σ² at reset and after k samples, and lag-k
    correlation e^{−kT/τ} (exact discretisation of the first-order Gauss–Markov process)."""
    sig_a, sig_g, tau, rate, k = 0.02, 0.004, 0.5, 100.0, 50
    cfg = ImuConfig.from_dict(
        {**ZERO_NOISE, "drift_tau_s": tau, "accel_drift_sigma": sig_a, "gyro_drift_sigma": sig_g}
    )
    imu = Imu(cfg, VEHICLE, rate_hz=rate)
    n = 2000
    d0 = np.empty((n, 6))
    dk = np.empty((n, 6))
    for i, child in enumerate(np.random.default_rng(3).spawn(n)):
        imu.reset(child)
        d0[i] = imu.total_bias
        for _ in range(k):
            imu.sample(0.0, np.zeros(3), np.zeros(3), HOVER)
        dk[i] = imu.total_bias
    for cols, sig in ((slice(0, 3), sig_a), (slice(3, 6), sig_g)):
        assert_zero_mean(d0[:, cols], sig)
        assert_variance(d0[:, cols], sig)
        assert_variance(dk[:, cols], sig)
        x, y = d0[:, cols].ravel(), dk[:, cols].ravel()
        rho = math.exp(-k / rate / tau)
        slope = float(x @ y / (x @ x))
        se = math.sqrt(1 - rho**2) / math.sqrt(x.size)
        assert abs(slope - rho) < 5 * se, (slope, rho, se)


def test_noise_free_imu_measures_before_drift_update():
    """With drift on and white noise off, a sample reads exactly the bias of that instant."""
    cfg = ImuConfig.from_dict({**ZERO_NOISE, "gyro_drift_sigma": 0.01, "drift_tau_s": 1.0})
    imu = Imu(cfg, VEHICLE, 100.0)
    imu.reset(np.random.default_rng(4))
    for _ in range(10):
        before = imu.total_bias.copy()
        s = imu.sample(0.0, np.zeros(3), np.zeros(3), HOVER)
        np.testing.assert_allclose(s.gyro, before[3:], atol=1e-15)


# ----------------------------------------------------------------------------- LiDAR
NOISE_FREE_LIDAR = {
    "azimuth_fov_deg": 45.0,
    "elevation_fov_deg": 30.0,
    "range_min_m": 2.0,
    "range_max_m": 50.0,
    "sigma_azimuth_deg": 0.0,
    "sigma_elevation_deg": 0.0,
    "sigma_range_m": 0.0,
}
POSE_EULER = (0.1, -0.2, 2.0)
POSE_POS = np.array([1.0, -2.0, -3.0])


def _scan(cfg_dict, points, ids=None, seed=0):
    lidar = Lidar(LidarConfig.from_dict(cfg_dict))
    lidar.reset(np.random.default_rng(seed))
    dcm = c3c2c1(*POSE_EULER)
    ids = np.arange(len(points)) if ids is None else np.asarray(ids)
    return lidar.scan(0.5, POSE_POS, dcm, ids, np.array(points, dtype=float))


def test_lidar_fov_and_range_limits():
    dcm = c3c2c1(*POSE_EULER)
    eps = 0.1
    cases = [  # (azimuth deg, elevation deg, range m, visible?)
        (0.0, 0.0, 10.0, True),
        (45.0 - eps, 0.0, 10.0, True),
        (-45.0 + eps, 0.0, 10.0, True),
        (45.0 + eps, 0.0, 10.0, False),
        (-45.0 - eps, 0.0, 10.0, False),
        (0.0, 30.0 - eps, 10.0, True),
        (0.0, -30.0 + eps, 10.0, True),
        (0.0, 30.0 + eps, 10.0, False),
        (0.0, -30.0 - eps, 10.0, False),
        (0.0, 0.0, 2.0 + eps, True),
        (0.0, 0.0, 2.0 - eps, False),
        (0.0, 0.0, 50.0 - eps, True),
        (0.0, 0.0, 50.0 + eps, False),
        (180.0, 0.0, 10.0, False),  # behind
        (30.0, 20.0, 40.0, True),
        (-44.0, -29.0, 3.0, True),
    ]
    points = [lidar_point(POSE_POS, dcm, a, e, r) for a, e, r, _ in cases]
    scan = _scan(NOISE_FREE_LIDAR, points)
    expected_ids = [i for i, c in enumerate(cases) if c[3]]
    np.testing.assert_array_equal(scan.ids, expected_ids)
    assert scan.meas.shape == (len(expected_ids), 3)
    assert scan.count == len(expected_ids)
    # Noise-free: the model value, (α, β, δ) of the construction.
    expected = np.array(
        [[math.radians(cases[i][0]), math.radians(cases[i][1]), cases[i][2]] for i in expected_ids]
    )
    np.testing.assert_allclose(scan.meas, expected, rtol=0, atol=1e-12)


def test_lidar_returns_nothing_when_all_outside():
    dcm = c3c2c1(*POSE_EULER)
    points = [lidar_point(POSE_POS, dcm, a, 0.0, 10.0) for a in (60.0, 120.0, -90.0, 179.0)]
    points.append(lidar_point(POSE_POS, dcm, 0.0, 0.0, 80.0))
    scan = _scan(NOISE_FREE_LIDAR, points)
    assert scan.count == 0
    assert scan.meas.shape == (0, 3)


def test_lidar_360_azimuth_sees_behind():
    dcm = c3c2c1(*POSE_EULER)
    cfg = {**NOISE_FREE_LIDAR, "azimuth_fov_deg": 180.0}
    points = [lidar_point(POSE_POS, dcm, a, 5.0, 10.0) for a in (179.0, -179.0, 90.0)]
    scan = _scan(cfg, points)
    np.testing.assert_allclose(
        scan.meas[:, 0], np.radians([179.0, -179.0, 90.0]), rtol=0, atol=1e-12
    )


def test_lidar_ids_sorted_and_rows_match():
    dcm = c3c2c1(*POSE_EULER)
    ids = np.array([3, 7, 10, 42, 99])
    azs = [10.0, 90.0, -20.0, 30.0, 170.0]  # ids 7 and 99 are outside the FOV
    points = [lidar_point(POSE_POS, dcm, a, 0.0, 5.0 + i) for i, a in enumerate(azs)]
    scan = _scan(NOISE_FREE_LIDAR, points, ids=ids)
    np.testing.assert_array_equal(scan.ids, [3, 10, 42])
    assert np.all(np.diff(scan.ids) > 0)
    np.testing.assert_allclose(scan.meas[:, 2], [5.0, 7.0, 8.0], atol=1e-12)
    np.testing.assert_allclose(scan.meas[:, 0], np.radians([10.0, -20.0, 30.0]), atol=1e-12)


def test_lidar_same_seed_same_scan():
    dcm = c3c2c1(*POSE_EULER)
    cfg = {**NOISE_FREE_LIDAR, "sigma_azimuth_deg": 0.3, "sigma_range_m": 0.1}
    points = [lidar_point(POSE_POS, dcm, a, 5.0, 10.0) for a in (-30.0, 0.0, 30.0)]
    a, b, c = _scan(cfg, points, seed=5), _scan(cfg, points, seed=5), _scan(cfg, points, seed=6)
    np.testing.assert_array_equal(a.meas, b.meas)
    np.testing.assert_array_equal(a.ids, b.ids)
    assert not np.array_equal(a.meas, c.meas)


def test_lidar_noise_statistics_and_azimuth_wrap():
    """Per-channel noise std equals the configured σ (χ² bound); azimuth stays wrapped."""
    sig = np.array([math.radians(2.0), math.radians(0.5), 0.2])
    cfg = {
        **NOISE_FREE_LIDAR,
        "azimuth_fov_deg": 180.0,
        "sigma_azimuth_deg": 2.0,
        "sigma_elevation_deg": 0.5,
        "sigma_range_m": 0.2,
    }
    lidar = Lidar(LidarConfig.from_dict(cfg))
    lidar.reset(np.random.default_rng(7))
    dcm = c3c2c1(*POSE_EULER)
    # One landmark just inside +180° azimuth (noise will push it across the ±π seam),
    # one ahead.
    truth = np.array([[math.radians(179.5), 0.1, 10.0], [0.0, -0.2, 20.0]])
    pts = np.array(
        [lidar_point(POSE_POS, dcm, math.degrees(a), math.degrees(e), r) for a, e, r in truth]
    )
    n = 3000
    res = np.empty((n, 2, 3))
    for k in range(n):
        scan = lidar.scan(0.0, POSE_POS, dcm, np.arange(2), pts)
        assert np.all(scan.meas[:, 0] > -math.pi) and np.all(scan.meas[:, 0] <= math.pi)
        d = scan.meas - truth
        d[:, 0] = math.pi - np.mod(math.pi - d[:, 0], 2 * math.pi)  # wrapped residual
        res[k] = d
    for ch in range(3):
        assert_zero_mean(res[:, :, ch], sig[ch])
        assert_variance(res[:, :, ch], sig[ch])
