"""``quadslam sweep``: run a spec's jobs as Ray tasks and collect one table.

Flow: the spec is read and every job checked (:mod:`agents.lab.sweep.spec`), the output folder
checked, then Ray is started locally (``--address`` unset) or joined (``auto``,
``HOST:PORT`` or ``ray://HOST:PORT``). Each unfinished job runs as a Ray task reserving its
``cpus`` (:func:`agents.lab.sweep.jobs.execute_job`); at most ``--workers`` jobs are in flight.
The driver writes each job's files under ``OUT/jobs/<job id>/`` as the job finishes, its
``result.json`` last and atomically: a job is finished exactly when that file exists, so
``--resume`` after an interruption (Ctrl-C, a killed driver, a lost node) reruns only the
rest. A job that raises is reported with its error (``OUT/jobs/<job id>/error.txt`` holds the
traceback) and the others go on. At the end the table ``OUT/results.csv`` /
``OUT/results.parquet`` and the summary plots ``OUT/plots/*.png`` are written from every
finished job (:mod:`agents.lab.sweep.table`, :mod:`agents.lab.sweep.plots`).

One sweep at a time per output folder: the driver holds an advisory lock
(``fcntl.flock``) on ``OUT/.sweep.lock`` while it runs, and a second sweep on the same folder
stops at once with a one-line error. SIGTERM stops a sweep like Ctrl-C (the finished jobs'
table is written, exit status 143; Ray's own handler, which would exit at once, is replaced
after ``ray.init``). A full disk stops the sweep with one line saying how many jobs are saved
in ``OUT`` and how to resume (exit status 2); every file is written atomically, so nothing
finished is lost or truncated.

Why plain Ray tasks and not Ray Tune for training jobs: the grid is fixed by the spec and
every trial runs to the end, so Tune's schedulers and search algorithms would have nothing to
do; a task's ``num_cpus`` is the same per-trial resource reservation Tune makes; and Tune's
experiment checkpointing would be a second resume mechanism beside the result files (which
also cover ``run`` and ``evaluate`` jobs).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import signal
import socket
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from agents.io.outputs import DiskFullError, is_disk_full, json_text, write_bytes_atomic
from agents.io.paths import check_output_dir
from agents.lab.sweep.cluster import (
    SweepError,
    check_address,
    check_cpus,
    connect,
    import_ray,
    use_cluster_token,
    warn_workers,
)
from agents.lab.sweep.jobs import RESULT_FILE, execute_job, read_result
from agents.lab.sweep.spec import Job, load_spec, spec_path

ERROR_FILE = "error.txt"
LOCK_FILE = ".sweep.lock"


@dataclass
class SweepReport:
    """What a sweep did.

    Attributes:
        jobs: Every job of the spec.
        ran: Ids of the jobs run (and finished) in this session.
        skipped: Ids of the jobs already finished before (``--resume``).
        failed: Job id → one-line error of the jobs that raised.
        interrupted: The sweep was stopped (Ctrl-C, SIGTERM) before every job ran.
        disk_full: The write that found no space left (the sweep stopped there), or ``None``.
        wall_s: Wall time of the session in s.
        rows: Rows of the table.
        summary: The printed summary (median metrics per swept setting).
        outputs: The table and plot files written.
    """

    jobs: list[Job]
    ran: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: dict[str, str] = field(default_factory=dict)
    interrupted: bool = False
    disk_full: OSError | None = None
    wall_s: float = 0.0
    rows: int = 0
    summary: str = ""
    outputs: list[Path] = field(default_factory=list)


def job_folder(out: Path, job: Job) -> Path:
    """``OUT/jobs/<job id>``."""
    return out / "jobs" / job.job_id


def save_job(out: Path, job: Job, payload: dict[str, Any]) -> None:
    """Write a finished job's files, then its ``result.json`` (atomically, last)."""
    folder = job_folder(out, job)
    for rel, data in payload["files"].items():
        path = folder / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes_atomic(path, data)
    folder.mkdir(parents=True, exist_ok=True)
    result = {**payload["result"], "job": _job_record(job)}
    write_bytes_atomic(folder / RESULT_FILE, json_text(result).encode())
    (folder / ERROR_FILE).unlink(missing_ok=True)


def _job_record(job: Job) -> dict[str, Any]:
    return {
        "id": job.job_id,
        "kind": job.kind,
        "block": job.block,
        "seeds": list(job.seeds),
        "columns": job.columns,
        "params": job.params,
    }


def _error_line(exc: BaseException) -> str:
    """``Type: message`` of the job's own exception (unwrapping Ray's), on one line."""
    cause = getattr(exc, "cause", None)
    inner = cause if isinstance(cause, BaseException) else exc
    text = " ".join(str(inner).split())
    if inner is not exc and "\n" in str(exc) and not text:
        text = str(exc).strip().splitlines()[-1]
    return f"{type(inner).__name__}: {text}" if text else type(inner).__name__


def _save_error(out: Path, job: Job, exc: BaseException) -> None:
    folder = job_folder(out, job)
    folder.mkdir(parents=True, exist_ok=True)
    write_bytes_atomic(folder / ERROR_FILE, f"{exc}\n".encode())


def run_jobs(
    ray: Any, jobs: list[Job], out: Path, limit: int, report: SweepReport, progress: bool = True
) -> None:
    """Run ``jobs`` as Ray tasks, at most ``limit`` at once; save each as it finishes.

    A job's exception is recorded in ``report.failed`` and its ``error.txt``; Ctrl-C or
    SIGTERM stops the loop (the jobs finished stay finished) and sets ``report.interrupted``;
    a full disk stops it and sets ``report.disk_full`` (the job being saved is not finished:
    its ``result.json``, written last, is missing, so ``--resume`` runs it again).
    """
    from tqdm import tqdm

    task = ray.remote(execute_job)
    queue = deque(jobs)
    pending: dict[Any, Job] = {}
    bar = tqdm(total=len(jobs), unit="job", file=sys.stderr, disable=not progress, desc="sweep")
    try:
        while queue or pending:
            while queue and len(pending) < limit:
                job = queue.popleft()
                ref = task.options(num_cpus=job.cpus, max_retries=1, name=job.job_id).remote(
                    job.kind, job.params
                )
                pending[ref] = job
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                job = pending.pop(ref)
                try:
                    payload = ray.get(ref)
                except Exception as exc:  # the job's error (or its worker's death)
                    report.failed[job.job_id] = _error_line(exc)
                    _save_error(out, job, exc)
                    bar.write(f"failed: {job.job_id}: {report.failed[job.job_id]}", sys.stderr)
                else:
                    save_job(out, job, payload)
                    report.ran.append(job.job_id)
                bar.update(1)
                bar.set_postfix(failed=len(report.failed), refresh=False)
    except OSError as exc:
        if not is_disk_full(exc):
            raise
        # The jobs in flight end with the Ray session, as after Ctrl-C.
        report.disk_full = exc
    except KeyboardInterrupt:  # Ctrl-C, or SIGTERM (agents.io.signals.Terminated)
        # The jobs in flight are not cancelled one by one (a forced ray.cancel racing with a
        # task's completion can abort Ray's core worker); they end with the driver's Ray
        # session: ray.shutdown() for a local Ray, the job's end on a cluster.
        report.interrupted = True
    finally:
        bar.close()


@contextlib.contextmanager
def out_lock(out: Path) -> Iterator[None]:
    """Hold the advisory lock of a sweep's output folder (``OUT/.sweep.lock``) in the block.

    The lock is ``fcntl.flock`` on the file (released by the kernel when the process ends,
    even on ``kill -9``), so a stale lock file never blocks a later sweep.

    Raises:
        SweepError: Another process holds the lock (one line naming the folder).
    """
    path = out / LOCK_FILE
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o644)
    except OSError as exc:
        raise SweepError(
            f"--out {str(out)!r}: cannot create the lock file {LOCK_FILE} "
            f"({exc.strerror}); allowed: a writable folder"
        ) from None
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise SweepError(
                f"--out {str(out)!r}: another quadslam sweep is running on this folder (it "
                f"holds {LOCK_FILE}); allowed: wait for it to end, or another --out"
            ) from None
        with contextlib.suppress(OSError):  # who holds it, for a curious user
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()} {socket.gethostname()}\n".encode())
        yield
    finally:
        os.close(fd)  # releases the lock


def _check_out(out: Path, jobs: list[Job], resume: bool) -> None:
    """The output folder must hold no finished job unless ``--resume`` (checked under the
    folder's lock)."""
    if resume:
        return
    finished = [j for j in jobs if (job_folder(out, j) / RESULT_FILE).exists()]
    others = list((out / "jobs").glob(f"*/{RESULT_FILE}")) if (out / "jobs").is_dir() else []
    if finished or others:
        raise SweepError(
            f"--out {str(out)!r}: holds {len(others)} finished job(s) of an earlier sweep; "
            "allowed: --resume to continue it (finished jobs are kept), or a new folder"
        )


def run_sweep(
    spec: str | Path,
    out: Path,
    address: str | None = None,
    resume: bool = False,
    workers: int | None = None,
    progress: bool = True,
) -> SweepReport:
    """Run a sweep and write its table and plots (see the module docstring).

    Args:
        spec: Spec file or shipped spec name.
        out: Output folder.
        address: ``None`` (a local Ray with ``workers`` CPUs), ``auto``, ``HOST:PORT`` or
            ``ray://HOST:PORT``.
        resume: Skip the jobs whose ``result.json`` exists.
        workers: Most jobs in flight (default: as many as Ray can place).
        progress: Show the tqdm progress bar on stderr.

    Raises:
        agents.lab.sweep.spec.SweepSpecError: A bad spec (before anything runs).
        SweepError: No Ray, an unreachable cluster, ``out`` in use by another sweep, or
            holding finished jobs without ``--resume``.
        agents.io.outputs.DiskFullError: No space left; the message says how many jobs are
            saved in ``out`` and how to resume.
    """
    tic = time.perf_counter()
    path = spec_path(spec)
    jobs = load_spec(path)
    if address is not None:
        use_cluster_token()  # before Ray is imported
    import_ray()  # also pandas / pyarrow for the table
    if address is not None:
        check_address(address)  # at once, before any folder is made
    else:
        warn_workers(workers)
    check_output_dir(out, "--out")
    with out_lock(out):
        try:
            report = _run_locked(path, jobs, out, address, resume, workers, progress, tic)
        except OSError as exc:
            if not is_disk_full(exc):
                raise
            raise _disk_full(exc, path, jobs, out) from None
        if report.disk_full is not None:
            raise _disk_full(report.disk_full, path, jobs, out)
    return report


def _disk_full(exc: OSError, spec: Path, jobs: list[Job], out: Path) -> DiskFullError:
    """The one-line report of a full disk: what did not fit, what is saved, how to resume."""
    saved = sum(read_result(job_folder(out, job)) is not None for job in jobs)
    return DiskFullError(
        f"no space left on device writing {exc.filename or 'a file'}; {saved} of {len(jobs)} "
        f"job(s) are saved in {out} (jobs/*/result.json); free some space, then: "
        f"quadslam sweep {spec} --resume --out {out}"
    )


def _run_locked(
    path: Path,
    jobs: list[Job],
    out: Path,
    address: str | None,
    resume: bool,
    workers: int | None,
    progress: bool,
    tic: float,
) -> SweepReport:
    """:func:`run_sweep` while holding the output folder's lock (``tic``: its start)."""
    _check_out(out, jobs, resume)
    report = SweepReport(jobs)
    todo = []
    for job in jobs:
        if resume and read_result(job_folder(out, job)) is not None:
            report.skipped.append(job.job_id)
        else:
            todo.append(job)
    if report.skipped:
        print(
            f"resume: {len(report.skipped)} of {len(jobs)} job(s) already finished, "
            f"{len(todo)} to run",
            file=sys.stderr,
        )
    if todo:
        ray = import_ray()
        handler = signal.getsignal(signal.SIGTERM)
        started = connect(ray, address, workers)
        if started and threading.current_thread() is threading.main_thread():
            # ray.init installed its own SIGTERM handler (sys.exit at once: no table, no
            # hint); the one from before (the CLI's, raising Terminated) comes back.
            signal.signal(signal.SIGTERM, handler if handler is not None else signal.SIG_DFL)
        try:
            write_bytes_atomic(out / "spec.yaml", path.read_bytes())
            check_cpus(ray, todo, address is None and started)
            run_jobs(ray, todo, out, workers or len(todo), report, progress)
        finally:
            if started:
                ray.shutdown()
    if report.disk_full is not None:
        return report  # the table and the record would not fit either; --resume writes them
    report.outputs = write_outputs(jobs, out, report)
    report.wall_s = time.perf_counter() - tic
    _write_sweep_record(out, path, report, address, workers)
    return report


def write_outputs(jobs: list[Job], out: Path, report: SweepReport) -> list[Path]:
    """The table (CSV, Parquet) and the summary plots of every finished job.

    Raises:
        agents.io.outputs.OutputWriteError: A file could not be written where asked (the
            message says where it went instead).
    """
    from agents.io.outputs import Saver
    from agents.lab.sweep.plots import plot_sweep
    from agents.lab.sweep.table import build_table, setting_columns, summary_text, write_table

    saver = Saver()
    df = build_table(jobs, out, report.failed)
    written = write_table(df, out, saver)
    written += plot_sweep(df, setting_columns(jobs), out / "plots", saver)
    report.rows = len(df)
    report.summary = summary_text(df, jobs)
    saver.check()
    return written


def add_sweep_parser(sub: Any, positive_int: Callable[[str], int]) -> None:
    """Add ``quadslam sweep`` to the CLI's subcommands (``sub``: argparse subparsers)."""
    sweep = sub.add_parser("sweep", help="run a grid of run/train/evaluate jobs on Ray")
    sweep.add_argument("spec", metavar="SPEC", help="sweep spec YAML, or a shipped spec name")
    sweep.add_argument("--address", help="join a Ray cluster: auto, HOST:PORT or ray://HOST:PORT")
    sweep.add_argument("--out", type=Path, help="output folder (default runs/sweep_<spec>)")
    sweep.add_argument("--resume", action="store_true", help="skip the jobs already finished")
    sweep.add_argument("--workers", type=positive_int, help="most jobs at once (local CPUs)")
    sweep.set_defaults(
        func=lambda args: main_sweep(args.spec, args.out, args.address, args.resume, args.workers)
    )


def main_sweep(
    spec: str | Path,
    out: Path | None,
    address: str | None,
    resume: bool,
    workers: int | None,
) -> int:
    """``quadslam sweep``: run, print the summary; exit status 0, 1 (a job failed) or 130
    (Ctrl-C; the CLI makes it 143 after SIGTERM)."""
    path = spec_path(spec)
    out = out if out is not None else Path("runs") / f"sweep_{path.stem}"
    report = run_sweep(path, out, address, resume, workers)
    print(report.summary)
    print(
        f"jobs: {len(report.ran)} ran, {len(report.skipped)} already finished, "
        f"{len(report.failed)} failed, of {len(report.jobs)}; wall time {report.wall_s:.1f} s"
    )
    print(f"table: {out / 'results.csv'} ({report.rows} rows), {out / 'results.parquet'}")
    plots = [p for p in report.outputs if p.suffix == ".png"]
    if plots:
        print(f"plots: {plots[0].parent} ({len(plots)} PNG)")
    for job_id, error in report.failed.items():
        print(f"quadslam sweep: job {job_id} failed: {error}", file=sys.stderr)
    if report.interrupted:
        print(
            f"quadslam sweep: interrupted; rerun with --resume --out {out} to run the rest",
            file=sys.stderr,
        )
        return 130
    return 1 if report.failed else 0


def _write_sweep_record(
    out: Path, spec: Path, report: SweepReport, address: str | None, workers: int | None
) -> None:
    """``OUT/sweep.json``: the last session's settings, counts and wall time."""
    from agents.rl.saved.run_folder import versions

    record = {
        "spec": str(spec),
        "address": address,
        "workers": workers,
        "jobs": len(report.jobs),
        "ran": len(report.ran),
        "skipped": len(report.skipped),
        "failed": report.failed,
        "interrupted": report.interrupted,
        "wall_s": round(report.wall_s, 2),
        "finished_at": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "versions": versions(),
    }
    write_bytes_atomic(out / "sweep.json", json.dumps(record, indent=2).encode() + b"\n")
