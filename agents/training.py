"""Train and load stable-baselines3 agents on the QuadSLAM envs (DESIGN.md §6).

Hyperparameters live in ``configs/agents/<algo>.yaml``, keyed by env id (rl-baselines3-zoo
style). Each entry may hold:

==================  =========================================================================
key                 meaning
==================  =========================================================================
``n_envs``          lanes of the native vector env (one process; ``agents.vec_adapter``)
``n_timesteps``     total env steps (over all envs)
``policy``          SB3 policy name, e.g. ``MlpPolicy``
``policy_kwargs``   a mapping, or a zoo-style string ``"dict(net_arch=[64, 64],
                    activation_fn=nn.Tanh)"`` (only ``dict``, ``nn``/``th``/``torch`` names)
``env_kwargs``      keyword arguments of ``gymnasium.make`` (``scenario``, section overrides)
``wrapper``         ``none`` or ``{name: residual_dflqr, scale: …}``
                    (see :mod:`agents.wrappers`)
``normalize``       ``false``, ``true`` or ``VecNormalize`` kwargs (``{norm_obs: true,
                    norm_reward: false}``)
``eval_freq``       env steps between ``EvalCallback`` evaluations (0: off; default 50 000)
``n_eval_episodes`` episodes per evaluation (default 3)
``checkpoint_freq`` env steps between checkpoints (0: off; default 100 000)
anything else       keyword arguments of the algorithm (``learning_rate``, ``n_steps``, …);
                    ``lin_<x>`` means a linear schedule from ``x`` to 0, numeric strings
                    such as ``3e-4`` (YAML reads them as strings) become numbers
==================  =========================================================================

A run folder (``<out_dir>/<algo>_<env_id>_s<seed>_<time>``) holds ``config.yaml`` (the resolved
entry, the algorithm, env id, seed and the env's full resolved scenario), ``seed.txt``,
``versions.json``, ``model.zip`` (+ ``vecnormalize.pkl``), ``learning_curve.png``,
``monitor/`` (``lanes.monitor.csv``: every lane's episodes), ``logs/`` (TensorBoard events +
``progress.csv``; the ``quadslam/*`` scalars are the env's ``est_*``/``track_*``/``reward_*``
metrics), ``eval/`` (``evaluations.npz``, ``best_model.zip``) and ``checkpoints/``. A run's
``config.yaml`` can be passed back as ``config_path`` to repeat it.

:func:`load_model` turns a run folder (or a model ``.zip``) back into a policy with SB3's
``predict`` on the *raw* env observation, applying the same ``VecNormalize`` statistics and
residual wrapper as in training.
"""

from __future__ import annotations

import ast
import contextlib
import copy
import importlib.metadata
import inspect
import json
import math
import pickle
import platform
import sys
import time
import warnings
import zipfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import yaml

from agents.dflqr import DFLQRPolicy
from agents.wrappers import (
    DEFAULT_RESIDUAL_SCALE,
    as_residual_scale,
    make_wrapped_env,
    parse_wrapper_spec,
    residual_action,
)
from quadslam_env.config import deep_merge, parse_yaml

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
_ACTIVATIONS = ("ReLU", "Tanh", "ELU", "LeakyReLU", "GELU", "SiLU", "Sigmoid")


def algorithms() -> dict[str, type]:
    """Supported algorithm names → SB3 classes (imported lazily)."""
    from stable_baselines3 import A2C, PPO, SAC, TD3

    return {"ppo": PPO, "sac": SAC, "td3": TD3, "a2c": A2C}


# ---------------------------------------------------------------------------- configuration
def default_config_path(algo: str) -> Path:
    """``configs/agents/<algo>.yaml`` (honours ``QUADSLAM_CONFIG_DIR``)."""
    from quadslam_env.config import config_dir

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


def parse_policy_kwargs(value: Any) -> dict[str, Any]:
    """``policy_kwargs`` from a mapping or a zoo-style ``"dict(...)"`` string.

    Strings are evaluated with only ``dict``, ``nn``, ``th`` and ``torch`` in scope; an
    ``activation_fn`` given as a name (``"tanh"``, ``"nn.ReLU"``) becomes the ``torch.nn`` class.

    Raises:
        ValueError: Unparseable string, not a mapping, or unknown activation.
    """
    import torch
    from torch import nn

    if value is None:
        return {}
    if isinstance(value, str):
        try:
            value = eval(  # restricted namespace; zoo-compatible config syntax
                value, {"__builtins__": {}}, {"dict": dict, "nn": nn, "th": torch, "torch": torch}
            )
        except Exception as exc:
            raise ValueError(f"policy_kwargs: cannot parse {value!r} ({exc})") from exc
    if not isinstance(value, dict):
        raise ValueError(f"policy_kwargs: got {value!r}; allowed: a mapping or 'dict(...)' string")
    out = dict(value)
    act = out.get("activation_fn")
    if isinstance(act, str):
        name = act.split(".")[-1].lower()
        match = [a for a in _ACTIVATIONS if a.lower() == name]
        if not match:
            raise ValueError(
                f"policy_kwargs.activation_fn: got {act!r}; allowed: {list(_ACTIVATIONS)}"
            )
        out["activation_fn"] = getattr(nn, match[0])
    return out


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
            try:
                value = ast.literal_eval(value)
            except (ValueError, SyntaxError) as exc:
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
        A dict with ``n_envs``, ``n_timesteps``, ``policy``, ``policy_kwargs`` (parsed),
        ``env_kwargs``, ``wrapper`` (parsed ``(name, kwargs)`` or ``None``), ``normalize``
        (``VecNormalize`` kwargs or ``None``), ``eval_freq``, ``n_eval_episodes``,
        ``checkpoint_freq`` and ``algo_kwargs``.

    Raises:
        ValueError: Missing ``n_timesteps``, bad values, unknown algorithm arguments.
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
    params = inspect.signature(cls.__init__).parameters
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
    return {
        "n_envs": _positive_int("n_envs", full["n_envs"]),
        "n_timesteps": _positive_int("n_timesteps", full["n_timesteps"]),
        "policy": full["policy"],
        "policy_kwargs": parse_policy_kwargs(full["policy_kwargs"]),
        "env_kwargs": dict(env_kwargs),
        "wrapper": parse_wrapper_spec(full["wrapper"]),
        "normalize": parse_normalize(full["normalize"]),
        "eval_freq": _positive_int("eval_freq", full["eval_freq"], allow_zero=True),
        "n_eval_episodes": _positive_int("n_eval_episodes", full["n_eval_episodes"]),
        "checkpoint_freq": _positive_int("checkpoint_freq", full["checkpoint_freq"], True),
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


def versions() -> dict[str, str]:
    """Versions of Python and the packages that determine a run's result."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for dist, key in (
        ("numpy", "numpy"),
        ("scipy", "scipy"),
        ("torch", "torch"),
        ("stable-baselines3", "sb3"),
        ("gymnasium", "gymnasium"),
        ("quadslam", "quadslam"),
    ):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "unknown"
    return out


def _new_run_dir(out_dir: str | Path | None, algo: str, env_id: str, seed: int) -> Path:
    parent = Path(out_dir) if out_dir is not None else Path("runs")
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = parent / f"{algo}_{env_id}_s{seed}_{stamp}"
    run_dir, i = base, 1
    while run_dir.exists():
        run_dir = base.with_name(f"{base.name}-{i}")
        i += 1
    run_dir.mkdir(parents=True)
    return run_dir


@contextlib.contextmanager
def _torch_settings(threads: int | None) -> Any:
    """Deterministic torch algorithms (and optionally a thread count) inside the block."""
    import torch

    enabled = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    old_threads = torch.get_num_threads()
    torch.use_deterministic_algorithms(True, warn_only=True)
    if threads is not None:
        torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.use_deterministic_algorithms(enabled, warn_only=warn_only)
        torch.set_num_threads(old_threads)


# ---------------------------------------------------------------------------- training
def _make_vec_env(
    env_id: str,
    settings: dict[str, Any],
    n_envs: int,
    seed: int,
    monitor_dir: Path | None,
) -> Any:
    """``n_envs`` lanes of the native vector env in this process, as an SB3 ``VecEnv``.

    Lane i is the env seeded ``seed + i`` (as SB3's ``make_vec_env`` seeds its envs); one
    ``VecMonitor`` records every lane's episodes in ``monitor_dir/lanes.monitor.csv``.
    """
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.vec_adapter import QuadSLAMVecEnv

    wrapper = settings["wrapper"]
    spec = None if wrapper is None else {"name": wrapper[0], **wrapper[1]}
    venv = QuadSLAMVecEnv(env_id, n_envs, seed=seed, wrapper=spec, **settings["env_kwargs"])
    filename = None
    if monitor_dir is not None:
        monitor_dir.mkdir(parents=True, exist_ok=True)
        filename = str(monitor_dir / "lanes")
    return VecMonitor(venv, filename=filename)


def train(
    algo: str,
    env_id: str,
    config_path: str | Path | None = None,
    timesteps: int | None = None,
    n_envs: int | None = None,
    seed: int = 0,
    out_dir: str | Path | None = None,
    progress: bool = True,
    *,
    hyperparams: dict[str, Any] | None = None,
    verbose: int = 0,
    torch_threads: int | None = None,
) -> Path:
    """Train ``algo`` on ``env_id`` with the zoo-style config and write a run folder.

    Args:
        algo: ``"ppo"`` or ``"sac"`` (also ``"td3"``, ``"a2c"`` given a config file).
        env_id: Registered env id; also the key of the config entry.
        config_path: Config file (default ``configs/agents/<algo>.yaml``) or a run's
            ``config.yaml``.
        timesteps: Override ``n_timesteps``.
        n_envs: Override ``n_envs``.
        seed: Seeds Python, NumPy, torch (SB3 ``seed=``), the envs (``seed + rank``) and the
            evaluation env (``seed + 10_000``); torch runs with deterministic algorithms.
        out_dir: Parent folder of the run folder (default ``runs``).
        progress: Show a tqdm progress bar on stderr.
        hyperparams: Entries merged into the config entry (mappings merge recursively), e.g.
            ``{"policy_kwargs": {"net_arch": [8]}, "env_kwargs": {"episode": {...}}}``.
        verbose: SB3 verbosity (1 also prints the SB3 log table).
        torch_threads: Torch threads during training (default
            torch's default: the lanes step in this process between updates); restored
            afterwards.

    Returns:
        The run folder.

    Raises:
        ValueError: Unknown algorithm/env id, bad config or env settings.
        FileNotFoundError: Missing config file.

    Note:
        The ``n_envs`` envs are lanes of the native vector env in this process
        (:class:`agents.vec_adapter.QuadSLAMVecEnv`).
    """
    from stable_baselines3.common.callbacks import (
        CallbackList,
        CheckpointCallback,
        EvalCallback,
    )
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.callbacks import (
        EstimationMetricsCallback,
        SaveVecNormalizeCallback,
        TqdmProgressCallback,
    )

    algo = algo.lower()
    if env_id not in gym.registry:
        quad = sorted(k for k in gym.registry if k.startswith("QuadSLAM"))
        raise ValueError(f"env: got {env_id!r}; allowed: {quad} or another registered id")
    source = Path(config_path) if config_path is not None else default_config_path(algo)
    entry = load_hyperparams(algo, env_id, source)
    if hyperparams:
        entry = deep_merge(entry, hyperparams)
    if timesteps is not None:
        entry["n_timesteps"] = int(timesteps)
    if n_envs is not None:
        entry["n_envs"] = int(n_envs)
    settings = resolve_settings(algo, entry)
    n = settings["n_envs"]
    threads = torch_threads

    # Build one env up front: validates env_kwargs / wrapper before any folder is written.
    wrapper_spec = entry.get("wrapper", DEFAULTS["wrapper"])
    probe = make_wrapped_env(env_id, settings["env_kwargs"], wrapper_spec)
    scenario = getattr(probe.unwrapped, "scenario", None)
    scenario_dict = scenario.to_dict() if scenario is not None else None
    probe.close()

    run_dir = _new_run_dir(out_dir, algo, env_id, seed)
    config = {
        "algo": algo,
        "env_id": env_id,
        "seed": int(seed),
        "config_file": str(source.resolve()),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "hyperparams": {**{k: v for k, v in DEFAULTS.items() if k not in entry}, **entry},
        "torch_threads": threads,
        "scenario": scenario_dict,
    }
    (run_dir / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    (run_dir / "seed.txt").write_text(f"{int(seed)}\n")
    (run_dir / "versions.json").write_text(json.dumps(versions(), indent=2) + "\n")

    with _torch_settings(threads):
        venv = _make_vec_env(env_id, settings, n, seed, run_dir / "monitor")
        eval_venv = None
        try:
            norm = settings["normalize"]
            if norm is not None:
                gamma = settings["algo_kwargs"].get("gamma", 0.99)
                venv = VecNormalize(venv, **{"gamma": gamma, **norm})
            model = algorithms()[algo](
                settings["policy"],
                venv,
                seed=seed,
                policy_kwargs=settings["policy_kwargs"] or None,
                verbose=verbose,
                **settings["algo_kwargs"],
            )
            formats = ["csv", "tensorboard"] + (["stdout"] if verbose else [])
            model.set_logger(configure(str(run_dir / "logs"), formats))

            callbacks: list[Any] = [EstimationMetricsCallback()]
            if settings["eval_freq"] > 0:
                eval_venv = _make_vec_env(env_id, settings, 1, seed + 10_000, None)
                if norm is not None:
                    eval_venv = VecNormalize(
                        eval_venv, training=False, **{**norm, "norm_reward": False}
                    )
                on_best = (
                    SaveVecNormalizeCallback(run_dir / "eval" / "best_vecnormalize.pkl")
                    if norm is not None
                    else None
                )
                callbacks.append(
                    EvalCallback(
                        eval_venv,
                        callback_on_new_best=on_best,
                        n_eval_episodes=settings["n_eval_episodes"],
                        eval_freq=max(settings["eval_freq"] // n, 1),
                        log_path=str(run_dir / "eval"),
                        best_model_save_path=str(run_dir / "eval"),
                        deterministic=True,
                        verbose=verbose,
                    )
                )
            if settings["checkpoint_freq"] > 0:
                callbacks.append(
                    CheckpointCallback(
                        save_freq=max(settings["checkpoint_freq"] // n, 1),
                        save_path=str(run_dir / "checkpoints"),
                        name_prefix="model",
                        save_vecnormalize=True,
                    )
                )
            if progress:
                callbacks.append(TqdmProgressCallback(desc=f"{algo} {env_id}"))

            interrupted = False
            with warnings.catch_warnings():
                # The eval env is wrapped differently (VecNormalize with training=False).
                warnings.filterwarnings("ignore", message="Training and eval env are not of")
                try:
                    model.learn(
                        total_timesteps=settings["n_timesteps"],
                        callback=CallbackList(callbacks),
                    )
                except KeyboardInterrupt:
                    interrupted = True
                    print(
                        f"training interrupted at {model.num_timesteps} steps; saving the model",
                        file=sys.stderr,
                    )
            model.save(run_dir / "model.zip")
            if norm is not None:
                model.get_vec_normalize_env().save(str(run_dir / "vecnormalize.pkl"))
            if interrupted:
                (run_dir / "INTERRUPTED").write_text(f"{model.num_timesteps}\n")
        finally:
            for vec in (venv, eval_venv):
                # Workers may already be gone after Ctrl-C (they exit on KeyboardInterrupt).
                with contextlib.suppress(EOFError, BrokenPipeError, ConnectionError):
                    if vec is not None:
                        vec.close()
    plot_learning_curve(run_dir)
    return run_dir


# ---------------------------------------------------------------------------- learning curve
def read_monitor_episodes(monitor_dir: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Episodes from SB3 ``*.monitor.csv`` files, in wall-clock order.

    Returns:
        ``(timesteps at episode end (cumulative over envs), returns, lengths)``.
    """
    rows: list[tuple[float, float, int]] = []
    for path in sorted(Path(monitor_dir).glob("*.monitor.csv")):
        lines = path.read_text().splitlines()
        for line in lines[2:]:  # '#{json}' header, then 'r,l,t'
            parts = line.split(",")
            if len(parts) >= 3:
                try:
                    rows.append((float(parts[2]), float(parts[0]), int(float(parts[1]))))
                except ValueError:
                    continue
    rows.sort()
    if not rows:
        return np.zeros(0), np.zeros(0), np.zeros(0, dtype=int)
    _, r, length = (np.array(c) for c in zip(*rows, strict=True))
    return np.cumsum(length), r, length.astype(int)


def plot_learning_curve(run_dir: str | Path) -> Path:
    """Write ``learning_curve.png``: training episode returns (Monitor) and evaluations.

    Returns:
        The PNG path.
    """
    from matplotlib.figure import Figure

    run_dir = Path(run_dir)
    steps, returns, lengths = read_monitor_episodes(run_dir / "monitor")
    fig = Figure(figsize=(9, 6.5), layout="constrained")
    ax_r, ax_l = fig.subplots(2, 1, sharex=True)
    if returns.size:
        ax_r.plot(steps, returns, ".", ms=3, alpha=0.35, color="tab:blue", label="episode")
        window = max(1, min(50, returns.size // 10))
        if window > 1:
            smooth = np.convolve(returns, np.ones(window) / window, mode="valid")
            ax_r.plot(steps[window - 1 :], smooth, color="tab:blue", label=f"mean of {window}")
        ax_l.plot(steps, lengths, ".", ms=3, alpha=0.5, color="tab:gray")
    evals = run_dir / "eval" / "evaluations.npz"
    if evals.exists():
        with np.load(evals) as data:
            ts, res, ep_len = data["timesteps"], data["results"], data["ep_lengths"]
        if ts.size:
            mean, std = res.mean(axis=1), res.std(axis=1)
            ax_r.errorbar(
                ts, mean, yerr=std, fmt="o-", color="tab:red", ms=4, capsize=3, label="evaluation"
            )
            ax_l.plot(ts, ep_len.mean(axis=1), "o-", color="tab:red", ms=4)
    if not returns.size and not evals.exists():
        ax_r.text(0.5, 0.5, "no completed episodes", ha="center", transform=ax_r.transAxes)
    ax_r.set_ylabel("episode return")
    ax_r.grid(alpha=0.3)
    if ax_r.get_legend_handles_labels()[0]:
        ax_r.legend(loc="lower right")
    ax_l.set_ylabel("episode length [steps]")
    ax_l.set_xlabel("environment steps")
    ax_l.grid(alpha=0.3)
    fig.suptitle(run_dir.name, fontsize=10)
    out = run_dir / "learning_curve.png"
    fig.savefig(out, dpi=110)
    return out


# ---------------------------------------------------------------------------- loading
class TrainedPolicy:
    """A trained SB3 model with the training-time observation/action processing.

    ``predict`` takes the raw env observation, normalises it with the saved ``VecNormalize``
    statistics (if the run used them), queries the model and, for residual runs, adds the
    model's output as a residual to the DF-LQR action of the same raw observation — i.e. the
    action the env saw during training.

    Attributes:
        model: The SB3 algorithm instance.
        algo: Algorithm name.
        config: The run's ``config.yaml`` (``None`` for a bare ``.zip``).
        vec_normalize: ``VecNormalize`` statistics (``training=False``) or ``None``.
        controller: DF-LQR controller for residual runs, else ``None``.
        scale: (4,) residual scale for residual runs, else ``None``.
    """

    def __init__(
        self,
        model: Any,
        algo: str,
        config: dict[str, Any] | None = None,
        vec_normalize: Any = None,
        controller: DFLQRPolicy | None = None,
        scale: np.ndarray | None = None,
    ) -> None:
        self.model = model
        self.algo = algo
        self.config = config
        self.vec_normalize = vec_normalize
        self.controller = controller
        self.scale = scale

    @property
    def observation_space(self) -> gym.Space:
        """The model's observation space."""
        return self.model.observation_space

    @property
    def action_space(self) -> gym.Space:
        """The model's action space."""
        return self.model.action_space

    def predict(
        self,
        observation: np.ndarray,
        state: Any = None,
        episode_start: Any = None,
        deterministic: bool = True,
    ) -> tuple[np.ndarray, Any]:
        """SB3-style ``predict`` on raw observations (obs_dim,) or (n, obs_dim)."""
        obs = np.asarray(observation, dtype=np.float32)
        single = obs.ndim == 1
        batch = obs[None, :] if single else obs
        model_obs = (
            self.vec_normalize.normalize_obs(batch) if self.vec_normalize is not None else batch
        )
        act, state = self.model.predict(
            model_obs, state=state, episode_start=episode_start, deterministic=deterministic
        )
        act = np.asarray(act, dtype=np.float32)
        if self.controller is not None and self.scale is not None:
            base, _ = self.controller.predict(batch)
            act = residual_action(base, act, self.scale)
        return (act[0] if single else act), state

    def __repr__(self) -> str:
        extras = []
        if self.vec_normalize is not None:
            extras.append("VecNormalize")
        if self.controller is not None:
            extras.append(f"residual_dflqr(scale={self.scale.tolist()})")
        return f"TrainedPolicy({self.algo}{', ' if extras else ''}{', '.join(extras)})"


def _read_run_config(folder: Path) -> dict[str, Any] | None:
    """``folder/config.yaml`` if it is a run config written by :func:`train`, else ``None``."""
    cfg = folder / "config.yaml"
    if not cfg.is_file():
        return None
    try:
        data = parse_yaml(cfg.read_text())
    except (OSError, yaml.YAMLError):
        return None
    if isinstance(data, dict) and "algo" in data and "hyperparams" in data:
        return data
    return None


def _find_run_dir(zip_path: Path) -> Path | None:
    """The run folder a model zip belongs to (its folder or that folder's parent)."""
    for cand in (zip_path.parent, zip_path.parent.parent):
        if _read_run_config(cand) is not None:
            return cand
    return None


def run_config(path: str | Path) -> dict[str, Any] | None:
    """The resolved ``config.yaml`` of the run a folder or model zip belongs to.

    Useful to rebuild the training env for evaluation, e.g.
    ``gymnasium.make(cfg["env_id"], **cfg["hyperparams"]["env_kwargs"])``.

    Returns:
        The config mapping, or ``None`` for anything that is not part of a run folder.
    """
    path = Path(path)
    if path.is_dir():
        return _read_run_config(path)
    run_dir = _find_run_dir(path) if path.is_file() else None
    return None if run_dir is None else _read_run_config(run_dir)


def _vecnormalize_path(zip_path: Path, run_dir: Path) -> Path:
    """The ``VecNormalize`` statistics saved with a given model zip of a run."""
    if zip_path.parent == run_dir / "checkpoints":  # model_<N>_steps.zip
        stem = zip_path.stem
        if stem.startswith("model_") and stem.endswith("_steps"):
            steps = stem[len("model_") : -len("_steps")]
            return zip_path.parent / f"model_vecnormalize_{steps}_steps.pkl"
    if zip_path.parent == run_dir / "eval":
        return run_dir / "eval" / "best_vecnormalize.pkl"
    return run_dir / "vecnormalize.pkl"


def _algo_hint(zip_path: Path) -> str | None:
    """Guess the algorithm from the policy class recorded in an SB3 zip."""
    try:
        with zipfile.ZipFile(zip_path) as archive:
            data = json.loads(archive.read("data").decode())
        text = json.dumps(data.get("policy_class", ""))
    except (OSError, KeyError, ValueError, zipfile.BadZipFile):
        return None
    for name in ("sac", "td3"):
        if f"stable_baselines3.{name}" in text:
            return name
    return None


def _load_sb3(zip_path: Path, algo: str | None) -> tuple[Any, str]:
    algos = algorithms()
    if algo is not None and algo not in algos:
        raise ValueError(f"{zip_path}: run config names algorithm {algo!r}; known: {list(algos)}")
    if not zipfile.is_zipfile(zip_path):
        raise ValueError(f"{zip_path}: not a stable-baselines3 model (.zip) file")
    hint = algo or _algo_hint(zip_path)
    order = [hint] if algo is not None else [*([hint] if hint else []), "ppo", "sac", "td3"]
    errors = []
    for name in dict.fromkeys(order):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return algos[name].load(zip_path, device="cpu"), name
        except Exception as exc:  # SB3 raises many kinds on a foreign/corrupt archive
            errors.append(f"{name}: {type(exc).__name__}: {exc}")
    raise ValueError(f"{zip_path}: cannot load as a stable-baselines3 model ({'; '.join(errors)})")


def _load_vecnormalize(path: Path) -> Any:
    from stable_baselines3.common.vec_env import VecNormalize

    try:
        with path.open("rb") as fh:
            vec_normalize = pickle.load(fh)
    except Exception as exc:
        raise ValueError(f"{path}: cannot read the VecNormalize statistics ({exc})") from exc
    if not isinstance(vec_normalize, VecNormalize):
        raise ValueError(f"{path}: not a VecNormalize file (got {type(vec_normalize).__name__})")
    vec_normalize.training = False
    vec_normalize.norm_reward = False
    return vec_normalize


def load_model(path: str | Path, env: gym.Env) -> TrainedPolicy:
    """Load a run folder or a model ``.zip`` as a policy for ``env``.

    A run folder gives ``model.zip``; a zip inside a run folder (``model.zip``,
    ``eval/best_model.zip``, ``checkpoints/model_<N>_steps.zip``) uses that run's config and
    matching ``VecNormalize`` statistics; a bare zip is tried as the algorithm named in it,
    then PPO, SAC, TD3, without normalisation or wrapper. Like any pickle-based format, only
    load files you trust.

    Args:
        path: Run folder or ``.zip``.
        env: The evaluation env (raw ``QuadSLAMEnv`` observations and actions).

    Raises:
        FileNotFoundError: The path, or a run folder's ``model.zip``, does not exist.
        ValueError: Unreadable file, or the model's observation/action shape differs from
            ``env``'s (the message names both).
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"{path}: no such file or folder")
    if path.is_dir():
        run_dir: Path | None = path
        zip_path = path / "model.zip"
        if not zip_path.is_file():
            ckpts = sorted((path / "checkpoints").glob("*.zip"))
            hint = f"; checkpoints: {[c.name for c in ckpts]}" if ckpts else ""
            raise FileNotFoundError(f"{path}: run folder without model.zip{hint}")
        if _find_run_dir(zip_path) != path:
            raise ValueError(f"{path}: model.zip found but config.yaml is missing or unreadable")
    else:
        zip_path = path
        run_dir = _find_run_dir(zip_path)
    config = _read_run_config(run_dir) if run_dir else None
    model, algo = _load_sb3(zip_path, config["algo"] if config else None)

    obs_shape, act_shape = model.observation_space.shape, model.action_space.shape
    env_obs, env_act = env.observation_space.shape, env.action_space.shape
    env_name = env.spec.id if env.spec is not None else type(env.unwrapped).__name__
    if obs_shape != env_obs or act_shape != env_act:
        trained = f" (trained on {config['env_id']})" if config else ""
        raise ValueError(
            f"{path}: model observation/action shapes {obs_shape}/{act_shape}{trained} do not "
            f"match the env {env_name} observation/action shapes {env_obs}/{env_act}"
        )

    vec_normalize = controller = scale = None
    if config is not None and run_dir is not None:
        hp = config.get("hyperparams", {})
        _warn_if_env_differs(config, env)
        if parse_normalize(hp.get("normalize", False)) is not None:
            vn_path = _vecnormalize_path(zip_path, run_dir)
            if not vn_path.is_file():
                raise FileNotFoundError(
                    f"{path}: the run used VecNormalize but {vn_path} is missing"
                )
            vec_normalize = _load_vecnormalize(vn_path)
            if vec_normalize.obs_rms.mean.shape != env_obs:
                shape = vec_normalize.obs_rms.mean.shape
                raise ValueError(
                    f"{vn_path}: VecNormalize statistics of shape {shape} do not match the env "
                    f"{env_name} observation shape {env_obs}"
                )
        wrapper = parse_wrapper_spec(hp.get("wrapper"))
        if wrapper is not None:
            controller = DFLQRPolicy.from_env(env)
            scale = as_residual_scale(wrapper[1].get("scale", DEFAULT_RESIDUAL_SCALE))
    return TrainedPolicy(model, algo, config, vec_normalize, controller, scale)


def _warn_if_env_differs(config: dict[str, Any], env: gym.Env) -> None:
    """Warn when evaluating on another env id or scenario than the run was trained on."""
    env_id = env.spec.id if env.spec is not None else None
    trained_id = config.get("env_id")
    scenario = getattr(env.unwrapped, "scenario", None)
    trained_scn = (config.get("scenario") or {}).get("name")
    diffs = []
    if env_id is not None and trained_id is not None and env_id != trained_id:
        diffs.append(f"env {env_id!r} (trained on {trained_id!r})")
    if scenario is not None and trained_scn is not None and scenario.name != trained_scn:
        diffs.append(f"scenario {scenario.name!r} (trained on {trained_scn!r})")
    if diffs:
        warnings.warn(
            "evaluating on a different setup than training: " + ", ".join(diffs),
            UserWarning,
            stacklevel=3,
        )
