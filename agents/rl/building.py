"""What a training session is built from: torch's settings, the lanes of the native vector
env as an SB3 ``VecEnv``, the model (SB3's, or sbx's with ``backend: sbx``:
:mod:`agents.rl.sbx_backend`) and its callbacks (docs/design.md §6).
"""

from __future__ import annotations

import contextlib
import warnings
from pathlib import Path
from typing import Any

from agents.rl import sbx_backend
from agents.rl.hyperparams import algorithms
from agents.rl.policy_kwargs import ASYMMETRIC, build_policy_kwargs
from quadslam_env.extras import MissingExtraError


@contextlib.contextmanager
def torch_settings(threads: int | None) -> Any:
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


def make_vec_env(
    env_id: str,
    settings: dict[str, Any],
    n_envs: int,
    seed: int,
    monitor_dir: Path | None,
    stagger: bool = False,
    info_keys: tuple[str, ...] | None = (),
    name: str = "lanes",
) -> Any:
    """``n_envs`` lanes of the native vector env in this process, as an SB3 ``VecEnv``.

    Lane i is the env seeded ``seed + i`` (as SB3's ``make_vec_env`` seeds its envs); one
    ``VecMonitor`` records every lane's episodes in ``monitor_dir/<name>.monitor.csv``. With
    ``stagger`` the lanes' first episodes are cut at spread lengths (``QuadSLAMVecEnv``); the
    asymmetric actor-critic policy gets the privileged dict observation.
    """
    from stable_baselines3.common.vec_env import VecMonitor

    from agents.rl.vec_adapter import QuadSLAMVecEnv

    wrapper = settings["wrapper"]
    spec = None if wrapper is None else {"name": wrapper[0], **wrapper[1]}
    # By default per-lane info dicts only for the lanes that end (SB3 reads nothing else from
    # them; the metrics callback reads the adapter's step_info arrays): ~25% of the step at 64
    # lanes.
    venv = QuadSLAMVecEnv(
        env_id,
        n_envs,
        seed=seed,
        wrapper=spec,
        info_keys=info_keys,
        stagger=stagger,
        privileged=settings["policy"] == ASYMMETRIC,
        **settings["env_kwargs"],
    )
    filename = None
    if monitor_dir is not None:
        monitor_dir.mkdir(parents=True, exist_ok=True)
        filename = str(monitor_dir / name)
    return VecMonitor(venv, filename=filename)


def policy_arguments(settings: dict[str, Any]) -> tuple[Any, dict[str, Any] | None]:
    """``(policy, policy_kwargs)`` for an SB3 constructor: the policy's name (or the
    privileged critic's class) and its keyword arguments built from the plain data."""
    policy: Any = settings["policy"]
    if policy == ASYMMETRIC:
        from agents.rl.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy
    return policy, build_policy_kwargs(settings["policy_kwargs"]) or None


def build_model(algo: str, settings: dict[str, Any], venv: Any, seed: int, verbose: int = 0) -> Any:
    """The algorithm on ``venv`` with the resolved settings: SB3's, or sbx's for
    ``backend: sbx`` (:func:`agents.rl.sbx_backend.build_model`).

    Raises:
        quadslam_env.extras.MissingExtraError: ``backend: sbx`` without sbx installed.
    """
    if settings.get("backend") == "sbx":
        return sbx_backend.build_model(algo, settings, venv, seed, verbose)
    policy, policy_kwargs = policy_arguments(settings)
    return algorithms()[algo](
        policy,
        venv,
        seed=seed,
        policy_kwargs=policy_kwargs,
        verbose=verbose,
        **settings["algo_kwargs"],
    )


ON_POLICY_BYTES_PER_VALUE = 8
"""Bytes per stored value of an on-policy rollout (PPO, A2C): SB3's float32 buffer and the
flattened copy its ``get()`` hands the minibatches."""

OFF_POLICY_BYTES_PER_VALUE = 4
"""Bytes per stored value of an off-policy replay buffer (SAC, TD3): float32."""


def registered_scenario(env_id: str, env_kwargs: dict[str, Any]) -> Any:
    """The :class:`~quadslam_env.config.ScenarioConfig` that ``gymnasium.make(env_id,
    **env_kwargs)`` builds for a QuadSLAM id (no env is built), or ``None`` for another id.

    Raises:
        ConfigError: Bad ``env_kwargs`` (as the env would say).
    """
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from quadslam_env.config.scenario import load_scenario

    spec = gym.spec(env_id)
    if spec.entry_point != "quadslam_env.env:QuadSLAMEnv":
        return None
    kwargs = {**spec.kwargs, **env_kwargs}
    for key in ("render_mode", "autoreset_mode", "max_episode_steps"):
        kwargs.pop(key, None)
    name, swap = kwargs.pop("scenario", None), kwargs.pop("estimator_name", None)
    return load_scenario(name, kwargs, swap)


def load_saved_model(algo: str, settings: dict[str, Any], path: Path, venv: Any) -> Any:
    """A model saved by ``model.save`` on ``venv``, by its backend's ``load`` (``--resume``:
    this unpickles the zip's ``data``)."""
    if settings.get("backend") == "sbx":
        return sbx_backend.load_model(algo, path, venv)
    cls: Any = algorithms()[algo]
    return cls.load(path, env=venv, device="cpu")


def learner_terms(algo: str, settings: dict[str, Any], obs_dim: int, act_dim: int) -> list[Any]:
    """The learner's buffers as memory terms: an on-policy rollout of ``n_steps`` per lane
    (observation, action and six scalars per transition), or an off-policy replay buffer of
    ``buffer_size`` transitions (two observations, the action and three scalars)."""
    import inspect

    from quadslam_env.estimation.memory import MemoryTerm

    cls = algorithms()[algo]
    key = "n_steps" if algo in ("ppo", "a2c") else "buffer_size"
    if key not in inspect.signature(cls).parameters:
        return []
    count = int(settings["algo_kwargs"].get(key, inspect.signature(cls).parameters[key].default))
    if key == "n_steps":
        per = ON_POLICY_BYTES_PER_VALUE * (obs_dim + act_dim + 6) * settings["n_envs"]
        what = f"the rollout buffer (n_steps × n_envs × 8 B × {obs_dim + act_dim + 6} values)"
    else:
        per = OFF_POLICY_BYTES_PER_VALUE * (2 * obs_dim + act_dim + 3)
        what = f"the replay buffer (buffer_size × 4 B × {2 * obs_dim + act_dim + 3} values)"

    def most(room: int) -> str | None:
        return f"{key} at most {room // per}" if room >= per else None

    return [MemoryTerm(count * per, key, count, what, most, per_lane=key == "n_steps")]


def check_training_memory(algo: str, settings: dict[str, Any], env_id: str) -> None:
    """Refuse a training whose lanes, evaluation lanes and learner's buffers would not fit in
    memory, before any of them is built (``n_envs`` from ``--n-envs`` or the config).

    Raises:
        quadslam_env.estimation.MemoryLimitError: One line naming the setting that
            dominates, its size and what fits.
    """
    from quadslam_env.episode.observation import observation_size
    from quadslam_env.estimation.memory import MemoryTerm
    from quadslam_env.memory import check_env_memory, env_memory_terms

    scenario = registered_scenario(env_id, settings["env_kwargs"])
    if scenario is None:
        return
    dim = observation_size(scenario.observation) * (2 if settings["policy"] == ASYMMETRIC else 1)
    extra = learner_terms(algo, settings, dim, scenario.action.dim)
    if settings["eval_freq"] > 0:
        n_eval = settings["n_eval_episodes"]
        lanes = sum(t.nbytes for t in env_memory_terms(scenario, n_eval))
        what = f"the evaluation env's {n_eval} lane(s)"
        extra.append(MemoryTerm(lanes, "n_eval_episodes", n_eval, what, per_lane=False))
    check_env_memory(scenario, settings["n_envs"], "--n-envs", extra)


def check_setup(algo: str, settings: dict[str, Any], env_id: str) -> dict[str, Any]:
    """Build the lanes and the model once, on a throwaway vector env, before any folder exists.

    First the memory the training will hold is checked (:func:`check_training_memory`).
    Building the lanes validates ``env_kwargs`` and the wrapper (their errors propagate as
    they are). SB3 validates many values only when the model is built (``n_steps=0`` is an
    ``AssertionError``, ``learning_rate: fast`` a ``TypeError`` from the optimizer); those
    become a one-line ``ValueError``.

    Returns:
        The env's full resolved scenario (for the run's ``config.yaml``).

    Raises:
        ValueError: The algorithm rejects the hyperparameters (the message has SB3's reason),
            or the training would not fit in memory (a ``MemoryLimitError``).
        quadslam_env.extras.MissingExtraError: ``backend: sbx`` without sbx installed.
    """
    if settings.get("backend") == "sbx":
        sbx_backend.require_sbx()  # before the lanes are built
    check_training_memory(algo, settings, env_id)
    venv = make_vec_env(env_id, settings, settings["n_envs"], 0, None)
    try:
        scenario: dict[str, Any] = venv.get_attr("scenario", [0])[0].to_dict()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            build_model(algo, settings, venv, 0)
    except MissingExtraError:
        raise
    except (AssertionError, ValueError, TypeError, KeyError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        who = f"sbx's {algo.upper()}" if settings.get("backend") == "sbx" else algo.upper()
        raise ValueError(f"hyperparameters rejected by {who}: {reason}") from None
    finally:
        venv.close()
    return scenario


def training_callbacks(
    run_dir: Path,
    env_id: str,
    settings: dict[str, Any],
    seed: int,
    progress: bool,
    verbose: int,
    label: str,
) -> tuple[list[Any], Any, Any]:
    """The training callbacks: ``(callbacks, eval vector env or None, eval callback or None)``.

    Every file they write is written atomically (:mod:`agents.rl.callbacks`).
    """
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.rl.callbacks import (
        AtomicCheckpointCallback,
        AtomicEvalCallback,
        EstimationMetricsCallback,
        SaveVecNormalizeCallback,
        TqdmProgressCallback,
    )

    n, norm = settings["n_envs"], settings["normalize"]
    callbacks: list[Any] = [EstimationMetricsCallback()]
    eval_venv = eval_cb = None
    if settings["eval_freq"] > 0:
        # One lane per evaluation episode: SB3's evaluate_policy runs them in parallel.
        n_eval = settings["n_eval_episodes"]
        eval_venv = make_vec_env(env_id, settings, n_eval, seed + 10_000, None)
        if norm is not None:
            eval_venv = VecNormalize(eval_venv, training=False, **{**norm, "norm_reward": False})
        on_best = (
            SaveVecNormalizeCallback(run_dir / "eval" / "best_vecnormalize.pkl")
            if norm is not None
            else None
        )
        eval_cb = AtomicEvalCallback(
            eval_venv,
            callback_on_new_best=on_best,
            n_eval_episodes=settings["n_eval_episodes"],
            eval_freq=max(settings["eval_freq"] // n, 1),
            log_path=str(run_dir / "eval"),
            best_model_save_path=str(run_dir / "eval"),
            deterministic=True,
            verbose=verbose,
        )
        callbacks.append(eval_cb)
    if settings["checkpoint_freq"] > 0:
        callbacks.append(
            AtomicCheckpointCallback(
                save_freq=max(settings["checkpoint_freq"] // n, 1),
                save_path=str(run_dir / "checkpoints"),
                name_prefix="model",
                save_vecnormalize=True,
            )
        )
    if progress:
        callbacks.append(TqdmProgressCallback(desc=label))
    return callbacks, eval_venv, eval_cb
