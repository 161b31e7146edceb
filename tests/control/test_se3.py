"""The geometric SE(3) baseline: hover command and small-angle attitude law against their
analytic values, zero steady-state error under a constant disturbance (flown), lanes equal to
the scalar env, and its bad gains."""

from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from test_lqi import _hover_in_wind

import quadslam_env  # noqa: F401
from agents.control.se3 import SE3Policy
from quadslam_env.schema import ConfigError
from quadslam_env.types import GRAVITY


def _policy(**kwargs: object) -> SE3Policy:
    env = gym.make("QuadSLAM-Oracle-v0")
    try:
        return SE3Policy.from_env(env, **kwargs)
    finally:
        env.close()


def test_on_the_reference_at_hover_it_commands_the_hover_thrust_and_no_torque() -> None:
    policy = _policy()
    act, _ = policy.predict(np.zeros(16))
    veh = policy.vehicle
    assert act[0] == pytest.approx(2.0 * veh.mass * GRAVITY / veh.max_thrust - 1.0, abs=1e-6)
    np.testing.assert_allclose(act[1:], 0.0, atol=1e-7)


def test_small_attitude_errors_get_the_pd_torque() -> None:
    # On the reference with a small roll error φ: R_d = I, e_R ≈ (φ, 0, 0), so M ≈ −k_R φ e1
    # (−k_R ψ̃ e3 for a heading error), to first order in the angle.
    policy = _policy()
    for axis, index in ((0, 6), (2, 8)):
        obs = np.zeros(16)
        obs[index] = 1e-4
        act, _ = policy.predict(obs)
        torque = act[1 + axis] * policy.vehicle.max_torque[axis]
        assert torque == pytest.approx(-policy.kR[axis] * 1e-4, rel=1e-3)


def test_flown_in_a_steady_wind_the_integral_removes_the_offset() -> None:
    assert np.abs(_hover_in_wind("se3")).max() < 0.005


def test_vector_lanes_equal_the_scalar_env() -> None:
    kwargs = {"wind": {"steady_mps": [1.5, -1.0, 0.0]}, "vehicle": {"drag_per_s": 0.3}}
    vec = gym.make_vec("QuadSLAM-Oracle-v0", num_envs=2, vectorization_mode="vector_entry_point",
                       **kwargs)  # fmt: skip
    env = gym.make("QuadSLAM-Oracle-v0", **kwargs)
    try:
        pv, ps = SE3Policy.from_env(vec), SE3Policy.from_env(env)
        obs_v, _ = vec.reset(seed=21)
        obs_s, _ = env.reset(seed=22)  # lane 1 is seeded 21 + 1
        sv = ss = None
        for _ in range(200):
            av, sv = pv.predict(obs_v, state=sv)
            a, ss = ps.predict(obs_s, state=ss)
            np.testing.assert_array_equal(av[1], a)
            obs_v, *_ = vec.step(av)
            obs_s, *_ = env.step(a)
            np.testing.assert_array_equal(obs_v[1], obs_s)
    finally:
        vec.close()
        env.close()


@pytest.mark.parametrize(
    ("gains", "match"),
    [
        ((-1.0, 3.0, 1.0), ">= 0"),
        ((6.0, 3.0, 20.0), "Routh-Hurwitz"),
        ((float("nan"), 3.0, 1.0), "finite"),
        ((400.0, 40.0, 1.0), "fastest pole"),
    ],
)
def test_bad_gains_are_refused(gains: tuple[float, float, float], match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        _policy(position_gains=gains)
