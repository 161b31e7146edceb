"""The CPU cores this process may run on (the default of ``--jobs`` and ``--workers`` checks)."""

from __future__ import annotations

import os


def available_cpus() -> int:
    """Cores this process may run on: its affinity mask where the OS has one (a container or
    ``taskset`` limits it below the machine's count), else ``os.cpu_count()``; at least 1."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except (AttributeError, OSError):  # no affinity call on this OS
        return max(1, os.cpu_count() or 1)
