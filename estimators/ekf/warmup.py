"""Compile the EKF-SLAM update in a second process while the first compiles the rest.

The kernels compile on first use and numba caches them on disk (:mod:`quadslam_env.models.jit`),
so only the first process after an install pays. That first process compiles about 100
kernels one after another; the LiDAR update (:func:`estimators.ekf.update.update_lanes` and
its callees) is about 40% of it and is first needed at the first scan, after the physics,
sensors, prediction, metrics and observation kernels.

Only when asked (:func:`enable`, which the ``quadslam`` command does, or
``QUADSLAM_EKF_WARMUP=1``) and when its cache entry is missing, building an
:class:`~estimators.ekf.filter.EkfSlamBatch` starts ``python -m estimators.ekf.compile_update``,
which compiles (and caches) the update while this process compiles everything before the first
scan; the first :meth:`EkfSlamBatch.update` waits for it and loads the update from the cache.
On a machine with two or more cores the first ``make_vec`` then takes the longer of the two
halves instead of their sum (docs/performance.md). Nothing changes once the cache is warm, or
where numba has no cache location; ``QUADSLAM_EKF_WARMUP=0`` keeps it off even when asked.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ENV_VAR = "QUADSLAM_EKF_WARMUP"
WAIT_S = 300.0
"""Longest wait for the warm-up process before compiling here anyway (a stuck process
must not hang the env)."""

_process: subprocess.Popen[bytes] | None = None
_enabled = False


def enable() -> None:
    """Ask for the warm-up process from now on in this process (see the module docstring)."""
    global _enabled
    _enabled = True


def _index_path() -> Path | None:
    """The cache index file of the update kernel, or ``None`` without a cache."""
    from estimators.ekf.update import update_lanes

    cache = getattr(update_lanes, "_cache", None)
    cache_file = getattr(cache, "_cache_file", None)
    index = getattr(cache_file, "_index_path", None)
    return None if index is None else Path(index)


def start() -> None:
    """Start the warm-up process if asked and the update kernel is not cached yet (once per
    process)."""
    global _process
    asked = os.environ.get(ENV_VAR, "1" if _enabled else "0")
    if _process is not None or asked == "0":
        return
    index = _index_path()
    if index is None or index.exists():
        return
    env = dict(os.environ, **{ENV_VAR: "0"})  # the child must not start another
    try:
        _process = subprocess.Popen(
            [sys.executable, "-m", "estimators.ekf.compile_update"],
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    except OSError:  # no interpreter to start (frozen app, exhausted limits): compile here
        _process = None


def wait() -> None:
    """Let a running warm-up process finish, so the update is loaded from the cache."""
    global _process
    process, _process = _process, None
    if process is None:
        return
    try:
        process.wait(timeout=WAIT_S)
    except subprocess.TimeoutExpired:
        process.kill()
