"""Per-axis inertia randomisation (``randomize.inertia_scale_per_axis``, docs/physics.md "Domain
randomisation").

Independent facts: each body axis's scale lies in ``inertia_scale``'s range and is uniform
(Kolmogorov–Smirnov), the axes and the lanes are independent; J' = D^½ J D^½ (an analytic
matrix, SPD, its stored inverse the inverse) and Euler's equation at rest, ω̇ = J'⁻¹ τ, gives
the pinned axes' angular accelerations; the option leaves every other draw of the same seed
unchanged (so with it off nothing moves: tests/sim/test_randomize.py); vector lane i equals the
scalar env; bad pins are ConfigErrors naming the key.
"""

from __future__ import annotations

import dataclasses

import gymnasium as gym
import lane_cases as tve
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from scipy.stats import kstest

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.randomize import AXIS_KEYS, RandomizeConfig
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.schema import ConfigError
from quadslam_env.sim.randomize import AXIS_INFO_KEYS, RANDOMIZED_KEYS, Randomizer, scaled_vehicle
from quadslam_env.sim.vehicle import VehicleBatch

INERTIA = [0.6, 1.4]
RANGES = {"mass_scale": [0.9, 1.1], "inertia_scale": INERTIA, "lidar_noise_scale": [0.5, 2.0]}
PER_AXIS = {**RANGES, "inertia_scale_per_axis": True}
SHORT = {"duration_s": 0.3}


def _env(randomize: dict, **kwargs: object) -> gym.Env:
    return gym.make("QuadSLAM-EKF-v0", episode=SHORT, randomize=randomize, **kwargs)


def test_axis_scales_lie_in_the_range_are_uniform_and_independent() -> None:
    n = 4000
    params = VEHICLE_PRESETS["rauniyar2023"]
    rand = Randomizer(RandomizeConfig.from_dict(PER_AXIS), params, n)
    vehicle = VehicleBatch(params, 0.002, n)
    rand.begin(np.arange(n), np.random.default_rng(77).spawn(n), None, vehicle)
    nominal = np.diag(params.inertia)
    diag = np.diagonal(vehicle.lane_inertia, axis1=1, axis2=2) / nominal  # (n, 3)
    np.testing.assert_allclose(diag, rand.axes, rtol=1e-14)
    lo, hi = INERTIA
    for axis in range(3):
        s = diag[:, axis]
        assert lo <= s.min() and s.max() <= hi
        assert kstest(s, "uniform", args=(lo, hi - lo)).pvalue > 1e-3, axis
    # The three axes and the other scales pairwise uncorrelated (independent uniforms).
    table = np.column_stack((rand.axes, rand.values[:, [0, 6]]))  # + mass, LiDAR noise
    corr = np.corrcoef(table.T)
    assert np.max(np.abs(corr - np.eye(5))) < 0.1
    # A diagonal J stays diagonal.
    off = vehicle.lane_inertia * (1.0 - np.eye(3))
    assert not off.any()


def test_scaled_inertia_is_the_congruence_with_the_axis_scales() -> None:
    """A full J (products of inertia): J' = D^½ J D^½ entry by entry, symmetric positive
    definite, its stored inverse the inverse; the estimator's scaled vehicle is the truth's."""
    base = VEHICLE_PRESETS["rauniyar2023"]
    J = np.array([[0.11, 0.004, -0.006], [0.004, 0.06, 0.002], [-0.006, 0.002, 0.17]])
    params = dataclasses.replace(base, inertia=J)
    vehicle = VehicleBatch(params, 0.002, 2)
    rand = Randomizer(RandomizeConfig.from_dict(PER_AXIS), params, 2)
    pins = {"inertia_scale_x": 1.3, "inertia_scale_y": 0.7, "inertia_scale_z": 1.1}
    rand.begin(np.array([1]), [np.random.default_rng(0)], pins, vehicle)
    s = np.array([1.3, 0.7, 1.1])
    root = np.diag(np.sqrt(s))
    want = root @ J @ root
    got = vehicle.lane_inertia
    np.testing.assert_array_equal(got[0], J)  # the other lane untouched
    np.testing.assert_allclose(got[1], want, rtol=1e-14)
    np.testing.assert_allclose(np.diag(got[1]), s * np.diag(J), rtol=1e-14)
    assert np.all(np.linalg.eigvalsh(got[1]) > 0.0)
    inverse = vehicle._bodies[1, 11:20].reshape(3, 3)
    np.testing.assert_allclose(inverse @ got[1], np.eye(3), atol=1e-12)
    told = rand.vehicles(np.array([1]))[0]
    np.testing.assert_allclose(told.inertia, got[1], rtol=1e-14)
    np.testing.assert_allclose(told.inertia_inv, inverse, rtol=1e-12)
    assert scaled_vehicle(params, 1.0, np.ones(3), 1.0, 1.0) is params


def test_pinned_axes_act_on_the_body_by_eulers_equation() -> None:
    """From rest, the same torque on every axis spins lane 1 (axes pinned to s) about axis i
    1/s_i times as fast as the nominal lane 0 (ω̇ = J⁻¹ τ; the gyroscopic term ω × Jω is
    second order over a short step)."""
    params = VEHICLE_PRESETS["rauniyar2023"]
    vehicle = VehicleBatch(params, 0.002, 2)
    rand = Randomizer(RandomizeConfig.from_dict(PER_AXIS), params, 2)
    s = np.array([1.25, 0.8, 1.5])
    pins = dict(zip(AXIS_KEYS, s.tolist(), strict=True))
    rand.begin(np.array([1]), [np.random.default_rng(0)], pins, vehicle)
    vehicle.reset([0, 1], np.zeros((2, 12)))
    thrust = np.full(2, params.hover_thrust)
    vehicle.step(thrust, np.full((2, 3), 1e-3), 0.01)
    rates = vehicle.state[:, 9:12]
    np.testing.assert_allclose(rates[1] / rates[0], 1.0 / s, rtol=1e-6)


def test_the_option_adds_draws_after_the_eight_and_moves_none_of_them() -> None:
    """Same seed with and without the option: every common scale equal, the x axis takes the
    common inertia draw, the landmarks and the estimator's start equal; y and z are new draws."""
    plain, axes = _env(RANGES), _env(PER_AXIS)
    _, info0 = plain.reset(seed=4)
    _, info1 = axes.reset(seed=4)
    for key in RANDOMIZED_KEYS:
        if key != "rand_inertia_scale":
            assert info1[key] == info0[key], key
    assert "rand_inertia_scale" not in info1 and "rand_inertia_scale_y" not in info0
    assert info1["rand_inertia_scale_x"] == info0["rand_inertia_scale"]
    assert len({info1[key] for key in AXIS_INFO_KEYS}) == 3
    core0, core1 = plain.unwrapped._core, axes.unwrapped._core
    np.testing.assert_array_equal(core0.landmarks, core1.landmarks)
    np.testing.assert_array_equal(core0.est.position, core1.est.position)
    # Held over the episode; a new episode draws new axes.
    _, _, _, _, info = axes.step(axes.unwrapped.hover_action)
    assert all(info[key] == info1[key] for key in AXIS_INFO_KEYS)
    _, info2 = axes.reset()
    assert all(info2[key] != info1[key] for key in AXIS_INFO_KEYS)


def test_lanes_draw_their_axes_from_their_own_seeds() -> None:
    def draws(seeds: list[int]) -> np.ndarray:
        vec = gym.make_vec(
            "QuadSLAM-EKF-v0", num_envs=2, vectorization_mode="vector_entry_point",
            episode=SHORT, randomize=PER_AXIS,
        )  # fmt: skip
        _, info = vec.reset(seed=seeds)
        vec.close()
        return np.array([info[key] for key in AXIS_INFO_KEYS]).T  # (2 lanes, 3 axes)

    a, b, c = draws([0, 5]), draws([1, 5]), draws([0, 6])
    np.testing.assert_array_equal(a[1], b[1])  # lane 1's draws ignore lane 0's seed
    assert np.all(a[0] != b[0]) and np.all(a[1] != c[1]) and np.all(a[0] != a[1])


def test_vector_lanes_equal_the_scalar_env_through_autoresets(monkeypatch) -> None:
    case = {**tve.SHORT, "randomize": PER_AXIS}
    monkeypatch.setitem(tve.CASES, "QuadSLAM-EKF-v0-axes", case)
    tve.assert_lanes_equal_scalar_rollouts("QuadSLAM-EKF-v0-axes", AutoresetMode.NEXT_STEP)


def test_pins_apply_to_their_axes_and_inertia_scale_pins_all_three() -> None:
    env = _env(PER_AXIS)
    nominal = np.diag(env.unwrapped._core.vehicle_params.inertia)
    _, info = env.reset(seed=2, options={"randomized": {"inertia_scale_y": 1.3}})
    assert info["rand_inertia_scale_y"] == 1.3
    assert INERTIA[0] <= info["rand_inertia_scale_x"] <= INERTIA[1]
    diag = np.diag(env.unwrapped._core.vehicle.lane_inertia[0])
    want = [info[key] for key in AXIS_INFO_KEYS]
    np.testing.assert_allclose(diag, np.array(want) * nominal, rtol=1e-14)
    _, info = env.reset(seed=2, options={"randomized": {"inertia_scale": 0.9}})
    assert [info[key] for key in AXIS_INFO_KEYS] == [0.9, 0.9, 0.9]
    # With the section off, an axis pin still applies to its episode (the option is on).
    off = _env({"inertia_scale_per_axis": True})
    _, info = off.reset(seed=2, options={"randomized": {"inertia_scale_z": 1.2}})
    assert [info[key] for key in AXIS_INFO_KEYS] == [1.0, 1.0, 1.2]
    _, info = off.reset(seed=2)
    assert "rand_inertia_scale_z" not in info
    np.testing.assert_array_equal(np.diag(off.unwrapped._core.vehicle.lane_inertia[0]), nominal)


@pytest.mark.parametrize(
    ("randomize", "pins", "fragment"),
    [
        (RANGES, {"inertia_scale_x": 1.1}, "randomized.inertia_scale_x: got 1.1"),
        (PER_AXIS, {"inertia_scale": 1.1, "inertia_scale_z": 1.2}, "not both"),
        (PER_AXIS, {"inertia_scale_y": 0.0}, "randomized.inertia_scale_y: got 0.0"),
        (PER_AXIS, {"inertia_scale_y": "big"}, "randomized.inertia_scale_y"),
        (PER_AXIS, {"inertia_scale_w": 1.0}, "randomized.inertia_scale_w: unknown key"),
    ],
)
def test_bad_axis_pins_name_the_key_and_change_nothing(
    randomize: dict, pins: dict, fragment: str
) -> None:
    env = _env(randomize)
    env.reset(seed=1)
    before = env.unwrapped._core.vehicle.lane_inertia
    with pytest.raises(ConfigError, match="allowed") as err:
        env.reset(seed=2, options={"randomized": pins})
    assert fragment in str(err.value)
    np.testing.assert_array_equal(env.unwrapped._core.vehicle.lane_inertia, before)


def test_a_non_boolean_option_is_a_config_error() -> None:
    with pytest.raises(ConfigError, match=r"randomize\.inertia_scale_per_axis"):
        _env({**RANGES, "inertia_scale_per_axis": "yes"})
