"""Layer-1 models checked against independent facts (docs/design.md §2–3, §8).

Rotations: the seed-001 elementary matrices, orthonormality, round trips, finite differences.
Dynamics: hover fixed point, Newton and Euler laws in the inertial frame (finite differences
along RK4 trajectories), conservation of angular momentum and rotational energy without torque,
free fall. The LiDAR model: tests/sim/test_lidar_model.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from reference_math import c1, c2, c3, random_euler, ref_dcm, ref_skew, ref_wrap

from quadslam_env.models.frames import (
    dcm_euler_partials,
    dcm_from_euler,
    dcm_from_euler_batch,
    euler_from_dcm,
    euler_rate_matrix,
    rot1,
    rot2,
    rot3,
    rotation_angle_between,
    skew,
    wrap_angle,
)
from quadslam_env.models.integrators import rk4_integrate, state_derivative
from quadslam_env.models.params import VEHICLE_PRESETS, VehicleParams
from quadslam_env.models.rigid_body import saturate_inputs, specific_force
from quadslam_env.sim.vehicle import Vehicle
from quadslam_env.types import GRAVITY

N3 = np.array([0.0, 0.0, 1.0])
B3 = np.array([0.0, 0.0, 1.0])


def custom_vehicle() -> VehicleParams:
    """A vehicle with a full (non-diagonal) symmetric positive-definite inertia matrix."""
    inertia = np.array([[0.10, 0.01, -0.005], [0.01, 0.08, 0.002], [-0.005, 0.002, 0.15]])
    return VehicleParams(
        name="custom", mass=1.3, inertia=inertia, max_thrust=40.0, max_torque=[1.0, 1.0, 0.5]
    )


def state(pos=(0, 0, 0), vel=(0, 0, 0), euler=(0, 0, 0), rates=(0, 0, 0)) -> np.ndarray:
    return np.concatenate([pos, vel, euler, rates]).astype(float)


# ----------------------------------------------------------------------------- rotations
class TestRotations:
    def test_elementary_matrices_match_seed001(self):
        for angle in (-2.5, -0.3, 0.0, 0.7, 3.0):
            np.testing.assert_allclose(rot1(angle), c1(angle), atol=1e-15)
            np.testing.assert_allclose(rot2(angle), c2(angle), atol=1e-15)
            np.testing.assert_allclose(rot3(angle), c3(angle), atol=1e-15)

    def test_dcm_is_c3_c2_c1(self):
        rng = np.random.default_rng(0)
        for eul in random_euler(rng, 50):
            np.testing.assert_allclose(dcm_from_euler(eul), ref_dcm(eul), atol=1e-14)

    def test_dcm_orthonormal_det_one(self):
        rng = np.random.default_rng(1)
        for eul in random_euler(rng, 50, max_pitch=math.pi):
            dcm = dcm_from_euler(eul)
            np.testing.assert_allclose(dcm.T @ dcm, np.eye(3), atol=1e-14)
            assert np.linalg.det(dcm) == pytest.approx(1.0, abs=1e-14)

    def test_dcm_physical_directions(self):
        # Yaw +90°: the nose (b1) points east (n2).
        np.testing.assert_allclose(
            dcm_from_euler([0, 0, math.pi / 2]) @ [1, 0, 0], [0, 1, 0], atol=1e-15
        )
        # Pitch up by θ: the nose rises, i.e. gets a negative (up) n3 component.
        th = 0.3
        np.testing.assert_allclose(
            dcm_from_euler([0, th, 0]) @ [1, 0, 0], [math.cos(th), 0, -math.sin(th)], atol=1e-15
        )
        # Roll right by φ: the right arm (b2) goes down (positive n3).
        ph = 0.4
        np.testing.assert_allclose(
            dcm_from_euler([ph, 0, 0]) @ [0, 1, 0], [0, math.cos(ph), math.sin(ph)], atol=1e-15
        )

    def test_batch_matches_single(self):
        rng = np.random.default_rng(2)
        eul = random_euler(rng, 24).reshape(4, 6, 3)
        batch = dcm_from_euler_batch(eul)
        assert batch.shape == (4, 6, 3, 3)
        for idx in np.ndindex(4, 6):
            np.testing.assert_allclose(batch[idx], ref_dcm(eul[idx]), atol=1e-14)

    def test_round_trip_euler_dcm_euler(self):
        rng = np.random.default_rng(3)
        for eul in random_euler(rng, 200, max_pitch=1.55):
            back = euler_from_dcm(dcm_from_euler(eul))
            np.testing.assert_allclose(back, eul, atol=1e-9)

    def test_round_trip_dcm_euler_dcm(self):
        # Any rotation (here: from random unit quaternions) is reproduced by its Euler angles.
        rng = np.random.default_rng(4)
        for q in rng.standard_normal((100, 4)):
            w, x, y, z = q / np.linalg.norm(q)
            dcm = np.array(
                [
                    [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                    [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                    [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
                ]
            )
            eul = euler_from_dcm(dcm)
            assert -math.pi <= eul[0] <= math.pi and -math.pi <= eul[2] <= math.pi
            assert abs(eul[1]) <= math.pi / 2
            np.testing.assert_allclose(dcm_from_euler(eul), dcm, atol=1e-9)

    def test_wrap_angle_range_and_equivalence(self):
        rng = np.random.default_rng(5)
        x = np.concatenate([rng.uniform(-50, 50, 2000), [0.0, math.pi, -math.pi, 3 * math.pi]])
        out = np.asarray(wrap_angle(x))
        assert out.shape == x.shape
        assert np.all(out > -math.pi) and np.all(out <= math.pi)
        turns = (x - out) / (2 * math.pi)
        np.testing.assert_allclose(turns, np.round(turns), atol=1e-9)
        np.testing.assert_allclose(out, ref_wrap(x), atol=1e-9)

    @pytest.mark.parametrize(
        ("angle", "expected"),
        [
            (math.pi, math.pi),
            (-math.pi, math.pi),
            (3 * math.pi, math.pi),
            (-3 * math.pi, math.pi),
            (2 * math.pi, 0.0),
            (0.5, 0.5),
            (-0.5, -0.5),
            (2 * math.pi + 0.5, 0.5),
            (-2 * math.pi - 0.5, -0.5),
        ],
    )
    def test_wrap_angle_values_scalar_and_array(self, angle, expected):
        scalar = wrap_angle(angle)
        assert isinstance(scalar, float)
        assert scalar == pytest.approx(expected, abs=1e-12)
        arr = np.asarray(wrap_angle(np.array([angle])))
        assert arr[0] == pytest.approx(expected, abs=1e-12)
        assert -math.pi < scalar <= math.pi and -math.pi < arr[0] <= math.pi

    def test_skew_is_cross_product(self):
        rng = np.random.default_rng(6)
        for a, b in rng.standard_normal((20, 2, 3)):
            np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), atol=1e-14)

    def test_rotation_angle_between(self):
        rng = np.random.default_rng(7)
        for _ in range(20):
            axis = rng.standard_normal(3)
            axis /= np.linalg.norm(axis)
            angle = rng.uniform(0, math.pi)
            k = ref_skew(axis)
            rot = np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * k @ k  # Rodrigues
            base = ref_dcm(random_euler(rng, 1)[0])
            assert rotation_angle_between(base, base @ rot) == pytest.approx(angle, abs=1e-7)

    def test_dcm_euler_partials_vs_finite_differences(self):
        rng = np.random.default_rng(8)
        h = 1e-6
        for eul in random_euler(rng, 20):
            partials = dcm_euler_partials(eul)
            assert partials.shape == (3, 3, 3)
            for i in range(3):
                d = np.zeros(3)
                d[i] = h
                fd = (ref_dcm(eul + d) - ref_dcm(eul - d)) / (2 * h)
                np.testing.assert_allclose(partials[i], fd, atol=1e-9)

    def test_euler_rate_matrix_inverts_body_rate_map(self):
        # Textbook 3-2-1 map ω = E(Λ) Λ̇; D(Λ) must be its inverse.
        rng = np.random.default_rng(9)
        for phi, theta, _psi in random_euler(rng, 20):
            e = np.array(
                [
                    [1.0, 0.0, -math.sin(theta)],
                    [0.0, math.cos(phi), math.sin(phi) * math.cos(theta)],
                    [0.0, -math.sin(phi), math.cos(phi) * math.cos(theta)],
                ]
            )
            np.testing.assert_allclose(
                euler_rate_matrix([phi, theta, 0.0]) @ e, np.eye(3), atol=1e-12
            )


# ----------------------------------------------------------------------------- dynamics
@pytest.mark.parametrize("preset", sorted(VEHICLE_PRESETS))
def test_hover_is_fixed_point(preset):
    params = VEHICLE_PRESETS[preset]
    x0 = state(pos=(1.0, -2.0, -3.0), euler=(0.0, 0.0, 0.7))
    thrust = params.mass * GRAVITY
    deriv = state_derivative(x0, thrust, np.zeros(3), params)
    np.testing.assert_allclose(deriv, np.zeros(12), atol=1e-12)
    x1 = rk4_integrate(x0, thrust, np.zeros(3), params, duration=1.0, substep=0.002)
    np.testing.assert_allclose(x1, x0, atol=1e-10)


def test_specific_force_in_hover():
    for params in VEHICLE_PRESETS.values():
        f = specific_force(np.zeros(3), params.mass * GRAVITY, params)
        np.testing.assert_allclose(f, [0.0, 0.0, -GRAVITY], atol=1e-12)


def test_euler_kinematics_vs_dcm_finite_difference():
    """Λ̇ from the model must satisfy d/dt C_NB(Λ(t)) = C_NB skew(ω) (Poisson's equation)."""
    params = custom_vehicle()
    rng = np.random.default_rng(10)
    h = 1e-6
    for eul in random_euler(rng, 30, max_pitch=1.3):
        rates = rng.uniform(-3, 3, 3)
        x = state(vel=rng.standard_normal(3), euler=eul, rates=rates)
        eul_dot = state_derivative(x, 5.0, rng.standard_normal(3) * 0.1, params)[6:9]
        fd = (ref_dcm(eul + h * eul_dot) - ref_dcm(eul - h * eul_dot)) / (2 * h)
        np.testing.assert_allclose(fd, ref_dcm(eul) @ ref_skew(rates), atol=1e-8)


def test_position_derivative_is_inertial_velocity():
    params = custom_vehicle()
    rng = np.random.default_rng(11)
    for eul in random_euler(rng, 20):
        vel = rng.standard_normal(3)
        x = state(pos=rng.standard_normal(3), vel=vel, euler=eul, rates=rng.standard_normal(3))
        np.testing.assert_allclose(
            state_derivative(x, 7.0, np.zeros(3), params)[0:3], ref_dcm(eul) @ vel, atol=1e-12
        )


def _trajectory(x0, thrust, torque, params, times, substep=1e-3):
    """States at ``times`` (increasing) by chained rk4_integrate calls."""
    out, x, t_prev = [], np.array(x0, dtype=float), 0.0
    for t in times:
        if t > t_prev:
            x = rk4_integrate(x, thrust, torque, params, t - t_prev, substep)
        out.append(x.copy())
        t_prev = t
    return np.array(out)


def test_newton_and_euler_laws_in_inertial_frame():
    """Along an RK4 trajectory with constant inputs:
    d/dt(C v) = g n3 − (f/m) C b3  and  d/dt(C J ω) = C τ  (finite differences in time)."""
    params = custom_vehicle()
    thrust, torque = 9.0, np.array([0.05, -0.03, 0.02])
    x0 = state(vel=(1.0, -0.5, 0.3), euler=(0.2, -0.1, 0.5), rates=(0.8, -0.6, 1.5))
    h = 1e-4
    for t in (0.3, 0.9, 1.6):
        xm, x, xp = _trajectory(x0, thrust, torque, params, [t - h, t, t + h])

        def vel_n(s):
            return ref_dcm(s[6:9]) @ s[3:6]

        def mom_n(s):
            return ref_dcm(s[6:9]) @ params.inertia @ s[9:12]

        acc_fd = (vel_n(xp) - vel_n(xm)) / (2 * h)
        np.testing.assert_allclose(
            acc_fd, GRAVITY * N3 - thrust / params.mass * ref_dcm(x[6:9]) @ B3, atol=1e-6
        )
        mdot_fd = (mom_n(xp) - mom_n(xm)) / (2 * h)
        np.testing.assert_allclose(mdot_fd, ref_dcm(x[6:9]) @ torque, atol=1e-7)


@pytest.mark.parametrize("params", [custom_vehicle(), VEHICLE_PRESETS["rauniyar2023"]])
def test_torque_free_tumbling_conserves_momentum_and_energy(params):
    x0 = state(euler=(0.2, -0.1, 0.5), rates=(0.8, -0.6, 3.0))
    times = np.linspace(0.0, 4.0, 17)
    traj = _trajectory(x0, 0.0, np.zeros(3), params, times, substep=1e-3)
    assert np.max(np.abs(traj[:, 7])) < 1.2  # stays clear of the Euler singularity
    assert np.ptp(traj[:, 9:12], axis=0).max() > 0.1  # really tumbling (body rates change)
    j = params.inertia
    mom = np.array([ref_dcm(s[6:9]) @ j @ s[9:12] for s in traj])
    energy = np.array([0.5 * s[9:12] @ j @ s[9:12] for s in traj])
    rel_mom = np.linalg.norm(mom - mom[0], axis=1) / np.linalg.norm(mom[0])
    assert rel_mom.max() < 1e-6
    assert np.max(np.abs(energy - energy[0])) / energy[0] < 1e-6


def test_free_fall_level():
    params = VEHICLE_PRESETS["rauniyar2023"]
    x0 = state(pos=(0.0, 0.0, -10.0))
    for t in (0.5, 1.0, 2.0):
        x = rk4_integrate(x0, 0.0, np.zeros(3), params, t, 0.002)
        assert x[2] == pytest.approx(-10.0 + 0.5 * GRAVITY * t * t, abs=1e-9)
        np.testing.assert_allclose(x[0:2], 0.0, atol=1e-12)
        np.testing.assert_allclose(x[6:12], 0.0, atol=1e-12)


def test_free_fall_while_tumbling_is_a_parabola():
    """With zero thrust, ρ̈ = g n3 whatever the attitude motion: ρ(t) = ρ0 + C0 v0 t + ½ g n3 t²."""
    params = custom_vehicle()
    x0 = state(pos=(1.0, 2.0, -3.0), vel=(1.0, -0.5, 0.3), euler=(0.2, -0.1, 0.5))
    x0[9:12] = (0.8, -0.6, 3.0)
    v0_n = ref_dcm(x0[6:9]) @ x0[3:6]
    times = np.linspace(0.25, 2.0, 8)
    traj = _trajectory(x0, 0.0, np.zeros(3), params, times, substep=1e-3)
    for t, x in zip(times, traj, strict=True):
        expected = x0[0:3] + v0_n * t + 0.5 * GRAVITY * N3 * t * t
        np.testing.assert_allclose(x[0:3], expected, atol=1e-8)


def test_saturate_inputs():
    params = VEHICLE_PRESETS["rauniyar2023"]
    f, tau = saturate_inputs(-3.0, [10.0, -10.0, 0.1], params)
    assert f == 0.0
    np.testing.assert_array_equal(tau, [params.max_torque[0], -params.max_torque[1], 0.1])
    f, tau = saturate_inputs(1e6, [0.0, 0.0, -1e6], params)
    assert f == params.max_thrust
    np.testing.assert_array_equal(tau, [0.0, 0.0, -params.max_torque[2]])
    f, _ = saturate_inputs(10.0, np.zeros(3), params)
    assert f == 10.0


def test_vehicle_saturates_thrust():
    """A huge thrust command climbs at exactly (f_max/m − g) when level, no more."""
    params = VEHICLE_PRESETS["rauniyar2023"]
    veh = Vehicle(params, 0.002)
    veh.reset(np.zeros(12))
    t = 0.0
    for _ in range(10):
        veh.step(1e6, np.zeros(3), 0.01)
        t += 0.01
    acc = params.max_thrust / params.mass - GRAVITY
    assert veh.state[2] == pytest.approx(-0.5 * acc * t * t, rel=1e-9)
    assert veh.applied_thrust == params.max_thrust


def test_vehicle_saturates_torque_and_reports_mean_rates():
    """Constant yaw torque from rest on a diagonal-J vehicle: r(t) = τ t / J33 (linear),
    so the period-mean rate is τ T / (2 J33); the torque is clipped to max_torque first."""
    params = VEHICLE_PRESETS["rauniyar2023"]
    veh = Vehicle(params, 0.002)
    veh.reset(np.zeros(12))
    mean_rates = veh.step(0.0, np.array([0.0, 0.0, 50.0]), 0.1)
    tau = params.max_torque[2]
    j33 = params.inertia[2, 2]
    assert veh.state[11] == pytest.approx(tau * 0.1 / j33, rel=1e-9)
    np.testing.assert_allclose(mean_rates, [0.0, 0.0, tau * 0.1 / (2 * j33)], rtol=1e-9)


def test_actuator_lag_is_exact_first_order():
    params = VehicleParams(
        name="lag",
        mass=1.0,
        inertia=np.diag([0.01, 0.01, 0.02]),
        max_thrust=30.0,
        max_torque=[1.0, 1.0, 1.0],
        actuator_tau=0.05,
    )
    veh = Vehicle(params, 0.002)
    veh.reset(np.zeros(12))
    f0 = params.hover_thrust
    veh.step(20.0, np.zeros(3), 0.03)
    assert veh.applied_thrust == pytest.approx(20.0 + (f0 - 20.0) * math.exp(-0.03 / 0.05))
