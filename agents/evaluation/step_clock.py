"""The wall clock of an episode's steps, without the kernels' compilation.

numba compiles a kernel, or loads it from its cache, the first time a process calls it: the
first step and the first LiDAR scan of a process take tens of seconds on a cold cache and tens
of milliseconds on a warm one, against a fraction of a millisecond for a step after them. A
rate over all the steps of a short episode measures that, not the env. :class:`StepClock`
times each step and leaves out the first one and every step in which numba held its compiler
lock (it compiled or loaded a kernel, or the EKF-SLAM update's warm-up process was waited for
and its kernel loaded), so ``steps_per_s`` is the rate of the steps after the warm-up.
"""

from __future__ import annotations

import math
import time

from numba.core import event

LOCK_EVENT = "numba:compiler_lock"
"""The numba event of its compiler lock, taken to compile a kernel or load one from the cache."""


class _LockCounter(event.Listener):
    """Counts the times numba takes its compiler lock."""

    def __init__(self) -> None:
        self.count = 0

    def on_start(self, ev: event.Event) -> None:
        self.count += 1

    def on_end(self, ev: event.Event) -> None:
        """Nothing when the lock is released."""


_LOCKS: _LockCounter | None = None


def _lock_count() -> int:
    """How often numba took its compiler lock in this process since the first call (which
    starts listening)."""
    global _LOCKS
    if _LOCKS is None:
        _LOCKS = _LockCounter()
        event.register(LOCK_EVENT, _LOCKS)
    return _LOCKS.count


class StepClock:
    """Times the steps of an episode, leaving out its first step and every step that compiled
    or loaded a kernel: wrap each step in :meth:`start` and :meth:`stop`.

    Attributes:
        steps: Steps counted (those timed and kept).
        seconds: Their wall time.
        left_out: Steps not counted (the first, and those that compiled or loaded a kernel).
    """

    def __init__(self) -> None:
        self.steps = 0
        self.seconds = 0.0
        self.left_out = 0
        self._mark = _lock_count()
        self._tic = 0.0

    def start(self) -> None:
        """Start timing a step."""
        self._mark = _lock_count()
        self._tic = time.perf_counter()

    def stop(self) -> None:
        """End the step begun by :meth:`start`: count it unless it is the first or numba took
        its compiler lock during it."""
        toc = time.perf_counter()
        first = self.steps + self.left_out == 0
        if first or _lock_count() != self._mark:
            self.left_out += 1
        else:
            self.steps += 1
            self.seconds += toc - self._tic

    @property
    def rate(self) -> float:
        """Counted steps per wall second (NaN before any step was counted)."""
        return self.steps / self.seconds if self.seconds > 0 else math.nan
