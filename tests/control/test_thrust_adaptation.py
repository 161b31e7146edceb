"""The thrust adaptation of ``lqi`` and ``se3`` (``thrust_adaptation``,
agents/control/adaptation.py): flown on the truth in hover, the estimated ratio converges to the
true ``m / (k m_nom)`` (mass and thrust scales pinned, with and without a steady wind) with no
position error left; nominal, it is 1 (exactly, with a zero integral); the adapted command is
the one of the reference acceleration scaled by the ratio written out in the test; with a zero
integral it is the unadapted command bit for bit; off, the controllers fly as before; lanes
equal the scalar env; a zero residual on the adapted base flies the base; the refusals."""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import assert_lanes_equal_scalar_env, assert_zero_residual_flies_base

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.adaptation import RATIO_BOUNDS, thrust_ratio
from agents.control.lqi import LQIPolicy
from agents.control.named import build_controller
from agents.control.se3 import SE3Policy
from agents.lab.cli.main import main
from agents.rl.wrappers import ResidualDFLQRVectorWrapper, parse_wrapper_spec
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY

POLICIES: dict[str, Any] = {"lqi": LQIPolicy, "se3": SE3Policy}
RANDOMIZED: dict[str, Any] = {"scenario": "ekf_figure8_randomized"}


def _hover(name: str, adapt: bool, pins: dict[str, float], **env: Any) -> tuple[Any, Any, Any]:
    """(policy, last observation, last state) after 30 s of hover on the truth with the
    randomised scales ``pins`` pinned through ``reset``."""
    episode = {"duration_s": 30.0, "max_pos_err_m": 30.0}
    e = gym.make("QuadSLAM-Oracle-v0", scenario="hover", episode=episode, **env)
    try:
        policy = build_controller(name, e, thrust_adaptation=adapt)
        obs, _ = e.reset(seed=0, options={"randomized": pins})
        state, start, done = None, np.array([True]), False
        while not done:
            action, state = policy.predict(obs, state=state, episode_start=start)
            start = np.array([False])
            obs, _, terminated, truncated, _ = e.step(action)
            done = terminated or truncated
        assert not terminated
        return policy, np.asarray(obs, dtype=float), state
    finally:
        e.close()


@pytest.mark.parametrize("name", sorted(POLICIES))
@pytest.mark.parametrize(
    ("mass", "thrust", "wind"),
    [(1.2, 1.0, False), (0.9, 1.1, False), (1.2, 1.0, True)],
)
def test_in_hover_the_ratio_converges_to_the_true_thrust_ratio(name, mass, thrust, wind):
    # The vehicle gets k f_T / m of the thrust f_T = m_nom ‖u_p‖: the ratio r = m / (k m_nom).
    # A steady 2 m/s wind with 0.3 1/s drag is a horizontal disturbance: the vertical balance,
    # and so r̂, is unchanged, and the integrals still leave no offset (final-value theorem).
    env = {"wind": {"steady_mps": [2.0, 0.0, 0.0]}, "vehicle": {"drag_per_s": 0.3}} if wind else {}
    policy, obs, state = _hover(name, True, {"mass_scale": mass, "thrust_scale": thrust}, **env)
    assert policy.thrust_ratio(state)[0] == pytest.approx(mass / thrust, rel=1e-6)
    assert np.abs(obs[:3]).max() < 1e-5


def _figure8_error(name: str, adapt: bool) -> tuple[float, float]:
    """(RMS position error in m over the last 20 s, largest |r̂ − 1.2| over them) of 40 s of
    the figure-8 on the truth with the vehicle 20 % heavier than the model."""
    env = gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 40.0}, **RANDOMIZED)
    try:
        policy = build_controller(name, env, thrust_adaptation=adapt)
        obs, _ = env.reset(seed=0, options={"randomized": {"mass_scale": 1.2, "thrust_scale": 1.0}})
        state, errors, ratios, done = None, [], [], False
        while not done:
            action, state = policy.predict(obs, state=state)
            obs, _, terminated, truncated, _ = env.step(action)
            errors.append(float(np.linalg.norm(obs[:3])))
            ratios.append(float(policy.thrust_ratio(state)[0]))
            done = terminated or truncated
        assert not terminated
        last = slice(-2000, None)
        rms = float(np.sqrt(np.mean(np.square(errors[last]))))
        return rms, float(np.max(np.abs(np.subtract(ratios[last], 1.2))))
    finally:
        env.close()


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_on_the_figure8_the_scaled_feedforward_removes_the_mass_error(name):
    # Without it the integral must follow (r − 1) ρ̈_d as the figure-8 turns, and lags; with it
    # r̂ holds the ratio (the vertical balance is the same on a level reference) and the
    # feed-forward supplies (r − 1) ρ̈_d.
    off, ratio_off = _figure8_error(name, False)
    on, ratio_on = _figure8_error(name, True)
    assert ratio_off < 1e-3 and ratio_on < 1e-3
    assert on < 0.3 * off


def test_nominal_the_ratio_is_one() -> None:
    for policy in _policies(True).values():
        assert policy.thrust_ratio(None)[0] == 1.0
    for name in sorted(POLICIES):
        policy, _, state = _hover(name, True, {"mass_scale": 1.0, "thrust_scale": 1.0})
        assert policy.thrust_ratio(state)[0] == pytest.approx(1.0, abs=1e-7)


def test_the_ratio_reads_the_gravity_deficit_within_its_bounds() -> None:
    # NED: a vertical command c_z < 0 asks for more thrust, a heavier vehicle (r > 1).
    c_z = np.array([0.0, -0.2 * GRAVITY, 0.1 * GRAVITY, -5.0 * GRAVITY, 5.0 * GRAVITY])
    np.testing.assert_allclose(thrust_ratio(c_z), [1.0, 1.2, 0.9, *RATIO_BOUNDS[::-1]])
    assert RATIO_BOUNDS == (0.5, 2.0)


def _obs(rng: np.random.Generator, n: int) -> np.ndarray:
    """n observations near the reference: small errors, a figure-8-like reference acceleration."""
    obs = np.zeros((n, 16))
    obs[:, :6] = 0.05 * rng.standard_normal((n, 6))
    obs[:, 6:12] = 0.02 * rng.standard_normal((n, 6))
    obs[:, 12:14] = rng.uniform(-0.6, 0.6, (n, 2))
    obs[:, 14] = rng.uniform(-0.2, 0.2, n)
    return obs


def _policies(adapt: bool) -> dict[str, Any]:
    e = gym.make("QuadSLAM-Oracle-v0", scenario="hover")
    try:
        return {name: cls.from_env(e, thrust_adaptation=adapt) for name, cls in POLICIES.items()}
    finally:
        e.close()


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_the_adapted_command_is_the_one_of_the_scaled_reference_acceleration(name):
    # u_p = r̂ ρ̈_d − K_r r̃ − g n3 + c with r̂ = 1 − c_z / g written out here from the vertical
    # integral gain (LQI: K_ξ[2, 2]; SE(3): k_I): the command, without adaptation, of the
    # observation whose reference acceleration is r̂ ρ̈_d, on the same integrals.
    on, off = _policies(True)[name], _policies(False)[name]
    obs = _obs(np.random.default_rng(5), 6)
    n = 4 if name == "lqi" else 3
    state = np.zeros((6, n))
    state[:, 2] = np.linspace(-0.5, 0.5, 6)  # vertical integrals in m·s: r̂ from 0.8 to 1.2
    k_i = on.K_xi[2, 2] if name == "lqi" else on.gains[2]
    ratio = 1.0 + k_i * state[:, 2] / GRAVITY  # c_z = −k_i ξ_z (NED: ξ_z > 0 is below)
    np.testing.assert_allclose(on.thrust_ratio(state), ratio, rtol=1e-12)
    assert ratio.min() < 0.85 and ratio.max() > 1.15
    scaled = obs.copy()
    scaled[:, 12:15] *= ratio[:, None]
    a_on, s_on = on.predict(obs, state=state)
    a_off, s_off = off.predict(scaled, state=state)
    np.testing.assert_allclose(a_on, a_off, atol=1e-6)
    np.testing.assert_array_equal(s_on, s_off)  # the integrals follow the same errors
    assert np.max(np.abs(a_on - off.predict(obs, state=state)[0])) > 1e-3


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_with_a_zero_integral_it_is_the_unadapted_command_bit_for_bit(name):
    on, off = _policies(True)[name], _policies(False)[name]
    obs = _obs(np.random.default_rng(9), 32)
    state = np.zeros((32, 4 if name == "lqi" else 3))
    assert np.array_equal(on.thrust_ratio(state), np.ones(32))
    a_on, s_on = on.predict(obs, state=state)
    a_off, s_off = off.predict(obs, state=state)
    np.testing.assert_array_equal(a_on, a_off)
    np.testing.assert_array_equal(s_on, s_off)


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_off_it_flies_as_before_bit_for_bit(name):
    # nominal physics: the adapted controller's first command (zero integral, r̂ = 1) too
    e = gym.make("QuadSLAM-Oracle-v0", episode={"duration_s": 3.0}, **RANDOMIZED)
    try:
        before = POLICIES[name].from_env(e)
        after = POLICIES[name].from_env(e, thrust_adaptation=False)
        adapted = POLICIES[name].from_env(e, thrust_adaptation=True)
        assert not before.adaptation and not after.adaptation and adapted.adaptation
        obs, _ = e.reset(seed=3)
        assert np.array_equal(adapted.predict(obs)[0], before.predict(obs)[0])
        s_b = s_a = None
        done = False
        while not done:
            a_b, s_b = before.predict(obs, state=s_b)
            a_a, s_a = after.predict(obs, state=s_a)
            np.testing.assert_array_equal(a_a, a_b)
            obs, _, term, trunc, _ = e.step(a_b)
            done = term or trunc
    finally:
        e.close()


@pytest.mark.parametrize("name", sorted(POLICIES))
def test_lanes_equal_the_scalar_env_with_the_adaptation(name):
    policy, state = assert_lanes_equal_scalar_env(
        "QuadSLAM-Oracle-v0", RANDOMIZED, name, [21, 22], 400, thrust_adaptation=True
    )
    assert np.all(np.abs(policy.thrust_ratio(state) - 1.0) > 0.01)  # adapting


def test_a_zero_residual_on_the_adapted_base_flies_the_base() -> None:
    def make() -> Any:
        return gym.make_vec("QuadSLAM-Oracle-v0", num_envs=2,
                            vectorization_mode="vector_entry_point", **RANDOMIZED)  # fmt: skip

    spec = parse_wrapper_spec({"name": "residual_dflqr", "base": "se3", "thrust_adaptation": True})
    assert spec is not None
    wrapped = ResidualDFLQRVectorWrapper(make(), **spec[1])
    try:
        base: Any = wrapped.residual.controller
        assert base.adaptation
    finally:
        wrapped.close()
    assert_zero_residual_flies_base(make, "se3", 200, thrust_adaptation=True)


def test_bad_adaptation_settings_are_refused() -> None:
    e = gym.make("QuadSLAM-Oracle-v0", scenario="hover")
    try:
        for name, cls in POLICIES.items():
            with pytest.raises(ConfigError, match=rf"{name}.thrust_adaptation: got 'yes'; "
                               r"allowed: true or false"):  # fmt: skip
                cls.from_env(e, thrust_adaptation="yes")
        with pytest.raises(ConfigError, match=r"lqi.thrust_adaptation: got true with "
                           r"integral_weights \[0.0, 0.0, 0.0, 0.0\]"):  # fmt: skip
            LQIPolicy.from_env(e, integral_weights=np.zeros(4), thrust_adaptation=True)
        with pytest.raises(ConfigError, match=r"se3.thrust_adaptation: .* k_I > 0"):
            SE3Policy.from_env(e, position_gains=(6.7, 3.7, 0.0), thrust_adaptation=True)
        with pytest.raises(ValueError, match=r"thrust_adaptation: got True with --policy dflqr; "
                           r"allowed: false, or a controller with the thrust adaptation "
                           r"\(lqi, se3\)"):  # fmt: skip
            build_controller("dflqr", e, thrust_adaptation=True)
    finally:
        e.close()
    for spec, match in (
        ({"base": "dflqr", "thrust_adaptation": True}, r"wrapper.thrust_adaptation: got True "
         r"with wrapper.base 'dflqr'; allowed: false, or true with a base that has it"),
        ({"base": "lqi", "thrust_adaptation": 1}, r"wrapper.thrust_adaptation: got 1"),
    ):  # fmt: skip
        with pytest.raises(ValueError, match=match):
            parse_wrapper_spec({"name": "residual_dflqr", **spec})
    with pytest.raises(SystemExit, match=r"--thrust-adaptation: only with --policy lqi or se3 "
                       r"\(got --policy dflqr\)"):  # fmt: skip
        main(["run", "--duration", "0.5", "--no-plots", "--thrust-adaptation"])
