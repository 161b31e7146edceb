"""Train stable-baselines3 agents on the QuadSLAM envs (DESIGN.md §6).

:func:`train` reads the zoo-style entry (:mod:`agents.hyperparams`), builds ``n_envs`` lanes of
the native vector env in this process (:class:`agents.vec_adapter.QuadSLAMVecEnv`), trains,
and writes a run folder (:mod:`agents.run_folder`); :mod:`agents.loading` loads it back.
"""

from __future__ import annotations

import contextlib
import json
import signal
import sys
import threading
import time
import warnings
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

from agents.curves import plot_learning_curve
from agents.hyperparams import (
    ASYMMETRIC,
    DEFAULTS,
    algorithms,
    build_policy_kwargs,
    default_config_path,
    load_hyperparams,
    resolve_settings,
)
from agents.run_folder import new_run_dir, read_run_config, versions
from quadslam_env.config import deep_merge


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

    from agents.vec_adapter import QuadSLAMVecEnv

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


def _build_model(
    algo: str, settings: dict[str, Any], venv: Any, seed: int, verbose: int = 0
) -> Any:
    """The SB3 algorithm on ``venv`` with the resolved settings."""
    policy: Any = settings["policy"]
    if policy == ASYMMETRIC:
        from agents.asymmetric import AsymmetricActorCriticPolicy

        policy = AsymmetricActorCriticPolicy
    return algorithms()[algo](
        policy,
        venv,
        seed=seed,
        policy_kwargs=build_policy_kwargs(settings["policy_kwargs"]) or None,
        verbose=verbose,
        **settings["algo_kwargs"],
    )


def _check_setup(algo: str, settings: dict[str, Any], env_id: str) -> dict[str, Any]:
    """Build the lanes and the model once, on a throwaway vector env, before any folder exists.

    Building the lanes validates ``env_kwargs`` and the wrapper (their errors propagate as
    they are). SB3 validates many values only when the model is built (``n_steps=0`` is an
    ``AssertionError``, ``learning_rate: fast`` a ``TypeError`` from the optimizer); those
    become a one-line ``ValueError``.

    Returns:
        The env's full resolved scenario (for the run's ``config.yaml``).

    Raises:
        ValueError: The algorithm rejects the hyperparameters (the message has SB3's reason).
    """
    venv = _make_vec_env(env_id, settings, settings["n_envs"], 0, None)
    try:
        scenario: dict[str, Any] = venv.get_attr("scenario", [0])[0].to_dict()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _build_model(algo, settings, venv, 0)
    except (AssertionError, ValueError, TypeError, KeyError) as exc:
        reason = " ".join(str(exc).split()) or type(exc).__name__
        raise ValueError(f"hyperparameters rejected by {algo.upper()}: {reason}") from None
    finally:
        venv.close()
    return scenario


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
    torch_threads: int | None = 1,
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
        torch_threads: Torch threads during training, restored afterwards (``None``: torch's
            default). Default 1: the networks are small, and with 2 threads a busy second
            core made each PPO minibatch update ~2x slower (131k steps of the EKF residual
            config: 71 s with torch's 2 threads vs 37 s with 1, another job running).

    Returns:
        The run folder.

    Raises:
        ValueError: Unknown algorithm/env id, bad config or env settings.
        FileNotFoundError: Missing config file.

    Note:
        The ``n_envs`` envs are lanes of the native vector env in this process
        (:class:`agents.vec_adapter.QuadSLAMVecEnv`).
    """

    import quadslam_env  # noqa: F401  (registers the ids)

    tic = time.perf_counter()
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
    threads = torch_threads

    scenario_dict = _check_setup(algo, settings, env_id)  # before any folder is written
    run_dir = new_run_dir(out_dir, algo, env_id, seed)
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

    return _learn(run_dir, algo, env_id, settings, seed, progress, verbose, threads, tic)


@dataclass(frozen=True)
class Checkpoint:
    """Where a resumed run continues: a model zip, its VecNormalize statistics, its step."""

    model: Path
    vecnormalize: Path | None
    steps: int


def latest_checkpoint(run_dir: Path) -> Checkpoint | None:
    """The furthest saved point of a run: a checkpoint, or an interrupted run's model."""
    found: list[Checkpoint] = []
    for path in (run_dir / "checkpoints").glob("model_*_steps.zip"):
        steps = path.stem[len("model_") : -len("_steps")]
        if steps.isdigit():
            pkl = path.parent / f"model_vecnormalize_{steps}_steps.pkl"
            found.append(Checkpoint(path, pkl if pkl.is_file() else None, int(steps)))
    marker = run_dir / "INTERRUPTED"
    if marker.is_file() and (run_dir / "model.zip").is_file():
        text = marker.read_text().strip()
        if text.isdigit():
            pkl = run_dir / "vecnormalize.pkl"
            found.append(
                Checkpoint(run_dir / "model.zip", pkl if pkl.is_file() else None, int(text))
            )
    return max(found, key=lambda c: c.steps, default=None)


def resume(
    run_dir: str | Path,
    progress: bool = True,
    *,
    verbose: int = 0,
    torch_threads: int | None = 1,
) -> Path:
    """Continue a run folder from its latest checkpoint up to its ``n_timesteps``.

    The model, optimizer state, ``VecNormalize`` statistics and step count come from the
    checkpoint (or an interrupted run's ``model.zip``); lane i restarts with seed
    ``seed + steps + i`` (fresh episodes, not those of the first session). The new session's
    episodes go to ``monitor/lanes_from_<steps>.monitor.csv``, its logs to
    ``logs/from_<steps>/``; ``model.zip``, ``vecnormalize.pkl`` and ``timing.json`` are
    replaced.

    Raises:
        ValueError: Not a run folder, nothing saved to resume from, or already finished.
    """
    tic = time.perf_counter()
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    if config is None:
        raise ValueError(f"--resume {str(run_dir)!r}: not a run folder (no readable config.yaml)")
    algo, env_id, seed = config["algo"], config["env_id"], int(config["seed"])
    settings = resolve_settings(algo, config["hyperparams"])
    start = latest_checkpoint(run_dir)
    if start is None:
        raise ValueError(
            f"--resume {str(run_dir)!r}: no checkpoint (checkpoints/model_<N>_steps.zip) and no "
            "interrupted model.zip to continue from"
        )
    if start.steps >= settings["n_timesteps"]:
        raise ValueError(
            f"--resume {str(run_dir)!r}: already at {start.steps} of its "
            f"{settings['n_timesteps']} steps"
        )
    if settings["normalize"] is not None and start.vecnormalize is None:
        raise ValueError(f"--resume {str(run_dir)!r}: {start.model.name} has no VecNormalize file")
    (run_dir / "INTERRUPTED").unlink(missing_ok=True)
    return _learn(
        run_dir, algo, env_id, settings, seed, progress, verbose, torch_threads, tic, start
    )


def _learn(
    run_dir: Path,
    algo: str,
    env_id: str,
    settings: dict[str, Any],
    seed: int,
    progress: bool,
    verbose: int,
    threads: int | None,
    tic: float,
    start: Checkpoint | None = None,
) -> Path:
    """Build the lanes and the model (or load ``start``), learn, save; returns ``run_dir``."""
    from stable_baselines3.common.callbacks import (
        CallbackList,
        CheckpointCallback,
        EvalCallback,
    )
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    from agents.callbacks import (
        EstimationMetricsCallback,
        SaveVecNormalizeCallback,
        TqdmProgressCallback,
    )

    n = settings["n_envs"]
    done = 0 if start is None else start.steps
    suffix = "" if start is None else f"_from_{done}"
    with _torch_settings(threads):
        venv = _make_vec_env(
            env_id, settings, n, seed + done, run_dir / "monitor", True, name=f"lanes{suffix}"
        )
        eval_venv = None
        try:
            norm = settings["normalize"]
            if start is not None and start.vecnormalize is not None:
                venv = VecNormalize.load(str(start.vecnormalize), venv)
                venv.training = True
            elif norm is not None:
                gamma = settings["algo_kwargs"].get("gamma", 0.99)
                venv = VecNormalize(venv, **{"gamma": gamma, **norm})
            if start is None:
                model = _build_model(algo, settings, venv, seed, verbose)
            else:
                cls: Any = algorithms()[algo]
                model = cls.load(start.model, env=venv, device="cpu")
            formats = ["csv", "tensorboard"] + (["stdout"] if verbose else [])
            log_dir = run_dir / "logs" / suffix.lstrip("_") if start else run_dir / "logs"
            model.set_logger(configure(str(log_dir), formats))

            callbacks: list[Any] = [EstimationMetricsCallback()]
            if settings["eval_freq"] > 0:
                # One lane per evaluation episode: SB3's evaluate_policy runs them in parallel.
                n_eval = settings["n_eval_episodes"]
                eval_venv = _make_vec_env(env_id, settings, n_eval, seed + 10_000, None)
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
            learn_tic = time.perf_counter()
            with warnings.catch_warnings():
                # The eval env is wrapped differently (VecNormalize with training=False).
                warnings.filterwarnings("ignore", message="Training and eval env are not of")
                try:
                    model.learn(
                        total_timesteps=settings["n_timesteps"] - done,
                        callback=CallbackList(callbacks),
                        reset_num_timesteps=start is None,
                    )
                except KeyboardInterrupt:
                    interrupted = True
                    print(
                        f"training interrupted at {model.num_timesteps} steps; saving the model",
                        file=sys.stderr,
                    )
            learn_s = time.perf_counter() - learn_tic
            with _sigint_deferred():  # a second Ctrl-C must not leave a half-written folder
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
    with _sigint_deferred():
        plot_learning_curve(run_dir)
        timing = {
            "timesteps": int(model.num_timesteps),
            "learn_s": round(learn_s, 2),  # model.learn: stepping, updates, evaluations
            "wall_s": round(time.perf_counter() - tic, 2),  # all of train(), config to plot
            "steps_per_s": round(model.num_timesteps / max(learn_s, 1e-9), 1),
        }
        (run_dir / "timing.json").write_text(json.dumps(timing, indent=2) + "\n")
    return run_dir


@contextlib.contextmanager
def _sigint_deferred() -> Iterator[None]:
    """Hold Ctrl-C while the model, its statistics, the learning curve and ``timing.json`` are
    written: an interrupt then only prints a note, so the run folder is never left half-written
    (a second Ctrl-C after the one that stopped training used to end in a traceback and no
    learning curve). Outside the main thread signals cannot be handled and nothing changes."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def note(signum: int, frame: Any) -> None:
        print("quadslam train: saving the run folder, please wait", file=sys.stderr)

    previous = signal.signal(signal.SIGINT, note)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
