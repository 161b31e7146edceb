"""Asymmetric actor-critic for SB3's PPO: the actor flies on the estimate, the critic also sees
the truth during training.

The training env's observation is a dict (:class:`agents.rl.vec_adapter.QuadSLAMVecEnv` with
``privileged=True``):

- ``"obs"``: the env's observation, built from the *estimate* (what a deployed agent sees);
- ``"privileged"``: the same observation built from the *true* state
  (:meth:`quadslam_env.core.SimCore.true_observation`), so the estimation error is
  ``obs − privileged`` in every block.

:class:`AsymmetricActorCriticPolicy` feeds ``obs`` alone to the actor and ``obs`` together with
``privileged`` to the critic. The critic sees the actor's observation as well as the state: a
critic of the state alone is biased under partial observability (Baisero & Amato, "Unbiased
Asymmetric Reinforcement Learning under Partial Observability", AAMAS 2022); learning-to-fly
(Eschmann et al., RA-L 2024) trains its quadrotor policy with such a privileged critic. At
deployment only the actor runs (:meth:`AsymmetricActorCriticPolicy.actor_action`), on the plain
observation array; the privileged entries are never read.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.policies import ActorCriticPolicy
from stable_baselines3.common.torch_layers import BaseFeaturesExtractor, MlpExtractor
from torch import nn

from agents.rl.lane_share import ACTOR_KEY, PRIVILEGED_KEY
from agents.rl.policy_kwargs import ASYMMETRIC, check_fixed_policy_kwargs


class SelectKeys(BaseFeaturesExtractor):
    """Concatenate the (flat) entries ``keys`` of a dict observation; other keys are ignored.

    Args:
        observation_space: The dict space.
        keys: Entries to read, in order.
    """

    def __init__(self, observation_space: gym.spaces.Dict, keys: tuple[str, ...]) -> None:
        dims = [int(np.prod(observation_space[key].shape or ())) for key in keys]
        super().__init__(observation_space, features_dim=sum(dims))
        self.keys = tuple(keys)

    def forward(self, observations: dict[str, th.Tensor]) -> th.Tensor:
        """(n, features_dim): the selected entries, flattened and concatenated."""
        return th.cat([th.flatten(observations[key], start_dim=1) for key in self.keys], dim=1)


class _SplitMlpExtractor(nn.Module):
    """Policy and value MLPs with different input widths (SB3's ``MlpExtractor`` has one)."""

    def __init__(
        self, pi_dim: int, vf_dim: int, net_arch: Any, activation_fn: type[nn.Module]
    ) -> None:
        super().__init__()
        arch = net_arch if isinstance(net_arch, dict) else {"pi": net_arch, "vf": net_arch}
        self.policy_net = MlpExtractor(pi_dim, {"pi": arch["pi"], "vf": []}, activation_fn)
        self.value_net = MlpExtractor(vf_dim, {"pi": [], "vf": arch["vf"]}, activation_fn)
        self.latent_dim_pi = self.policy_net.latent_dim_pi
        self.latent_dim_vf = self.value_net.latent_dim_vf

    def forward_actor(self, features: th.Tensor) -> th.Tensor:
        """Actor latent from the actor features."""
        return self.policy_net.forward_actor(features)

    def forward_critic(self, features: th.Tensor) -> th.Tensor:
        """Critic latent from the critic features."""
        return self.value_net.forward_critic(features)


class AsymmetricActorCriticPolicy(ActorCriticPolicy):
    """PPO/A2C policy whose actor reads ``obs`` and whose critic reads ``obs`` + ``privileged``.

    Takes ``ActorCriticPolicy``'s arguments (``net_arch``, ``activation_fn``, ``log_std_init``,
    ...); the features extractors are fixed (:class:`SelectKeys`) and never shared.

    Raises:
        ValueError: The observation space is not a dict with ``obs`` and ``privileged``, or
            ``features_extractor_class``/``features_extractor_kwargs`` are given
            (:func:`agents.rl.hyperparams.check_fixed_policy_kwargs`).
    """

    def __init__(
        self,
        observation_space: gym.spaces.Space,
        action_space: gym.spaces.Space,
        lr_schedule: Any,
        **kwargs: Any,
    ) -> None:
        if not (
            isinstance(observation_space, gym.spaces.Dict)
            and set(observation_space.spaces) == {ACTOR_KEY, PRIVILEGED_KEY}
        ):
            raise ValueError(
                f"AsymmetricActorCriticPolicy: got observation space {observation_space}; "
                f"allowed: a Dict with keys {ACTOR_KEY!r} and {PRIVILEGED_KEY!r} (train with "
                "privileged observations)"
            )
        check_fixed_policy_kwargs(kwargs, ASYMMETRIC)
        kwargs["share_features_extractor"] = False
        super().__init__(
            observation_space,
            action_space,
            lr_schedule,
            features_extractor_class=SelectKeys,
            features_extractor_kwargs={"keys": (ACTOR_KEY,)},
            **kwargs,
        )

    def _build_mlp_extractor(self) -> None:
        # ActorCriticPolicy built both extractors from features_extractor_kwargs (actor keys);
        # the critic's reads the privileged entry too.
        space = self.observation_space
        assert isinstance(space, gym.spaces.Dict)  # checked in __init__
        self.vf_features_extractor = SelectKeys(space, (ACTOR_KEY, PRIVILEGED_KEY))
        self.mlp_extractor = _SplitMlpExtractor(  # type: ignore[assignment]
            self.pi_features_extractor.features_dim,
            self.vf_features_extractor.features_dim,
            self.net_arch,
            self.activation_fn,
        )

    def actor_action(self, observation: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Actions (n, act_dim) for plain (already normalised) observations (n, obs_dim).

        The deployment path: only the actor runs, and nothing privileged is needed.
        """
        self.set_training_mode(False)
        with th.no_grad():
            obs = th.as_tensor(np.asarray(observation, dtype=np.float32), device=self.device)
            features = self.pi_features_extractor({ACTOR_KEY: obs})
            latent = self.mlp_extractor.forward_actor(features)
            actions = self._get_action_dist_from_latent(latent).get_actions(deterministic)
        out = actions.cpu().numpy()
        assert isinstance(self.action_space, gym.spaces.Box)
        return np.clip(out, self.action_space.low, self.action_space.high)
