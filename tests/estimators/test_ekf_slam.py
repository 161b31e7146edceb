"""Tests of the EKF-SLAM estimator (estimators/ekf/) against independent facts.

Finite differences, a dense textbook Kalman filter, dense first-order covariance propagation,
the simulator's rigid-body dynamics, Monte-Carlo sampling and χ² bounds on NEES.
"""

from __future__ import annotations

import copy

import numpy as np
import pytest
from conftest import fd_jacobian, lane_predict, lane_reset, lane_update, random_spd
from scipy.stats import chi2

import estimators
from estimators.ekf.filter import EkfSlamBatch
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler, dcm_from_euler_batch, wrap_angle
from quadslam_env.models.integrators import rk4_integrate
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset
from quadslam_env.models.rigid_body import specific_force
from quadslam_env.models.strapdown import process_derivative, process_jacobians
from quadslam_env.types import GRAVITY

SIG_LIDAR = np.array([np.deg2rad(0.33), np.deg2rad(0.30), 0.1])  # seed 001 Table 4
SIG_ACC = 300e-6 * GRAVITY * 10.0  # seed 001 Table 5 density × √(100 Hz)
SIG_GYR = np.deg2rad(0.01) * 10.0
NO_CONTROL = Control(0.0, np.zeros(3))


def _landmarks(rng: np.random.Generator, count: int) -> np.ndarray:
    """Landmarks on a shell 8–20 m around the origin, like seed 001 Table 3."""
    az = rng.uniform(-np.pi, np.pi, count)
    el = rng.uniform(-np.deg2rad(50), np.deg2rad(50), count)
    rng_m = rng.uniform(8.0, 20.0, count)
    return np.stack(
        [rng_m * np.cos(el) * np.cos(az), rng_m * np.cos(el) * np.sin(az), rng_m * np.sin(el)],
        axis=1,
    )


def _scan(pos, euler, lms, ids, rng=None, sigma=SIG_LIDAR) -> LidarScan:
    ids = np.asarray(ids)
    meas = lidar_measure(np.asarray(pos), dcm_from_euler(euler), lms[ids])
    if rng is not None:
        meas = meas + sigma * rng.normal(size=meas.shape)
        meas[:, :2] = wrap_angle(meas[:, :2])
    return LidarScan(0.0, ids, meas, np.array(sigma))


def _imu(accel, gyro, sig_a=SIG_ACC, sig_g=SIG_GYR) -> ImuSample:
    return ImuSample(0.0, np.asarray(accel, float), np.asarray(gyro, float), sig_a, sig_g)


def _one_lane(**params) -> EkfSlamBatch:
    """The batch filter with one lane (room for 32 landmark ids before it grows)."""
    return EkfSlamBatch(1, 32, **params)


def _mapped_filter(rng, n_lm=5, **params):
    """A SLAM filter that has registered ``n_lm`` landmarks from a slightly tilted pose."""
    f = _one_lane(**params)
    mean0 = np.zeros(12)
    mean0[6:9] = [0.05, -0.08, 0.3]
    lane_reset(f, mean0, np.diag([0.01] * 6 + [0.001] * 3 + [0.0] * 3), rng)
    lms = _landmarks(rng, n_lm)
    lane_update(f, _scan(mean0[:3], mean0[6:9], lms, np.arange(n_lm), rng))
    return f, lms


def _stacked_h_full(x: np.ndarray, cols_lm: list[np.ndarray]) -> np.ndarray:
    """Stacked measurement of landmarks stored at ``cols_lm`` of the full state x (eq. 34)."""
    C = dcm_from_euler(x[6:9])
    return np.concatenate([lidar_measure(x[0:3], C, x[c]) for c in cols_lm])


# ----------------------------------------------------------------------------- construction
def test_registry_and_defaults():
    assert isinstance(estimators.make("ekf_slam", num_lanes=2), EkfSlamBatch)
    f = _one_lane()
    assert f.gate_threshold == pytest.approx(11.345, abs=1e-3)
    assert not f.known_map[0] and not f.estimate_imu_bias


@pytest.mark.parametrize(
    ("params", "needle"),
    [
        ({"bogus": 1}, "bogus"),
        ({"known_map": True}, "known_map"),
        ({"process_noise": [0.1] * 8}, "process_noise"),
        ({"process_noise": [0.1] * 8 + [-1.0]}, "process_noise"),
        ({"gyro_bias_walk": -1e-3}, ">= 0"),
        ({"gate_probability": 1.5}, "gate_probability"),
        ({"accel_bias_sigma0": float("nan")}, "accel_bias_sigma0"),
    ],
)
def test_bad_params_raise(params, needle):
    with pytest.raises(ValueError, match=needle):
        _one_lane(**params)


def test_known_map_mode_follows_reset_landmarks():
    f = _one_lane()
    lms = np.array([[10.0, 0.0, 0.0]])
    lane_reset(f, np.zeros(12), np.eye(12), np.random.default_rng(0), (np.arange(1), lms))
    assert f.known_map[0]
    lane_reset(f, np.zeros(12), np.eye(12), np.random.default_rng(0))
    assert not f.known_map[0]


# ----------------------------------------------------------------------------- 1. process model
def test_process_jacobians_match_finite_differences():
    rng = np.random.default_rng(1)
    for _ in range(5):
        s = np.r_[rng.normal(size=3), rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)]
        az, gyro = -GRAVITY + rng.normal(), rng.normal(size=3)
        F, G = process_jacobians(s, az, gyro)
        F_fd = fd_jacobian(lambda z, az=az, g=gyro: process_derivative(z, az, g), s)
        G_fd = fd_jacobian(lambda lam, s=s: process_derivative(s, lam[0], lam[1:]), np.r_[az, gyro])
        np.testing.assert_allclose(F, F_fd, atol=1e-7)
        np.testing.assert_allclose(G, G_fd, atol=1e-7)


def test_process_matches_simulator_dynamics():
    """Noise-free IMU ⇒ the filter mean follows the simulator's rigid-body RK4 (eq. 2 vs 24)."""
    veh = vehicle_preset("rauniyar2023")
    truth = np.zeros(12)
    truth[3:6] = [1.0, -0.5, 0.3]
    truth[6:9] = [0.1, -0.2, 0.5]
    truth[9:12] = [0.0, 0.0, 0.4]  # spin about a principal axis: ω stays constant
    thrust = 1.1 * veh.hover_thrust
    f = _one_lane(process_noise=[0.0] * 9)
    lane_reset(f, truth, np.zeros((12, 12)), np.random.default_rng(0))
    dt = 0.01
    for _ in range(100):
        imu = _imu(specific_force(truth[3:6], thrust, veh), truth[9:12], 0.0, 0.0)
        lane_predict(f, imu, Control(thrust, np.zeros(3)), dt)
        truth = rk4_integrate(truth, thrust, np.zeros(3), veh, dt, 0.002)
    est = f.lane_estimate(0)
    np.testing.assert_allclose(est.position[0], truth[0:3], atol=1e-8)
    np.testing.assert_allclose(est.vel_body[0], truth[3:6], atol=1e-8)
    np.testing.assert_allclose(est.euler[0], truth[6:9], atol=1e-9)
    np.testing.assert_allclose(est.vel_inertial[0], dcm_from_euler(truth[6:9]) @ truth[3:6])
    np.testing.assert_allclose(est.pose_cov[0], 0.0, atol=1e-300)


@pytest.mark.parametrize("bias", [False, True])
def test_predict_equals_dense_first_order_propagation(bias):
    """P⁺ = Φ P Φᵀ + Q_d on the dense full matrix, Φ built from finite differences; P_mm kept."""
    rng = np.random.default_rng(2)
    qc = np.array([0.2, 0.1, 0.05, 0.01, 0.02, 0.03, 0.02, 0.2, 0.1])
    f, _ = _mapped_filter(rng, 4, estimate_imu_bias=bias, process_noise=qc.tolist())
    x0, _, _ = f.full_state()
    n = x0.size
    nv = 13 if bias else 9
    x0[3:6] = [1.0, 0.5, -0.2]
    x0[6:9] = [0.2, -0.3, 1.0]
    if bias:
        x0[9:13] = [0.01, -0.02, 0.03, 0.1]
    P0 = random_spd(rng, n)
    f.set_full_state(x0, P0)
    accel, gyro = np.array([0.3, -0.2, -9.0]), np.array([0.2, -0.4, 0.3])
    dt, sa, sg = 0.01, 0.05, 0.004
    lane_predict(f, _imu(accel, gyro, sa, sg), NO_CONTROL, dt)
    x1, P1, _ = f.full_state()

    def f_aug(z):  # augmented process over (s, b): biases subtract from the inputs
        b = z[9:13] if bias else np.zeros(4)
        out = np.zeros(nv)
        out[:9] = process_derivative(z[:9], accel[2] - b[3], gyro - b[:3])
        return out

    def f_in(lam):
        return process_derivative(x0[:9], lam[0], lam[1:])

    b0 = x0[9:13] if bias else np.zeros(4)
    lam0 = np.r_[accel[2] - b0[3], gyro - b0[:3]]
    A = fd_jacobian(f_aug, x0[:nv]) * dt
    Phi_v = np.eye(nv) + A + 0.5 * A @ A
    G = np.zeros((nv, 4))
    G[:9] = fd_jacobian(f_in, lam0)
    Gam = (np.eye(nv) * dt + 0.5 * A * dt) @ G @ np.diag([sa, sg, sg, sg])
    Qc = np.r_[qc, [1e-4**2] * 3 + [1e-3**2]] if bias else qc
    Phi = np.eye(n)
    Phi[:nv, :nv] = Phi_v
    Qd = np.zeros((n, n))
    Qd[:nv, :nv] = Gam @ Gam.T + np.diag(Qc) * dt
    np.testing.assert_allclose(P1, Phi @ P0 @ Phi.T + Qd, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(P1[nv:, nv:], P0[nv:, nv:])  # P_mm untouched
    np.testing.assert_array_equal(x1[nv:], x0[nv:])  # landmarks and biases are static


def test_imu_noise_mapping_matches_monte_carlo():
    """With P0 = 0 and Q = 0, P after 20 steps equals the spread of states driven by noisy IMU."""
    rng = np.random.default_rng(3)
    s0 = np.array([0.0, 0.0, -1.0, 2.0, -1.0, 0.5, 0.3, -0.2, 0.7])
    accel, gyro = np.array([0.0, 0.0, -10.5]), np.array([0.3, -0.5, 0.4])
    sa, sg, dt, steps, n_mc, sub = 0.8, 0.08, 0.01, 20, 4000, 8
    f = _one_lane(process_noise=[0.0] * 9)
    lane_reset(f, np.r_[s0, gyro], np.zeros((12, 12)), rng)
    for _ in range(steps):
        lane_predict(f, _imu(accel, gyro, sa, sg), NO_CONTROL, dt)
    P = f.lane_estimate(0).pose_cov[0]

    # Independent vectorised simulation: Euler substeps, each sample's input held over dt.
    s = np.tile(s0, (n_mc, 1))
    for _ in range(steps):
        az = accel[2] + sa * rng.normal(size=n_mc)
        w = gyro + sg * rng.normal(size=(n_mc, 3))
        for _ in range(sub):
            C = dcm_from_euler_batch(s[:, 6:9])
            v = s[:, 3:6]
            phi, th = s[:, 6], s[:, 7]
            ds = np.empty_like(s)
            ds[:, 0:3] = np.einsum("kij,kj->ki", C, v)
            ds[:, 3:6] = -np.cross(w, v) + GRAVITY * C[:, 2, :]
            ds[:, 5] += az
            p, q, r = w.T
            ds[:, 6] = p + (np.sin(phi) * q + np.cos(phi) * r) * np.tan(th)
            ds[:, 7] = np.cos(phi) * q - np.sin(phi) * r
            ds[:, 8] = (np.sin(phi) * q + np.cos(phi) * r) / np.cos(th)
            s = s + ds * (dt / sub)
    P_mc = np.cov(s.T)
    scale = np.sqrt(np.outer(np.diag(P_mc), np.diag(P_mc)))
    np.testing.assert_allclose(P / scale, P_mc / scale, atol=0.08)


# ----------------------------------------------------------------------------- 2. measurement H
@pytest.mark.parametrize("bias", [False, True])
def test_stacked_h_matches_finite_differences_of_full_state(bias):
    rng = np.random.default_rng(4)
    f, _ = _mapped_filter(rng, 6, estimate_imu_bias=bias)
    x, P, slots_ids = f.full_state()
    nv = 13 if bias else 9
    x[6:9] = [0.3, -0.4, 2.5]
    x[nv:] += rng.normal(scale=0.5, size=x.size - nv)
    f.set_full_state(x, P)
    ids = np.array([4, 1, 5])
    cols, h, H = f.stacked_measurement(ids)
    slot_of = {int(i): j for j, i in enumerate(slots_ids)}
    cols_lm = [nv + 3 * slot_of[int(i)] + np.arange(3) for i in ids]
    H_full = np.zeros((9, x.size))
    H_full[:, cols] = H
    H_fd = fd_jacobian(lambda z: _stacked_h_full(z, cols_lm), x)
    np.testing.assert_allclose(h, _stacked_h_full(x, cols_lm), atol=1e-12)
    np.testing.assert_allclose(H_full, H_fd, atol=1e-6)
    assert np.all(H_full[:, 3:6] == 0.0) and np.all(H_full[:, 9:nv] == 0.0)


def test_known_map_h_is_over_pose_only():
    rng = np.random.default_rng(5)
    lms = _landmarks(rng, 5)
    f = _one_lane()
    mean0 = np.r_[0.1, -0.2, -1.0, 0, 0, 0, 0.1, 0.2, -0.3, 0, 0, 0]
    lane_reset(f, mean0, np.eye(12) * 0.01, rng, (np.arange(10, 15), lms))
    cols, h, H = f.stacked_measurement(np.array([12, 10]))
    np.testing.assert_array_equal(cols, np.arange(9))

    def hx(s):
        return np.concatenate([lidar_measure(s[:3], dcm_from_euler(s[6:9]), lms[[2, 0]])]).ravel()

    np.testing.assert_allclose(h, hx(mean0[:9]), atol=1e-12)
    np.testing.assert_allclose(H, fd_jacobian(hx, mean0[:9]), atol=1e-6)


# ----------------------------------------------------------------------------- 3. textbook KF
@pytest.mark.parametrize("bias", [False, True])
def test_update_equals_dense_textbook_kalman_filter(bias):
    rng = np.random.default_rng(6)
    f, lms = _mapped_filter(rng, 6, estimate_imu_bias=bias, gate_probability=1.0)
    x0, _, _ = f.full_state()
    n = x0.size
    P0 = random_spd(rng, n)
    f.set_full_state(x0, P0)
    ids = np.array([0, 2, 3, 5])
    scan = _scan([0.2, -0.1, 0.1], [0.07, -0.05, 0.28], lms, ids, rng)
    cols, h, H = f.stacked_measurement(ids)
    H_full = np.zeros((3 * ids.size, n))
    H_full[:, cols] = H
    nu = scan.meas.ravel() - h
    nu = np.where(np.arange(nu.size) % 3 < 2, (nu + np.pi) % (2 * np.pi) - np.pi, nu)
    R = np.diag(np.tile(SIG_LIDAR**2, ids.size))
    K = P0 @ H_full.T @ np.linalg.inv(H_full @ P0 @ H_full.T + R)
    I_KH = np.eye(n) - K @ H_full
    P_joseph = I_KH @ P0 @ I_KH.T + K @ R @ K.T  # Joseph form: an independent formula
    x_kf = x0 + K @ nu
    lane_update(f, scan)
    x1, P1, _ = f.full_state()
    np.testing.assert_allclose(x1, x_kf, rtol=0, atol=1e-9)
    np.testing.assert_allclose(P1, P_joseph, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(P1, P1.T)
    S = H_full @ P0 @ H_full.T + R
    diag = f.lane_estimate(0).diagnostics
    assert diag["nis"][0] == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-9)
    assert diag["nis_dof"][0] == 3 * ids.size


def test_azimuth_innovation_is_wrapped():
    """A landmark right behind the vehicle (α ≈ ±π) must not produce a 2π innovation."""
    rng = np.random.default_rng(7)
    lms = np.array([[-10.0, 1e-9, 0.0], [5.0, 5.0, -1.0]])
    f = _one_lane(process_noise=[0.0] * 9)
    lane_reset(f, np.zeros(12), np.eye(12) * 1e-4, rng, (np.array([0, 1]), lms))
    meas = lidar_measure(np.zeros(3), np.eye(3), lms)
    meas[0, 0] = -np.pi + 1e-4  # predicted is ≈ +π
    lane_update(f, LidarScan(0.0, np.array([0, 1]), meas, SIG_LIDAR))
    d = f.lane_estimate(0).diagnostics
    assert d["n_rejected"][0] == 0 and d["nis"][0] < 11.0
    assert np.all(np.abs(f.lane_estimate(0).position[0]) < 0.05)


# ----------------------------------------------------------------------------- 4. registration
@pytest.mark.parametrize("bias", [False, True])
def test_registration_equals_dense_first_order_covariance(bias):
    rng = np.random.default_rng(8)
    f, lms = _mapped_filter(rng, 3, estimate_imu_bias=bias)
    x0, _, _ = f.full_state()
    n = x0.size
    x0[6:9] = [0.2, -0.1, 0.9]
    P0 = random_spd(rng, n)
    f.set_full_state(x0, P0)
    new_lms = _landmarks(rng, 3)
    all_lms = np.vstack([lms, new_lms])
    scan = _scan([0.3, 0.1, -0.2], [0.1, -0.1, 0.8], all_lms, [3, 4, 5], rng)
    y = scan.meas.ravel()

    def g(xy):  # inverse model of the 3 measurements, written out from eq. 44–45
        xs, ys = xy[:n], xy[n:].reshape(3, 3)
        a, b, d = ys[:, 0], ys[:, 1], ys[:, 2]
        body = np.stack([d * np.cos(b) * np.cos(a), d * np.cos(b) * np.sin(a), d * np.sin(b)], 1)
        return (xs[0:3] + body @ dcm_from_euler(xs[6:9]).T).ravel()

    xy0 = np.r_[x0, y]
    J = np.zeros((n + 9, n + 9))
    J[:n, :n] = np.eye(n)
    J[n:, :] = fd_jacobian(g, xy0, eps=1e-7)  # [G_x, G_y]
    P_xy = np.zeros((n + 9, n + 9))
    P_xy[:n, :n] = P0
    P_xy[n:, n:] = np.diag(np.tile(SIG_LIDAR**2, 3))
    P_expected = (J @ P_xy @ J.T)[: n + 9, : n + 9]
    lane_update(f, scan)
    x1, P1, slot_ids = f.full_state()
    np.testing.assert_array_equal(slot_ids, [0, 1, 2, 3, 4, 5])
    np.testing.assert_allclose(x1, np.r_[x0, g(xy0)], atol=1e-12)
    np.testing.assert_allclose(P1, P_expected, rtol=0, atol=1e-7)
    np.testing.assert_array_equal(P1, P1.T)


def test_capacity_grows_by_doubling_and_keeps_content():
    rng = np.random.default_rng(9)
    f, lms = _mapped_filter(rng, 30)
    cap0 = f.state_capacity
    x0, P0, _ = f.full_state()
    more = _landmarks(rng, 10)
    lane_update(f, _scan(x0[:3], x0[6:9], np.vstack([lms, more]), np.arange(30, 40), rng))
    assert f.state_capacity == 2 * cap0
    x1, P1, ids = f.full_state()
    assert x1.size == 9 + 3 * 40 and ids.size == 40
    np.testing.assert_array_equal(x1[: x0.size], x0)
    np.testing.assert_array_equal(P1[: x0.size, : x0.size], P0)


# ----------------------------------------------------------------------------- 5. gating
def test_outlier_is_gated_and_counted():
    rng = np.random.default_rng(10)
    f, lms = _mapped_filter(rng, 6)
    for _ in range(5):
        lane_predict(f, _imu([0, 0, -GRAVITY], [0, 0, 0]), NO_CONTROL, 0.01)
    g = copy.deepcopy(f)
    scan = _scan(np.zeros(3), [0.05, -0.08, 0.3], lms, np.arange(6), rng)
    bad = scan.meas.copy()
    bad[2, 2] += 5.0
    lane_update(f, LidarScan(0.0, scan.ids, bad, SIG_LIDAR))
    d = f.lane_estimate(0).diagnostics
    assert d["n_rejected"][0] == 1 and d["n_rejected_last"][0] == 1 and d["nis_dof"][0] == 15
    keep = np.array([0, 1, 3, 4, 5])
    lane_update(g, LidarScan(0.0, scan.ids[keep], scan.meas[keep], SIG_LIDAR))
    xf, Pf, _ = f.full_state()
    xg, Pg, _ = g.full_state()
    np.testing.assert_allclose(xf, xg, atol=1e-12)
    np.testing.assert_allclose(Pf, Pg, atol=1e-14)
    np.testing.assert_array_equal(Pf, Pf.T)
    assert np.linalg.eigvalsh(Pf).min() > -1e-12


def test_non_pd_innovation_sets_diverged_and_keeps_state():
    rng = np.random.default_rng(11)
    f, lms = _mapped_filter(rng, 4)
    x0, _, _ = f.full_state()
    f.set_full_state(x0, -np.eye(x0.size))
    lane_update(f, _scan(np.zeros(3), [0.05, -0.08, 0.3], lms, np.arange(4), rng))
    x1, P1, _ = f.full_state()
    assert f.lane_estimate(0).diagnostics["diverged"][0] == 1.0
    np.testing.assert_array_equal(x1, x0)
    np.testing.assert_array_equal(P1, -np.eye(x0.size))


# ----------------------------------------------------------------------------- estimate()
def test_estimate_is_a_snapshot_and_sorted_by_id():
    rng = np.random.default_rng(12)
    f = _one_lane()
    lane_reset(f, np.zeros(12), np.eye(12) * 0.01, rng)
    lms = _landmarks(rng, 6)
    lane_update(f, _scan(np.zeros(3), np.zeros(3), lms, [3, 5], rng))
    lane_update(f, _scan(np.zeros(3), np.zeros(3), lms, [0, 1, 3], rng))
    est = f.lane_estimate(0)
    assert np.isnan(_one_lane().lane_estimate(0).diagnostics["nis"][0])
    ids, means, covs = est.mapped_landmarks()
    np.testing.assert_array_equal(ids, [0, 1, 3, 5])
    assert means.shape == (4, 3) and covs.shape == (4, 3, 3)
    np.testing.assert_allclose(means, lms[[0, 1, 3, 5]], atol=1.0)
    for c in covs:
        assert np.linalg.eigvalsh(c).min() > 0
    assert est.accel_bias is None and est.gyro_bias is None
    assert all(v.shape == (1,) and v.dtype == float for v in est.diagnostics.values())
    pos = est.position[0].copy()
    est.position[0, :] = 99.0
    est.pose_cov[0, :] = 99.0
    lane_predict(f, _imu([0, 0, -GRAVITY], [0.1, 0, 0]), NO_CONTROL, 0.01)
    est2 = f.lane_estimate(0)
    np.testing.assert_allclose(est2.position[0], pos, atol=1e-3)
    np.testing.assert_allclose(est2.rates[0], [0.1, 0, 0])
    assert est2.pose_cov[0, 0, 0] < 1.0


# ----------------------------------------------------------------------------- 6. NEES
def _hover_run(f: EkfSlamBatch, rng, lms, truth, steps, bias_g=None, bias_az=0.0):
    bias_g = np.zeros(3) if bias_g is None else bias_g
    ids = np.arange(lms.shape[0])
    C = dcm_from_euler(truth[6:9])
    for i in range(steps):
        acc = np.array([0.0, 0.0, -GRAVITY + bias_az]) + SIG_ACC * rng.normal(size=3)
        gyr = bias_g + SIG_GYR * rng.normal(size=3)
        lane_predict(f, _imu(acc, gyr), NO_CONTROL, 0.01)
        if i % 10 == 9:
            meas = lidar_measure(truth[:3], C, lms) + SIG_LIDAR * rng.normal(size=(ids.size, 3))
            meas[:, :2] = wrap_angle(meas[:, :2])
            lane_update(f, LidarScan(i * 0.01, ids, meas, SIG_LIDAR))
    return f.lane_estimate(0)


def test_known_map_hover_nees_is_chi2_consistent():
    """Mean NEES over 100 seeded runs lies in the two-sided 95% χ² interval (3 and 9 DOF).

    The model matches the truth exactly (hover, IMU noise only, Q = 0), so the filter should
    be consistent; with 1000 runs the mean pose NEES was 9.35 ± 0.14 (9 DOF) with these P0 and
    99% gating, 8.98 ± 0.13 with a tiny P0 and no gating.
    """
    runs, steps = 100, 200
    truth = np.zeros(12)
    truth[2] = -2.0
    truth[8] = 0.4
    P0 = np.diag([0.01] * 6 + [0.001] * 3 + [0.0] * 3)
    nees_pos, nees_pose = [], []
    for k in range(runs):
        rng = np.random.default_rng(k)
        lms = _landmarks(rng, 8)
        f = _one_lane(process_noise=[0.0] * 9)
        mean0 = truth.copy()
        mean0[:9] += rng.multivariate_normal(np.zeros(9), P0[:9, :9])
        lane_reset(f, mean0, P0, rng, (np.arange(8), lms))
        est = _hover_run(f, rng, lms, truth, steps)
        assert est.diagnostics["diverged"][0] == 0.0
        e = np.r_[
            est.position[0] - truth[:3], est.vel_body[0], wrap_angle(est.euler[0] - truth[6:9])
        ]
        nees_pos.append(e[:3] @ np.linalg.solve(est.pose_cov[0, :3, :3], e[:3]))
        nees_pose.append(e @ np.linalg.solve(est.pose_cov[0], e))
    for values, dof in ((nees_pos, 3), (nees_pose, 9)):
        lo, hi = chi2.ppf([0.025, 0.975], dof * runs) / runs
        assert lo <= np.mean(values) <= hi, (dof, np.mean(values), lo, hi)


def test_slam_hover_maps_landmarks_consistently():
    """Unknown map: relative map error (landmark − vehicle) is within its 3σ bound."""
    rng = np.random.default_rng(13)
    truth = np.zeros(12)
    truth[2] = -1.0
    lms = _landmarks(rng, 10)
    f = _one_lane(process_noise=[0.0] * 9)
    lane_reset(f, truth, np.diag([1e-4] * 6 + [1e-5] * 3 + [0.0] * 3), rng)
    est = _hover_run(f, rng, lms, truth, 500)
    assert est.diagnostics["diverged"][0] == 0.0 and est.diagnostics["n_mapped"][0] == 10.0
    ids, means, covs = est.mapped_landmarks()
    err = means - lms[ids]
    sd = np.sqrt(np.einsum("kii->ki", covs))
    assert np.all(np.abs(err) < 4 * sd)
    assert np.sqrt(np.mean(err**2)) < 0.1
    _, P, _ = f.full_state()
    np.testing.assert_array_equal(P, P.T)
    assert np.linalg.eigvalsh(P).min() > -1e-12


# ----------------------------------------------------------------------------- 7. IMU bias
def test_gyro_and_accel_bias_converge():
    rng = np.random.default_rng(14)
    truth = np.zeros(12)
    truth[2] = -2.0
    lms = _landmarks(rng, 10)
    b_g, b_az = np.array([0.02, -0.015, 0.01]), 0.1
    f = _one_lane(estimate_imu_bias=True, process_noise=[1e-6] * 9)
    lane_reset(f, truth, np.diag([1e-3] * 6 + [1e-4] * 3 + [0.0] * 3), rng, (np.arange(10), lms))
    est = _hover_run(f, rng, lms, truth, 3000, b_g, b_az)
    assert est.diagnostics["diverged"][0] == 0.0
    _, P, _ = f.full_state()
    sd = np.sqrt(np.diag(P)[9:13])
    err = np.r_[est.gyro_bias[0] - b_g, est.accel_bias[0, 2] - b_az]
    assert np.all(np.abs(err) < 4 * sd), (err, sd)
    assert np.all(np.abs(err[:3]) < 2e-3) and abs(err[3]) < 0.02
    assert est.accel_bias[0, 0] == 0.0 and est.accel_bias[0, 1] == 0.0
