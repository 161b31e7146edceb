"""The Ray side of ``quadslam sweep``: importing Ray, reaching or starting a cluster, and
checking that the jobs fit on it (docs/design.md §6).
"""

from __future__ import annotations

import logging
import os
import socket
import sys
from pathlib import Path
from typing import Any

from agents.lab.sweep.spec import Job

INSTALL_HINT = "install it with: pip install 'quadslam[ray]'"
# Single-threaded BLAS in every worker (see agents/lab/cli/main.py); set for cluster nodes too.
_THREAD_VARS = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


class SweepError(ValueError):
    """A sweep that cannot start (no Ray, unreachable cluster, output folder in use)."""


def import_ray() -> Any:
    """``import ray``, or a one-line :class:`SweepError` saying how to get it."""
    try:
        import ray
    except ImportError:
        raise SweepError(f"Ray is not installed; {INSTALL_HINT}") from None
    for module in ("pandas", "pyarrow"):
        try:
            __import__(module)
        except ImportError:
            raise SweepError(f"{module} is not installed; {INSTALL_HINT}") from None
    return ray


def check_address(address: str) -> None:
    """Fail in one line when ``HOST:PORT`` / ``ray://HOST:PORT`` accepts no connection.

    ``ray.init`` itself waits minutes for an unreachable head node; a TCP connection to the
    address (5 s at most) says the same at once. ``auto`` is left to Ray.

    Raises:
        SweepError: A malformed or unreachable address.
    """
    if address == "auto":
        return
    hostport = address.removeprefix("ray://")
    host, _, port = hostport.rpartition(":")
    host = host.strip("[]")
    if not host or not port.isdigit():
        raise SweepError(
            f"--address: got {address!r}; allowed: auto, HOST:PORT (a Ray head node) or "
            "ray://HOST:PORT (Ray Client)"
        )
    try:
        socket.create_connection((host, int(port)), timeout=5.0).close()
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
        raise SweepError(
            f"--address {address}: cannot reach a Ray cluster at {host}:{port} ({reason}); "
            "start one with 'ray start --head' there, or omit --address for a local sweep"
        ) from None


def connect(ray: Any, address: str | None, workers: int | None) -> bool:
    """Start a local Ray (``address`` None) or join a cluster; True if this call started it.

    An already initialised Ray (e.g. by a test or a notebook) is used as it is.

    Raises:
        SweepError: The cluster cannot be reached (one line).
    """
    if ray.is_initialized():
        return False
    options: dict[str, Any] = {
        "include_dashboard": False,
        "log_to_driver": False,
        "logging_level": logging.WARNING,
        "runtime_env": {"env_vars": _THREAD_VARS},
    }
    if address is None:
        options.update(address="local", num_cpus=workers or os.cpu_count() or 1)
    else:
        check_address(address)
        options["address"] = address
    try:
        ray.init(**options)
    except (ConnectionError, RuntimeError, TimeoutError) as exc:
        if address == "auto":
            raise SweepError(
                "--address auto: no running Ray cluster found on this machine; start one with "
                "'ray start --head', or omit --address for a local sweep"
            ) from None
        message = " ".join(str(exc).split()) or type(exc).__name__
        raise SweepError(
            f"--address {address}: cannot join the Ray cluster ({message}); a cluster with "
            "token authentication also needs its token here (~/.ray/auth_token or "
            "RAY_AUTH_TOKEN)"
        ) from None
    return True


def use_cluster_token() -> None:
    """Ask Ray for token authentication when joining a cluster with a token at hand.

    Ray (2.60) turns token authentication on by itself only for a cluster it starts; a
    driver joining a ``ray start`` cluster must set ``RAY_AUTH_MODE=token`` before Ray is
    imported, or the head node refuses it. This does so when ``RAY_AUTH_MODE`` is unset and a
    token is available (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH`` or ``~/.ray/auth_token``);
    a token-mode driver also joins a cluster without authentication.
    """
    if "RAY_AUTH_MODE" in os.environ or "ray" in sys.modules:
        return
    have = os.environ.get("RAY_AUTH_TOKEN") or os.environ.get("RAY_AUTH_TOKEN_PATH")
    if have or (Path.home() / ".ray" / "auth_token").is_file():
        os.environ["RAY_AUTH_MODE"] = "token"


def warn_workers(workers: int | None) -> None:
    """One warning line when a local sweep asks for more workers than this machine's cores
    (each job then gets a share of a core: slower, and timings are not comparable)."""
    from agents.io.cpus import available_cpus

    cores = available_cpus()
    if workers is not None and workers > cores:
        print(
            f"quadslam sweep: warning: --workers {workers} is more than the {cores} CPU "
            f"core(s) of this machine; the jobs will share cores",
            file=sys.stderr,
        )


def check_cpus(ray: Any, jobs: list[Job], local: bool) -> None:
    """Every job must fit on the cluster (else Ray would wait for it forever)."""
    total = float(ray.cluster_resources().get("CPU", 0.0))
    worst = max(jobs, key=lambda j: j.cpus)
    if worst.cpus > total:
        where = "the local Ray (--workers)" if local else "the cluster"
        raise SweepError(
            f"{worst.job_id}: cpus {worst.cpus:g} > the {total:g} CPU(s) of {where}; "
            "allowed: cpus <= the CPUs available"
        )
