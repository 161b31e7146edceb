"""A study's trainings, up to ``jobs`` at a time in worker processes (``--jobs``).

A training uses one core (``torch_threads=1``; the native vector env steps its lanes in the
training's process, on one thread), so the studies train their agents side by side on a
multi-core machine. A run is defined by its
:class:`TrainJob` alone: :func:`agents.rl.training.train` seeds Python, NumPy, torch and every
lane from the job's seed, and nothing else is shared between trainings, so a policy trained
in a worker is bit-identical to the one trained in the study's own process (``jobs=1``).

The workers are spawned (a fresh interpreter: no forked numba or torch state). They ignore
Ctrl-C, which a terminal sends to every process of the job; the study's process, on Ctrl-C,
SIGTERM or the failure of one training, sends SIGTERM to every worker instead, and a training
stopped that way saves its run folder with the ``INTERRUPTED`` marker
(:func:`agents.rl.training.train`), so a rerun trains it again rather than reusing it.
"""

from __future__ import annotations

import contextlib
import json
import math
import multiprocessing as mp
import os
import signal
import sys
from concurrent.futures import FIRST_COMPLETED, Future, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.io.signals import Terminated, sigterm_as_request

_POLL_S = 0.2
"""Longest wait, s, between two looks at whether a SIGTERM asked the study to stop."""


@dataclass(frozen=True)
class TrainJob:
    """One training of a study: ``train("ppo", env_id, ...)`` into a folder of its own.

    Attributes:
        label: Names the run in printouts and errors (``"ppo_ekf seed 1"``).
        folder: Parent of the run folder; a finished run found there is reused.
        env_id: Env id to train on.
        seed: Training seed.
        timesteps: Budget override (``None``: the entry's ``n_timesteps``).
        hyperparams: Merged into the ``ppo.yaml`` entry of ``env_id`` (``None``: as it is).
    """

    label: str
    folder: Path
    env_id: str
    seed: int
    timesteps: int | None = None
    hyperparams: dict[str, Any] | None = None


@dataclass(frozen=True)
class Trained:
    """A finished run: its folder and the wall time of its ``train()`` (``timing.json``)."""

    run: Path
    wall_s: float


def finished_run(folder: Path) -> Trained | None:
    """The first finished run in ``folder``: ``timing.json`` (written last by ``train()``)
    and no ``INTERRUPTED`` marker; ``None`` when there is none.

    Raises:
        ValueError: That run's ``timing.json`` is not the one ``train()`` writes
            (:func:`recorded_wall_s`).
    """
    for done in sorted(folder.glob("*/timing.json")):
        if not (done.parent / "INTERRUPTED").exists():
            return Trained(done.parent, recorded_wall_s(done))
    return None


def recorded_wall_s(timing: Path) -> float:
    """The wall time in s of a run's ``train()``, from its ``timing.json``.

    A ``timing.json`` marks a run as finished, and ``train()`` always records ``wall_s`` in
    it, so a file that cannot be read, is not a JSON object or has no finite ``wall_s`` >= 0
    is not one ``train()`` wrote: the run is not reused on its word.

    Raises:
        ValueError: One line naming the file, what is wrong with it, and what to do.
    """
    try:
        data = json.loads(timing.read_text(encoding="utf-8"))
    except OSError as exc:
        problem = f"cannot be read ({exc.strerror or exc})"
    except ValueError as exc:  # JSONDecodeError, UnicodeDecodeError
        problem = f"is not JSON ({' '.join(str(exc).split())})"
    else:
        value = data.get("wall_s") if isinstance(data, dict) else None
        seconds = math.nan  # stays NaN unless value is a number (a bool is not)
        if isinstance(value, int | float) and not isinstance(value, bool):
            with contextlib.suppress(OverflowError):  # an integer beyond any float
                seconds = float(value)
        if not isinstance(data, dict):
            problem = f"holds {type(data).__name__}, not a JSON object"
        elif "wall_s" not in data:
            problem = "has no 'wall_s' (the wall time train() records)"
        elif not 0.0 <= seconds < math.inf:
            shown = repr(value) if len(repr(value)) <= 40 else f"{repr(value)[:37]}..."
            problem = f"has 'wall_s' {shown}, not a finite number of seconds >= 0"
        else:
            return seconds
    raise ValueError(
        f"{timing}: {problem}; allowed: the timing.json train() writes, with 'wall_s' in s "
        f"(delete the run folder {timing.parent} to train it again)"
    )


def train_all(jobs: list[TrainJob], n_jobs: int) -> list[Trained]:
    """Train every job not already finished in its folder, at most ``n_jobs`` at a time.

    With ``n_jobs`` 1 (or a single run to train) the runs are trained one after the other in
    this process, with a progress bar; otherwise in a pool of spawned worker processes. Each
    finished training prints one line (label, wall time, run folder) on stderr.

    Raises ``ValueError`` for ``n_jobs`` < 1, before anything is trained.

    Returns:
        The run of each job, in the order of ``jobs``.

    Raises:
        KeyboardInterrupt: Ctrl-C or SIGTERM (:class:`agents.io.signals.Terminated`), or a
            training stopped by a signal of its own; every running training saved its run
            folder marked ``INTERRUPTED`` first.
        Exception: A training failed: the worker's exception, of the same type where it can
            be rebuilt, its message starting with the job's label; the other trainings are
            stopped as on Ctrl-C.
    """
    if n_jobs < 1:
        raise ValueError(f"jobs: got {n_jobs}; allowed: 1 or more trainings at a time")
    runs: list[Trained | None] = []
    for job in jobs:
        reused = finished_run(job.folder)
        if reused is not None:
            print(f"  reusing {reused.run}", file=sys.stderr)
        runs.append(reused)
    todo = [i for i, run in enumerate(runs) if run is None]
    workers = min(n_jobs, len(todo))
    if todo:
        where = "in this process" if workers == 1 else f"in {workers} worker processes"
        print(f"training {len(todo)} run(s) {where} ...", file=sys.stderr)
    if workers == 1:
        for i in todo:
            try:
                trained = _train(jobs[i], progress=True)
            except Exception as exc:
                raise _named(exc, jobs[i].label) from exc
            runs[i] = _report(jobs[i], trained)
    elif todo:
        _train_in_pool(jobs, todo, runs, workers)
    return [run for run in runs if run is not None]


def _train(job: TrainJob, progress: bool) -> Trained | None:
    """Train ``job``; ``None`` when Ctrl-C stopped it (``train()`` then saved the run folder,
    marked ``INTERRUPTED``, and returned). SIGTERM (:class:`agents.io.signals.Terminated`)
    propagates, after the run folder was saved the same way."""
    from agents.rl.training import train

    run = train(
        "ppo",
        job.env_id,
        timesteps=job.timesteps,
        seed=job.seed,
        out_dir=job.folder,
        progress=progress,
        hyperparams=job.hyperparams,
    )
    if (run / "INTERRUPTED").exists():
        return None
    return Trained(run, recorded_wall_s(run / "timing.json"))


def _report(job: TrainJob, trained: Trained | None) -> Trained:
    """Print a finished training's line; a stopped one (``None``) stops the study."""
    if trained is None:
        raise KeyboardInterrupt  # its run folder is saved and marked INTERRUPTED
    print(f"  {job.label}: trained in {trained.wall_s:.0f} s ({trained.run})", file=sys.stderr)
    return trained


def _named(exc: Exception, label: str) -> Exception:
    """``exc`` rebuilt with ``training <label>:`` before its message (a ``ValueError`` stays a
    ``ValueError``: the command line still reports it on one line); a type that cannot be
    rebuilt from one message becomes a ``RuntimeError`` naming it."""
    message = f"training {label}: {exc}"
    try:
        named = type(exc)(message)
    except Exception:
        named = None
    if named is None or str(named) != message:
        return RuntimeError(f"training {label}: {type(exc).__name__}: {exc}")
    return named


def _train_in_pool(
    jobs: list[TrainJob], todo: list[int], runs: list[Trained | None], workers: int
) -> None:
    """Train ``jobs[i]`` for ``i`` in ``todo`` in ``workers`` spawned processes into ``runs``.

    Anything that ends the wait early (Ctrl-C, SIGTERM, a failed training) cancels the runs
    not handed out yet, tells the workers to start no other run, sends SIGTERM to every
    worker, waits for them to save, and is raised again.
    """
    ctx = mp.get_context("spawn")  # a fresh interpreter: no forked numba/torch state
    pids = ctx.SimpleQueue()  # each worker's pid: whom to send SIGTERM
    stop = ctx.Event()  # set before the SIGTERMs: a run handed out but not started stays so
    pool = ProcessPoolExecutor(workers, ctx, initializer=_init_worker, initargs=(pids, stop))
    futures: dict[Future[Trained | None], int] = {}
    # SIGTERM is polled between short waits, not raised inside concurrent.futures (where it
    # could leave a lock held that the pool's manager thread, and so the shutdown below, would
    # wait for), and a repeated one during the shutdown is only noted. Ctrl-C still raises
    # where it lands (Python's own behaviour); the study's terminal is the user's.
    with sigterm_as_request() as asked:
        try:
            futures.update((pool.submit(_work, jobs[i]), i) for i in todo)
            pending = set(futures)
            while pending:
                done, pending = wait(pending, timeout=_POLL_S, return_when=FIRST_COMPLETED)
                if asked.is_set():
                    raise Terminated()
                for future in done:
                    i = futures[future]
                    try:
                        trained = future.result()
                    except Exception as exc:  # raised in the worker, or the worker died
                        raise _named(exc, jobs[i].label) from exc
                    runs[i] = _report(jobs[i], trained)
        except BaseException:
            # Not pool.shutdown(wait=False): it drops the pool's handle on its workers, and
            # the shutdown below would then not wait for them to save.
            for future in futures:
                future.cancel()  # the runs not handed to a worker yet
            stop.set()
            # Every worker that may have started a run put its pid before checking `stop`.
            while not pids.empty():
                with contextlib.suppress(ProcessLookupError):  # that worker has already exited
                    os.kill(pids.get(), signal.SIGTERM)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)  # the stopped workers save first
    if asked.is_set():  # a SIGTERM during the last shutdown: every run is saved; stop here
        raise Terminated()


_stop: Any = None
"""In a worker: the pool's stop event (:func:`_init_worker`)."""


def _init_worker(pids: Any, stop: Any) -> None:
    """In each worker: ignore Ctrl-C (the study's process stops the workers with SIGTERM), let
    a SIGTERM between two runs pass (``stop`` tells the worker to start no other run), and
    report this process's pid."""
    global _stop
    _stop = stop
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    # Not SIG_IGN: sigterm_as_interrupt keeps an inherited SIG_IGN, and a run must stop on it.
    signal.signal(signal.SIGTERM, _between_runs)
    pids.put(os.getpid())


def _between_runs(signum: int, frame: Any) -> None:
    """SIGTERM outside a run: nothing to save; ``_stop`` is set, so no run starts."""


def _work(job: TrainJob) -> Trained | None:
    """A worker's task: train ``job`` unless the pool is stopping; ``None`` when stopped."""
    from agents.io.signals import sigterm_as_interrupt

    try:
        with sigterm_as_interrupt():
            if _stop.is_set():  # set before any SIGTERM is sent: checked inside the block
                return None
            return _train(job, progress=False)
    except KeyboardInterrupt:  # Terminated: train() saved the run folder, marked INTERRUPTED
        return None
