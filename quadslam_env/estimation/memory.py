"""Memory before allocation: what the process may still allocate, the bytes of one buffer and
the one refusal (docs/reliability.md "Memory").

The ground floor of the memory checks. The estimators size their own state from a
:class:`Workload` (``memory_terms`` of an estimator class, asked through
:func:`quadslam_env.estimation.registry.memory_terms` before any estimator exists) and
:mod:`quadslam_env.memory` adds the env's own buffers; :func:`refuse_unless_fits` turns the
terms into one line naming the setting that dominates, the size and what fits, instead of a
numpy ``MemoryError`` halfway through building (or the kernel's out-of-memory killer once the
pages are touched).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from quadslam_env.schema import ConfigError

LIMIT_VARIABLE = "QUADSLAM_MEMORY_LIMIT_BYTES"
"""Environment variable that overrides the available memory (bytes), e.g. for tests."""

_CGROUP_LIMITS = (
    Path("/sys/fs/cgroup/memory.max"),  # cgroup v2
    Path("/sys/fs/cgroup/memory/memory.limit_in_bytes"),  # cgroup v1
)

LANES = "lanes"
"""The :attr:`MemoryTerm.setting` of a term that only the number of lanes sizes: the refusal
names the caller's key for B (``num_envs``, ``--n-envs``, ``--seeds``) instead."""

LANE_OBJECT_BYTES = 32 * 1024
"""Bytes per lane of a one-vehicle estimator's Python objects and the
:class:`~quadslam_env.estimation.lane_loop.LaneLoop`'s conversions of its inputs and snapshot
(rounded up: 19 KiB for a FastSLAM lane of 10 particles, 23 KiB for an iSAM2 lane, besides
their arrays and GTSAM's)."""

ENV_MEMORY_SHARE = 0.8
"""Share of the available memory one env's buffers may take in all: the rest is for the
interpreter, the libraries, a learner's buffers and the copies a step makes on the way (a
filter's one big buffer is held to half, :data:`estimators.memory.MEMORY_SHARE`)."""


class MemoryLimitError(ConfigError):
    """Settings whose buffers would not fit in memory: one line naming the setting, the size it
    would take and what fits (a ``ConfigError``, hence a ``ValueError``)."""


def format_bytes(n: float) -> str:
    """``n`` bytes in binary units, e.g. ``"15.2 GiB"``."""
    for unit in ("B", "KiB", "MiB", "GiB", "TiB"):
        if abs(n) < 1024.0 or unit == "TiB":
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1024.0
    raise AssertionError("unreachable")  # pragma: no cover


def available_memory_bytes() -> int:
    """Memory this process can still allocate, in bytes.

    ``MemAvailable`` of ``/proc/meminfo`` (else the physical memory), capped by a cgroup
    memory limit when one is set; :data:`LIMIT_VARIABLE` overrides all of them.
    """
    override = os.environ.get(LIMIT_VARIABLE)
    if override:
        return int(float(override))
    avail = None
    try:
        for line in Path("/proc/meminfo").read_text().splitlines():
            if line.startswith("MemAvailable:"):
                avail = int(line.split()[1]) * 1024
                break
    except (OSError, ValueError, IndexError):
        pass
    if avail is None:
        try:
            avail = os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
        except (AttributeError, ValueError, OSError):
            avail = 1 << 62  # unknown: do not reject anything
    for path in _CGROUP_LIMITS:
        try:
            text = path.read_text().strip()
        except OSError:
            continue
        if text.isdigit():
            avail = min(avail, int(text))
    return avail


@dataclass(frozen=True)
class Workload:
    """What an estimator of B lanes will be asked to hold, from the validated scenario.

    Attributes:
        num_lanes: B.
        landmark_capacity: Lmax, the landmark ids of the scenario's layout.
        known_map: The lanes localise against the true map (``estimator.known_map``): no
            landmark states.
        scan_hz: LiDAR scans per second (the keyframes of a smoother).
        duration_s: One episode, s (what a smoother without a window keeps).
    """

    num_lanes: int
    landmark_capacity: int
    known_map: bool
    scan_hz: float
    duration_s: float


@dataclass(frozen=True)
class MemoryTerm:
    """One buffer (or group of buffers) of an env, and the setting that sizes it.

    Attributes:
        nbytes: Its bytes for the whole env (all B lanes).
        setting: The key that makes it large (``action.delay_steps``, ``landmarks``,
            ``--seeds``; :data:`LANES` for the number of lanes).
        value: That setting's value as the message shows it.
        what: The buffer and its formula with the numbers filled in.
        fits: Given the bytes this term may take (the budget less every other term), what
            value of ``setting`` would fit, as a phrase (``"action.delay_steps at most
            1200"``), or ``None`` when none does.
        per_lane: The term grows with B (lanes that fit are counted from these).
    """

    nbytes: int
    setting: str
    value: object
    what: str
    fits: Callable[[int], str | None] | None = None
    per_lane: bool = True


def refuse_unless_fits(
    terms: Sequence[MemoryTerm], num_lanes: int, lanes_key: str = "num_envs"
) -> int:
    """Raise unless the ``terms`` fit in :data:`ENV_MEMORY_SHARE` of the available memory.

    Args:
        terms: Every buffer the env (and what its caller adds) will hold.
        num_lanes: B.
        lanes_key: How the caller sets B (``num_envs``, ``--n-envs``, ``--seeds``).

    Returns:
        The bytes of all the terms.

    Raises:
        MemoryLimitError: One line: the dominant term's setting, value, size and formula, the
            total, the budget, and what would fit (that setting, or fewer lanes).
    """
    need = sum(t.nbytes for t in terms)
    budget = int(ENV_MEMORY_SHARE * available_memory_bytes())
    if need <= budget:
        return need
    top = max(terms, key=lambda t: t.nbytes)
    setting = lanes_key if top.setting == LANES else top.setting
    allowed = []
    room = budget - (need - top.nbytes)
    if top.fits is not None and room > 0 and (phrase := top.fits(room)) is not None:
        allowed.append(phrase)
    lanes = _lanes_that_fit(terms, num_lanes, budget)
    if lanes is not None and setting != lanes_key:
        allowed.append(f"at most {lanes} lane(s) ({lanes_key})")
    elif lanes is not None and not allowed:
        allowed.append(f"{lanes_key} at most {lanes}")
    lanes_text = f"{num_lanes} lanes" if num_lanes > 1 else "one lane"
    raise MemoryLimitError(
        f"{setting}: {top.value} would need {format_bytes(top.nbytes)} for {top.what}; "
        f"{format_bytes(need)} in all with the env on {lanes_text}, more than the "
        f"{format_bytes(budget)} an env may use ({ENV_MEMORY_SHARE:.0%} of the available "
        f"memory); allowed: {', or '.join(allowed) if allowed else 'smaller settings'}"
    )


def _lanes_that_fit(terms: Sequence[MemoryTerm], num_lanes: int, budget: int) -> int | None:
    """The most lanes (≥ 1, fewer than ``num_lanes``) whose terms fit in ``budget``, or
    ``None`` when not even one does or there is only one lane."""
    per_lane = sum(t.nbytes for t in terms if t.per_lane) / num_lanes
    fixed = sum(t.nbytes for t in terms if not t.per_lane)
    if num_lanes <= 1 or per_lane <= 0 or budget <= fixed:
        return None
    most = int((budget - fixed) // per_lane)
    return most if 1 <= most < num_lanes else None
