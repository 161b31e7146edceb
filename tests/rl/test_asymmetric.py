"""Asymmetric actor-critic (privileged critic) and the training adapter's lane options."""

from __future__ import annotations

import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest
import torch

import quadslam_env  # noqa: F401  (registers the ids)
from agents.rl.asymmetric import AsymmetricActorCriticPolicy
from agents.rl.lane_share import ACTOR_KEY, PRIVILEGED_KEY
from agents.rl.loading import load_model
from agents.rl.training import train
from agents.rl.vec_adapter import QuadSLAMVecEnv

SHORT = {"episode": {"duration_s": 0.3}}  # 30 steps


def _policy(obs_dim: int = 16) -> AsymmetricActorCriticPolicy:
    box = gym.spaces.Box(-100.0, 100.0, (obs_dim,), np.float32)
    space = gym.spaces.Dict({ACTOR_KEY: box, PRIVILEGED_KEY: box})
    action = gym.spaces.Box(-1.0, 1.0, (4,), np.float32)
    return AsymmetricActorCriticPolicy(
        space, action, lambda _: 1e-3, net_arch={"pi": [8], "vf": [8]}
    )


def test_actor_never_reads_the_privileged_entry() -> None:
    torch.manual_seed(0)
    policy = _policy()
    rng = np.random.default_rng(0)
    obs = torch.as_tensor(rng.normal(size=(5, 16)), dtype=torch.float32)
    outputs = []
    for privileged in (torch.zeros(5, 16), torch.full((5, 16), math.nan), obs * 7.0):
        with torch.no_grad():
            actions, values, _ = policy({ACTOR_KEY: obs, PRIVILEGED_KEY: privileged}, True)
        outputs.append((actions, values))
    # The actor's output is the same whatever the privileged entry holds (even NaN) ...
    for actions, _ in outputs[1:]:
        assert torch.equal(actions, outputs[0][0])
    # ... while the critic reads it.
    assert not torch.allclose(outputs[0][1], outputs[2][1])
    assert torch.isnan(outputs[1][1]).all()
    # The deployment path needs no privileged entry and gives the same actions.
    deployed = policy.actor_action(obs.numpy())
    np.testing.assert_allclose(deployed, np.clip(outputs[0][0].numpy(), -1, 1), atol=1e-6)
    # The critic's input is the actor's observation and the privileged one.
    assert policy.vf_features_extractor.features_dim == 32
    assert policy.pi_features_extractor.features_dim == 16


def test_policy_rejects_a_plain_observation_space() -> None:
    box = gym.spaces.Box(-1.0, 1.0, (16,), np.float32)
    with pytest.raises(ValueError, match="privileged"):
        AsymmetricActorCriticPolicy(box, box, lambda _: 1e-3)


def test_privileged_observation_is_the_truth_twin_of_the_observation() -> None:
    """With the Oracle the estimate is the truth: both entries must be equal, every step and
    in the terminal observations; with EKF-SLAM they differ by the estimation error."""
    oracle = QuadSLAMVecEnv("QuadSLAM-Oracle-v0", 3, seed=1, privileged=True, **SHORT)
    obs = oracle.reset()
    assert set(obs) == {ACTOR_KEY, PRIVILEGED_KEY}
    np.testing.assert_array_equal(obs[ACTOR_KEY], obs[PRIVILEGED_KEY])
    action = np.tile(oracle.get_attr("hover_action")[0], (3, 1)).astype(np.float32)
    ended = 0
    for _ in range(35):
        obs, _, dones, infos = oracle.step(action)
        np.testing.assert_array_equal(obs[ACTOR_KEY], obs[PRIVILEGED_KEY])
        for i in np.flatnonzero(dones):
            final = infos[i]["terminal_observation"]
            np.testing.assert_array_equal(final[ACTOR_KEY], final[PRIVILEGED_KEY])
            ended += 1
    assert ended == 3
    oracle.close()
    ekf = QuadSLAMVecEnv("QuadSLAM-EKF-v0", 2, seed=1, privileged=True, **SHORT)
    ekf.reset()
    for _ in range(20):
        obs, *_ = ekf.step(action[:2])
    err = np.abs(obs[ACTOR_KEY][:, :3] - obs[PRIVILEGED_KEY][:, :3])
    assert (err > 0).all() and (err < 1.0).all()  # a position error, m
    ekf.close()


def test_stagger_cuts_first_episodes_at_spread_lengths() -> None:
    lanes, max_steps = 4, 30
    venv = QuadSLAMVecEnv("QuadSLAM-Oracle-v0", lanes, seed=0, stagger=True, **SHORT)
    venv.reset()
    action = np.tile(venv.get_attr("hover_action")[0], (lanes, 1)).astype(np.float32)
    first_end = np.zeros(lanes, dtype=int)
    for step in range(1, 2 * max_steps + 1):
        _, _, dones, infos = venv.step(action)
        for i in np.flatnonzero(dones):
            if first_end[i] == 0:
                first_end[i] = step
                assert infos[i]["TimeLimit.truncated"]
            else:  # later episodes run their full length
                assert step - first_end[i] == max_steps
    expected = [math.ceil(max_steps * (i + 1) / lanes) for i in range(lanes)]
    np.testing.assert_array_equal(first_end, expected)
    venv.close()


def test_train_and_deploy_asymmetric_ppo(tmp_path: Path) -> None:
    run = train(
        "ppo",
        "QuadSLAM-EKF-v0",
        timesteps=128,
        n_envs=2,
        out_dir=tmp_path,
        progress=False,
        hyperparams={
            "policy": "AsymmetricActorCriticPolicy",
            "n_steps": 32,
            "batch_size": 32,
            "n_epochs": 1,
            "policy_kwargs": {"net_arch": [8]},
            "env_kwargs": SHORT,
            "eval_freq": 64,
            "n_eval_episodes": 2,
            "checkpoint_freq": 0,
        },
    )
    env = gym.make("QuadSLAM-EKF-v0", scenario="ekf_figure8_biased_imu", **SHORT)
    policy = load_model(run, env)
    assert policy.actor_only and policy.observation_space == env.observation_space
    obs, _ = env.reset(seed=3)
    action, _ = policy.predict(obs)
    assert action.shape == (4,) and np.isfinite(action).all()
    # Deployment reads the actor's observation only: the batch path agrees row by row.
    batch, _ = policy.predict(np.stack([obs, obs]))
    np.testing.assert_allclose(batch, np.stack([action, action]), atol=1e-6)


def test_asymmetric_policy_is_rejected_for_off_policy_algorithms(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="on-policy"):
        train(
            "sac",
            "QuadSLAM-EKF-v0",
            timesteps=64,
            out_dir=tmp_path,
            progress=False,
            hyperparams={"policy": "AsymmetricActorCriticPolicy"},
        )
