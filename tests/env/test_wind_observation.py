"""The wind blocks of the observation (``observation.estimated_wind``, ``air_velocity``): the
estimated wind equal to the ``info`` terms, the air velocity against the rotation written with
scipy, nothing else of the flight changed, the privileged observation's true wind, and the
estimators refused."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.named import build_controller
from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation.registry import estimates_wind
from quadslam_env.schema import ConfigError

WIND_OBS = {"estimated_wind": True, "air_velocity": True}


def _env(**kwargs: Any) -> gym.Env:
    return gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states",
                    episode={"duration_s": 0.4}, **kwargs)  # fmt: skip


def _c_nb(euler: np.ndarray) -> np.ndarray:
    """C_NB = C3(ψ) C2(θ) C1(φ) (3, 3) from scipy (intrinsic z-y-x), not the project's frames."""
    return Rotation.from_euler("ZYX", [euler[2], euler[1], euler[0]]).as_matrix()


def test_the_blocks_hold_the_info_wind_and_the_estimated_air_velocity_and_change_nothing_else():
    plain, wind = _env(), _env(observation=WIND_OBS)
    try:
        assert wind.observation_space.shape == (16 + 2 + 3,)
        ctrl = build_controller("lqi", plain)
        o_p, _ = plain.reset(seed=5)
        o_w, _ = wind.reset(seed=5)
        state, done = None, False
        while not done:
            np.testing.assert_array_equal(o_w[:16], o_p[:16])
            act, state = ctrl.predict(o_p, state=state)
            o_p, r_p, *_ = plain.step(act)
            o_w, r_w, term, trunc, info = wind.step(act)
            done = term or trunc
            assert r_w == r_p
            est = wind.unwrapped.last_estimate  # type: ignore[attr-defined]
            assert est.wind is not None
            # the estimated wind: the info terms, in the world frame
            assert o_w[16] == np.float32(info["est_wind_n_mps"])
            assert o_w[17] == np.float32(info["est_wind_e_mps"])
            np.testing.assert_array_equal(o_w[16:18], est.wind[0].astype(np.float32))
            # v̂_a = v̂ − C_NBᵀ ŵ in the body frame
            w = np.array([*est.wind[0], 0.0])
            want = est.vel_body[0] - _c_nb(est.euler[0]).T @ w
            np.testing.assert_allclose(o_w[18:21], want, rtol=1e-6, atol=1e-6)
        assert not term
    finally:
        plain.close()
        wind.close()


def test_the_privileged_observation_holds_the_true_wind_and_air_velocity():
    env = _env(observation=WIND_OBS)
    try:
        env.reset(seed=1)
        base: Any = env.unwrapped
        for _ in range(5):
            env.step(base.hover_action)
        core = base.core
        true = core.true_observation()[0]
        wind = core.wind.velocity[0]
        x = core.vehicle.state[0]
        np.testing.assert_array_equal(true[16:18], wind[:2].astype(np.float32))
        want = x[3:6] - _c_nb(x[6:9]).T @ np.array([wind[0], wind[1], 0.0])
        np.testing.assert_allclose(true[18:21], want, rtol=1e-6, atol=1e-6)
    finally:
        env.close()


@pytest.mark.parametrize(
    ("overrides", "match"),
    [
        ({"observation": {"estimated_wind": True}},
         r"observation.estimated_wind: got true with estimator.name = 'ekf_slam' and "
         r"estimator.params.wind = 'none', which estimates no wind; allowed: false, or"),
        ({"observation": {"air_velocity": True}, "estimator": {"name": "oracle"}},
         r"observation.air_velocity: got true with estimator.name = 'oracle', which"),
        ({"observation": WIND_OBS, "estimator": {"name": "fastslam"},
          "wind": {"steady_mps": [1.0, 0.0, 0.0], "inform_estimator": True},
          "vehicle": {"drag_per_s": 0.3}},
         r"observation.estimated_wind: got true with estimator.name = 'fastslam'"),
        ({"observation": {"estimated_wind": "yes"}},
         r"observation.estimated_wind: got 'yes'; allowed: true or false"),
        ({"observation": {"air_velocity": 1}},
         r"observation.air_velocity: got 1; allowed: true or false"),
    ],
)  # fmt: skip
def test_an_estimator_without_wind_states_and_bad_values_are_refused(overrides, match):
    with pytest.raises(ConfigError, match=match):
        load_scenario("paper_ekf_figure8", overrides)


def test_the_capability_is_asked_of_the_class_from_the_settings():
    assert estimates_wind("ekf_slam", {"wind": "estimate"})
    assert not estimates_wind("ekf_slam", {})
    assert not estimates_wind("oracle", {})
    assert not estimates_wind("fastslam", {})
    with pytest.raises(ConfigError, match=r"wind: got 'gusty'"):
        estimates_wind("ekf_slam", {"wind": "gusty"})
    # the shipped scenario with the wind states takes both blocks
    scenario = load_scenario("ekf_figure8_wind_states", {"observation": WIND_OBS})
    assert scenario.observation.estimated_wind and scenario.observation.air_velocity
