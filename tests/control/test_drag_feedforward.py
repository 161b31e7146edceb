"""The drag feed-forward of ``lqi`` and ``se3`` (``drag_feedforward``, agents/control/drag.py):
its compensation against the drag written out in the test (linear and quadratic, the attitude
from scipy), the command it shifts by exactly that on an env whose estimated wind is the true
constant wind with linear drag, lanes equal to the scalar env, off = the controllers as before
bit for bit, and the refusals."""

from __future__ import annotations

import dataclasses
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import assert_lanes_equal_scalar_env, assert_zero_residual_flies_base
from scipy.spatial.transform import Rotation

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.lqi import LQIPolicy
from agents.control.named import build_controller
from agents.control.se3 import SE3Policy
from agents.rl.wrappers import parse_wrapper_spec
from quadslam_env.config.files import config_dir, load_yaml
from quadslam_env.models.params import vehicle_preset
from quadslam_env.schema import ConfigError

WIND_OBS = {"estimated_wind": True, "air_velocity": True}
AIR = 16 + 2  # the air velocity's first entry with both blocks
POLICIES: dict[str, Any] = {"lqi": LQIPolicy, "se3": SE3Policy}


def _linear_scenario() -> dict[str, Any]:
    """ekf_figure8_wind_states with linear drag only and a constant wind (no gusts), both
    wind blocks observed: the drag on the air velocity is −μ v_a."""
    data = load_yaml(config_dir() / "scenarios" / "ekf_figure8_wind_states.yaml")
    data["vehicle"]["drag_quadratic_per_m"] = [0.0, 0.0, 0.0]
    data["wind"] = {"steady_mps": [2.0, -1.0, 0.0]}
    data["observation"] = WIND_OBS
    data["episode"]["duration_s"] = 2.0
    return data


def _heading_dcm(obs: np.ndarray) -> np.ndarray:
    """C_HB = C3(ψ̂ − ψ_d) C2(θ̂) C1(φ̂) (3, 3) from the observation's attitude, by scipy."""
    return Rotation.from_euler("ZYX", [obs[8], obs[7], obs[6]]).as_matrix()


def _obs(rng: np.random.Generator, n: int) -> np.ndarray:
    """n observations near hover with random attitude errors and air velocities."""
    obs = np.zeros((n, AIR + 3))
    obs[:, :6] = 0.2 * rng.standard_normal((n, 6))
    obs[:, 6:9] = rng.uniform(-0.4, 0.4, (n, 3))
    obs[:, 12:15] = 0.3 * rng.standard_normal((n, 3))
    obs[:, 16:18] = rng.uniform(-3.0, 3.0, (n, 2))
    obs[:, AIR:] = rng.uniform(-4.0, 4.0, (n, 3))
    return obs


@pytest.mark.parametrize("name", sorted(POLICIES))
@pytest.mark.parametrize("cq", [(0.0, 0.0, 0.0), (0.02, 0.03, 0.05)])
def test_the_compensation_is_minus_the_drag_turned_into_the_heading_frame(name, cq):
    vehicle = dataclasses.replace(
        vehicle_preset("rauniyar2023"), drag=0.3, drag_quadratic=np.array(cq)
    )
    policy = POLICIES[name](vehicle, drag_feedforward=True, air_velocity_index=AIR)
    obs = _obs(np.random.default_rng(3), 4)
    got = policy.feedforward.compensation(obs)
    for b in range(obs.shape[0]):
        va = obs[b, AIR:]
        drag_body = -0.3 * va - np.array(cq) * np.linalg.norm(va) * va
        np.testing.assert_allclose(got[b], -_heading_dcm(obs[b]) @ drag_body, atol=1e-12)


def _shifted(obs: np.ndarray, comp: np.ndarray) -> np.ndarray:
    """``obs`` with the reference acceleration (entries 12–14, heading frame) raised by ``comp``:
    what the controller without feed-forward must see to command the same acceleration."""
    out = np.array(obs, dtype=float)
    out[..., 12:15] += comp
    return out


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_with_the_true_wind_the_command_shifts_by_the_linear_drag_exactly(name):
    env = gym.make("QuadSLAM-v0", scenario=_linear_scenario())
    try:
        off = build_controller(name, env)
        on = build_controller(name, env, drag_feedforward=True)
        obs, _ = env.reset(seed=2)
        state = None
        for _ in range(60):  # into the figure-8, tilted and moving through the wind
            act, state = off.predict(obs, state=state)
            obs, *_ = env.step(act)
        base: Any = env.unwrapped
        est = base.last_estimate
        wind = base.core.wind.velocity[0]
        # the observation the env emits when the estimated wind is the true constant wind
        told = base.observation_from(dataclasses.replace(est, wind=wind[None, :2].copy()))
        # −a_D = μ C3(ψ_d)ᵀ (C_NB v̂ − w): the linear drag on the estimated air velocity
        c_nb = Rotation.from_euler("ZYX", est.euler[0, ::-1]).as_matrix()
        c_3 = Rotation.from_euler("z", base.reference().yaw).as_matrix()
        want = 0.3 * c_3.T @ (c_nb @ est.vel_body[0] - np.array([wind[0], wind[1], 0.0]))
        assert np.linalg.norm(want) > 0.3  # a real drag, not a vanishing one
        comp = on.feedforward.compensation(told[None].astype(float))[0]
        np.testing.assert_allclose(comp, want, atol=2e-6)
        a_on, s_on = on.predict(told, state=state)
        a_off, s_off = off.predict(_shifted(told, comp), state=state)
        np.testing.assert_allclose(a_on, a_off, atol=1e-6)
        np.testing.assert_array_equal(s_on, s_off)
        assert np.max(np.abs(a_on - off.predict(told, state=state)[0])) > 1e-3
    finally:
        env.close()


def test_lanes_equal_the_scalar_env_with_the_feedforward():
    kwargs: dict[str, Any] = {"scenario": "ekf_figure8_wind_states", "observation": WIND_OBS,
                              "episode": {"duration_s": 0.6}}  # fmt: skip
    assert_lanes_equal_scalar_env("QuadSLAM-v0", kwargs, "se3", [7, 8], 60, drag_feedforward=True)


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_off_it_flies_as_before_bit_for_bit(name):
    plain = gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states", episode={"duration_s": 0.5})
    wind = gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states", episode={"duration_s": 0.5},
                    observation=WIND_OBS)  # fmt: skip
    try:
        before = POLICIES[name].from_env(plain)
        after = POLICIES[name].from_env(wind, drag_feedforward=False)
        assert before.feedforward is None and after.feedforward is None
        o_p, _ = plain.reset(seed=4)
        o_w, _ = wind.reset(seed=4)
        s_p = s_w = None
        done = False
        while not done:
            a_p, s_p = before.predict(o_p, state=s_p)
            a_w, s_w = after.predict(o_w, state=s_w)
            np.testing.assert_array_equal(a_w, a_p)
            o_p, *_ = plain.step(a_p)
            o_w, _, term, trunc, _ = wind.step(a_w)
            np.testing.assert_array_equal(o_w[:16], o_p[:16])
            done = term or trunc
    finally:
        plain.close()
        wind.close()


def test_a_zero_residual_on_the_feedforward_base_flies_the_base():
    kwargs: dict[str, Any] = {"scenario": "ekf_figure8_wind_states", "observation": WIND_OBS,
                              "episode": {"duration_s": 0.3}}  # fmt: skip

    def make() -> Any:
        return gym.make_vec("QuadSLAM-v0", num_envs=2, vectorization_mode="vector_entry_point",
                            **kwargs)  # fmt: skip

    assert_zero_residual_flies_base(make, "lqi", 20, drag_feedforward=True)


def test_bad_feedforward_settings_are_refused():
    plain = gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states", episode={"duration_s": 0.1})
    wind = gym.make("QuadSLAM-v0", scenario="ekf_figure8_wind_states", episode={"duration_s": 0.1},
                    observation={"estimated_wind": True})  # fmt: skip
    try:
        for env in (plain, wind):  # no air velocity in the observation
            for name in ("lqi", "se3"):
                with pytest.raises(
                    ConfigError,
                    match=rf"{name}.drag_feedforward: got true with "
                    r"air_velocity_index = None .*observation.air_velocity: true",
                ):
                    build_controller(name, env, drag_feedforward=True)
        for value in ("yes", 1, None):
            with pytest.raises(
                ConfigError,
                match=r"lqi.drag_feedforward: got .*; allowed: true "
                "or false",
            ):
                LQIPolicy.from_env(plain, drag_feedforward=value)
        with pytest.raises(ConfigError, match=r"se3.drag_feedforward: got 'on'"):
            SE3Policy.from_env(plain, drag_feedforward="on")
        with pytest.raises(
            ValueError,
            match=r"drag_feedforward: got True with --policy dflqr; "
            r"allowed: false, or a controller with the drag feed-forward \(lqi, "
            r"se3\)",
        ):
            build_controller("dflqr", plain, drag_feedforward=True)
    finally:
        plain.close()
        wind.close()
    vehicle = dataclasses.replace(vehicle_preset("rauniyar2023"), drag=0.3)
    with pytest.raises(ConfigError, match=r"lqi.air_velocity_index: got -1"):
        LQIPolicy(vehicle, drag_feedforward=True, air_velocity_index=-1)
    short = LQIPolicy(vehicle, drag_feedforward=True, air_velocity_index=16)
    with pytest.raises(ValueError, match=r"observations of 16 entries; allowed: at least 19"):
        short.predict(np.zeros(16))
    for spec, match in (
        ({"base": "dflqr", "drag_feedforward": True}, r"wrapper.drag_feedforward: got True with "
         r"wrapper.base 'dflqr'; allowed: false, or true with a base that has it"),
        ({"base": "lqi", "drag_feedforward": "yes"}, r"wrapper.drag_feedforward: got 'yes'"),
        ({"base": "lqi", "feedforward": True}, r"wrapper.feedforward: unknown key"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            parse_wrapper_spec({"name": "residual_dflqr", **spec})
