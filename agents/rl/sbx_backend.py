"""The JAX learner backend (``backend: sbx``): PPO from sbx, SB3's JAX sibling (the
training docs, "Learner backends").

Everything sbx-specific lives here: which settings it takes (:func:`check_settings`, which does
not import sbx, so a run folder of this backend is read and evaluated without it), building and
loading the model (:func:`build_model`, :func:`load_model`, behind a one-line error naming the
``sbx`` extra), the activation names mapped to ``flax.linen`` (:data:`FLAX_ACTIVATIONS`), and
the conversion of sbx's flax parameters into the ``state_dict`` layout of SB3's torch
``ActorCriticPolicy`` (:func:`torch_layout`), which :func:`agents.rl.saved.safe_files.write_policy`
writes as ``policy.npz``: evaluation rebuilds the torch policy from it as for an SB3 run.

sbx's PPO takes SB3's constructor arguments. What differs, and is therefore refused or set
here:

- gSDE: sbx's own comment says it is "not properly implemented" (``use_sde`` only reuses one
  Gaussian noise sample for ``sde_sample_freq`` steps; there is no state-dependent noise), so
  ``use_sde: true`` is refused;
- ``clip_range_vf`` is accepted by sbx's constructor and then ignored, so it is refused;
- ``target_kl`` adapts sbx's learning rate to the KL divergence (overriding the schedule), where
  SB3 stops the epochs early: the same key, another method;
- ``policy_kwargs``: ``net_arch``, ``log_std_init``, ``ortho_init`` and ``activation_fn``
  only; ``ortho_init`` defaults to true as in SB3 (sbx's default is false). sbx's
  ``ortho_init`` initialises the action layer alone, orthogonal with gain 0.01 and zero bias
  (a residual policy starts near zero, as with SB3); the hidden layers keep flax's LeCun-normal
  initialisation where SB3 makes them orthogonal with gain √2;
- ``policy: MlpPolicy`` only (the privileged critic, :mod:`agents.rl.asymmetric`, is torch).
"""

from __future__ import annotations

import functools
import re
from typing import Any

import numpy as np

from agents.rl.policy_kwargs import validate_policy_kwargs
from quadslam_env.extras import require
from quadslam_env.schema import ConfigError

BACKENDS = ("sb3", "sbx")
"""The learner backends: SB3 on torch (the default), sbx on JAX."""

ALGOS = ("ppo",)
"""The algorithms of the sbx backend."""

ALGO_KWARGS = (
    "learning_rate",
    "n_steps",
    "batch_size",
    "n_epochs",
    "gamma",
    "gae_lambda",
    "clip_range",
    "normalize_advantage",
    "ent_coef",
    "vf_coef",
    "max_grad_norm",
    "use_sde",
    "sde_sample_freq",
    "target_kl",
    "device",
)
"""The algorithm arguments of a PPO entry that sbx's PPO takes and uses as SB3's does
(``use_sde`` only false; ``sde_sample_freq`` then unused, as in SB3)."""

POLICY_KWARGS = ("net_arch", "log_std_init", "ortho_init", "activation_fn")
"""The ``policy_kwargs`` of the sbx backend."""

FLAX_ACTIVATIONS: dict[str, str] = {
    "tanh": "tanh",
    "relu": "relu",
    "elu": "elu",
    "leaky_relu": "leaky_relu",
    "silu": "silu",
    "gelu": "gelu",
    "sigmoid": "sigmoid",
}
"""``policy_kwargs.activation_fn`` names (:data:`agents.rl.policy_kwargs.ACTIVATIONS`) →
``flax.linen`` functions; each computes what the ``torch.nn`` class of the same name does with
its defaults (GELU exact, not tanh-approximated: flax's default is the approximation)."""

TORCH_POLICY_CLASS = "ActorCriticPolicy"
"""The SB3 policy class whose ``state_dict`` layout :func:`torch_layout` writes."""

SBX_DEFAULT_POLICY_KWARGS: dict[str, Any] = {"ortho_init": True}
"""Where the sbx backend departs from sbx's defaults to match SB3's (an entry's own value wins)."""


def check_backend(value: Any) -> str:
    """The ``backend`` of an entry, checked.

    Raises:
        ConfigError: Not one of :data:`BACKENDS`.
    """
    if not isinstance(value, str) or value not in BACKENDS:
        raise ConfigError(f"backend: got {value!r}; allowed: {list(BACKENDS)}")
    return value


def check_settings(
    algo: str, policy: str, algo_kwargs: dict[str, Any], policy_kwargs: dict[str, Any]
) -> None:
    """Refuse what the sbx backend does not do as SB3 does (without importing sbx).

    Args:
        algo: The algorithm name.
        policy: The entry's ``policy``.
        algo_kwargs: The algorithm arguments (already checked against SB3's constructor).
        policy_kwargs: The validated ``policy_kwargs``.

    Raises:
        ConfigError: Another algorithm than PPO, another policy than ``MlpPolicy``, ``use_sde``
            true, or an argument or ``policy_kwargs`` key the backend does not take; the
            message names the key, the value and what is allowed.
    """
    if algo not in ALGOS:
        raise ConfigError(
            f"backend: got 'sbx' with algo {algo!r}; allowed: 'sbx' with algo "
            f"{' or '.join(repr(a) for a in ALGOS)}, or 'sb3' with any algo"
        )
    if policy != "MlpPolicy":
        raise ConfigError(
            f"policy: got {policy!r} with backend: sbx; allowed: 'MlpPolicy' (backend: sb3 for "
            "other policies)"
        )
    if algo_kwargs.get("use_sde"):
        raise ConfigError(
            f"use_sde: got {algo_kwargs['use_sde']!r} with backend: sbx; allowed: false (sbx's "
            "PPO does not implement gSDE: it only reuses one Gaussian noise sample for "
            "sde_sample_freq steps); set use_sde: false (--hyperparams use_sde=false) for "
            "Gaussian action noise, or train gSDE with backend: sb3"
        )
    for key, value in algo_kwargs.items():
        if key not in ALGO_KWARGS:
            raise ConfigError(
                f"{key}: got {value!r} with backend: sbx, whose PPO does not take or use it; "
                f"allowed: {list(ALGO_KWARGS)} (or backend: sb3)"
            )
    for key in policy_kwargs:
        if key not in POLICY_KWARGS:
            raise ConfigError(
                f"policy_kwargs.{key}: not taken with backend: sbx; allowed: "
                f"{list(POLICY_KWARGS)} (or backend: sb3)"
            )


def require_sbx() -> Any:
    """The ``sbx`` module, or a one-line error naming the ``sbx`` extra.

    Raises:
        quadslam_env.extras.MissingExtraError: sbx is not installed.
    """
    return require("sbx", "sbx", "training with backend: sbx")


def flax_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """Validated plain ``policy_kwargs`` → sbx's ``PPOPolicy`` keyword arguments.

    ``activation_fn`` becomes the ``flax.linen`` function (:data:`FLAX_ACTIVATIONS`),
    ``ortho_init`` defaults to true (:data:`SBX_DEFAULT_POLICY_KWARGS`), and a ``net_arch``
    mapping gets an empty list for a missing ``pi`` or ``vf`` (as SB3 reads it).

    Raises:
        ConfigError: An invalid entry, or a key the backend does not take.
    """
    from flax import linen

    out = {**SBX_DEFAULT_POLICY_KWARGS, **validate_policy_kwargs(policy_kwargs)}
    for key in out:
        if key not in POLICY_KWARGS:
            raise ConfigError(f"policy_kwargs.{key}: not taken with backend: sbx")
    if "activation_fn" in out:
        name = out["activation_fn"]
        function = getattr(linen, FLAX_ACTIVATIONS[name])
        out["activation_fn"] = (
            functools.partial(function, approximate=False) if name == "gelu" else function
        )
    arch = out.get("net_arch")
    if isinstance(arch, dict):
        out["net_arch"] = {"pi": list(arch.get("pi", [])), "vf": list(arch.get("vf", []))}
    return out


def build_model(algo: str, settings: dict[str, Any], venv: Any, seed: int, verbose: int) -> Any:
    """sbx's ``algo`` on ``venv`` with the resolved settings (see the module's notes).

    Raises:
        quadslam_env.extras.MissingExtraError: sbx is not installed.
        ConfigError: A setting the backend does not take.
    """
    sbx = require_sbx()
    check_settings(algo, settings["policy"], settings["algo_kwargs"], settings["policy_kwargs"])
    return sbx.PPO(
        settings["policy"],
        venv,
        seed=seed,
        policy_kwargs=flax_policy_kwargs(settings["policy_kwargs"]),
        verbose=verbose,
        **settings["algo_kwargs"],
    )


def load_model(algo: str, path: Any, venv: Any) -> Any:
    """An sbx model saved by ``model.save`` (``--resume``: it unpickles the zip's ``data``).

    Raises:
        quadslam_env.extras.MissingExtraError: sbx is not installed.
    """
    sbx = require_sbx()
    if algo not in ALGOS:
        raise ConfigError(f"backend: got 'sbx' with algo {algo!r}; allowed: {list(ALGOS)}")
    return sbx.PPO.load(path, env=venv, device="cpu")


def is_sbx_model(model: Any) -> bool:
    """Whether ``model`` is an sbx algorithm (without importing sbx)."""
    return type(model).__module__.split(".")[0] == "sbx"


def _dense_layers(params: Any, what: str) -> list[tuple[np.ndarray, np.ndarray]]:
    """The ``(kernel, bias)`` of flax's ``Dense_0``, ``Dense_1``, … in order."""
    found: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    for name, layer in params.items():
        match = re.fullmatch(r"Dense_(\d+)", str(name))
        if match:
            found[int(match.group(1))] = (np.asarray(layer["kernel"]), np.asarray(layer["bias"]))
    if sorted(found) != list(range(len(found))) or not found:
        raise ValueError(f"the {what}'s parameters: got layers {sorted(params)}; allowed: Dense_0…")
    return [found[i] for i in range(len(found))]


def _linear(prefix: str, kernel: np.ndarray, bias: np.ndarray) -> dict[str, np.ndarray]:
    """A torch ``nn.Linear``'s entries: its weight is flax's kernel (in, out) transposed."""
    weight = np.ascontiguousarray(kernel.T, dtype=np.float32)
    return {f"{prefix}.weight": weight, f"{prefix}.bias": np.asarray(bias, dtype=np.float32)}


def torch_layout(model: Any) -> dict[str, np.ndarray]:
    """An sbx PPO model's parameters as the ``state_dict`` of SB3's torch
    ``ActorCriticPolicy`` with the same ``net_arch`` and activation (separate actor and
    critic networks, a flattened observation, a diagonal Gaussian with state-independent
    ``log_std``).

    The actor's ``Dense_i`` (all but the last) become ``mlp_extractor.policy_net.{2i}``, its
    last ``action_net``; the critic's become ``mlp_extractor.value_net.{2i}`` and
    ``value_net``; ``log_std`` stays ``log_std``. Each weight is the flax kernel transposed.
    The deterministic actions of SB3's policy with these weights are sbx's, to float32
    precision.

    Raises:
        ValueError: Not the parameters of sbx's MLP ``PPOPolicy`` on a Box action space.
    """
    actor = model.policy.actor_state.params["params"]
    critic = model.policy.vf_state.params["params"]
    if "log_std" not in actor:
        raise ValueError("the actor's parameters have no log_std (a Box action space only)")
    out: dict[str, np.ndarray] = {"log_std": np.asarray(actor["log_std"], dtype=np.float32)}
    for heads, (hidden, last) in (
        (_dense_layers(actor, "actor"), ("mlp_extractor.policy_net", "action_net")),
        (_dense_layers(critic, "critic"), ("mlp_extractor.value_net", "value_net")),
    ):
        for i, (kernel, bias) in enumerate(heads[:-1]):
            out.update(_linear(f"{hidden}.{2 * i}", kernel, bias))
        out.update(_linear(last, *heads[-1]))
    return out
