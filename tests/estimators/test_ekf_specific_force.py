"""EKF-SLAM with the whole specific force (``specific_force: full``): its Jacobians against
finite differences, its prediction against a dense first-order propagation built from
finite differences, the thrust-axis model left bit for bit, and the drag it no longer reads as
tilt (flown: the attitude error in a steady wind against the thrust-axis model's)."""

from __future__ import annotations

import numpy as np
import pytest
from conftest import fd_jacobian, lane_predict, lane_reset, random_spd

import quadslam_env  # noqa: F401
from estimators.ekf.filter import EkfSlamBatch
from estimators.ekf.settings import PAPER_Q_UNKNOWN
from quadslam_env.estimation.measurements import Control, ImuSample
from quadslam_env.models.strapdown import process_derivative, process_jacobians
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY

NO_CONTROL = Control(0.0, np.zeros(3))


def test_full_jacobians_match_finite_differences() -> None:
    rng = np.random.default_rng(7)
    for _ in range(5):
        s = np.r_[rng.normal(size=3), rng.normal(size=3), rng.uniform(-0.6, 0.6, 3)]
        az, gyro, axy = -GRAVITY + rng.normal(), rng.normal(size=3), rng.normal(size=2)
        F, G = process_jacobians(s, az, gyro, full=True)
        F_fd = fd_jacobian(lambda z, az=az, g=gyro, a=axy: process_derivative(z, az, g, a), s)

        def by_input(lam: np.ndarray, s: np.ndarray = s) -> np.ndarray:  # λ = (a_z, ω, a_x, a_y)
            return process_derivative(s, lam[0], lam[1:4], (lam[4], lam[5]))

        G_fd = fd_jacobian(by_input, np.r_[az, gyro, axy])
        np.testing.assert_allclose(F, F_fd, atol=1e-7)
        np.testing.assert_allclose(G, G_fd, atol=1e-7)
        # the thrust-axis model is the first four columns
        np.testing.assert_array_equal(G[:, :4], process_jacobians(s, az, gyro)[1])


def test_full_prediction_equals_dense_first_order_propagation() -> None:
    """P⁺ = Φ P Φᵀ + Q_d over (s, b_ω, b_az, b_ax, b_ay), Φ and G from finite differences."""
    rng = np.random.default_rng(2)
    qc = np.array([0.2, 0.1, 0.05, 0.01, 0.02, 0.03, 0.02, 0.2, 0.1])
    f = EkfSlamBatch(1, 4, estimate_imu_bias=True, specific_force="full",
                     process_noise=qc.tolist())  # fmt: skip
    lane_reset(f, np.zeros(12), np.eye(12) * 0.01, rng)
    nv = 15
    x0, _, _ = f.full_state()
    assert x0.size == nv
    x0[3:6] = [1.0, 0.5, -0.2]
    x0[6:9] = [0.2, -0.3, 1.0]
    x0[9:15] = [0.01, -0.02, 0.03, 0.1, -0.05, 0.07]
    P0 = random_spd(rng, nv)
    f.set_full_state(x0, P0)
    accel, gyro = np.array([0.3, -0.2, -9.0]), np.array([0.2, -0.4, 0.3])
    dt, sa, sg = 0.01, 0.05, 0.004
    lane_predict(f, ImuSample(0.0, accel, gyro, sa, sg), NO_CONTROL, dt)
    x1, P1, _ = f.full_state()

    def f_aug(z: np.ndarray) -> np.ndarray:  # the biases subtract from the inputs
        b = z[9:15]
        out = np.zeros(nv)
        out[:9] = process_derivative(z[:9], accel[2] - b[3], gyro - b[:3],
                                     (accel[0] - b[4], accel[1] - b[5]))  # fmt: skip
        return out

    b0 = x0[9:15]
    lam0 = np.r_[accel[2] - b0[3], gyro - b0[:3], accel[:2] - b0[4:6]]
    A = fd_jacobian(f_aug, x0) * dt
    Phi = np.eye(nv) + A + 0.5 * A @ A
    G = np.zeros((nv, 6))
    G[:9] = fd_jacobian(
        lambda lam: process_derivative(x0[:9], lam[0], lam[1:4], (lam[4], lam[5])), lam0
    )
    Gam = (np.eye(nv) * dt + 0.5 * A * dt) @ G @ np.diag([sa, sg, sg, sg, sa, sa])
    walks = [1e-4**2] * 3 + [1e-3**2] * 3  # the settings' default bias walks
    Qd = Gam @ Gam.T + np.diag(np.r_[qc, walks]) * dt
    np.testing.assert_allclose(P1, Phi @ P0 @ Phi.T + Qd, rtol=0, atol=1e-10)
    np.testing.assert_array_equal(x1[9:], x0[9:])  # biases are static
    # the mean is classical RK4 of the full process with the inputs held (written out here)
    k1 = f_aug(x0)
    k2 = f_aug(x0 + 0.5 * dt * k1)
    k3 = f_aug(x0 + 0.5 * dt * k2)
    k4 = f_aug(x0 + dt * k3)
    np.testing.assert_allclose(x1[:9], (x0 + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4))[:9], atol=1e-12)


def test_thrust_axis_ignores_the_horizontal_accelerometer_axes() -> None:
    def predicted(accel: np.ndarray, mode: str) -> np.ndarray:
        f = EkfSlamBatch(1, 4, specific_force=mode)
        lane_reset(f, np.zeros(12), np.eye(12) * 0.01, np.random.default_rng(0))
        lane_predict(f, ImuSample(0.0, accel, np.zeros(3), 0.01, 0.001), NO_CONTROL, 0.01)
        return f.full_state()[0]

    a1, a2 = np.array([0.0, 0.0, -GRAVITY]), np.array([0.8, -0.5, -GRAVITY])
    np.testing.assert_array_equal(predicted(a1, "thrust_axis"), predicted(a2, "thrust_axis"))
    assert not np.array_equal(predicted(a1, "full"), predicted(a2, "full"))
    # with no horizontal specific force both models predict the same mean
    np.testing.assert_array_equal(predicted(a1, "full"), predicted(a1, "thrust_axis"))


def test_an_unknown_specific_force_model_is_refused() -> None:
    with pytest.raises(ConfigError, match=r"specific_force.*'thrust'.*thrust_axis"):
        EkfSlamBatch(1, 4, specific_force="thrust")


def _steady_attitude_rmse(mode: str, process_noise: list[float]) -> list[float]:
    """Steady-state (t > 10 s) attitude RMSE (deg) of EKF-SLAM on ``ekf_figure8_wind`` (2.2 m/s
    steady wind, Dryden gusts, rotor and body drag; SLAM), 25 s of DF-LQR on the estimate (the
    soft loop that keeps the thrust-axis filter flying), seeds 0 and 1."""
    from agents.lab.control_studies.learned_rows import fly

    params = {"specific_force": mode, "process_noise": process_noise}
    kwargs = {"scenario": "ekf_figure8_wind", "episode": {"duration_s": 25.0},
              "estimator": {"params": params}}  # fmt: skip
    episodes = fly("dflqr", "QuadSLAM-EKF-v0", kwargs, [0, 1])
    assert not any(e["terminated"] for e in episodes)
    return [e["est_att_rmse_steady_deg"] for e in episodes]


def test_flown_in_wind_the_full_model_does_not_read_drag_as_tilt() -> None:
    # A drag of ~0.3 s⁻¹ × 2.2 m/s = 0.67 m/s² along the body's horizontal axes: the thrust-axis
    # model can only explain it by a tilt of atan(0.67 / g) ≈ 3.9°. The full model measures it
    # (no drag model needed) and so needs no extra process noise either.
    thrust_axis = _steady_attitude_rmse("thrust_axis", list(PAPER_Q_UNKNOWN))
    full = _steady_attitude_rmse("full", [0.0] * 9)
    assert min(thrust_axis) > 2.0
    assert max(full) < 0.3
