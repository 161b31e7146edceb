"""Memory of this process, in MiB: current and peak resident set size (soak and bench)."""

from __future__ import annotations

import resource
import sys


def _status_mib(field: str) -> float | None:
    """A ``kB`` line of ``/proc/self/status`` in MiB, or ``None`` where there is none."""
    try:
        with open("/proc/self/status") as status:
            for line in status:
                if line.startswith(f"{field}:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    return None


def peak_rss_mb() -> float:
    """Peak resident set size of this process in MiB.

    On Linux this is ``VmHWM`` of ``/proc/self/status``: ``getrusage(RUSAGE_SELF).ru_maxrss``
    there keeps the high-water mark of the memory image replaced by ``exec``, i.e. a
    subprocess reports at least its parent's peak (a 400 MB parent made a 10 MB child report
    407 MB). Elsewhere ``ru_maxrss`` (KiB; bytes on macOS).
    """
    peak = _status_mib("VmHWM")
    if peak is not None:
        return peak
    maxrss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return maxrss / (1024.0**2 if sys.platform == "darwin" else 1024.0)


def rss_mb() -> float:
    """Current resident set size of this process in MiB (``VmRSS``; the peak as a fallback)."""
    current = _status_mib("VmRSS")
    return peak_rss_mb() if current is None else current
