"""Zoo-style hyperparameter files: reading, validation, overrides (docs/design.md §6).

Hyperparameters live in ``configs/agents/<algo>.yaml`` (package data: ``quadslam_env.configs``),
keyed by env id (rl-baselines3-zoo style). Each entry may hold:

==================  =========================================================================
key                 meaning
==================  =========================================================================
``n_envs``          lanes of the native vector env (one process; ``agents.rl.vec_adapter``)
``n_timesteps``     total env steps (over all envs)
``policy``          SB3 policy name, e.g. ``MlpPolicy``, or ``AsymmetricActorCriticPolicy``
                    (PPO/A2C; :mod:`agents.rl.asymmetric`: the critic also sees the truth)
``policy_kwargs``   a mapping of plain data, e.g. ``{net_arch: [64, 64], activation_fn: tanh}``
                    (:mod:`agents.rl.policy_kwargs` lists the keys; strings are
                    rejected, never evaluated)
``env_kwargs``      keyword arguments of ``gymnasium.make`` (``scenario``, section overrides)
``wrapper``         ``none`` or ``{name: residual_dflqr, scale: …}``
                    (see :mod:`agents.rl.wrappers`)
``normalize``       ``false``, ``true`` or ``VecNormalize`` kwargs (``{norm_obs: true,
                    norm_reward: false}``)
``eval_freq``       env steps between ``EvalCallback`` evaluations (0: off; default 50 000)
``n_eval_episodes`` episodes per evaluation (default 3)
``checkpoint_freq`` env steps between checkpoints (0: off; default 100 000)
``backend``         the learner: ``sb3`` (torch, the default) or ``sbx`` (JAX, PPO only;
                    :mod:`agents.rl.sbx_backend`); ``quadslam train --backend`` overrides it
anything else       keyword arguments of the algorithm (``learning_rate``, ``n_steps``, …);
                    ``lin_<x>`` means a linear schedule from ``x`` to 0, numeric strings
                    such as ``3e-4`` (YAML reads them as strings) become numbers
==================  =========================================================================
"""

from __future__ import annotations

import copy
import inspect
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import yaml

from agents.rl import sbx_backend
from agents.rl.policy_kwargs import ASYMMETRIC, validate_policy_kwargs
from agents.rl.wrappers import parse_wrapper_spec
from quadslam_env.config.files import parse_yaml
from quadslam_env.extras import require

RESERVED_KEYS = (
    "n_envs",
    "n_timesteps",
    "policy",
    "policy_kwargs",
    "env_kwargs",
    "wrapper",
    "normalize",
    "eval_freq",
    "n_eval_episodes",
    "checkpoint_freq",
    "backend",
)
DEFAULTS: dict[str, Any] = {
    "n_envs": 1,
    "policy": "MlpPolicy",
    "policy_kwargs": None,
    "env_kwargs": {},
    "wrapper": None,
    "normalize": False,
    "eval_freq": 50_000,
    "n_eval_episodes": 3,
    "checkpoint_freq": 100_000,
    "backend": "sb3",
}
# Algorithm arguments that a config may not set (objects, or set by train() itself).
_FORBIDDEN_ALGO_KWARGS = (
    "self",
    "env",
    "seed",
    "tensorboard_log",
    "action_noise",
    "replay_buffer_class",
    "rollout_buffer_class",
    "_init_setup_model",
)
_SCHEDULE_KEYS = ("learning_rate", "clip_range", "clip_range_vf")
_VECNORMALIZE_KEYS = ("norm_obs", "norm_reward", "clip_obs", "clip_reward", "gamma", "epsilon")


def algorithms() -> dict[str, type]:
    """Supported algorithm names → SB3 classes (imported lazily; ``quadslam[rl]``)."""
    require("stable_baselines3", "rl", "training and loading agents")
    from stable_baselines3 import A2C, PPO, SAC, TD3

    return {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C}


# ---------------------------------------------------------------------------- configuration
def default_config_path(algo: str) -> Path:
    """``configs/agents/<algo>.yaml`` (honours ``QUADSLAM_CONFIG_DIR``)."""
    from quadslam_env.config.files import config_dir

    return config_dir() / "agents" / f"{algo.lower()}.yaml"


def _read_yaml(path: Path) -> Any:
    try:
        text = Path(path).read_text()
    except OSError as exc:
        raise FileNotFoundError(f"config file {str(path)!r}: cannot be read ({exc})") from exc
    try:
        return parse_yaml(text)
    except yaml.YAMLError as exc:
        raise ValueError(f"config file {str(path)!r}: malformed YAML ({exc})") from exc


def load_hyperparams(algo: str, env_id: str, config_path: str | Path | None = None) -> dict:
    """The raw config entry for ``env_id`` (a copy).

    Args:
        algo: Algorithm name (selects the default file ``configs/agents/<algo>.yaml``).
        env_id: Env id, the key of the entry.
        config_path: Another zoo-style file, or a run folder's ``config.yaml`` (whose
            ``hyperparams`` are used when its ``env_id`` matches).

    Raises:
        FileNotFoundError: The file does not exist.
        ValueError: Malformed YAML, or no entry for ``env_id``.
    """
    path = Path(config_path) if config_path is not None else default_config_path(algo)
    data = _read_yaml(path)
    if not isinstance(data, dict):
        raise ValueError(
            f"config file {str(path)!r}: got {type(data).__name__}; allowed: a mapping of env "
            "ids to hyperparameter entries"
        )
    if "hyperparams" in data and "env_id" in data:  # a run folder's config.yaml
        if data["env_id"] != env_id:
            raise ValueError(
                f"config file {str(path)!r}: a run config for env {data['env_id']!r}, "
                f"not {env_id!r}"
            )
        entry = data["hyperparams"]
    elif env_id in data:
        entry = data[env_id]
    else:
        raise ValueError(
            f"config file {str(path)!r}: no entry for env {env_id!r}; "
            f"available: {sorted(str(k) for k in data)}"
        )
    if not isinstance(entry, dict):
        raise ValueError(
            f"config file {str(path)!r}: entry {env_id!r} must be a mapping, "
            f"got {type(entry).__name__}"
        )
    return copy.deepcopy(entry)


def parse_normalize(value: Any) -> dict[str, Any] | None:
    """``normalize`` entry → ``VecNormalize`` kwargs, or ``None`` when off.

    Raises:
        ValueError: Not a bool or a mapping of ``VecNormalize`` arguments.
    """
    if isinstance(value, str):
        low = value.strip().lower()
        if low in ("true", "false", "none", ""):
            value = low == "true"
        else:
            try:  # YAML flow syntax, e.g. "{norm_obs: true}" (plain data, never evaluated)
                value = parse_yaml(value)
            except yaml.YAMLError as exc:
                raise ValueError(f"normalize: cannot parse {value!r}") from exc
    if value is None or value is False:
        return None
    if value is True:
        return {}
    if isinstance(value, dict):
        unknown = set(value) - set(_VECNORMALIZE_KEYS)
        if unknown:
            raise ValueError(
                f"normalize.{sorted(unknown)[0]}: unknown key; allowed: {list(_VECNORMALIZE_KEYS)}"
            )
        return dict(value)
    raise ValueError(f"normalize: got {value!r}; allowed: true, false or VecNormalize kwargs")


def _to_number(key: str, value: Any, default: Any) -> Any:
    """Numeric strings → numbers, ``lin_<x>`` → linear schedule; ints where SB3 expects ints."""
    from stable_baselines3.common.utils import LinearSchedule

    if isinstance(value, str):
        if value.startswith("lin_") and key in _SCHEDULE_KEYS:
            try:
                return LinearSchedule(float(value[4:]), 0.0, 1.0)
            except ValueError:
                raise ValueError(f"{key}: got {value!r}; allowed: lin_<number>") from None
        try:
            value = float(value)
        except ValueError:
            return value  # e.g. ent_coef: auto, device: cpu
    if (
        isinstance(value, float)
        and isinstance(default, int)
        and not isinstance(default, bool)
        and value.is_integer()
    ):
        return int(value)
    return value


def _positive_int(key: str, value: Any, allow_zero: bool = False) -> int:
    try:
        out = float(value)
    except (TypeError, ValueError):
        out = math.nan
    if not out.is_integer() or out < (0 if allow_zero else 1):
        kind = "a non-negative" if allow_zero else "a positive"
        raise ValueError(f"{key}: got {value!r}; allowed: {kind} integer")
    return int(out)


def resolve_settings(algo: str, entry: dict[str, Any]) -> dict[str, Any]:
    """Validate an entry and build constructor-ready objects.

    Returns:
        A dict with ``n_envs``, ``n_timesteps``, ``policy``, ``policy_kwargs`` (validated
        plain data; :func:`build_policy_kwargs` makes the SB3 arguments),
        ``env_kwargs``, ``wrapper`` (parsed ``(name, kwargs)`` or ``None``), ``normalize``
        (``VecNormalize`` kwargs or ``None``), ``eval_freq``, ``n_eval_episodes``,
        ``checkpoint_freq``, ``backend`` and ``algo_kwargs``.

    Raises:
        ValueError: Missing ``n_timesteps``, bad values, unknown algorithm arguments, or
            what the ``backend`` does not take (:func:`agents.rl.sbx_backend.check_settings`;
            sbx itself is not imported).
    """
    algos = algorithms()
    if algo not in algos:
        raise ValueError(f"algo: got {algo!r}; allowed: {sorted(algos)}")
    cls = algos[algo]
    full = {**DEFAULTS, **entry}
    if "n_timesteps" not in full:
        raise ValueError("n_timesteps: missing from the config entry (or pass timesteps=)")
    env_kwargs = full["env_kwargs"] or {}
    if not isinstance(env_kwargs, dict):
        raise ValueError(f"env_kwargs: got {env_kwargs!r}; allowed: a mapping")
    params = inspect.signature(cls).parameters  # the constructor's
    algo_kwargs: dict[str, Any] = {}
    for key, value in entry.items():
        if key in RESERVED_KEYS:
            continue
        if key not in params or key in _FORBIDDEN_ALGO_KWARGS:
            allowed = sorted(
                k for k in params if k not in _FORBIDDEN_ALGO_KWARGS and k not in RESERVED_KEYS
            )
            raise ValueError(
                f"{key}: unknown hyperparameter for {cls.__name__}; allowed: "
                f"{sorted(RESERVED_KEYS)} and {allowed}"
            )
        algo_kwargs[key] = _to_number(key, value, params[key].default)
    if not isinstance(full["policy"], str):
        raise ValueError(f"policy: got {full['policy']!r}; allowed: an SB3 policy name")
    if full["policy"] == ASYMMETRIC and algo not in ("ppo", "a2c"):
        raise ValueError(f"policy: {ASYMMETRIC} is an on-policy actor-critic; algo {algo!r}")
    backend = sbx_backend.check_backend(full["backend"])
    policy_kwargs = validate_policy_kwargs(full["policy_kwargs"], full["policy"])
    if backend == "sbx":
        sbx_backend.check_settings(algo, full["policy"], algo_kwargs, policy_kwargs)
    return {
        "n_envs": _positive_int("n_envs", full["n_envs"]),
        "n_timesteps": _positive_int("n_timesteps", full["n_timesteps"]),
        "policy": full["policy"],
        "policy_kwargs": policy_kwargs,
        "env_kwargs": dict(env_kwargs),
        "wrapper": parse_wrapper_spec(full["wrapper"]),
        "normalize": parse_normalize(full["normalize"]),
        "eval_freq": _positive_int("eval_freq", full["eval_freq"], allow_zero=True),
        "n_eval_episodes": _positive_int("n_eval_episodes", full["n_eval_episodes"]),
        "checkpoint_freq": _positive_int("checkpoint_freq", full["checkpoint_freq"], True),
        "backend": backend,
        "algo_kwargs": algo_kwargs,
    }


def parse_hyperparam_overrides(items: Sequence[str] | None) -> dict[str, Any]:
    """``KEY=VALUE`` pairs (dotted keys nest, values parsed as YAML) → a nested mapping.

    Example: ``["n_steps=512", "env_kwargs.episode.duration_s=10"]`` →
    ``{"n_steps": 512, "env_kwargs": {"episode": {"duration_s": 10}}}``.

    Raises:
        ValueError: An item without ``=`` or with unparseable YAML.
    """
    out: dict[str, Any] = {}
    for item in items or ():
        key, sep, text = item.partition("=")
        if not sep or not key:
            raise ValueError(f"--hyperparams: got {item!r}; allowed: KEY=VALUE (e.g. n_steps=512)")
        try:
            value = parse_yaml(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"--hyperparams {key}: cannot parse {text!r} ({exc})") from None
        node = out
        *parents, leaf = key.split(".")
        for part in parents:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise ValueError(f"--hyperparams: {key!r} conflicts with another entry")
        node[leaf] = value
    return out
