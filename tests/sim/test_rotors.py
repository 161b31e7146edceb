"""Rotors (quadslam_env.models.rotors): the mixer and its inverse, the motor lag, the limits,
the torque around hover, the Crazyflie 2.0 preset and the bench's rotor vehicle flown by
DF-LQR on the oracle, and the vector env's lanes."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.lab.bench.envs import VECTOR_SCENARIOS
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.params import vehicle_preset
from quadslam_env.models.rotors import (
    CRAZYFLIE2_ROTORS,
    LAYOUTS,
    RotorParams,
    allocate_lanes,
    mixer_inverse,
    mixer_matrix,
)
from quadslam_env.schema import ConfigError
from quadslam_env.sim.vehicle import VehicleBatch
from quadslam_env.types import GRAVITY


@pytest.mark.parametrize("layout", LAYOUTS)
def test_mixer_times_its_inverse_is_the_identity_on_random_inputs(layout: str) -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        arm, k_f, k_m = rng.uniform(0.02, 0.5), rng.uniform(1e-9, 1e-5), rng.uniform(1e-11, 1e-6)
        m = mixer_matrix(layout, arm, k_f, k_m)
        inv = mixer_inverse(m)
        np.testing.assert_allclose(m @ inv, np.eye(4), rtol=0, atol=1e-12)
        np.testing.assert_allclose(inv @ m, np.eye(4), rtol=0, atol=1e-12)
        thrusts = rng.uniform(0.0, 5.0, 4)
        np.testing.assert_allclose(inv @ (m @ thrusts), thrusts, rtol=0, atol=1e-12)


def test_one_rotor_pushed_gives_the_hand_derived_wrench() -> None:
    arm, k_f, k_m, t = 0.1, 2e-8, 5e-10, 0.3
    c, a = k_m / k_f, arm / math.sqrt(2.0)
    # FRD: rotor 1 of x is front-right (x = y = a), counter-clockwise seen from above: lifting
    # the right side rolls left (τ_x < 0), lifting the front pitches up (τ_y > 0), and its drag
    # reaction yaws the body clockwise seen from above (τ_z > 0, ψ grows in NED).
    w = mixer_matrix("x", arm, k_f, k_m) @ np.array([t, 0.0, 0.0, 0.0])
    np.testing.assert_allclose(w, [t, -a * t, a * t, c * t], rtol=1e-15)
    # plus: rotor 2 is on the right arm (y = L), clockwise: roll left, no pitch, yaw left.
    w = mixer_matrix("plus", arm, k_f, k_m) @ np.array([0.0, t, 0.0, 0.0])
    np.testing.assert_allclose(w, [t, -arm * t, 0.0, -c * t], rtol=1e-15, atol=1e-18)
    # rotor 4 of x: front-left (x = a, y = -a), clockwise: roll right, pitch up, yaw left.
    w = mixer_matrix("x", arm, k_f, k_m) @ np.array([0.0, 0.0, 0.0, t])
    np.testing.assert_allclose(w, [t, a * t, a * t, -c * t], rtol=1e-15)


def test_inverse_mixer_keeps_the_torques_and_gives_up_thrust_at_the_limits() -> None:
    r = CRAZYFLIE2_ROTORS
    t_min, t_max = r.thrust_min, r.thrust_max
    tau_x = 0.5 * r.max_torque[0]
    # A feasible wrench comes back exactly.
    thrust, torque = np.array([0.3]), np.array([[tau_x, -0.001, 0.0005]])
    out = np.empty((1, 4))
    allocate_lanes(thrust, torque, np.array(r.mixer_inv), t_min, t_max, out)
    np.testing.assert_allclose(r.mixer @ out[0], [0.3, tau_x, -0.001, 0.0005], rtol=1e-12)
    # Zero thrust with a roll torque needs negative thrusts: the collective thrust rises, the
    # torques stay, every rotor is inside its limits and one sits on the lower one.
    allocate_lanes(np.array([0.0]), np.array([[tau_x, 0.0, 0.0]]), np.array(r.mixer_inv),
                   t_min, t_max, out)  # fmt: skip
    w = r.mixer @ out[0]
    np.testing.assert_allclose(w[1:], [tau_x, 0.0, 0.0], atol=1e-15)
    assert w[0] > 0.0 and out.min() == pytest.approx(t_min, abs=1e-15)
    assert out.max() <= t_max
    # Full thrust with the same torque: the collective thrust drops, the torque stays.
    allocate_lanes(np.array([4.0 * t_max]), np.array([[tau_x, 0.0, 0.0]]),
                   np.array(r.mixer_inv), t_min, t_max, out)  # fmt: skip
    w = r.mixer @ out[0]
    np.testing.assert_allclose(w[1:], [tau_x, 0.0, 0.0], atol=1e-15)
    assert out.max() == pytest.approx(t_max, rel=1e-15) and w[0] < 4.0 * t_max
    # A torque beyond the rotors' range: clipped to the limits.
    allocate_lanes(np.array([0.3]), np.array([[10.0, 0.0, 0.0]]), np.array(r.mixer_inv),
                   t_min, t_max, out)  # fmt: skip
    assert out.min() >= t_min and out.max() <= t_max


def test_inverse_mixer_gives_up_yaw_before_thrust_roll_and_pitch() -> None:
    r = CRAZYFLIE2_ROTORS
    t_min, t_max = r.thrust_min, r.thrust_max
    c = r.k_m / r.k_f  # yaw torque per newton of thrust difference (m)
    out = np.empty((1, 4))
    # Hover thrust with a yaw demand far beyond what the rotors can give: each rotor starts at
    # f/4 and the yaw part moves them by ±τ_z/(4c), so the largest yaw torque that keeps all
    # four inside the limits is 4c·min(T_max − f/4, f/4 − T_min); thrust, roll and pitch stay.
    f = 2.0 * r.thrust_min + 2.0 * r.thrust_max - 0.3 * (r.thrust_max - r.thrust_min)
    for sign in (1.0, -1.0):
        allocate_lanes(np.array([f]), np.array([[0.0, 0.0, sign * 1.0]]),
                       np.array(r.mixer_inv), t_min, t_max, out)  # fmt: skip
        w = r.mixer @ out[0]
        yaw_max = 4.0 * c * min(t_max - f / 4.0, f / 4.0 - t_min)
        np.testing.assert_allclose(w[:3], [f, 0.0, 0.0], atol=1e-12)
        assert w[3] == pytest.approx(sign * yaw_max, rel=1e-9)
        assert out.min() >= t_min and out.max() <= t_max
    # With a roll torque that fits, the roll torque and the thrust are kept and the yaw shrinks
    # to the first rotor that reaches a limit (checked against a fine scan of the share kept).
    tau_x = 0.3 * r.max_torque[0]
    allocate_lanes(np.array([f]), np.array([[tau_x, 0.0, 1.0]]), np.array(r.mixer_inv),
                   t_min, t_max, out)  # fmt: skip
    w = r.mixer @ out[0]
    np.testing.assert_allclose(w[:3], [f, tau_x, 0.0], atol=1e-12)
    shares = np.linspace(0.0, 1.0, 200_001)
    thrusts = np.array(r.mixer_inv) @ np.array([f, tau_x, 0.0, 0.0])
    yaw_col = np.array(r.mixer_inv)[:, 3]
    inside = np.all(
        (thrusts[None] + shares[:, None] * yaw_col[None] >= t_min - 1e-15)
        & (thrusts[None] + shares[:, None] * yaw_col[None] <= t_max + 1e-15),
        axis=1,
    )
    best = shares[inside].max()
    assert w[3] > 0.0 and w[3] == pytest.approx(best, abs=1e-5)


@pytest.mark.parametrize("tau", [0.015, 0.05])
def test_rotor_speed_step_response_is_first_order(tau: float) -> None:
    rotors = RotorParams("x", 0.046, CRAZYFLIE2_ROTORS.k_f, CRAZYFLIE2_ROTORS.k_m, tau, 0.0,
                         CRAZYFLIE2_ROTORS.omega_max)  # fmt: skip
    from quadslam_env.models.params import rotor_vehicle

    params = rotor_vehicle("cf", 0.027, np.diag([1.4e-5, 1.4e-5, 2.2e-5]), rotors)
    vehicle = VehicleBatch(params, 0.002, 2)
    vehicle.reset([0, 1], np.zeros((2, 12)))
    vehicle.rotor_speed[:] = 0.0  # motors at rest, then a hover command from t = 0
    omega_cmd = rotors.hover_speed(params.hover_thrust)
    dt = 0.01
    for k in range(1, 31):
        vehicle.step(np.full(2, params.hover_thrust), np.zeros((2, 3)), dt)
        want = omega_cmd * (1.0 - math.exp(-k * dt / tau))
        np.testing.assert_allclose(vehicle.rotor_speed, want, rtol=1e-12)


def test_thrust_to_weight_below_one_is_a_config_error() -> None:
    # ω_max at which 4 k_f ω² = m g exactly: not above the weight.
    w_hover = CRAZYFLIE2_ROTORS.hover_speed(0.027 * GRAVITY)
    with pytest.raises(ConfigError, match=r"vehicle\.rotor_omega_max_rad_s.*thrust-to-weight"):
        load_scenario("crazyflie_hover", {"vehicle": {"rotor_omega_max_rad_s": w_hover}})
    with pytest.raises(ConfigError, match=r"vehicle\.rotor_omega_max_rad_s.*thrust-to-weight"):
        load_scenario("crazyflie_hover", {"vehicle": {"mass_kg": 0.07}})
    load_scenario("crazyflie_hover", {"vehicle": {"rotor_omega_max_rad_s": 1.01 * w_hover}})


@pytest.mark.parametrize(
    ("vehicle", "fragment"),
    [
        ({"rotor_k_f": -1e-8}, r"vehicle\.rotor_k_f: got -1e-08"),
        ({"rotor_k_m": float("nan")}, r"vehicle\.rotor_k_m: got nan"),
        ({"rotor_arm_m": 0.0}, r"vehicle\.rotor_arm_m: got 0\.0"),
        ({"rotor_motor_tau_s": -0.01}, r"vehicle\.rotor_motor_tau_s"),
        ({"rotor_omega_max_rad_s": float("inf")}, r"vehicle\.rotor_omega_max_rad_s: got inf"),
        ({"rotor_layout": "hexa"}, r"vehicle\.rotor_layout: got 'hexa'.*'x', 'plus'"),
        ({"rotor_omega_min_rad_s": 3000.0}, r"vehicle\.rotor_omega_max_rad_s.*> vehicle"),
        ({"max_thrust_n": 1.0}, r"vehicle\.max_thrust_n: got 1\.0 on a vehicle with rotors"),
        ({"actuator_tau_s": 0.02}, r"vehicle\.actuator_tau_s: got 0\.02 on a vehicle with"),
    ],
)
def test_bad_rotor_settings_name_the_key_and_the_value(vehicle: dict, fragment: str) -> None:
    with pytest.raises(ConfigError, match=fragment):
        load_scenario("crazyflie_hover", {"vehicle": vehicle})


def test_rotor_settings_on_a_vehicle_without_rotors() -> None:
    with pytest.raises(ConfigError, match=r"action\.mode: got 'rotor_thrust'.*without rotors"):
        load_scenario("hover", {"action": {"mode": "rotor_thrust"}})
    with pytest.raises(ConfigError, match=r"vehicle\.rotor_k_f: got 1e-06 on a vehicle without"):
        load_scenario("hover", {"vehicle": {"rotor_k_f": 1e-6}})
    with pytest.raises(ConfigError, match=r"vehicle\.rotor_arm_m: got null"):
        load_scenario("hover", {"vehicle": {"rotor_layout": "plus"}})
    # A plus vehicle built on the paper's preset from its settings alone.
    cfg = load_scenario(
        "hover",
        {"vehicle": {"rotor_layout": "plus", "rotor_arm_m": 0.25, "rotor_k_f": 1e-5,
                     "rotor_k_m": 2e-7, "rotor_omega_max_rad_s": 1000.0}},
    )  # fmt: skip
    params = cfg.vehicle.params()
    assert params.rotors is not None and params.max_thrust == pytest.approx(40.0)
    # Off by default: the paper's presets have no rotors, the Crazyflie has.
    assert load_scenario("hover").vehicle.params().rotors is None
    assert vehicle_preset("crazyflie2").rotors is CRAZYFLIE2_ROTORS


def _fly(env: gym.Env, seed: int) -> np.ndarray:
    infos, terminated = fly_dflqr(env, seed)
    assert not terminated
    return np.array([info["track_pos_err_m"] for info in infos])


def test_dflqr_hovers_the_crazyflie_through_the_inverse_mixer() -> None:
    # Started 0.17 m off the set point, the paper's slow LQR weights bring it in within
    # ~8 s (observed with seed 0: 0.094 m at 3 s, 0.037 m at 5 s, at most 0.005 m after 8 s).
    env = gym.make(
        "QuadSLAM-v0",
        scenario="crazyflie_hover",
        episode={"duration_s": 12.0, "initial_position": [0.1, -0.1, -0.4]},
    )
    errors = _fly(env, 0)
    assert errors[0] > 0.17
    assert errors[800:].max() < 0.01


def test_dflqr_tracks_the_small_figure8_on_the_crazyflie() -> None:
    # Observed with seed 0: RMSE 0.021 m, max 0.029 m over the 20 s (two laps).
    errors = _fly(gym.make("QuadSLAM-v0", scenario="crazyflie_figure8"), 0)
    assert math.sqrt(np.mean(errors**2)) < 0.035
    assert errors.max() < 0.05


def _random_rotor_actions(lanes: int, steps: int) -> np.ndarray:
    env = gym.make("QuadSLAM-v0", **ROTOR_CASE)
    hover = env.unwrapped.hover_action
    rng = np.random.default_rng(5)
    return (hover + 0.1 * rng.standard_normal((steps, lanes, 4))).astype(np.float32)


ROTOR_CASE = {
    "scenario": "crazyflie_figure8",
    "action": {"mode": "rotor_thrust"},
    "episode": {"duration_s": 0.4},
}


def test_vector_lanes_equal_the_scalar_env_with_rotor_actions() -> None:
    lanes, steps, seed = 3, 60, 11
    acts = _random_rotor_actions(lanes, steps)
    vec = gym.make_vec("QuadSLAM-v0", num_envs=lanes, vectorization_mode="vector_entry_point",
                       **ROTOR_CASE)  # fmt: skip
    obs, _ = vec.reset(seed=seed)
    got = [obs]
    for a in acts:
        got.append(vec.step(a)[0])
    vec.close()
    for lane in range(lanes):
        env = gym.make("QuadSLAM-v0", **ROTOR_CASE)
        obs, _ = env.reset(seed=seed + lane)
        np.testing.assert_array_equal(got[0][lane], obs)
        done, resets = False, 0
        for k, a in enumerate(acts, start=1):
            if done:  # the vector env resets an ended lane on the next step (action unused)
                obs, _ = env.reset()
                done, resets = False, resets + 1
            else:
                obs, _, term, trunc, _ = env.step(a[lane])
                done = term or trunc
            np.testing.assert_array_equal(got[k][lane], obs, err_msg=f"lane {lane} step {k}")
        assert resets >= 1  # compared through an autoreset


def test_same_seed_same_rollout_and_rotor_action_equals_its_wrench() -> None:
    acts = _random_rotor_actions(1, 30)[:, 0]

    def rollout(**kwargs: object) -> list[np.ndarray]:
        env = gym.make("QuadSLAM-v0", **{**ROTOR_CASE, **kwargs})
        env.reset(seed=3)
        states = []
        for a in acts:
            env.step(a)
            states.append(env.unwrapped._core.vehicle.state[0].copy())
        return states

    first, second = rollout(), rollout()
    for x, y in zip(first, second, strict=True):
        np.testing.assert_array_equal(x, y)
    # The same rotor thrusts commanded as thrust and torque go through the inverse mixer back
    # to the same rotors: the same flight to round-off.
    r, vp = CRAZYFLIE2_ROTORS, vehicle_preset("crazyflie2")
    wrench = (0.5 * (acts.astype(float) + 1.0) * r.thrust_max) @ r.mixer.T
    tt = np.column_stack([2.0 * wrench[:, 0] / vp.max_thrust - 1.0, wrench[:, 1:] / vp.max_torque])
    assert np.abs(tt).max() <= 1.0
    env = gym.make("QuadSLAM-v0", **{**ROTOR_CASE, "action": {"mode": "thrust_torque"}})
    env.reset(seed=3)
    for a, want in zip(tt, first, strict=True):
        env.step(a)
        np.testing.assert_allclose(env.unwrapped._core.vehicle.state[0], want, atol=1e-9)


def _bench_rotor_vehicle() -> dict[str, object]:
    """The vehicle section of the bench's full-physics case: the paper vehicle on rotors."""
    kwargs = next(kw for label, _, kw in VECTOR_SCENARIOS if label == "ekf_rotors_wind_randomized")
    return {"preset": "rauniyar2023", **kwargs["vehicle"]}


def test_hover_torque_is_what_the_inverse_mixer_gives_at_hover_thrust() -> None:
    params = load_scenario("hover", {"vehicle": _bench_rotor_vehicle()}).vehicle.params()
    r = params.rotors
    assert r is not None
    t_h = params.hover_thrust / 4.0
    step = min(r.thrust_max - t_h, t_h - r.thrust_min)
    # x layout: all four rotors at L/√2 from both body axes, drag arm c = k_m/k_f for yaw.
    expected = np.array([4.0 * r.arm / math.sqrt(2.0), 4.0 * r.arm / math.sqrt(2.0), 0.0])
    expected[2] = 4.0 * (r.k_m / r.k_f) * step
    expected[:2] *= step
    np.testing.assert_allclose(params.hover_torque, expected, rtol=1e-12)
    assert params.hover_torque[2] < 0.85 * params.max_torque[2]  # 0.240 vs 0.300 N·m
    # The inverse mixer, asked for ten times the yaw torque at hover thrust, gives exactly it.
    out = np.empty((1, 4))
    allocate_lanes(np.array([params.hover_thrust]), np.array([[0.0, 0.0, 10.0 * expected[2]]]),
                   np.array(r.mixer_inv), r.thrust_min, r.thrust_max, out)  # fmt: skip
    np.testing.assert_allclose(r.mixer @ out[0], [params.hover_thrust, 0, 0, expected[2]],
                               rtol=1e-9, atol=1e-12)  # fmt: skip


def test_dflqr_turns_the_rotor_paper_vehicle_through_a_large_heading_error() -> None:
    # The bench's rotor vehicle has 1.4 rad/s² of yaw acceleration around hover (against 5.8
    # without rotors). Started 120° off the held heading, DF-LQR on the oracle must turn it
    # round and keep the point: with the yaw loop tuned for 10 rad/s the yaw torque sat at a
    # limit on 99 % of the steps and the heading swung by ±1.5 rad for the whole 10 s (seed 0).
    # Observed with seed 0 now: |ψ̃| 0.005 rad at 4 s, < 0.001 rad from 7 s; position error at
    # most 0.12 m, 0.10 m after 6 s.
    env = gym.make(
        "QuadSLAM-v0",
        scenario="hover",
        vehicle=_bench_rotor_vehicle(),
        estimator={"name": "oracle"},
        episode={"duration_s": 10.0, "initial_euler_deg": [0.0, 0.0, 120.0]},
    )
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=0)
    yaw_err, at_limit, pos_err = [], [], []
    for _ in range(1000):
        action = policy.predict(obs)[0]
        obs, _, terminated, _, info = env.step(action)
        assert not terminated
        yaw_err.append(abs(float(obs[8])))  # ψ̂ − ψ_d, the truth on the oracle
        at_limit.append(abs(float(action[3])) > 0.999)
        pos_err.append(info["track_pos_err_m"])
    assert yaw_err[0] > 2.0
    assert max(yaw_err[600:]) < 0.02
    assert np.mean(at_limit[600:]) < 0.05
    assert max(pos_err[600:]) < 0.15 and max(pos_err) < 0.2
