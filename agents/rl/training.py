"""Train stable-baselines3 (or sbx, ``backend: sbx``) agents on the QuadSLAM envs
(docs/design.md §6).

:func:`train` reads the zoo-style entry (:mod:`agents.rl.hyperparams`), builds ``n_envs`` lanes of
the native vector env in this process (:class:`agents.rl.vec_adapter.QuadSLAMVecEnv`), trains,
and writes a run folder (:mod:`agents.rl.saved.run_folder`); :mod:`agents.rl.loading` loads it back.
"""

from __future__ import annotations

import contextlib
import json
import shutil
import sys
import tempfile
import threading
import time
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import yaml

from agents.io.outputs import (
    DiskFullError,
    atomic_produce_all,
    commit,
    is_disk_full,
    write_text_atomic,
)
from agents.io.signals import Terminated, signals_deferred, sigterm_as_request
from agents.rl.building import (
    build_model,
    check_setup,
    load_saved_model,
    make_vec_env,
    torch_settings,
    training_callbacks,
)
from agents.rl.curves import plot_learning_curve
from agents.rl.hyperparams import (
    DEFAULTS,
    default_config_path,
    load_hyperparams,
    resolve_settings,
)
from agents.rl.saved.checkpoints import Checkpoint, checkpoint_problem, ended_short, saved_points
from agents.rl.saved.manifest import MANIFEST, verify_run, write_manifest
from agents.rl.saved.run_folder import new_run_dir, read_run_config, versions
from agents.rl.saved.safe_files import save_files
from quadslam_env.config.files import deep_merge


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
    backend: str | None = None,
) -> Path:
    """Train ``algo`` on ``env_id`` with the zoo-style config and write a run folder.

    Args:
        algo: ``"ppo"`` or ``"sac"`` (also ``"td3"``, ``"a2c"`` given a config file).
        env_id: Registered env id; also the key of the config entry.
        config_path: Config file (default ``configs/agents/<algo>.yaml``) or a run's
            ``config.yaml``.
        timesteps: Override ``n_timesteps``.
        n_envs: Override ``n_envs``.
        seed: Seeds Python, NumPy, torch (SB3 ``seed=``; sbx's JAX key), the envs (``seed +
            rank``), the evaluation env (``seed + 10_000``); torch is deterministic.
        out_dir: Parent folder of the run folder (default ``runs``).
        progress: Show a tqdm progress bar on stderr.
        hyperparams: Entries merged into the config entry (mappings merge recursively), e.g.
            ``{"policy_kwargs": {"net_arch": [8]}, "env_kwargs": {"episode": {...}}}``.
        verbose: SB3 verbosity (1 also prints the SB3 log table).
        torch_threads: Torch threads during training, restored afterwards (``None``: torch's
            default). Default 1: the networks are small, and with 2 threads a busy second
            core made each PPO minibatch update ~2x slower (131k steps of the EKF residual
            config: 71 s with torch's 2 threads vs 37 s with 1, another job running).
        backend: The learner, overriding the entry's ``backend``: ``"sb3"`` (torch) or
            ``"sbx"`` (JAX, PPO only; :mod:`agents.rl.sbx_backend`); ``None``: the entry's.

    Returns:
        The run folder.

    Raises:
        ValueError: Unknown algorithm/env id, bad config or env settings.
        FileNotFoundError: Missing config file.

    Note:
        The ``n_envs`` envs are lanes of the native vector env in this process
        (:class:`agents.rl.vec_adapter.QuadSLAMVecEnv`).
    """

    import quadslam_env  # noqa: F401  (registers the ids)

    tic = time.perf_counter()
    algo = algo.lower()
    if env_id not in gym.registry:
        quad = sorted(k for k in gym.registry if k.startswith("QuadSLAM"))
        raise ValueError(f"env: got {env_id!r}; allowed: {quad} or another registered id")
    source = Path(config_path) if config_path is not None else default_config_path(algo)
    entry = deep_merge(load_hyperparams(algo, env_id, source), hyperparams or {})
    overrides = {"n_timesteps": timesteps, "n_envs": n_envs, "backend": backend}
    entry.update(
        {k: v if k == "backend" else int(v) for k, v in overrides.items() if v is not None}
    )
    settings = resolve_settings(algo, entry)

    scenario_dict = check_setup(algo, settings, env_id)  # before any folder is written
    run_dir = new_run_dir(out_dir, algo, env_id, seed)
    config = {
        "algo": algo,
        "env_id": env_id,
        "seed": int(seed),
        "config_file": str(source.resolve()),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "hyperparams": {**{k: v for k, v in DEFAULTS.items() if k not in entry}, **entry},
        "torch_threads": torch_threads,
        "scenario": scenario_dict,
    }
    _write_run_config(run_dir, config)
    return _learn(run_dir, algo, env_id, settings, seed, progress, verbose, torch_threads, tic)


def _write_run_config(run_dir: Path, config: dict[str, Any]) -> None:
    """A new run folder's ``config.yaml``, ``seed.txt`` and ``versions.json``.

    Raises:
        agents.io.outputs.DiskFullError: No space left; the new folder was removed.
    """
    try:
        write_text_atomic(run_dir / "config.yaml", yaml.safe_dump(config, sort_keys=False))
        write_text_atomic(run_dir / "seed.txt", f"{config['seed']}\n")
        write_text_atomic(run_dir / "versions.json", json.dumps(versions(), indent=2) + "\n")
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        shutil.rmtree(run_dir, ignore_errors=True)  # just made, and holds nothing of value
        raise DiskFullError(
            f"no space left on device writing {exc.filename or run_dir}; nothing was trained "
            f"(the new run folder was removed); free some space and train again"
        ) from None


def resume(
    run_dir: str | Path,
    progress: bool = True,
    *,
    verbose: int = 0,
    torch_threads: int | None = 1,
) -> Path:
    """Continue a run folder from its latest checkpoint up to its ``n_timesteps``.

    The model, optimizer state, ``VecNormalize`` statistics and step count come from the
    checkpoint (or an interrupted run's ``model.zip``): SB3's zip and ``VecNormalize`` pickle,
    the only files that hold the optimizer state, so resuming unpickles the run's own files
    (resume only run folders you trust; evaluating one never does). Lane i restarts with seed
    ``seed + steps + i`` (fresh episodes, not those of the first session). The new session's
    episodes go to ``monitor/lanes_from_<steps>.monitor.csv``, its logs to
    ``logs/from_<steps>/``; ``model.zip``, ``policy.npz``, the statistics and ``timing.json``
    are replaced. A saved point that does not load (a truncated checkpoint) is skipped for the
    newest one that does; ``INTERRUPTED`` stays until the new session's final save is in
    place. A run stopped after its last step was saved is only finished (model, curve,
    ``timing.json``). A run stopped short of its budget whose ``INTERRUPTED`` is gone continues
    from its ``model.zip`` (:func:`agents.rl.saved.checkpoints.ended_short`). Before anything
    is loaded the folder is checked against its ``manifest.json``
    (:func:`agents.rl.saved.manifest.verify_run`; a folder without one is accepted with a warning);
    the manifest is removed when the new session starts and written again when it has saved.

    Raises:
        ValueError: Not a run folder, nothing saved to resume from, finished, or a timing.json
            without the step count.
        agents.rl.saved.manifest.ManifestError: A file differs from the manifest or is not listed.
    """
    tic = time.perf_counter()
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    if config is None:
        raise ValueError(f"--resume {str(run_dir)!r}: not a run folder (no readable config.yaml)")
    algo, env_id, seed = config["algo"], config["env_id"], int(config["seed"])
    settings = resolve_settings(algo, config["hyperparams"])
    # A session ended (timing.json, no INTERRUPTED): finished, or short of the budget.
    try:
        ended_at = ended_short(run_dir, int(settings["n_timesteps"]))
    except ValueError as exc:
        raise ValueError(f"--resume {str(run_dir)!r}: {exc}") from None
    points = saved_points(run_dir, ended_at)
    # Before anything is unpickled: the folder's files as its last session saved them.
    saved = [p for point in points for p in (point.model, point.vecnormalize) if p]
    verify_run(run_dir, [run_dir / "config.yaml", *saved])
    if not points:
        raise ValueError(
            f"--resume {str(run_dir)!r}: no checkpoint (checkpoints/model_<N>_steps.zip) and no "
            "interrupted model.zip to continue from"
        )
    # A save cut short (a crash, a full disk, a kill -9 while SB3 wrote a checkpoint) leaves
    # a truncated file: go back to the newest one that loads.
    problems: list[str] = []
    start = None
    for point in points:
        problem = checkpoint_problem(point, settings["normalize"] is not None)
        if problem is None:
            start = point
            break
        problems.append(problem)
    if start is None:
        raise ValueError(f"--resume {str(run_dir)!r}: no saved point loads ({'; '.join(problems)})")
    if problems or ended_at is not None:
        skipped = f"skipped {'; '.join(problems)}; " if problems else ""
        print(
            f"resume: {skipped}continuing from {start.model.relative_to(run_dir)} "
            f"({start.steps:,} of {settings['n_timesteps']:,} steps)",
            file=sys.stderr,
        )
    for folder in (run_dir, run_dir / "checkpoints", run_dir / "eval"):
        for stale in folder.glob(".*.tmp-*"):  # a save the killed session never finished
            stale.unlink(missing_ok=True)
    # The INTERRUPTED marker stays until this session's final model and timing.json are
    # written: a session killed before then must not leave a folder that looks finished.
    # This session changes the folder: its manifest is written again once it has saved.
    (run_dir / MANIFEST).unlink(missing_ok=True)
    return _learn(
        run_dir, algo, env_id, settings, seed, progress, verbose, torch_threads, tic, start
    )


def _run_learn(
    model: Any, callbacks: list[Any], total: int, fresh: bool, asked: threading.Event
) -> tuple[KeyboardInterrupt | None, OSError | None, float]:
    """``model.learn`` up to ``total`` steps, or until ``asked`` is set (a SIGTERM,
    :func:`agents.io.signals.sigterm_as_request`); ``(stop, full, seconds)``.

    ``stop`` is the Ctrl-C (``KeyboardInterrupt``) or SIGTERM (:class:`Terminated`) that
    ended it early, ``full`` the ``ENOSPC`` of a checkpoint or log write that did.
    """
    from stable_baselines3.common.callbacks import CallbackList

    from agents.rl.callbacks import StopWhenSet

    # From the loaded model's own count: a session stopped between replacing model.zip and
    # updating INTERRUPTED resumes where the model really is.
    remaining = total - int(model.num_timesteps)
    tic = time.perf_counter()
    stop: KeyboardInterrupt | None = None
    full: OSError | None = None
    with warnings.catch_warnings():
        # The eval env is wrapped differently (VecNormalize with training=False).
        warnings.filterwarnings("ignore", message="Training and eval env are not of")
        try:
            if remaining > 0:
                model.learn(
                    total_timesteps=remaining,
                    callback=CallbackList([*callbacks, StopWhenSet(asked)]),
                    reset_num_timesteps=fresh,
                )
            if asked.is_set():
                raise Terminated()
        except KeyboardInterrupt as exc:
            stop = exc
            how = "terminated (SIGTERM)" if isinstance(exc, Terminated) else "interrupted"
            print(
                f"training {how} at {model.num_timesteps} steps; saving the model",
                file=sys.stderr,
            )
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            full = exc  # reported in one line once what fits is saved (_disk_full)
    return stop, full, time.perf_counter() - tic


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
    """Build the lanes and the model (or load ``start``), learn, save; returns ``run_dir``.

    The files are written atomically; Ctrl-C and SIGTERM are held from the moment the model
    is saved until the learning curve and ``timing.json`` are written. ``INTERRUPTED`` (the
    step count of an unfinished ``model.zip``) is written when training stopped early, and
    removed only once a finished session's ``timing.json`` is in place.

    Raises:
        agents.io.signals.Terminated: SIGTERM, after the run folder was saved (``run_dir`` set).
        agents.io.outputs.DiskFullError: No space left; the message names the last good save.
    """
    done = 0 if start is None else start.steps
    suffix = "" if start is None else f"_from_{done}"
    saving = contextlib.ExitStack()  # entered when the model is saved, left after timing.json
    # SIGTERM only asks (learning stops at its next step): an exception raised at an arbitrary
    # point of SB3's loop could leave a lock held that the save then waits for. The request
    # block spans the save too, so no SIGTERM can fall between learning and saving; while
    # saving it is held (signals_deferred) and then noted here. Ctrl-C raises as usual.
    try:
        with sigterm_as_request() as asked, saving, torch_settings(threads):
            venv = make_vec_env(
                env_id, settings, settings["n_envs"], seed + done, run_dir / "monitor", True,
                name=f"lanes{suffix}",
            )  # fmt: skip
            eval_venv = eval_cb = None
            try:
                venv, model = _model_on(venv, run_dir, algo, settings, seed, verbose, start)
                callbacks, eval_venv, eval_cb = training_callbacks(
                    run_dir, env_id, settings, seed, progress, verbose, f"{algo} {env_id}"
                )
                # full: the ENOSPC (no space left on the device) that ended learning early.
                stop, full, learn_s = _run_learn(
                    model, callbacks, settings["n_timesteps"], start is None, asked
                )
                # A second Ctrl-C (or a SIGTERM) must not leave a half-written folder.
                saving.enter_context(signals_deferred(SAVING_NOTE))
                unsaved = _save_run(model, run_dir, settings, stop is not None or full is not None)
                full = full or unsaved
            finally:
                if eval_cb is not None:
                    eval_cb.clean_up()
                _close_lanes(venv, eval_venv)
            if full is not None:
                raise _disk_full(run_dir, full, settings)
            _finish(run_dir, model, learn_s, tic, settings, finished=stop is None)
    except Terminated as exc:
        # A SIGTERM held while saving is delivered once the folder is complete.
        if exc.run_dir is None and (run_dir / "timing.json").is_file():
            raise Terminated(run_dir) from None
        raise
    if isinstance(stop, Terminated) or asked.is_set():  # the latter: a SIGTERM while saving
        raise Terminated(run_dir)
    return run_dir


def _model_on(
    venv: Any,
    run_dir: Path,
    algo: str,
    settings: dict[str, Any],
    seed: int,
    verbose: int,
    start: Checkpoint | None,
) -> tuple[Any, Any]:
    """``(venv, model)``: the lanes under ``VecNormalize`` (fresh, or with ``start``'s
    statistics) when the settings normalise, and the model built on them (or loaded from
    ``start``), logging to ``logs/`` (``logs/from_<steps>/`` for a resumed session)."""
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.vec_env import VecNormalize

    norm = settings["normalize"]
    if start is not None and start.vecnormalize is not None:
        venv = VecNormalize.load(str(start.vecnormalize), venv)
        venv.training = True
    elif norm is not None:
        gamma = settings["algo_kwargs"].get("gamma", 0.99)
        venv = VecNormalize(venv, **{"gamma": gamma, **norm})
    if start is None:
        model = build_model(algo, settings, venv, seed, verbose)
    else:
        model = load_saved_model(algo, settings, start.model, venv)
    formats = ["csv", "tensorboard"] + (["stdout"] if verbose else [])
    log_dir = run_dir / "logs" / f"from_{start.steps}" if start else run_dir / "logs"
    model.set_logger(configure(str(log_dir), formats))
    return venv, model


def _save_run(model: Any, run_dir: Path, settings: dict[str, Any], early: bool) -> OSError | None:
    """Save the model (:func:`_save_model`) and, when learning ended ``early`` (a stop or a
    full disk), ``INTERRUPTED`` with its step count; the ``ENOSPC`` that cut this short."""
    try:
        _save_model(model, run_dir, settings["normalize"] is not None)
        if early:
            write_text_atomic(run_dir / "INTERRUPTED", f"{model.num_timesteps}\n")
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        return exc
    return None


def _close_lanes(*vecs: Any) -> None:
    """Close the vector envs given (``None`` skipped)."""
    for vec in vecs:
        # Workers may already be gone after Ctrl-C (they exit on KeyboardInterrupt).
        with contextlib.suppress(EOFError, BrokenPipeError, ConnectionError):
            if vec is not None:
                vec.close()


def _finish(
    run_dir: Path,
    model: Any,
    learn_s: float,
    tic: float,
    settings: dict[str, Any],
    finished: bool,
) -> None:
    """The learning curve, then ``timing.json``; for a ``finished`` session the
    ``INTERRUPTED`` marker goes; last, ``manifest.json`` (:mod:`agents.rl.saved.manifest`)."""
    try:
        _plot_curve(run_dir)
        timing = {
            "timesteps": int(model.num_timesteps),
            "learn_s": round(learn_s, 2),  # model.learn: stepping, updates, evaluations
            "wall_s": round(time.perf_counter() - tic, 2),  # all of train(), config to plot
            "steps_per_s": round(model.num_timesteps / max(learn_s, 1e-9), 1),
        }
        write_text_atomic(run_dir / "timing.json", json.dumps(timing, indent=2) + "\n")
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        raise _disk_full(run_dir, exc, settings) from None
    if finished:  # only now does the folder look finished
        (run_dir / "INTERRUPTED").unlink(missing_ok=True)
    model.logger.close()  # the TensorBoard and CSV logs are complete before they are hashed
    try:
        write_manifest(run_dir)
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        print(
            f"quadslam train: warning: no space left on device for {run_dir / MANIFEST}; the "
            "run is saved, but its files cannot be checked when it is loaded",
            file=sys.stderr,
        )


SAVING_NOTE = "quadslam train: saving the run folder, please wait"


def _save_model(model: Any, run_dir: Path, normalized: bool) -> None:
    """``policy.npz`` and ``model.zip`` (and ``vecnormalize.npz``, ``vecnormalize.pkl``),
    written atomically together: a failed save (a full disk, a kill) leaves the previous set
    whole, never a new model with old statistics (:func:`agents.rl.saved.safe_files.save_files`)."""
    atomic_produce_all(save_files(model, run_dir / "model.zip", run_dir, normalized))


def _plot_curve(run_dir: Path) -> None:
    """``learning_curve.png``, written atomically.

    :func:`agents.rl.curves.plot_learning_curve` writes into the folder it is given, so it gets
    a staging folder of the run's name whose ``monitor``, ``logs`` and ``eval`` link to the
    run's; the PNG is then moved into place. Without symbolic links (some file systems) the
    curve is written in place.
    """
    with tempfile.TemporaryDirectory(prefix=".curve-", dir=run_dir) as tmp:
        staged = Path(tmp) / run_dir.name
        staged.mkdir()
        try:
            for sub in ("monitor", "logs", "eval"):
                if (run_dir / sub).exists():
                    (staged / sub).symlink_to((run_dir / sub).resolve(), target_is_directory=True)
        except OSError:
            plot_learning_curve(run_dir)
            return
        plot_learning_curve(staged)
        commit(staged / "learning_curve.png", run_dir / "learning_curve.png")


def _disk_full(run_dir: Path, exc: OSError, settings: dict[str, Any]) -> DiskFullError:
    """The one-line report of a full disk: the file that did not fit, the last good save."""
    total = int(settings["n_timesteps"])
    needs_norm = settings["normalize"] is not None
    good = next(
        (p for p in saved_points(run_dir) if checkpoint_problem(p, needs_norm) is None), None
    )
    head = f"no space left on device writing {exc.filename or 'a file'}"
    if good is None:
        return DiskFullError(
            f"{head}; nothing in the run folder {run_dir} can be resumed (no checkpoint was "
            "saved); free some space and train again"
        )
    return DiskFullError(
        f"{head}; the run folder {run_dir} keeps its last good save "
        f"({good.model.relative_to(run_dir)}, {good.steps:,} of {total:,} steps); free some "
        f"space, then: quadslam train --resume {run_dir}"
    )
