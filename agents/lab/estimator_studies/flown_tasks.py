"""What the flown estimator studies (``integrity``, ``cooperative``) share: their tasks flown in
spawned processes, and whether their iSAM2 rows can be flown (the ``gtsam`` extra)."""

from __future__ import annotations

import importlib.util
import multiprocessing as mp
import sys
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor
from typing import Any, TypeVar

T = TypeVar("T")


def map_tasks(fn: Callable[[Any], T], tasks: Sequence[Any], jobs: int) -> list[T]:
    """``[fn(t) for t in tasks]`` in the tasks' order, ``jobs`` at a time, each in its own
    spawned process (a fresh interpreter: no forked numba state; 1: in this one)."""
    if jobs > 1:
        with ProcessPoolExecutor(jobs, mp.get_context("spawn")) as pool:
            return list(pool.map(fn, tasks))
    return [fn(t) for t in tasks]


def has_isam2(study: str) -> bool:
    """Whether GTSAM is installed; if not, ``study`` says on stderr that it has no iSAM2 rows."""
    if importlib.util.find_spec("gtsam") is not None:
        return True
    print(f"{study}: GTSAM is not installed; no iSAM2 rows (pip install 'quadslam[gtsam]')",
          file=sys.stderr)  # fmt: skip
    return False
