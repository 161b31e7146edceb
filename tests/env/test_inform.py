"""Telling the estimator what the world drew: ``randomize.inform_estimator`` and
``wind.inform_estimator`` (docs/physics.md "Domain randomisation", "Wind").

Independent facts: an informed FastSLAM lane models the truth's own mass and inertia (the
simulator's per-lane bodies and the ``rand_*`` of ``info``), lane by lane, through partial
resets; the scalar env equals every vector lane with both settings on; an estimator whose model
uses no vehicle (EKF-SLAM) flies bit for bit as uninformed; in a known wind the model's drag is
``drag · C_NBᵀ w`` (Newton's second law on a body at rest); with a mass 1.3 times the nominal or
a 3 m/s wind, the informed filter's velocity error is smaller on every one of a fixed list of
seeds; the settings are refused where they cannot be honoured.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import lane_cases as tve
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from estimators.fastslam.process import DynamicsModel
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.schema import ConfigError
from quadslam_env.sim.randomize import scaled_vehicle
from quadslam_env.types import GRAVITY, VEL

RANGES = {
    "mass_scale": [0.7, 1.3],
    "inertia_scale": [0.6, 1.5],
    "thrust_scale": [0.9, 1.2],
    "lag_scale": [0.5, 2.0],
}
FAST = {"episode": {"duration_s": 0.3}, "estimator": {"params": {"n_particles": 30}}}
DRAG = {"drag_per_s": 0.3, "actuator_tau_s": 0.03}


def _vec(num_envs: int, **kwargs: object) -> gym.vector.VectorEnv:
    return gym.make_vec(
        "QuadSLAM-FastSLAM-v0",
        num_envs=num_envs,
        vectorization_mode="vector_entry_point",
        **{**FAST, **kwargs},
    )


def _assert_lanes_model_their_truth(core, lanes: list[int], info: dict, rows: list[int]) -> None:
    """Lane ``lanes[j]``'s filter model has the truth's mass and inertia and the vehicle of
    ``info`` row ``rows[j]``'s draw."""
    nominal = core.vehicle_params
    for lane, row in zip(lanes, rows, strict=True):
        est = core.estimator.lanes[lane]
        mass_scale, inertia_scale = info["rand_mass_scale"][row], info["rand_inertia_scale"][row]
        thrust_scale, lag_scale = info["rand_thrust_scale"][row], info["rand_lag_scale"][row]
        assert est.model.mass == pytest.approx(mass_scale * nominal.mass, rel=1e-12)
        assert est.model.mass == pytest.approx(core.vehicle.lane_mass[lane], rel=1e-12)
        np.testing.assert_allclose(est.model.inertia, core.vehicle.lane_inertia[lane], rtol=1e-12)
        np.testing.assert_allclose(est.model.inertia, inertia_scale * nominal.inertia, rtol=1e-12)
        # The inertia identification starts from the drawn inertia, not the nominal one.
        np.testing.assert_allclose(
            est.inertia_id.theta0, 1.0 / np.diag(core.vehicle.lane_inertia[lane]), rtol=1e-12
        )
        assert est.vehicle.max_thrust == pytest.approx(thrust_scale * nominal.max_thrust)
        assert est.vehicle.actuator_tau == pytest.approx(lag_scale * nominal.actuator_tau)


def test_informed_lanes_model_their_own_draw_through_partial_resets() -> None:
    vec = _vec(3, randomize={**RANGES, "inform_estimator": True}, vehicle=DRAG)
    _, info = vec.reset(seed=11)
    core = vec.unwrapped.core
    masses = core.vehicle.lane_mass
    assert len(set(masses.tolist())) == 3  # three different draws
    _assert_lanes_model_their_truth(core, [0, 1, 2], info, [0, 1, 2])
    before = [core.estimator.lanes[i].model.mass for i in range(3)]
    # A new episode in lane 1 only: its model follows its new draw, the others keep theirs.
    _, info1 = core.reset_lanes([1], vec.unwrapped.lane_rngs([1]))
    assert core.vehicle.lane_mass[1] != masses[1]
    _assert_lanes_model_their_truth(core, [1], info1, [0])
    assert [core.estimator.lanes[i].model.mass for i in (0, 2)] == [before[0], before[2]]
    # Uninformed, every lane keeps the nominal model whatever the draw.
    off = _vec(3, randomize=RANGES, vehicle=DRAG)
    off.reset(seed=11)
    ocore = off.unwrapped.core
    assert not np.allclose(ocore.vehicle.lane_mass, ocore.vehicle_params.mass)
    for est in ocore.estimator.lanes:
        assert est.model.mass == ocore.vehicle_params.mass
        np.testing.assert_array_equal(est.model.inertia, ocore.vehicle_params.inertia)


def test_a_pinned_then_nominal_episode_gives_the_nominal_model_back() -> None:
    env = gym.make("QuadSLAM-FastSLAM-v0", **FAST, randomize={"inform_estimator": True})
    env.reset(seed=0, options={"randomized": {"mass_scale": 1.3}})
    core = env.unwrapped.core
    est = core.estimator.lanes[0]
    assert est.model.mass == pytest.approx(1.3 * core.vehicle_params.mass)
    env.reset(seed=0)
    assert core.estimator.lanes[0].model.mass == core.vehicle_params.mass


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP])
def test_scalar_env_equals_every_vector_lane_with_both_settings_on(monkeypatch, mode) -> None:
    case = {
        **tve.FAST_FASTSLAM,
        "randomize": {**RANGES, "wind_scale": [0.5, 1.5], "inform_estimator": True},
        "wind": {
            "steady_mps": [2.0, 1.0, 0.0],
            "turbulence": "dryden",
            "w20_mps": 3.0,
            "inform_estimator": True,
        },
        "vehicle": DRAG,
    }
    monkeypatch.setitem(tve.CASES, "QuadSLAM-FastSLAM-v0-informed", case)
    tve.assert_lanes_equal_scalar_rollouts("QuadSLAM-FastSLAM-v0-informed", mode)


def _ekf_rollout(inform: bool) -> list:
    env = gym.make(
        "QuadSLAM-EKF-v0",
        episode={"duration_s": 0.3},
        randomize={**RANGES, "inform_estimator": inform},
        vehicle=DRAG,
    )
    obs, info = env.reset(seed=5)
    out = [obs, info["est_pos_err_m"]]
    hover = env.unwrapped.hover_action
    for _ in range(25):
        obs, reward, _, _, info = env.step(hover)
        out += [obs, reward, info["est_pos_err_m"]]
    return out


def test_an_estimator_without_a_vehicle_model_is_unchanged_bit_for_bit() -> None:
    """EKF-SLAM is driven by the IMU: there is nothing to tell it, and informing it is a no-op."""
    for a, b in zip(_ekf_rollout(False), _ekf_rollout(True), strict=True):
        np.testing.assert_array_equal(a, b)


def test_the_models_drag_in_a_known_wind_is_newtons_second_law() -> None:
    """A level body at rest with the hover thrust in a wind w: ``v̇ = drag · w`` (C_NB = I)."""
    vehicle = VEHICLE_PRESETS["rauniyar2023"]
    drag = 0.4
    model = DynamicsModel(dataclasses.replace(vehicle, drag=drag))
    x = np.zeros((1, 12))
    wind = (3.0, -1.0, 0.5)
    air = (*wind, 0.0, 0.0, 0.0)
    xdot_still = model.derivative(x, vehicle.mass * GRAVITY, np.zeros(3))
    h = 1e-6
    moved = model.propagate(x, vehicle.mass * GRAVITY, np.zeros(3), h, method="euler", air=air)
    np.testing.assert_allclose(xdot_still[0, VEL], 0.0, atol=1e-12)
    np.testing.assert_allclose((moved[0, VEL] - x[0, VEL]) / h, drag * np.array(wind), rtol=1e-9)


def _vel_rmse(
    seed: int, inform: bool, kind: str, duration_s: float = 2.0, particles: int = 60
) -> float:
    """RMS of the inertial velocity error (m/s) over ``duration_s`` of DF-LQR flight on the
    estimate of a ``particles``-particle FastSLAM, with a pinned mass scale of 1.3 (``kind``
    ``mass``) or a 3 m/s wind on a 0.3 1/s drag (``wind``), told or not."""
    kwargs: dict = {
        "episode": {"duration_s": duration_s},
        "estimator": {"params": {"n_particles": particles}},
    }
    options = None
    if kind == "mass":
        kwargs["randomize"] = {"inform_estimator": inform}
        options = {"randomized": {"mass_scale": 1.3}}
    else:
        kwargs["wind"] = {"steady_mps": [3.0, 0.0, 0.0], "inform_estimator": inform}
        kwargs["vehicle"] = {"drag_per_s": 0.3}
    env = gym.make("QuadSLAM-FastSLAM-v0", **kwargs)
    policy = DFLQRPolicy.from_env(env)
    obs, _ = env.reset(seed=seed, options=options)
    errors, done = [], False
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
        errors.append(info["est_vel_err_mps"])
        done = terminated or truncated
    return float(np.sqrt(np.mean(np.square(errors))))


@pytest.mark.parametrize("kind", ["mass", "wind"])
def test_informing_reduces_the_velocity_error(kind: str) -> None:
    """A 30 % heavier vehicle (or a 3 m/s wind on a 0.3 1/s drag) is a bias in the model's
    acceleration of g·0.3/1.3 ≈ 2.3 m/s² (0.9 m/s²) that the uninformed filter must absorb
    through its process noise; the informed one has none."""
    for seed in (0, 1, 2):
        informed, blind = _vel_rmse(seed, True, kind), _vel_rmse(seed, False, kind)
        assert informed < 0.5 * blind, (seed, informed, blind)


@pytest.mark.parametrize(
    ("over", "key", "what"),
    [
        ({"wind": {"inform_estimator": True}}, "wind.inform_estimator", "'ekf_slam'"),
        (
            {"wind": {"inform_estimator": True}, "estimator": {"name": "fastslam_kinematic"}},
            "wind.inform_estimator",
            "'fastslam_kinematic'",
        ),
        (
            {
                "wind": {"inform_estimator": True},
                "estimator": {"name": "fastslam"},
                "imu": {"rate_hz": 10.0},
            },
            "wind.inform_estimator",
            "10 times slower",
        ),
        (
            {
                "wind": {"inform_estimator": True},
                "estimator": {"name": "fastslam"},
                "lidar": {"delay_steps": 2},
            },
            "wind.inform_estimator",
            "lidar.delay_steps = 2",
        ),
        ({"wind": {"inform_estimator": "yes"}}, "wind.inform_estimator", "'yes'"),
        ({"randomize": {"inform_estimator": 1}}, "randomize.inform_estimator", "1"),
    ],
)
def test_bad_settings_name_the_key_before_the_episode(over: dict, key: str, what: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario("paper_ekf_figure8", over)
    text = str(err.value)
    assert text.startswith(key) and what in text and "allowed" in text, text


def test_off_is_the_default() -> None:
    scenario = load_scenario("paper_fastslam_helix")
    assert scenario.randomize.inform_estimator is False
    assert scenario.wind.inform_estimator is False


def test_the_replayed_copy_of_a_slow_imu_is_told_the_vehicle_too() -> None:
    """An IMU slower than the control runs a copy of the estimator (the filter) beside the
    output; both model the lane's draw."""
    vec = _vec(2, randomize={**RANGES, "inform_estimator": True}, imu={"rate_hz": 10.0})
    vec.reset(seed=4)
    core = vec.unwrapped.core
    for est in (core.estimator, core._copies.filter):
        for lane in range(2):
            assert est.lanes[lane].model.mass == pytest.approx(core.vehicle.lane_mass[lane])


def test_a_scaled_rotor_vehicle_has_the_limits_of_its_scaled_rotors() -> None:
    """Rotors: the thrust scale acts on k_f and k_m, so the told vehicle's thrust and torque
    limits must be those its scaled rotors give (derived independently by the rotor model)."""
    nominal = VEHICLE_PRESETS["crazyflie2"]
    told = scaled_vehicle(nominal, 1.1, 0.9, 1.2, 1.5)
    assert told.rotors is not None and nominal.rotors is not None
    assert told.max_thrust == pytest.approx(told.rotors.max_collective_thrust, rel=1e-12)
    np.testing.assert_allclose(told.max_torque, told.rotors.max_torque, rtol=1e-12)
    assert told.rotors.motor_tau == pytest.approx(1.5 * nominal.rotors.motor_tau)
    assert told.mass == pytest.approx(1.1 * nominal.mass)
    np.testing.assert_allclose(told.inertia, 0.9 * nominal.inertia, rtol=1e-12)
    assert scaled_vehicle(nominal, 1.0, 1.0, 1.0, 1.0) is nominal
