"""Domain randomisation (docs/physics.md "Domain randomisation").

Independent facts: the draws lie in their ranges and are uniform (Kolmogorov–Smirnov on many
draws); an absent or all-nominal section changes nothing, bit for bit, and randomisation leaves
the other random streams (landmarks, estimator start) alone; the same seed gives the same draws
and rollout; every vector lane equals the scalar env through autoresets, and one lane's seed
never moves another lane's draws; pinned scales act on the truth by Newton's second law while
the estimator keeps the nominal model; bad ranges and infeasible ones are ConfigErrors.
"""

from __future__ import annotations

import math

import gymnasium as gym
import lane_cases as tve
import numpy as np
import pytest
from gymnasium.vector import AutoresetMode
from scipy.stats import kstest

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.randomize import SCALE_KEYS, RandomizeConfig
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.params import VEHICLE_PRESETS
from quadslam_env.schema import ConfigError
from quadslam_env.sim.randomize import RANDOMIZED_KEYS, Randomizer
from quadslam_env.sim.vehicle import VehicleBatch
from quadslam_env.types import GRAVITY

RANGES = {
    "mass_scale": [0.8, 1.25],
    "inertia_scale": [0.7, 1.3],
    "thrust_scale": [0.85, 1.15],
    "lag_scale": [0.5, 2.0],
    "imu_bias_scale": [0.5, 2.0],
    "imu_noise_scale": [0.5, 2.0],
    "lidar_noise_scale": [0.5, 3.0],
    "wind_scale": [0.0, 2.0],
}
SHORT = {"duration_s": 0.3}
WIND = {"steady_mps": [2.0, 1.0, 0.0], "turbulence": "dryden", "w20_mps": 3.0}
DRAG = {"drag_per_s": 0.3, "actuator_tau_s": 0.03}


def _env(**kwargs: object) -> gym.Env:
    return gym.make("QuadSLAM-EKF-v0", episode=SHORT, **kwargs)


def _rollout(env: gym.Env, seed: int, steps: int = 20) -> list:
    """Observations and info of a reset and ``steps`` hover-ish steps."""
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    hover = env.unwrapped.hover_action
    rng = np.random.default_rng(1)
    for _ in range(steps):
        obs, reward, _, _, info = env.step(hover + 0.05 * rng.standard_normal(4))
        out.append((obs, reward, info))
    return out


def _assert_same(a: list, b: list) -> None:
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[-1].keys() == y[-1].keys()
        for key, value in x[-1].items():
            assert value == y[-1][key] or (value != value and y[-1][key] != y[-1][key]), key


def test_draws_lie_in_their_ranges_and_are_uniform() -> None:
    n = 4000
    cfg = RandomizeConfig.from_dict(RANGES)
    params = VEHICLE_PRESETS["rauniyar2023"]
    rand = Randomizer(cfg, params, n)
    vehicle = VehicleBatch(params, 0.002, n)
    parents = np.random.default_rng(2024).spawn(n)
    rand.begin(np.arange(n), parents, None, vehicle)
    for j, key in enumerate(SCALE_KEYS):
        lo, hi = RANGES[key]
        v = rand.values[:, j]
        assert lo <= v.min() and v.max() <= hi, key
        assert kstest(v, "uniform", args=(lo, hi - lo)).pvalue > 1e-3, key
    # The scales pairwise uncorrelated (independent uniforms).
    corr = np.corrcoef(rand.values.T)
    assert np.max(np.abs(corr - np.eye(len(SCALE_KEYS)))) < 0.1
    np.testing.assert_allclose(vehicle.lane_mass, params.mass * rand.values[:, 0], rtol=1e-15)


@pytest.mark.parametrize("section", [{}, {key: [1.0, 1.0] for key in RANGES}])
def test_off_changes_nothing_bit_for_bit(section: dict) -> None:
    kwargs = {"wind": WIND, "vehicle": DRAG}
    base = _rollout(_env(**kwargs), 5)
    off = _rollout(_env(randomize=section, **kwargs), 5)
    _assert_same(base, off)
    assert not any(key.startswith("rand_") for key in off[0][1])


def test_randomisation_leaves_the_other_streams_alone() -> None:
    off, on = _env(), _env(randomize=RANGES)
    for env in (off, on):
        env.reset(seed=11)
    core_off, core_on = off.unwrapped._core, on.unwrapped._core
    np.testing.assert_array_equal(core_on.landmarks, core_off.landmarks)
    np.testing.assert_array_equal(core_on.est.position, core_off.est.position)  # initial error
    # The IMU's bias draws are the same, scaled by the lane's bias scale.
    scale = on.unwrapped._core.randomizer.values[0, SCALE_KEYS.index("imu_bias_scale")]
    np.testing.assert_allclose(core_on.imu.bias0, scale * core_off.imu.bias0, rtol=1e-15)


def test_same_seed_same_draws_and_rollout_and_new_draws_each_episode() -> None:
    kwargs = {"randomize": RANGES, "wind": WIND, "vehicle": DRAG}
    a, b = _rollout(_env(**kwargs), 9), _rollout(_env(**kwargs), 9)
    _assert_same(a, b)
    draws = {key: a[0][1][key] for key in RANDOMIZED_KEYS}
    assert all(a[-1][-1][key] == value for key, value in draws.items())  # held all episode
    env = _env(**kwargs)
    env.reset(seed=9)
    _, info = env.reset()  # the next episode of the same generator: new draws
    assert all(info[key] != draws[key] for key in RANDOMIZED_KEYS if key != "rand_wind_scale")


@pytest.mark.parametrize(
    "case",
    [
        {"randomize": RANGES, "wind": WIND, "vehicle": DRAG},
        {"randomize": RANGES, "vehicle": {"preset": "crazyflie2"}, "imu": {"rate_hz": 10.0}},
    ],
    ids=["collective-wind", "rotors-slow-imu"],
)
def test_vector_lanes_equal_the_scalar_env_through_autoresets(monkeypatch, case) -> None:
    monkeypatch.setitem(tve.CASES, "QuadSLAM-EKF-v0-randomized", {**tve.SHORT, **case})
    tve.assert_lanes_equal_scalar_rollouts("QuadSLAM-EKF-v0-randomized", AutoresetMode.NEXT_STEP)


def test_one_lane_seed_never_moves_another_lanes_draws() -> None:
    def lane1(seeds: list[int]) -> tuple[dict, np.ndarray]:
        vec = gym.make_vec(
            "QuadSLAM-EKF-v0", num_envs=2, vectorization_mode="vector_entry_point",
            episode=SHORT, randomize=RANGES,
        )  # fmt: skip
        obs, info = vec.reset(seed=seeds)
        hover = np.tile(vec.unwrapped.hover_action, (2, 1))
        for _ in range(10):
            obs, *_ = vec.step(hover)
        vec.close()
        return {key: info[key][1] for key in RANDOMIZED_KEYS}, obs[1]

    (d0, o0), (d1, o1) = lane1([0, 5]), lane1([1, 5])
    assert d0 == d1
    np.testing.assert_array_equal(o0, o1)
    (d2, _) = lane1([0, 6])
    assert all(d2[key] != d0[key] for key in RANDOMIZED_KEYS if key != "rand_wind_scale")


def test_pinned_mass_needs_that_much_more_thrust_to_hover() -> None:
    params = VEHICLE_PRESETS["rauniyar2023"]
    vehicle = VehicleBatch(params, 0.002, 2)
    rand = Randomizer(RandomizeConfig.from_dict({}), params, 2)
    rand.begin(np.array([1]), [np.random.default_rng(0)], {"mass_scale": 1.2}, vehicle)
    vehicle.reset([0, 1], np.zeros((2, 12)))
    np.testing.assert_allclose(vehicle.applied_thrust, [1.0, 1.2] * np.array(params.hover_thrust))
    thrust = np.full(2, 1.2 * params.mass * GRAVITY)  # hovers lane 1, lifts lane 0
    for _ in range(10):
        vehicle.step(thrust, np.zeros((2, 3)), 0.01)
    v_down = vehicle.state[:, 5]
    assert abs(v_down[1]) < 1e-12
    assert v_down[0] == pytest.approx(-0.2 * GRAVITY * 0.1, rel=1e-9)  # a = (1.2 - 1) g


def test_pinned_thrust_scale_on_rotors_scales_the_wrench() -> None:
    params = load_scenario("crazyflie_hover").vehicle.params()
    vehicle = VehicleBatch(params, 0.002, 2)
    rand = Randomizer(RandomizeConfig.from_dict({}), params, 2)
    rand.begin(np.array([1]), [np.random.default_rng(0)], {"thrust_scale": 1.25}, vehicle)
    vehicle.reset([0, 1], np.zeros((2, 12)))
    hover = np.full(2, params.hover_thrust)
    for _ in range(50):  # the motors settle at the hover command
        vehicle.step(hover, np.zeros((2, 3)), 0.01)
    assert vehicle.applied_thrust[1] == pytest.approx(1.25 * vehicle.applied_thrust[0], rel=1e-9)


def test_pins_apply_and_the_estimator_keeps_the_nominal_model() -> None:
    env = _env(randomize=RANGES, wind={"steady_mps": [2.0, 0.0, 0.0]}, vehicle=DRAG)
    pins = {"mass_scale": 1.2, "lidar_noise_scale": 2.0, "wind_scale": 0.5, "imu_noise_scale": 3}
    _, info = env.reset(seed=3, options={"randomized": pins})
    for key, value in pins.items():
        assert info[f"rand_{key}"] == value
    assert RANGES["inertia_scale"][0] <= info["rand_inertia_scale"] <= RANGES["inertia_scale"][1]
    core = env.unwrapped._core
    nominal = load_scenario("paper_ekf_figure8").vehicle.params()
    assert core.vehicle.lane_mass[0] == pytest.approx(1.2 * nominal.mass)
    np.testing.assert_allclose(core.lidar.lane_sigma[0], 2.0 * core.lidar.sigma)
    assert info["wind_n_mps"] == pytest.approx(1.0)
    est_vehicle = core.estimator.vehicle
    assert est_vehicle.mass == nominal.mass and core.vehicle_params.mass == nominal.mass
    np.testing.assert_array_equal(est_vehicle.inertia, nominal.inertia)
    assert core.imu_input_sigma[0] == core.imu.accel_sigma  # the filter's noise: nominal
    # With randomisation off, a pin alone applies to its episode, then the lane is nominal.
    off = _env()
    _, info = off.reset(seed=3, options={"randomized": {"mass_scale": 1.1}})
    assert info["rand_mass_scale"] == 1.1 and info["rand_thrust_scale"] == 1.0
    _, info = off.reset(seed=3)
    assert "rand_mass_scale" not in info
    assert off.unwrapped._core.vehicle.lane_mass[0] == nominal.mass


@pytest.mark.parametrize(
    ("section", "key"),
    [
        ({"mass_scale": [1.2, 0.8]}, "randomize.mass_scale"),
        ({"lag_scale": [-0.5, 1.0]}, "randomize.lag_scale[0]"),
        ({"imu_noise_scale": [0.5, math.nan]}, "randomize.imu_noise_scale[1]"),
        ({"wind_scale": [0.5, math.inf]}, "randomize.wind_scale[1]"),
        ({"thrust_scale": [1.0]}, "randomize.thrust_scale"),
        ({"inertia_scale": [0.0, 1.0]}, "randomize.inertia_scale"),
        ({"gain_scale": [1.0, 1.0]}, "randomize.gain_scale"),
        # T/W = 0.75 possible: the range set away from nominal leads the message
        ({"thrust_scale": [0.3, 1.0]}, "randomize.thrust_scale[0]: got 0.3 with"),
        ({"mass_scale": [1.0, 3.0]}, "randomize.mass_scale[1]: got 3 with"),  # T/W = 0.83
    ],
)
def test_bad_ranges_name_the_key_before_the_episode(section: dict, key: str) -> None:
    with pytest.raises(ConfigError, match="allowed") as err:
        _env(randomize=section)
    assert key in str(err.value)


@pytest.mark.parametrize(
    ("pins", "key"),
    [
        ({"mass_scale": -1.0}, "randomized.mass_scale"),
        ({"mass_scale": True}, "randomized.mass_scale"),
        ({"lidar_noise_scale": math.nan}, "randomized.lidar_noise_scale"),
        ({"heavy": 1.0}, "randomized.heavy"),
        ([1.2], "randomized"),
        # T/W < 1: the pinned scale leads the message, with the other one's key and value
        ({"mass_scale": 2.6}, "randomized.mass_scale: got 2.6 with randomize.thrust_scale[0] 1"),
        ({"thrust_scale": 0.3}, "randomized.thrust_scale: got 0.3 with randomize.mass_scale[1]"),
        (
            {"mass_scale": 2.0, "thrust_scale": 0.7},
            "randomized.thrust_scale: got 0.7 with reset options.randomized.mass_scale 2",
        ),
    ],
)
def test_bad_pins_name_the_key_and_change_nothing(pins: object, key: str) -> None:
    env = _env()
    env.reset(seed=1)
    state = env.unwrapped._core.vehicle.state.copy()
    with pytest.raises(ConfigError, match="allowed") as err:
        env.reset(seed=2, options={"randomized": pins})
    assert key in str(err.value)
    np.testing.assert_array_equal(env.unwrapped._core.vehicle.state, state)


@pytest.mark.parametrize("key", ["mass_scale", "thrust_scale"])
def test_an_infeasible_pin_names_the_scale_that_would_hover(key: str) -> None:
    """The bound the message allows is the nominal thrust-to-weight T/(m g) (a mass scale
    below it, a thrust scale above its inverse): a pin just inside it resets and one just
    outside does not."""
    nominal = load_scenario("paper_ekf_figure8").vehicle.params()
    ratio = nominal.max_thrust / (nominal.mass * GRAVITY)
    bound, inside, outside = (
        (ratio, 0.99 * ratio, 1.01 * ratio)
        if key == "mass_scale"
        else (1.0 / ratio, 1.01 / ratio, 0.99 / ratio)
    )
    env = _env()
    with pytest.raises(ConfigError) as err:
        env.reset(seed=0, options={"randomized": {key: outside}})
    message = str(err.value)
    word = "a mass scale <" if key == "mass_scale" else "a thrust scale >"
    assert message.startswith(f"reset options.randomized.{key}: got {outside:g} with")
    assert float(message.split(word)[1].split()[0]) == pytest.approx(bound, rel=1e-3)
    _, info = env.reset(seed=0, options={"randomized": {key: inside}})
    assert info[f"rand_{key}"] == inside
