"""Tests for the FastSLAM estimators (the estimators/fastslam package) against independent facts."""

from __future__ import annotations

import math

import numpy as np
import pytest

import estimators
from estimators.fastslam.bias_kf import H_BIAS, bias_kf_predict, bias_kf_update, bias_transition
from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.kinematic import KinematicFastSLAM
from estimators.fastslam.landmarks import landmark_ekf_update, landmark_init
from estimators.fastslam.process import (
    DynamicsModel,
    dynamics_derivative_batch,
    kinematic_derivative_batch,
)
from estimators.fastslam.resampling import (
    effective_sample_size,
    normalise_log_weights,
    systematic_resample,
)
from quadslam_env.estimation.lane_loop import LaneLoop
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.models.frames import dcm_from_euler, wrap_angle
from quadslam_env.models.integrators import rk4_integrate, state_derivative
from quadslam_env.models.lidar import lidar_inverse, lidar_jacobians, lidar_measure
from quadslam_env.models.params import VehicleParams, vehicle_preset
from quadslam_env.models.rigid_body import specific_force

LIDAR_SIGMA = np.array([math.radians(0.33), math.radians(0.30), 0.1])
POLES = np.array([[2.0, 2.0, -1.0], [-2.0, 2.0, -1.0], [-2.0, -2.0, -1.0], [2.0, -2.0, -1.0]])


def _random_states(rng: np.random.Generator, n: int) -> np.ndarray:
    x = rng.normal(size=(n, 12))
    x[:, 6:9] = rng.uniform([-1.0, -1.2, -math.pi], [1.0, 1.2, math.pi], size=(n, 3))
    return x


def _dragged_vehicle() -> VehicleParams:
    return VehicleParams(
        name="custom",
        mass=1.2,
        inertia=np.array([[0.02, 0.001, 0.0], [0.001, 0.03, 0.002], [0.0, 0.002, 0.05]]),
        max_thrust=30.0,
        max_torque=np.array([1.0, 1.0, 0.5]),
        drag=0.3,
    )


# ------------------------------------------------------------------------------- process models


@pytest.mark.parametrize(
    "vehicle",
    [vehicle_preset("rauniyar2023"), vehicle_preset("sadeghzadeh2021"), _dragged_vehicle()],
)
def test_vectorised_derivative_equals_scalar_model(vehicle: VehicleParams) -> None:
    rng = np.random.default_rng(0)
    states = _random_states(rng, 25)
    thrust, torque = 17.3, np.array([0.2, -0.1, 0.05])
    batch = dynamics_derivative_batch(states, thrust, torque, vehicle)
    for x, d in zip(states, batch, strict=True):
        np.testing.assert_allclose(
            d, state_derivative(x, thrust, torque, vehicle), rtol=1e-12, atol=1e-12
        )


def test_model_scales_change_mass_and_inertia() -> None:
    vehicle = vehicle_preset("sadeghzadeh2021")
    scaled = VehicleParams(
        name="custom",
        mass=vehicle.mass * 1.3,
        inertia=vehicle.inertia * 2.5,
        max_thrust=vehicle.max_thrust,
        max_torque=vehicle.max_torque,
    )
    x = _random_states(np.random.default_rng(1), 5)
    model = DynamicsModel(vehicle, mass_scale=1.3, inertia_scale=2.5)
    np.testing.assert_allclose(
        model.derivative(x, 12.0, np.array([0.1, 0.2, -0.1])),
        dynamics_derivative_batch(x, 12.0, [0.1, 0.2, -0.1], scaled),
        rtol=1e-12,
    )


def test_strapdown_with_true_specific_force_equals_dynamics() -> None:
    # With a_m = f_B exactly, the strapdown kinematics give the dynamics' ρ̇, v̇, Λ̇.
    vehicle = _dragged_vehicle()
    x = _random_states(np.random.default_rng(2), 10)
    thrust = 9.0
    f_b = np.array([specific_force(row[3:6], thrust, vehicle) for row in x])
    kin = kinematic_derivative_batch(x, f_b)
    dyn = dynamics_derivative_batch(x, thrust, np.zeros(3), vehicle)
    np.testing.assert_allclose(kin[:, :9], dyn[:, :9], rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(kin[:, 9:], 0.0)


# ------------------------------------------------------------------------- weights/resampling


def test_ess_of_uniform_and_one_hot_weights() -> None:
    assert effective_sample_size(np.full(500, 1.0 / 500)) == pytest.approx(500.0)
    one_hot = np.zeros(10)
    one_hot[3] = 1.0
    assert effective_sample_size(one_hot) == pytest.approx(1.0)


def test_log_weight_normalisation_is_stable() -> None:
    logw = np.array([-1e4, -1e4 + math.log(3.0), -np.inf])
    out = normalise_log_weights(logw)
    np.testing.assert_allclose(np.exp(out), [0.25, 0.75, 0.0], rtol=1e-12)


@pytest.mark.parametrize("seed", range(5))
def test_systematic_resampling_counts_are_floor_or_ceil(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = 97
    w = rng.dirichlet(np.full(n, 0.3))
    idx = systematic_resample(w, rng)
    counts = np.bincount(idx, minlength=n)
    assert counts.sum() == n
    assert np.all((counts == np.floor(n * w)) | (counts == np.ceil(n * w)))


def _mapped_filter(n: int = 50, **params: object) -> DynamicFastSLAM:
    est = DynamicFastSLAM(vehicle_preset("sadeghzadeh2021"), n_particles=n, **params)
    x0 = np.zeros(12)
    est.reset(x0, np.diag([1e-2] * 3 + [1e-4] * 9), np.random.default_rng(3))
    z = lidar_measure(np.zeros(3), np.eye(3), POLES)
    est.update(LidarScan(0.0, np.arange(4), z, LIDAR_SIGMA))
    return est


def test_resampled_particles_do_not_share_memory() -> None:
    est = _mapped_filter()
    old = {"x": est.state.x, "xb": est.bias.xb, "mu": est.state.mu, "sigma": est.state.sigma}
    idx = np.array([7] * 10 + list(range(40)))  # particle 7 copied 11 times
    est._resample(idx)
    for name, before in old.items():
        after = getattr(est.bias if name == "xb" else est.state, name)
        assert not np.shares_memory(after, before), name
    keep = est.state.mu[1].copy()
    est.state.mu[0, 2] += 5.0  # modify one copy of particle 7 ...
    est.state.sigma[0, 2] *= 3.0
    est.bias.xb[0] += 1.0
    np.testing.assert_array_equal(est.state.mu[1], keep)  # ... its twins are unchanged
    np.testing.assert_array_equal(est.state.sigma[1, 2], est.state.sigma[2, 2])
    np.testing.assert_array_equal(est.bias.xb[1], old["xb"][7])
    np.testing.assert_array_equal(old["mu"][7], keep)
    np.testing.assert_allclose(np.exp(est.state.logw), 1.0 / 50)


# ------------------------------------------------------------------------------- bias KF


def test_shared_covariance_kf_equals_per_particle_textbook_kf() -> None:
    rng = np.random.default_rng(4)
    A, Q = bias_transition(0.01, 100.0, 0.002, 0.003)
    R = np.diag([0.03**2] * 3 + [0.002**2] * 3)
    P0 = np.diag([0.01**2] * 6 + [0.002**2] * 6)
    means = rng.normal(0.0, 0.01, (3, 12))
    P = P0.copy()
    ref_m = [m.copy() for m in means]
    ref_P = [P0.copy() for _ in range(3)]
    for _ in range(30):
        z = rng.normal(size=6)
        hd = rng.normal(size=(3, 6))  # each particle's own h^d(x^D,i)
        means, P = bias_kf_predict(means, P, A, Q)
        innovation = z - hd - means @ H_BIAS.T
        means, P, loglik = bias_kf_update(means, P, innovation, H_BIAS, R)
        for i in range(3):  # textbook KF, one per particle
            m = A @ ref_m[i]
            Pi = A @ ref_P[i] @ A.T + Q
            S = H_BIAS @ Pi @ H_BIAS.T + R
            K = Pi @ H_BIAS.T @ np.linalg.inv(S)
            nu = z - hd[i] - H_BIAS @ m
            ref_m[i] = m + K @ nu
            ref_P[i] = (np.eye(12) - K @ H_BIAS) @ Pi
            expected_ll = -0.5 * (
                nu @ np.linalg.solve(S, nu) + np.log(np.linalg.det(2 * np.pi * S))
            )
            assert loglik[i] == pytest.approx(expected_ll, rel=1e-9)
    for i in range(3):
        np.testing.assert_allclose(means[i], ref_m[i], rtol=1e-9, atol=1e-14)
        np.testing.assert_allclose(P, ref_P[i], rtol=1e-7, atol=1e-16)


def test_bias_transition_is_exact_gauss_markov_discretisation() -> None:
    A, Q = bias_transition(0.5, 10.0, 0.2, 0.1)
    a = math.exp(-0.05)
    np.testing.assert_allclose(np.diag(A), [1.0] * 6 + [a] * 6)
    # The stationary variance σ² is preserved: a² σ² + q = σ².
    np.testing.assert_allclose(np.diag(Q)[6:9], 0.2**2 * (1 - a * a))
    np.testing.assert_allclose(np.diag(Q)[9:12], 0.1**2 * (1 - a * a))
    np.testing.assert_array_equal(np.diag(Q)[:6], 0.0)


# ------------------------------------------------------------------------------- landmark EKF


def test_landmark_ekf_update_equals_textbook_ekf() -> None:
    rng = np.random.default_rng(5)
    R = np.diag(LIDAR_SIGMA**2)
    n, m = 4, 3
    pos = rng.normal(0.0, 0.5, (n, 3))
    euler = rng.normal(0.0, 0.2, (n, 3))
    dcm = np.stack([dcm_from_euler(e) for e in euler])
    mu = rng.uniform(4.0, 9.0, (n, m, 3))
    sig = np.stack([[np.diag(rng.uniform(0.01, 0.1, 3)) for _ in range(m)] for _ in range(n)])
    z = np.array([[0.3, -0.1, 8.0], [-2.9, 0.2, 9.0], [1.0, 0.05, 7.0]])  # includes a wrap
    mu_new, sig_new, loglik, nis = landmark_ekf_update(
        mu, sig, pos[:, None], dcm[:, None], z[None], R
    )
    for i in range(n):
        for j in range(m):
            zhat = lidar_measure(pos[i], dcm[i], mu[i, j])
            _, _, H = lidar_jacobians(pos[i], euler[i], dcm[i], mu[i, j][None])
            H = H[0]
            S = H @ sig[i, j] @ H.T + R
            K = sig[i, j] @ H.T @ np.linalg.inv(S)
            nu = z[j] - zhat
            nu[:2] = wrap_angle(nu[:2])
            np.testing.assert_allclose(mu_new[i, j], mu[i, j] + K @ nu, rtol=1e-10)
            np.testing.assert_allclose(
                sig_new[i, j], (np.eye(3) - K @ H) @ sig[i, j], rtol=1e-8, atol=1e-15
            )
            assert nis[i, j] == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-9)
            expected = -0.5 * (nis[i, j] + np.log(np.linalg.det(2 * np.pi * S)))
            assert loglik[i, j] == pytest.approx(expected, rel=1e-9)


def test_landmark_init_inverts_the_measurement_with_g_r_gt() -> None:
    rng = np.random.default_rng(6)
    R = np.diag(LIDAR_SIGMA**2)
    pos = rng.normal(size=(2, 3))
    dcm = np.stack([dcm_from_euler(e) for e in rng.normal(0, 0.3, (2, 3))])
    z = np.array([[0.4, -0.2, 6.0], [-1.0, 0.3, 12.0]])
    mu, sig = landmark_init(pos, dcm, z, R)
    for i in range(2):
        for k in range(2):
            np.testing.assert_allclose(lidar_measure(pos[i], dcm[i], mu[i, k]), z[k], atol=1e-12)
            # G = ∂h⁻¹/∂z by central differences on the models' inverse.
            G = np.empty((3, 3))
            for c in range(3):
                dz = np.zeros(3)
                dz[c] = 1e-6
                G[:, c] = (
                    lidar_inverse(pos[i], dcm[i], z[k] + dz)
                    - lidar_inverse(pos[i], dcm[i], z[k] - dz)
                ) / 2e-6
            np.testing.assert_allclose(sig[i, k], G @ R @ G.T, rtol=1e-5, atol=1e-12)


# ------------------------------------------------------------------------------- estimator


def test_circular_mean_and_mixture_covariance() -> None:
    est = _mapped_filter(n=4, anchor_gauge=False)  # the particle moments alone (no gauge term)
    est.state.x[:, 8] = [math.pi - 0.01, -math.pi + 0.01, math.pi - 0.02, -math.pi + 0.02]
    est.state.set_logw(np.log(np.array([0.1, 0.2, 0.3, 0.4])))
    est.state.mu = np.random.default_rng(7).normal(size=est.state.mu.shape)
    e = est.estimate()
    w = np.array([0.1, 0.2, 0.3, 0.4])
    assert abs(wrap_angle(e.euler[0, 2] - math.pi)) < 0.02
    assert e.pose_cov[0, 8, 8] < 4e-4  # wrapped deviations, not ~π²
    assert np.all(np.linalg.eigvalsh(e.pose_cov[0]) > -1e-12)
    mean = np.einsum("n,nlk->lk", w, est.state.mu)
    d = est.state.mu - mean
    cov = np.einsum("n,nlij->lij", w, est.state.sigma) + np.einsum("n,nli,nlj->lij", w, d, d)
    np.testing.assert_array_equal(e.landmark_ids(), np.arange(4))
    np.testing.assert_allclose(e.mapped_landmarks()[1], mean, atol=1e-12)
    np.testing.assert_allclose(e.mapped_landmarks()[2], cov, atol=1e-12)


def test_all_zero_likelihood_flags_divergence_and_keeps_weights() -> None:
    est = _mapped_filter()
    before = est.state.logw.copy()
    est._apply_loglik(np.full(est.n_particles, -np.inf))
    e = est.estimate()
    assert e.diagnostics["diverged"][0] == 1.0
    np.testing.assert_array_equal(est.state.logw, before)
    assert np.all(np.isfinite(e.position[0])) and np.all(np.isfinite(e.pose_cov[0]))


def test_non_finite_propagation_keeps_previous_particles() -> None:
    est = _mapped_filter()
    x_before = est.state.x.copy()
    imu = ImuSample(0.01, np.array([0.0, 0.0, -9.81]), np.zeros(3), 0.03, 0.002)
    est.predict(imu, Control(float("nan"), np.zeros(3)), 0.01)
    e = est.estimate()
    assert e.diagnostics["diverged"][0] == 1.0
    np.testing.assert_array_equal(est.state.x, x_before)
    assert np.all(np.isfinite(e.position[0]))


def test_empty_scan_is_a_no_op_and_known_map_is_used() -> None:
    est = DynamicFastSLAM(vehicle_preset("sadeghzadeh2021"), n_particles=20)
    est.reset(
        np.zeros(12),
        np.eye(12) * 1e-4,
        np.random.default_rng(8),
        known_landmarks=(np.array([3, 1, 2, 0]), POLES),
    )
    logw = est.state.logw.copy()
    est.update(LidarScan(0.0, np.zeros(0, int), np.zeros((0, 3)), LIDAR_SIGMA))
    np.testing.assert_array_equal(est.state.logw, logw)
    e = est.estimate()
    np.testing.assert_array_equal(e.landmark_ids(), [0, 1, 2, 3])
    np.testing.assert_allclose(e.mapped_landmarks()[1], POLES[[3, 1, 2, 0]], atol=1e-12)
    assert np.all(e.mapped_landmarks()[2][:, [0, 1, 2], [0, 1, 2]] <= 1e-6 + 1e-12)
    assert math.isnan(e.diagnostics["nis"][0])


def _hover_run(
    name: str, seed: int, n_steps: int, **params: object
) -> tuple[object, np.ndarray, np.ndarray]:
    """Hovering vehicle (rk4_integrate), biased synthetic IMU, 4-pole scans at 10 Hz."""
    vehicle = vehicle_preset("sadeghzadeh2021")
    rng = np.random.default_rng(seed)
    x = np.zeros(12)
    thrust, torque = vehicle.mass * 9.81, np.zeros(3)
    gyro_bias = np.array([0.01, -0.008, 0.006])
    accel_bias = np.array([0.02, -0.01, 0.03])
    sa, sg = 0.03, 0.002
    est = estimators.make(name, vehicle=vehicle, **params).lanes[0]
    cov0 = np.diag([0.02**2] * 3 + [0.01**2] * 3 + [math.radians(0.2) ** 2] * 3 + [1e-8] * 3)
    est.reset(
        x + np.sqrt(np.diag(cov0)) * rng.normal(size=12), cov0, np.random.default_rng(seed + 1)
    )
    for k in range(n_steps):
        x = rk4_integrate(x, thrust, torque, vehicle, 0.01, 0.002)
        imu = ImuSample(
            (k + 1) * 0.01,
            specific_force(x[3:6], thrust, vehicle) + accel_bias + rng.normal(0, sa, 3),
            x[9:12] + gyro_bias + rng.normal(0, sg, 3),
            sa,
            sg,
        )
        est.predict(imu, Control(thrust, torque), 0.01)
        if (k + 1) % 10 == 0:
            z = lidar_measure(x[0:3], dcm_from_euler(x[6:9]), POLES)
            z = z + rng.normal(size=z.shape) * LIDAR_SIGMA
            est.update(LidarScan((k + 1) * 0.01, np.arange(4), z, LIDAR_SIGMA))
    return est.estimate(), x, np.r_[accel_bias, gyro_bias]


def test_dynamic_fastslam_hover_estimates_bias_and_stays_finite() -> None:
    e, x, bias = _hover_run("fastslam", seed=10, n_steps=500, n_particles=200)
    assert np.all(np.isfinite(e.position[0])) and np.all(np.isfinite(e.pose_cov[0]))
    assert np.all(np.isfinite(e.mapped_landmarks()[1])) and e.mapped_landmarks()[1].shape == (4, 3)
    # Biases move from the zero prior to the truth.
    assert np.linalg.norm(e.gyro_bias[0] - bias[3:]) < 0.25 * np.linalg.norm(bias[3:])
    assert np.linalg.norm(e.accel_bias[0] - bias[:3]) < 0.25 * np.linalg.norm(bias[:3])
    assert np.linalg.norm(e.position[0] - x[0:3]) < 0.2
    assert math.isfinite(e.diagnostics["nis"][0]) and e.diagnostics["nis_dof"][0] == 12.0
    assert 1.0 <= e.diagnostics["ess"][0] <= 200.0


def test_kinematic_fastslam_hover_stays_finite_without_bias_estimate() -> None:
    e, x, _ = _hover_run("fastslam_kinematic", seed=11, n_steps=300, n_particles=200)
    assert e.accel_bias is None and e.gyro_bias is None
    assert np.all(np.isfinite(e.position[0])) and np.linalg.norm(e.position[0] - x[0:3]) < 0.5


def test_stage2_runs_and_same_seed_reproduces() -> None:
    a, _, _ = _hover_run("fastslam", seed=12, n_steps=60, n_particles=50, stage2=True)
    b, _, _ = _hover_run("fastslam", seed=12, n_steps=60, n_particles=50, stage2=True)
    np.testing.assert_array_equal(a.position, b.position)
    np.testing.assert_array_equal(a.landmark_means, b.landmark_means)
    assert np.all(np.isfinite(a.pose_cov))


# ------------------------------------------------------------------------------- parameters


def test_registry_builds_both_filters() -> None:
    """Both are one vehicle's filters: the registry runs them lane by lane."""
    vehicle = vehicle_preset("rauniyar2023")
    dynamic = estimators.make("fastslam", num_lanes=2, vehicle=vehicle)
    assert isinstance(dynamic, LaneLoop) and dynamic.num_lanes == 2
    assert all(isinstance(lane, DynamicFastSLAM) for lane in dynamic.lanes)
    assert isinstance(estimators.make("fastslam_kinematic").lanes[0], KinematicFastSLAM)


def test_dynamic_filter_requires_vehicle() -> None:
    with pytest.raises(ValueError, match="vehicle"):
        DynamicFastSLAM()


@pytest.mark.parametrize(
    ("key", "value"),
    [
        ("n_particles", 0),
        ("n_particles", True),
        ("n_particles", 10.0),
        ("resample_threshold", 1.5),
        ("process_noise", [0.1, 0.2]),
        ("process_noise", -0.1),
        ("process_noise", "big"),
        ("integrator", "midpoint"),
        ("bias_tau_s", 0.0),
        ("accel_drift_sigma", -1.0),
        ("gyro_bias_sigma", float("nan")),
        ("inertia_scale", -2.5),
        ("mass_scale", 0),
        ("stage2", "yes"),
        ("known_map_sigma", 0.0),
        ("likelihood_inflation", 0.5),
        ("roughening", -0.1),
        ("nis_divergence", float("inf")),
        ("no_such_key", 1),
    ],
)
def test_invalid_parameters_raise_naming_the_key(key: str, value: object) -> None:
    with pytest.raises(ValueError, match=key):
        DynamicFastSLAM(vehicle_preset("rauniyar2023"), **{key: value})


def test_kinematic_rejects_dynamic_only_keys() -> None:
    with pytest.raises(ValueError, match="inertia_scale"):
        KinematicFastSLAM(inertia_scale=2.5)
    with pytest.raises(ValueError, match="imu_noise_scale"):
        KinematicFastSLAM(imu_noise_scale=-1.0)


def test_roughening_jitters_resampled_duplicates_in_proportion_to_the_spread() -> None:
    est = _mapped_filter(anchor_gauge=False, regularisation=0.0)  # roughening alone
    est.roughening = 0.5
    idx = np.full(est.n_particles, 7)  # every particle a copy of particle 7
    spread = np.std(est.state.x, axis=0)
    est._resample(idx)
    assert np.all(np.std(est.state.x[:, 0:3], axis=0) > 0.0)
    expected = 0.5 * spread * est.n_particles ** (-1.0 / 12)
    np.testing.assert_allclose(np.std(est.state.x, axis=0), expected, rtol=0.5)


def test_likelihood_inflation_tempers_the_weights_only() -> None:
    z = lidar_measure(np.array([0.05, 0.0, 0.0]), np.eye(3), POLES)
    scan = LidarScan(0.1, np.arange(4), z, LIDAR_SIGMA)
    plain, tempered = _mapped_filter(), _mapped_filter()
    tempered.likelihood_inflation = 10.0
    plain.resample_threshold = tempered.resample_threshold = 0.0
    plain.update(scan)
    tempered.update(scan)
    np.testing.assert_allclose(tempered.state.mu, plain.state.mu)  # the EKFs use the true R
    lw_p, lw_t = (
        plain.state.logw - plain.state.logw.max(),
        tempered.state.logw - tempered.state.logw.max(),
    )
    np.testing.assert_allclose(lw_t, lw_p / 10.0, atol=1e-9)


def test_sustained_huge_nis_flags_lost_lock_and_stays_flagged() -> None:
    est = _mapped_filter()
    est.nis_divergence, est.nis_divergence_s = 100.0, 0.5
    n = est.n_particles
    imu = ImuSample(0.01, np.array([0.0, 0.0, -9.81]), np.zeros(3), 0.03, 0.002)
    hover = Control(est.model.mass * 9.81, np.zeros(3))
    flags = []
    for k in range(100):
        est.predict(imu, hover, 0.01)
        nis = np.full(n, 1.0 if k < 20 else 1e4)  # lock lost after 0.2 s
        nis[0] = 1.0  # one lucky particle does not hide it (mean of the best 10 %)
        est._check_lock(nis)
        flags.append(est.estimate().diagnostics["diverged"][0])
    assert flags[60] == 0.0 and flags[-1] == 1.0  # 0.5 s of sustained NIS needed
    assert est.estimate().diagnostics["best_nis_per_dof"][0] > 100.0
    assert est.n_divergences == 1
    est.predict(imu, hover, 0.01)  # sticky
    assert est.estimate().diagnostics["diverged"][0] == 1.0
    est.reset(np.zeros(12), np.eye(12) * 1e-4, np.random.default_rng(0))
    assert est.estimate().diagnostics["diverged"][0] == 0.0


def test_helix_closed_loop_identifies_both_biases_within_20_percent() -> None:
    """Issue criterion on ``paper_fastslam_helix`` (biases 0.005, DF-LQR on the estimate).

    The truth is the simulator's total IMU bias; 4 seeds × 20 s (the docs/reproducing.md table uses
    10 × 30 s). The gyro bias is identified as ω_m − ω_dynamics, which needs the at-rest ω
    prior and a small ω process noise (with the earlier 1e-3 rad/s prior and 2e-4 rad/s/√s
    noise it was ~35 %).
    """
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.control.dflqr import DFLQRPolicy
    from agents.evaluation.episodes import run_episode

    env = gym.make("QuadSLAM-v0", scenario="paper_fastslam_helix", episode={"duration_s": 20.0})
    policy = DFLQRPolicy.from_env(env)
    records = [run_episode(env, policy, seed) for seed in range(4)]
    assert not any(r["terminated"] for r in records)
    assert np.median([r["gyro_bias_rel_err"] for r in records]) < 0.2
    assert np.median([r["accel_bias_rel_err"] for r in records]) < 0.2
    assert np.median([r["est_pos_rmse_m"] for r in records]) < 0.1
