"""``policy_kwargs`` of the agent configs: plain data, checked key by key, never evaluated;
turned into SB3's keyword arguments (``activation_fn`` → a ``torch.nn`` class) only when the
model is built (docs/design.md §6, §7).
"""

from __future__ import annotations

import contextlib
import copy
import math
from collections.abc import Callable, Iterable
from typing import Any

from quadslam_env.schema import ConfigError

# The policy name of agents.rl.asymmetric.AsymmetricActorCriticPolicy (actor on the estimate,
# critic also on the truth); it makes train() build privileged dict observations.
ASYMMETRIC = "AsymmetricActorCriticPolicy"
#: ``policy_kwargs.activation_fn`` names → ``torch.nn`` classes (resolved when the model is
#: built); the class names (``Tanh``, ``nn.ReLU``) are accepted too.
ACTIVATIONS: dict[str, str] = {
    "tanh": "Tanh",
    "relu": "ReLU",
    "elu": "ELU",
    "leaky_relu": "LeakyReLU",
    "silu": "SiLU",
    "gelu": "GELU",
    "sigmoid": "Sigmoid",
}
#: ``policy_kwargs`` that AsymmetricActorCriticPolicy sets itself.
ASYMMETRIC_FIXED_KWARGS = ("features_extractor_class", "features_extractor_kwargs")
_NET_ARCH_HEADS = ("pi", "vf", "qf")


def _activation_name(value: Any) -> str | None:
    """The :data:`ACTIVATIONS` key that ``value`` names (``tanh``, ``Tanh``, ``nn.Tanh``)."""
    if not isinstance(value, str):
        return None
    name = value.strip()
    for prefix in ("torch.nn.", "th.nn.", "nn."):
        if name.startswith(prefix):
            name = name[len(prefix) :]
            break
    key = name.lower().replace("_", "")
    for snake, cls_name in ACTIVATIONS.items():
        if key in (snake.replace("_", ""), cls_name.lower()):
            return snake
    return None


def _plain_int(value: Any) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


def _plain_number(key: str, value: Any) -> float | int:
    """A finite int/float (numeric strings such as ``1e-5`` too, as YAML may leave them)."""
    number = value
    if isinstance(value, str):
        with contextlib.suppress(ValueError):
            number = float(value)
    if isinstance(number, (int, float)) and not isinstance(number, bool) and math.isfinite(number):
        return number
    raise ConfigError(f"{key}: got {value!r}; allowed: a finite number")


def _check_bool(key: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ConfigError(f"{key}: got {value!r}; allowed: true or false")
    return value


def _check_layers(key: str, value: Any) -> list[int]:
    if not isinstance(value, list) or not all(_plain_int(v) and v > 0 for v in value):
        raise ConfigError(f"{key}: got {value!r}; allowed: a list of positive integers")
    return list(value)


def _check_net_arch(key: str, value: Any) -> list[int] | dict[str, list[int]]:
    if isinstance(value, dict):
        unknown = [k for k in value if k not in _NET_ARCH_HEADS]
        if unknown:
            raise ConfigError(
                f"{key}.{unknown[0]}: unknown network; allowed: {list(_NET_ARCH_HEADS)} (each a "
                "list of layer widths)"
            )
        return {k: _check_layers(f"{key}.{k}", v) for k, v in value.items()}
    if isinstance(value, list):
        return _check_layers(key, value)
    raise ConfigError(
        f"{key}: got {value!r}; allowed: a list of layer widths ([64, 64]) or a mapping of "
        f"them per network ({{pi: [64, 64], vf: [64, 64]}}; keys {list(_NET_ARCH_HEADS)})"
    )


def _check_activation(key: str, value: Any) -> str:
    name = _activation_name(value)
    if name is None:
        raise ConfigError(f"{key}: got {value!r}; allowed: one of {list(ACTIVATIONS)}")
    return name


def _check_n_critics(key: str, value: Any) -> int:
    if not _plain_int(value) or value < 1:
        raise ConfigError(f"{key}: got {value!r}; allowed: a positive integer")
    return int(value)


def _check_optimizer_kwargs(key: str, value: Any) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise ConfigError(
            f"{key}: got {value!r}; allowed: a mapping of optimizer arguments to numbers "
            "({eps: 1.0e-5, weight_decay: 0.0, betas: [0.9, 0.999]})"
        )
    out: dict[str, Any] = {}
    for name, item in value.items():
        where = f"{key}.{name}"
        if not isinstance(name, str) or not name.isidentifier():
            raise ConfigError(f"{key}: got key {name!r}; allowed: optimizer argument names")
        if isinstance(item, bool):
            out[name] = item
        elif isinstance(item, list):
            out[name] = [_plain_number(where, v) for v in item]
        else:
            out[name] = _plain_number(where, item)
    return out


#: The allowed ``policy_kwargs`` (plain data only) and their checks.
_POLICY_KWARGS: dict[str, Callable[[str, Any], Any]] = {
    "net_arch": _check_net_arch,
    "activation_fn": _check_activation,
    "ortho_init": _check_bool,
    "log_std_init": _plain_number,
    "full_std": _check_bool,
    "use_expln": _check_bool,
    "squash_output": _check_bool,
    "clip_mean": _plain_number,
    "share_features_extractor": _check_bool,
    "normalize_images": _check_bool,
    "n_critics": _check_n_critics,
    "optimizer_kwargs": _check_optimizer_kwargs,
}
POLICY_KWARGS_KEYS = tuple(_POLICY_KWARGS)


def check_fixed_policy_kwargs(keys: Iterable[str], policy: str | None) -> None:
    """Reject ``policy_kwargs`` that ``policy`` sets itself.

    Runs on a config's ``policy_kwargs`` (:func:`validate_policy_kwargs`) and when
    :class:`agents.rl.asymmetric.AsymmetricActorCriticPolicy` is constructed.

    Args:
        keys: The given ``policy_kwargs`` names.
        policy: The policy name.

    Raises:
        ConfigError: A key fixed by the policy.
    """
    if policy != ASYMMETRIC:
        return
    for key in keys:
        if key in ASYMMETRIC_FIXED_KWARGS:
            raise ConfigError(f"policy_kwargs.{key}: fixed by {ASYMMETRIC}")


def validate_policy_kwargs(value: Any, policy: str | None = None) -> dict[str, Any]:
    """Check ``policy_kwargs`` of a config: a mapping of plain data, never code.

    ``activation_fn`` stays a name from :data:`ACTIVATIONS` (``"tanh"``, ``"relu"``, …; the
    ``torch.nn`` class names are accepted); :func:`build_policy_kwargs` turns it into the class
    when the model is built. Allowed keys: :data:`POLICY_KWARGS_KEYS` (``net_arch`` a list of
    positive integers or a mapping of them with keys ``pi``/``vf``/``qf``; ``ortho_init``,
    ``full_std``, ``use_expln``, ``squash_output``, ``share_features_extractor``,
    ``normalize_images`` booleans; ``log_std_init``, ``clip_mean`` numbers; ``n_critics`` a
    positive integer; ``optimizer_kwargs`` a mapping to numbers, booleans or lists of numbers).
    Which keys a policy takes is SB3's to check when the model is built.

    Args:
        value: The ``policy_kwargs`` entry (``None``: none).
        policy: The policy name; ``AsymmetricActorCriticPolicy`` fixes some keys.

    Returns:
        A validated copy (plain data; activation names canonical, e.g. ``"tanh"``).

    Raises:
        ConfigError: Not a mapping (a ``"dict(...)"`` string included), an unknown key or a
            bad value; the one-line message names the key, the value and what is allowed.
    """
    if value is None:
        return {}
    if not isinstance(value, dict):
        note = " (strings are not evaluated)" if isinstance(value, str) else ""
        raise ConfigError(
            f"policy_kwargs: got {value!r}{note}; allowed: a mapping of plain values such as "
            f"{{net_arch: [64, 64], activation_fn: tanh}} (activation_fn one of "
            f"{list(ACTIVATIONS)}; keys {list(POLICY_KWARGS_KEYS)})"
        )
    check_fixed_policy_kwargs([str(k) for k in value], policy)
    out: dict[str, Any] = {}
    for key, item in value.items():
        check = _POLICY_KWARGS.get(key) if isinstance(key, str) else None
        if check is None:
            raise ConfigError(
                f"policy_kwargs.{key}: unknown key; allowed: {list(POLICY_KWARGS_KEYS)}"
            )
        out[key] = check(f"policy_kwargs.{key}", item)
    return out


def build_policy_kwargs(policy_kwargs: dict[str, Any] | None) -> dict[str, Any]:
    """Validated ``policy_kwargs`` → SB3 keyword arguments (``activation_fn`` → ``torch.nn``).

    Args:
        policy_kwargs: Plain ``policy_kwargs`` (as :func:`validate_policy_kwargs` returns).

    Raises:
        ConfigError: An invalid entry (it is validated again).
    """
    from torch import nn

    out = copy.deepcopy(validate_policy_kwargs(policy_kwargs))
    if "activation_fn" in out:
        out["activation_fn"] = getattr(nn, ACTIVATIONS[out["activation_fn"]])
    return out
