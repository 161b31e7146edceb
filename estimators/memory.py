"""Memory a filter's arrays will need, checked before they are allocated.

A map that cannot fit is rejected when the estimator is built (at env construction) with the
size it would need, instead of a numpy ``MemoryError`` deep in the first scan (or, worse, the
kernel's out-of-memory killer once the zero-filled pages are touched).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from pathlib import Path

_CGROUP_LIMITS = (
    Path("/sys/fs/cgroup/memory.max"),  # cgroup v2
    Path("/sys/fs/cgroup/memory/memory.limit_in_bytes"),  # cgroup v1
)


MEMORY_SHARE = 0.5
"""Share of the available memory one filter's big buffer may take: a growing map holds the
old and the new buffer at once, and the process needs memory for everything else."""


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
    memory limit when one is set; ``QUADSLAM_MEMORY_LIMIT_BYTES`` overrides all of them.
    """
    override = os.environ.get("QUADSLAM_MEMORY_LIMIT_BYTES")
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


def check_fits(need: int, what: str, formula: str, allowed: Callable[[int], str]) -> None:
    """Raise when ``need`` bytes exceed :data:`MEMORY_SHARE` of the available memory.

    Args:
        need: Bytes the arrays would take.
        what: The setting responsible, with its value (e.g. ``"landmarks: 15000 landmarks"``).
        formula: How ``need`` was computed, with the numbers filled in.
        allowed: What would fit, given the available bytes (e.g. ``"at most 4480
            landmarks"``).

    Raises:
        ValueError: One line naming ``what``, the size, the formula, the available memory and
            ``allowed``.
    """
    avail = int(MEMORY_SHARE * available_memory_bytes())
    if need > avail:
        raise ValueError(
            f"{what} would need {format_bytes(need)} for {formula}, more than the "
            f"{format_bytes(avail)} a filter may use (half the available memory); "
            f"allowed: {allowed(avail)}"
        )


def ekf_covariance_bytes(num_lanes: int, nv: int, slots: int) -> int:
    """Bytes of EKF-SLAM's covariance buffer P: ``8 B (nv + 3 L)²`` (float64) for B lanes,
    ``nv`` vehicle states and L map slots."""
    return 8 * num_lanes * (nv + 3 * slots) ** 2


def check_ekf_map(num_lanes: int, nv: int, slots: int) -> None:
    """Reject an EKF-SLAM map whose covariance would not fit in memory, before allocating it.

    Args:
        num_lanes: B.
        nv: Vehicle states (9, or 13 with IMU biases).
        slots: Landmark slots L per lane.

    Raises:
        ValueError: Names the landmark count, the bytes needed, the formula and the largest
            map that fits.
    """
    n = nv + 3 * slots

    def allowed(avail: int) -> str:
        most = max(0, int((math.sqrt(avail / (8 * num_lanes)) - nv) // 3))
        return (
            f"at most {most} landmarks per lane with {num_lanes} lane(s) (landmarks.count, "
            "the layout's positions or a reset's landmarks), or fewer lanes"
        )

    check_fits(
        ekf_covariance_bytes(num_lanes, nv, slots),
        f"landmarks: a map of {slots} landmarks with EKF-SLAM on {num_lanes} lane(s)",
        f"the covariance P (8 bytes × B × (nv + 3 L)² = 8 × {num_lanes} × {n}²)",
        allowed,
    )


FASTSLAM_BYTES_PER_LANDMARK = 8 * (3 + 9)
"""Bytes of one landmark in one particle: its mean (3) and covariance (3×3), float64."""

FASTSLAM_BYTES_PER_PARTICLE = 8 * 64
"""Bytes of one particle without its map, rounded up: the state and its resampling draw
(2 × 12), the weights and their scratch arrays (6), the IMU-bias filter's state and gain
(12 + 6) and the temporaries of a step, float64."""


def fastslam_bytes(num_lanes: int, n_particles: int, landmarks: int) -> int:
    """Bytes of FastSLAM's particles on B lanes: ``B × N × (512 + 96 × L)``."""
    per_particle = FASTSLAM_BYTES_PER_PARTICLE + FASTSLAM_BYTES_PER_LANDMARK * landmarks
    return num_lanes * n_particles * per_particle


def check_fastslam_map(num_lanes: int, n_particles: int, landmarks: int) -> None:
    """Reject FastSLAM particles and landmark filters that would not fit in memory.

    Every particle carries its state and a 3-D EKF per landmark it has seen; the bound is all
    ``landmarks`` of the layout seen by every particle of every lane. Called for one lane
    without a map before a filter allocates its particles, and for all lanes with the map
    before the lanes are built.

    Args:
        num_lanes: B (``num_envs`` of a vector env).
        n_particles: N per lane (``estimator.params.n_particles``).
        landmarks: Landmarks the layout makes (the map's size bound; 0 for the particles
            alone).

    Raises:
        ValueError: Names the particle, landmark and lane counts with their keys, the bytes
            needed, the formula, the available memory and what would fit.
    """
    per_particle = FASTSLAM_BYTES_PER_PARTICLE + FASTSLAM_BYTES_PER_LANDMARK * landmarks
    b, n = num_lanes, n_particles

    def allowed(avail: int) -> str:
        fits = []
        room = avail // (b * n) - FASTSLAM_BYTES_PER_PARTICLE  # per particle, for its map
        if landmarks and room >= 0:
            most = room // FASTSLAM_BYTES_PER_LANDMARK
            fits.append(f"at most {most} landmarks (landmarks.count or the layout's positions)")
        if avail // (b * per_particle) >= 1:
            most = avail // (b * per_particle)
            fits.append(f"at most {most} particles (estimator.params.n_particles)")
        if b > 1 and avail // (n * per_particle) >= 1:
            fits.append(f"at most {avail // (n * per_particle)} lanes (num_envs)")
        if not fits:
            return "fewer particles, landmarks and lanes"
        return ", or ".join(fits) + ", the others as they are"

    the_map = f" and a map of {landmarks} landmarks (landmarks)" if landmarks else ""
    lanes = f"on {b} lane(s) (num_envs)" if b > 1 else "on one lane"
    check_fits(
        fastslam_bytes(b, n, landmarks),
        f"FastSLAM with {n} particles (estimator.params.n_particles){the_map} {lanes}",
        f"the particles and their landmark filters (B × N × (512 + 96 × L) bytes = "
        f"{b} × {n} × (512 + 96 × {landmarks}))",
        allowed,
    )
