"""EKF-SLAM with the wind in the estimate (``wind: estimate``): the drag model's Jacobian
against finite differences, one prediction plus accelerometer update against a dense EKF built
here from finite differences, the settings it refuses, the snapshot and ``info`` terms, and the
wind and attitude flown in Dryden turbulence."""

from __future__ import annotations

import dataclasses
import math

import gymnasium as gym
import numpy as np
import pytest
from conftest import fd_jacobian, lane_predict, lane_reset, lane_update, random_spd

import quadslam_env  # noqa: F401
from agents.control.named import build_controller
from estimators.ekf.filter import EkfSlamBatch
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset
from quadslam_env.models.strapdown import (
    drag_measurement,
    drag_process_derivative,
    process_derivative,
    process_jacobians,
)
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY

NO_CONTROL = Control(0.0, np.zeros(3))
MU, CQ = 0.3, np.array([0.02, 0.02, 0.04])
VEHICLE = dataclasses.replace(vehicle_preset("rauniyar2023"), drag=MU, drag_quadratic=CQ)
SIG_LIDAR = np.array([np.deg2rad(0.33), np.deg2rad(0.30), 0.1])


def _drag(s: np.ndarray, wind_ne: np.ndarray, cq: np.ndarray = CQ) -> np.ndarray:
    """The vehicle's drag along b1, b2 written out: ``−μ v_a − c_q ∘ (‖v_a‖ v_a)`` on
    ``v_a = v − C_NBᵀ (w_N, w_E, 0)``."""
    va = s[3:6] - dcm_from_euler(s[6:9]).T @ np.r_[wind_ne, 0.0]
    return (-MU * va - cq * np.linalg.norm(va) * va)[:2]


@pytest.mark.parametrize("cq", [np.zeros(3), CQ])
def test_drag_model_and_jacobian_match_finite_differences(cq: np.ndarray) -> None:
    rng = np.random.default_rng(3)
    for _ in range(5):
        s = np.r_[rng.normal(size=3), rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)]
        wind = rng.normal(size=2) * 2.0
        h, D = drag_measurement(s, wind, MU, cq)
        np.testing.assert_allclose(h, _drag(s, wind, cq), atol=1e-14)

        def by_state(z: np.ndarray, s: np.ndarray = s) -> np.ndarray:  # z = (v, Λ, w_N, w_E)
            return _drag(np.r_[s[:3], z[:6]], z[6:], cq)

        np.testing.assert_allclose(D, fd_jacobian(by_state, np.r_[s[3:9], wind]), atol=1e-8)
        # the process is eq. 24 plus the drag on the body's horizontal axes
        gyro = rng.normal(size=3)
        extra = drag_process_derivative(s, -GRAVITY, gyro, wind, MU, cq) - process_derivative(
            s, -GRAVITY, gyro
        )
        np.testing.assert_allclose(extra, np.r_[0, 0, 0, h, 0, 0, 0, 0], atol=1e-13)


def _filter_with_landmark(bias: bool, rng: np.random.Generator) -> EkfSlamBatch:
    """A wind filter with one landmark in its state (so P has cross-covariances to keep)."""
    f = EkfSlamBatch(1, 2, vehicle=VEHICLE, wind="estimate", estimate_imu_bias=bias,
                     process_noise=[0.02, 0.01, 0.03, 0.01, 0.02, 0.01, 0.002, 0.001, 0.003],
                     wind_walk=0.4)  # fmt: skip
    lane_reset(f, np.zeros(12), np.eye(12) * 0.01, rng)
    lm = np.array([[6.0, 2.0, -1.0]])
    meas = lidar_measure(np.zeros(3), np.eye(3), lm)
    lane_update(f, LidarScan(0.0, np.array([0]), meas, SIG_LIDAR))
    return f


@pytest.mark.parametrize("bias", [False, True])
def test_prediction_and_accel_update_equal_a_dense_ekf(bias: bool) -> None:
    """One IMU sample: x⁻ by RK4 of the process, P⁻ = Φ P Φᵀ + Q_d with Φ = I + A + ½A² and A
    from finite differences of the whole state's derivative, then the EKF update with
    (ã_x, ã_y), H from finite differences of h over the whole state and R = σ_a² I."""
    rng = np.random.default_rng(11)
    f = _filter_with_landmark(bias, rng)
    x0, _, _ = f.full_state()
    nv = 17 if bias else 11
    n = x0.size
    assert n == nv + 3
    w = slice(nv - 2, nv)
    x0[3:6] = [1.0, 0.4, -0.2]
    x0[6:9] = [0.15, -0.2, 0.8]
    x0[w] = [2.0, -1.0]
    if bias:
        x0[9:15] = [0.01, -0.02, 0.03, 0.1, -0.05, 0.07]
    P0 = random_spd(rng, n)
    f.set_full_state(x0, P0)
    accel, gyro = np.array([0.4, -0.3, -9.6]), np.array([0.2, -0.3, 0.25])
    dt, sa, sg = 0.01, 0.03, 0.002
    lane_predict(f, ImuSample(0.0, accel, gyro, sa, sg), NO_CONTROL, dt)
    x1, P1, _ = f.full_state()

    def b_of(z: np.ndarray) -> np.ndarray:  # (b_ω, b_az, b_ax, b_ay), zero without biases
        return z[9:15] if bias else np.zeros(6)

    def f_aug(z: np.ndarray) -> np.ndarray:
        b = b_of(z)
        out = np.zeros(n)
        out[:9] = process_derivative(z[:9], accel[2] - b[3], gyro - b[:3])
        out[3:5] += _drag(z[:9], z[w])
        return out

    def h_aug(z: np.ndarray) -> np.ndarray:
        return _drag(z[:9], z[w]) + b_of(z)[4:6]

    A = fd_jacobian(f_aug, x0) * dt
    Phi = np.eye(n) + A + 0.5 * A @ A
    G = np.zeros((n, 4))  # λ = (a_z, ω)
    b0 = b_of(x0)
    G[:9] = fd_jacobian(
        lambda lam: process_derivative(x0[:9], lam[0], lam[1:4]),
        np.r_[accel[2] - b0[3], gyro - b0[:3]],
    )
    Gam = (np.eye(n) * dt + 0.5 * A * dt) @ G @ np.diag([sa, sg, sg, sg])
    qc = np.zeros(n)
    qc[:9] = [0.02, 0.01, 0.03, 0.01, 0.02, 0.01, 0.002, 0.001, 0.003]
    if bias:
        qc[9:15] = [1e-4**2] * 3 + [1e-3**2] * 3  # the settings' default bias walks
    qc[w] = 0.4**2
    k1 = f_aug(x0)
    k2 = f_aug(x0 + 0.5 * dt * k1)
    k3 = f_aug(x0 + 0.5 * dt * k2)
    k4 = f_aug(x0 + dt * k3)
    x_pred = x0 + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    P_pred = Phi @ P0 @ Phi.T + Gam @ Gam.T + np.diag(qc) * dt
    H = fd_jacobian(h_aug, x_pred)
    S = H @ P_pred @ H.T + sa**2 * np.eye(2)
    K = P_pred @ H.T @ np.linalg.inv(S)
    x_post = x_pred + K @ (accel[:2] - h_aug(x_pred))
    P_post = P_pred - K @ S @ K.T
    np.testing.assert_allclose(x1, x_post, rtol=0, atol=1e-9)
    np.testing.assert_allclose(P1, P_post, rtol=0, atol=1e-9)
    assert abs(x1[w] - x0[w]).max() > 1e-3  # the measurement did move the wind


def test_snapshot_holds_the_wind_and_the_horizontal_biases() -> None:
    f = EkfSlamBatch(2, 4, vehicle=VEHICLE, wind="estimate", estimate_imu_bias=True)
    assert (f.nv, EkfSlamBatch(1, 4, vehicle=VEHICLE, wind="estimate").nv) == (17, 11)
    f.reset_lanes(np.arange(2), np.zeros((2, 12)), np.tile(np.eye(12) * 0.01, (2, 1, 1)),
                  [np.random.default_rng(0)] * 2)  # fmt: skip
    x, P, _ = f.full_state(1)
    np.testing.assert_array_equal(x[15:17], 0.0)
    np.testing.assert_allclose(np.diag(P)[15:17], 3.0**2)  # wind_sigma0's default
    x[13:17] = [0.05, -0.04, 1.5, -0.5]
    f.set_full_state(x, P, lane=1)
    est = f.estimate()
    assert est.wind is not None and est.wind.shape == (2, 2)
    np.testing.assert_array_equal(est.wind[1], [1.5, -0.5])
    assert est.accel_bias is not None
    np.testing.assert_array_equal(est.accel_bias[1], [0.05, -0.04, 0.0])
    one = f.lane_estimate(1)
    assert one.wind is not None
    np.testing.assert_array_equal(one.wind, [[1.5, -0.5]])
    assert EkfSlamBatch(1, 4).estimate().wind is None


def test_bad_wind_settings_are_refused() -> None:
    with pytest.raises(ConfigError, match=r"wind: got 'gusty'; allowed.*'none', 'estimate'"):
        EkfSlamBatch(1, 4, vehicle=VEHICLE, wind="gusty")
    with pytest.raises(ConfigError, match=r"wind: got 'estimate' with .*specific_force 'full'"):
        EkfSlamBatch(1, 4, vehicle=VEHICLE, wind="estimate", specific_force="full")
    still = dataclasses.replace(VEHICLE, drag=0.0)
    with pytest.raises(ConfigError, match=r"wind: got 'estimate' with vehicle.drag_per_s = 0.0"):
        EkfSlamBatch(1, 4, vehicle=still, wind="estimate")
    with pytest.raises(ConfigError, match=r"drag_per_s = None"):
        EkfSlamBatch(1, 4, wind="estimate")
    with pytest.raises(ConfigError, match=r"wind_walk: got 0.5, which .*wind 'none' ignores"):
        EkfSlamBatch(1, 4, vehicle=VEHICLE, wind_walk=0.5)
    with pytest.raises(ConfigError, match=r"wind_sigma0: got 0.0"):
        EkfSlamBatch(1, 4, vehicle=VEHICLE, wind="estimate", wind_sigma0=0.0)
    with pytest.raises(ConfigError, match=r"wind: got 'estimate' with vehicle.drag_per_s = 0.0"):
        gym.make("QuadSLAM-EKF-v0", scenario="paper_ekf_figure8",
                 estimator={"params": {"wind": "estimate"}})  # fmt: skip


def test_info_reports_the_wind_estimate_and_its_episode_rmse() -> None:
    env = gym.make("QuadSLAM-EKF-v0", scenario="ekf_figure8_wind_states",
                   episode={"duration_s": 0.5})  # fmt: skip
    ctrl = build_controller("lqi", env)
    obs, _ = env.reset(seed=0)
    errs, done = [], False
    while not done:
        obs, _, terminated, truncated, info = env.step(ctrl.predict(obs)[0])
        done = terminated or truncated
        est = np.array([info["est_wind_n_mps"], info["est_wind_e_mps"]])
        err = math.hypot(*(est - [info["wind_n_mps"], info["wind_e_mps"]]))
        assert info["est_wind_err_mps"] == pytest.approx(err, abs=1e-12)
        errs.append(err)
    env.close()
    assert not terminated
    assert info["episode_est_wind_rmse_mps"] == pytest.approx(np.sqrt(np.mean(np.square(errs))))
    # an estimator without wind states reports none of it
    env = gym.make("QuadSLAM-EKF-v0", scenario="ekf_figure8_wind", episode={"duration_s": 0.05})
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.zeros(4))
    env.close()
    assert not {k for k in info if "est_wind" in k}


def test_flown_in_dryden_wind_the_wind_is_tracked_and_not_read_as_tilt() -> None:
    """ekf_figure8_wind_states, LQI on the estimate, 30 s, seeds 0 and 1, t > 10 s.

    The bound on the wind: 0.5 m/s, below the RMS of the horizontal gust alone
    (√2 · σ_u = √2 · 0.59 ≈ 0.83 m/s at 2 m for W20 = 3 m/s), so only an estimate that follows
    the gusts passes (knowing the steady 2.2 m/s exactly would not). The bound on the attitude:
    0.5°, an eighth of the tilt the thrust-axis model reads the drag as, atan(0.3 · 2.2 / g)
    ≈ 3.9° (tests/estimators/test_ekf_specific_force.py)."""
    for seed in (0, 1):
        env = gym.make("QuadSLAM-EKF-v0", scenario="ekf_figure8_wind_states",
                       episode={"duration_s": 30.0})  # fmt: skip
        ctrl = build_controller("lqi", env)
        obs, _ = env.reset(seed=seed)
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(ctrl.predict(obs)[0])
            done = terminated or truncated
        env.close()
        assert not terminated, info["termination_reason"]
        assert info["episode_est_wind_rmse_steady_mps"] <= 0.5
        assert info["episode_est_att_rmse_steady_deg"] < 0.5


def test_thrust_axis_jacobians_are_left_as_they_were() -> None:
    """The drag adds to F only in the velocity rows over (v, Λ): eq. 28's F elsewhere."""
    rng = np.random.default_rng(5)
    s = np.r_[rng.normal(size=3), rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)]
    wind, gyro = np.array([1.0, -2.0]), rng.normal(size=3)
    F, _ = process_jacobians(s, -GRAVITY, gyro)
    F_fd = fd_jacobian(lambda z: drag_process_derivative(z, -GRAVITY, gyro, wind, MU, CQ), s)
    _, D = drag_measurement(s, wind, MU, CQ)
    F[3:5, 3:9] += D[:, :6]
    np.testing.assert_allclose(F, F_fd, atol=1e-7)
