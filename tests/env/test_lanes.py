"""The batched core (docs/design.md §9): lane kernels, VehicleBatch, ImuBatch, LidarBatch.

Independent facts (hover fixed point, conservation laws without torque, the FOV) and the lane
contract: lane i of a B-lane object equals the one-lane object driven with the same inputs and
generator, bit for bit, and inactive lanes are untouched.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from quadslam_env.config.hardware import ImuConfig, LidarConfig
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_angle
from quadslam_env.models.integrators import RigidBodyLanes, vehicle_step_lanes
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams
from quadslam_env.models.rigid_body import pack_bodies
from quadslam_env.sim.imu import Imu, ImuBatch
from quadslam_env.sim.lidar import Lidar, LidarBatch
from quadslam_env.sim.vehicle import Vehicle, VehicleBatch
from quadslam_env.types import GRAVITY

_HECTOR = VEHICLE_PRESETS["sadeghzadeh2021"]
# Products of inertia and drag, so every term of the model is exercised.
TUMBLER = replace(
    _HECTOR, name="custom", inertia=np.diag([0.02, 0.03, 0.05]) + 0.001 * (1 - np.eye(3)), drag=0.3
)
LAGGED = replace(_HECTOR, name="custom", actuator_tau=0.03)


def _body(params):
    """The (20,) packed rigid-body row of ``params``."""
    j, j_inv = np.array(params.inertia)[None], np.array(params.inertia_inv)[None]
    return pack_bodies(params.mass, params.drag, j, j_inv)[0]


def _step_lanes(params, states, thrust_cmd, torque_cmd, active, duration, dt=0.002):
    """Call the lane kernel directly with fresh actuator arrays; returns everything."""
    b = states.shape[0]
    applied_thrust = np.full(b, params.hover_thrust)
    applied_torque = np.zeros((b, 3))
    mean_rates = np.zeros((b, 3))
    vehicle_step_lanes(
        states,
        applied_thrust,
        applied_torque,
        thrust_cmd,
        torque_cmd,
        active,
        np.tile(_body(params), (b, 1)),
        np.tile([params.max_thrust, *params.max_torque, params.actuator_tau, 1.0], (b, 1)),
        duration,
        dt,
        mean_rates,
        np.zeros((b, 3)),  # still air
        np.array(params.drag_quadratic),
        False,
    )
    return applied_thrust, applied_torque, mean_rates


@pytest.mark.parametrize("preset", sorted(VEHICLE_PRESETS))
def test_hover_is_a_fixed_point_of_the_lane_kernel(preset: str) -> None:
    params = VEHICLE_PRESETS[preset]
    b = 5
    states = np.zeros((b, 12))
    states[:, 0:3] = np.random.default_rng(0).normal(size=(b, 3))
    states[:, 8] = np.linspace(-3.0, 3.0, b)  # any heading hovers
    x0 = states.copy()
    active = np.ones(b, dtype=bool)
    for _ in range(100):  # 1 s
        _, _, rates = _step_lanes(
            params, states, np.full(b, params.mass * GRAVITY), np.zeros((b, 3)), active, 0.01
        )
    np.testing.assert_allclose(states, x0, atol=1e-12)
    np.testing.assert_allclose(rates, 0.0, atol=1e-15)


def test_torque_free_lanes_conserve_angular_momentum_and_energy() -> None:
    """Without torque, |J ω| (body-frame norm of the momentum) and ½ ωᵀJω are invariants."""
    b = 4
    rng = np.random.default_rng(1)
    states = np.zeros((b, 12))
    states[:, 6:9] = rng.uniform(-0.5, 0.5, size=(b, 3))
    states[:, 9:12] = rng.uniform(-3.0, 3.0, size=(b, 3))
    J = TUMBLER.inertia

    def invariants(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        h = x[:, 9:12] @ J.T
        return np.linalg.norm(h, axis=1), 0.5 * np.sum(x[:, 9:12] * h, axis=1)

    mom0, energy0 = invariants(states)
    w0 = states[:, 9:12].copy()
    for _ in range(200):  # 2 s of tumbling, free fall (zero thrust)
        _step_lanes(TUMBLER, states, np.zeros(b), np.zeros((b, 3)), np.ones(b, bool), 0.01)
    mom, energy = invariants(states)
    assert np.max(np.abs(states[:, 9:12] - w0)) > 0.1  # the rates really change
    np.testing.assert_allclose(mom, mom0, rtol=1e-7)
    np.testing.assert_allclose(energy, energy0, rtol=1e-7)


@pytest.mark.parametrize("params", [TUMBLER, LAGGED])
def test_vehicle_batch_lanes_equal_single_vehicles_and_inactive_lanes_are_untouched(
    params: VehicleParams,
) -> None:
    b = 6
    rng = np.random.default_rng(2)
    x0 = rng.normal(size=(b, 12)) * 0.3
    batch = VehicleBatch(params, 0.002, b)
    batch.reset(np.arange(b), x0)
    singles = [Vehicle(params, 0.002) for _ in range(b)]
    for vehicle, x in zip(singles, x0, strict=True):
        vehicle.reset(x)
    for _ in range(40):
        thrust = rng.uniform(-5.0, 40.0, b)  # includes commands beyond both limits
        torque = rng.normal(scale=0.5, size=(b, 3))
        active = rng.random(b) < 0.6
        before = (batch.state.copy(), batch.applied_thrust.copy(), batch.applied_torque.copy())
        rates = batch.step(thrust, torque, 0.01, active)
        for i, vehicle in enumerate(singles):
            if active[i]:
                r = vehicle.step(thrust[i], torque[i], 0.01)
                np.testing.assert_array_equal(rates[i], r)
            else:
                np.testing.assert_array_equal(batch.state[i], before[0][i])
                assert batch.applied_thrust[i] == before[1][i]
                np.testing.assert_array_equal(batch.applied_torque[i], before[2][i])
                np.testing.assert_array_equal(rates[i], 0.0)
            np.testing.assert_array_equal(batch.state[i], vehicle.state)
            assert batch.applied_thrust[i] == vehicle.applied_thrust
            np.testing.assert_array_equal(batch.applied_torque[i], vehicle.applied_torque)
    assert np.all(np.abs(batch.state[:, [6, 8]]) <= math.pi)


def test_reset_sets_hover_actuators_only_in_the_given_lanes() -> None:
    params = LAGGED
    batch = VehicleBatch(params, 0.002, 3)
    batch.reset(np.arange(3), np.zeros((3, 12)))
    batch.step(np.full(3, 20.0), np.full((3, 3), 0.2), 0.05)
    lagged = batch.applied_thrust[0]
    assert lagged != params.hover_thrust  # the lag moved toward the command
    batch.reset(np.array([1]), np.ones((1, 12)))
    assert batch.applied_thrust[1] == params.hover_thrust
    np.testing.assert_array_equal(batch.applied_torque[1], 0.0)
    np.testing.assert_array_equal(batch.state[1], 1.0)
    assert batch.applied_thrust[0] == lagged and batch.applied_thrust[2] == lagged


def test_particle_kernel_per_lane_inertia_equals_separate_shared_calls() -> None:
    rng = np.random.default_rng(3)
    n = 7
    x = rng.normal(size=(n, 12)) * 0.4
    thrust = rng.uniform(5.0, 20.0, n)
    torque = rng.normal(scale=0.1, size=(n, 3))
    J = np.array([np.diag(rng.uniform(0.01, 0.05, 3)) for _ in range(n)])
    out = RigidBodyLanes(1.3, 0.1, J).propagate(x, thrust, torque, 0.01, 2)
    for i in range(n):
        one = RigidBodyLanes(1.3, 0.1, J[i]).propagate(x[i : i + 1], thrust[i], torque[i], 0.01, 2)
        np.testing.assert_array_equal(out[i], one[0])


def test_wrap_angle_is_exact_and_half_open() -> None:
    inside = np.array([0.1, -3.0, 3.1, math.pi, 1e-300])
    np.testing.assert_array_equal(wrap_angle(inside), inside)  # no round-off inside (-π, π]
    assert wrap_angle(-math.pi) == math.pi
    np.testing.assert_array_equal(wrap_angle(np.array([-math.pi, 3 * math.pi])), math.pi)
    rng = np.random.default_rng(4)
    angles = rng.uniform(-100.0, 100.0, 1000)
    ref = np.array([math.remainder(a, 2 * math.pi) for a in angles])  # exact IEEE remainder
    ref[ref == -math.pi] = math.pi
    np.testing.assert_array_equal(wrap_angle(angles), ref)
    assert all(wrap_angle(float(a)) == r for a, r in zip(angles[:50], ref, strict=False))


# ----------------------------------------------------------------------------- IMU
IMU_CFG = ImuConfig.from_dict(
    {
        "accel_bias": [0.005, -0.004, 0.003],
        "gyro_bias": [0.005, 0.002, -0.001],
        "random_bias_sign": True,
        "accel_drift_sigma": 0.01,
        "gyro_drift_sigma": 0.002,
        "drift_tau_s": 2.0,
    }
)
IMU_VEHICLE = TUMBLER  # with drag, so the specific force depends on the velocity


def test_imu_random_stream_is_the_documented_per_lane_sequence() -> None:
    """Reference written out from docs/design.md §3 with the documented draw order."""
    rate = 100.0
    imu = ImuBatch(IMU_CFG, IMU_VEHICLE, rate, 1)
    imu.reset(np.array([0]), [np.random.default_rng(5)])
    ref_rng = np.random.default_rng(5)
    cfg = IMU_CFG
    bias0 = np.array(cfg.accel_bias + cfg.gyro_bias) * ref_rng.choice([-1.0, 1.0], size=6)
    drift_sigma = np.array([cfg.accel_drift_sigma] * 3 + [cfg.gyro_drift_sigma] * 3)
    drift = drift_sigma * ref_rng.standard_normal(6)
    sig_a = cfg.accel_noise_density * math.sqrt(rate)
    sig_g = cfg.gyro_noise_density * math.sqrt(rate)
    a = math.exp(-1.0 / (rate * cfg.drift_tau_s))
    rng = np.random.default_rng(6)
    for k in range(40):  # crosses the pre-draw block boundary twice
        vel, rates, thrust = rng.normal(size=3), rng.normal(size=3), rng.uniform(0.0, 20.0)
        accel, gyro = imu.sample(0.01 * k, vel[None], rates[None], np.array([thrust]))
        white = ref_rng.standard_normal(6)
        f_b = -IMU_VEHICLE.drag * vel - np.array([0.0, 0.0, thrust / IMU_VEHICLE.mass])
        np.testing.assert_allclose(accel[0], f_b + (bias0 + drift)[:3] + sig_a * white[:3])
        np.testing.assert_allclose(gyro[0], rates + (bias0 + drift)[3:] + sig_g * white[3:])
        drift = a * drift + math.sqrt(1 - a * a) * drift_sigma * ref_rng.standard_normal(6)
        np.testing.assert_allclose(imu.total_bias[0], bias0 + drift)


def test_imu_batch_lanes_equal_single_imus_and_inactive_lanes_draw_nothing() -> None:
    b = 5
    batch = ImuBatch(IMU_CFG, IMU_VEHICLE, 100.0, b)
    batch.reset(np.arange(b), [np.random.default_rng(10 + i) for i in range(b)])
    singles = [Imu(IMU_CFG, IMU_VEHICLE, 100.0) for _ in range(b)]
    for i, imu in enumerate(singles):
        imu.reset(np.random.default_rng(10 + i))
    rng = np.random.default_rng(7)
    for k in range(50):
        vel, rates = rng.normal(size=(b, 3)), rng.normal(size=(b, 3))
        thrust = rng.uniform(0.0, 20.0, b)
        active = rng.random(b) < 0.7
        if k == 20:  # a lane reset mid-run takes a fresh generator and a fresh stream
            batch.reset(np.array([2]), [np.random.default_rng(99)])
            singles[2].reset(np.random.default_rng(99))
        drift_before = batch.drift.copy()
        accel, gyro = batch.sample(0.01 * k, vel, rates, thrust, active)
        for i, imu in enumerate(singles):
            if active[i]:
                s = imu.sample(0.01 * k, vel[i], rates[i], thrust[i])
                np.testing.assert_array_equal(accel[i], s.accel)
                np.testing.assert_array_equal(gyro[i], s.gyro)
            else:
                np.testing.assert_array_equal(accel[i], 0.0)
                np.testing.assert_array_equal(batch.drift[i], drift_before[i])
            np.testing.assert_array_equal(batch.total_bias[i], imu.total_bias)


def test_imu_lane_used_before_reset_is_an_error() -> None:
    imu = ImuBatch(IMU_CFG, IMU_VEHICLE, 100.0, 2)
    imu.reset(np.array([0]), [np.random.default_rng(0)])
    z = np.zeros((2, 3))
    imu.sample(0.0, z, z, np.zeros(2), np.array([True, False]))
    with pytest.raises(RuntimeError, match=r"lanes \[1\]"):
        imu.sample(0.0, z, z, np.zeros(2))


# ----------------------------------------------------------------------------- LiDAR
def _scene(rng: np.random.Generator, b: int, lmax: int):
    pts = rng.uniform(-20.0, 20.0, (b, lmax, 3))
    pos = rng.normal(size=(b, 3))
    dcm = dcm_from_euler_batch(rng.normal(size=(b, 3)) * 0.4)
    n = rng.integers(0, lmax + 1, b)
    return pos, dcm, pts, n


@pytest.mark.parametrize(("b", "lmax"), [(1, 1), (3, 7), (9, 40)])
def test_lidar_batch_lanes_equal_single_lidars(b: int, lmax: int) -> None:
    cfg = LidarConfig.from_dict({"azimuth_fov_deg": 120.0})
    batch = LidarBatch(cfg, b)
    batch.reset(np.arange(b), [np.random.default_rng(20 + i) for i in range(b)])
    singles = [Lidar(cfg) for _ in range(b)]
    for i, lidar in enumerate(singles):
        lidar.reset(np.random.default_rng(20 + i))
    rng = np.random.default_rng(8)
    seen = 0
    for _ in range(10):
        pos, dcm, pts, n = _scene(rng, b, lmax)
        lanes = np.flatnonzero(rng.random(b) < 0.7)
        visible, meas = batch.scan(pos, dcm, pts, n, lanes)
        for i, lidar in enumerate(singles):
            if i not in lanes:
                assert not visible[i].any() and not meas[i].any()
                continue
            scan = lidar.scan(0.0, pos[i], dcm[i], np.arange(n[i]), pts[i, : n[i]])
            np.testing.assert_array_equal(np.flatnonzero(visible[i]), scan.ids)
            np.testing.assert_array_equal(meas[i][visible[i]], scan.meas)
            assert not meas[i][~visible[i]].any()
            seen += scan.count
    assert seen > 0


def test_lidar_returns_nothing_outside_its_fov_or_beyond_the_landmark_count() -> None:
    cfg = LidarConfig.from_dict(
        {
            "azimuth_fov_deg": 45.0,
            "elevation_fov_deg": 30.0,
            "range_min_m": 2.0,
            "range_max_m": 15.0,
            "sigma_azimuth_deg": 0.0,
            "sigma_elevation_deg": 0.0,
            "sigma_range_m": 0.0,
        }
    )
    b, lmax = 6, 200
    lidar = LidarBatch(cfg, b)
    lidar.reset(np.arange(b), [np.random.default_rng(i) for i in range(b)])
    pos, dcm, pts, n = _scene(np.random.default_rng(9), b, lmax)
    visible, meas = lidar.scan(pos, dcm, pts, n, np.arange(b))
    assert visible.sum() > 10
    for i in range(b):
        assert not visible[i, n[i] :].any()
        m = meas[i][visible[i]]
        assert np.all(np.abs(m[:, 0]) <= math.radians(45.0))
        assert np.all(np.abs(m[:, 1]) <= math.radians(30.0))
        assert np.all((m[:, 2] >= 2.0) & (m[:, 2] <= 15.0))
        # Noise-free: the returned range is the true distance in N.
        dist = np.linalg.norm(pts[i][visible[i]] - pos[i], axis=1)
        np.testing.assert_allclose(m[:, 2], dist, rtol=1e-12)
