"""Memory the estimators' arrays will need, checked before they are allocated.

A map that cannot fit is rejected when the estimator is built (at env construction) with the
size it would need, instead of a numpy ``MemoryError`` deep in the first scan (or, worse, the
kernel's out-of-memory killer once the zero-filled pages are touched). The ``*_terms``
functions size an estimator's state for a
:class:`~quadslam_env.estimation.memory.Workload` before any estimator exists: the classes'
``memory_terms`` return them, and the env adds its own buffers
(:mod:`quadslam_env.memory`, docs/reliability.md "Memory").
"""

from __future__ import annotations

import math
from collections.abc import Callable

from quadslam_env.estimation.memory import (
    LANES,
    MemoryLimitError,
    MemoryTerm,
    Workload,
    available_memory_bytes,
    format_bytes,
)

MEMORY_SHARE = 0.5
"""Share of the available memory one filter's big buffer may take: a growing map holds the
old and the new buffer at once, and the process needs memory for everything else."""


def check_fits(need: int, what: str, formula: str, allowed: Callable[[int], str]) -> None:
    """Raise when ``need`` bytes exceed :data:`MEMORY_SHARE` of the available memory.

    Args:
        need: Bytes the arrays would take.
        what: The setting responsible, with its value (e.g. ``"landmarks: 15000 landmarks"``).
        formula: How ``need`` was computed, with the numbers filled in.
        allowed: What would fit, given the available bytes (e.g. ``"at most 4480
            landmarks"``).

    Raises:
        MemoryLimitError: One line naming ``what``, the size, the formula, the available
            memory and ``allowed`` (a ``ValueError``).
    """
    avail = int(MEMORY_SHARE * available_memory_bytes())
    if need > avail:
        raise MemoryLimitError(
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
        lanes = avail // (8 * n * n)
        fewer = f"at most {lanes} lane(s)" if 1 <= lanes < num_lanes else "fewer lanes"
        return (
            f"at most {most} landmarks per lane with {num_lanes} lane(s) (landmarks.count, "
            f"the layout's positions or a reset's landmarks), or {fewer}"
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


# ---------------------------------------------------------------- the estimators' terms
EKF_BYTES_PER_ID = 128
"""Bytes per landmark id and lane of EKF-SLAM besides its covariance, rounded up: the id/slot
maps, the M-of-N counters (4 × int64), the known-map position and the snapshot's mean by id
(2 × 3 float64), the mapped, tentative and reported flags, and an unlabeled scan's row."""

EKF_LANE_BYTES = 256
"""Bytes per lane of EKF-SLAM besides its mean, covariance and map: rates, diagnostics, the
snapshot's pose arrays, the lane's counters (rounded up)."""


def ekf_terms(load: Workload, nv: int) -> list[MemoryTerm]:
    """EKF-SLAM's buffers for ``load``: the covariance (checked against its own share first,
    :func:`check_ekf_map`) and the mean with the map's bookkeeping.

    Args:
        load: The lanes and their map (no landmark states with a known map).
        nv: Vehicle states (9, 13 or 15; more with the wind states).

    Raises:
        MemoryLimitError: The covariance alone exceeds :data:`MEMORY_SHARE`.
    """
    b, lmax = load.num_lanes, load.landmark_capacity
    slots = 0 if load.known_map else lmax
    check_ekf_map(b, nv, slots)
    n = nv + 3 * slots

    def most(room: int) -> str | None:
        fit = int((math.sqrt(room / (8 * b)) - nv) // 3)
        return f"at most {fit} landmarks per lane (landmarks.count)" if fit >= 0 else None

    the_map = f"a map of {lmax} landmarks"
    cov = f"EKF-SLAM's covariance P (8 B × B × (nv + 3 L)² = 8 × {b} × {n}²)"
    rest = (
        f"EKF-SLAM's mean and map bookkeeping (B × ({EKF_LANE_BYTES} + 8 (nv + 3 L) + "
        f"{EKF_BYTES_PER_ID} Lmax) bytes = {b} × ({EKF_LANE_BYTES} + 8 × {n} + "
        f"{EKF_BYTES_PER_ID} × {lmax}))"
    )
    return [
        MemoryTerm(ekf_covariance_bytes(b, nv, slots), "landmarks", the_map, cov, most),
        MemoryTerm(b * (EKF_LANE_BYTES + 8 * n + EKF_BYTES_PER_ID * lmax), "landmarks",
                   the_map, rest),
    ]  # fmt: skip


def fastslam_terms(load: Workload, n_particles: int) -> list[MemoryTerm]:
    """FastSLAM's particles and landmark filters for ``load`` (checked against a filter's
    share first, :func:`check_fastslam_map`).

    Raises:
        MemoryLimitError: They exceed :data:`MEMORY_SHARE`.
    """
    b, n, lmax = load.num_lanes, n_particles, load.landmark_capacity
    check_fastslam_map(b, n, lmax)

    def most(room: int) -> str | None:
        fit = room // (b * (FASTSLAM_BYTES_PER_PARTICLE + FASTSLAM_BYTES_PER_LANDMARK * lmax))
        return f"at most {fit} particles (estimator.params.n_particles)" if fit >= 1 else None

    what = (
        f"FastSLAM's particles and landmark filters (B × N × (512 + 96 × L) bytes = {b} × {n} "
        f"× (512 + 96 × {lmax}))"
    )
    return [MemoryTerm(fastslam_bytes(b, n, lmax), "estimator.params.n_particles", n, what, most)]


ISAM2_LANE_BYTES = 32 * 1024
"""Bytes per lane of GTSAM's smoother before its first keyframe (its parameters, the
preintegration, the priors), besides the lane's Python objects."""

ISAM2_KEYFRAME_BYTES = 16 * 1024
"""Bytes per keyframe of the window besides its dense blocks: three variables, the IMU factor
with its preintegrated covariance, the bias prior and the LiDAR factor (rounded up)."""

ISAM2_MARGIN_KEYFRAMES = 5
"""Keyframes a window holds beyond ``window_s`` (it is marginalised every fifth keyframe)."""


def isam2_keyframes(load: Workload, window_s: float | None) -> int:
    """Keyframes a lane's smoother holds at most: ``window_s`` of scans and the margin, or the
    whole episode's scans (``window_s: null``, or a window longer than the episode)."""
    episode = math.ceil(load.duration_s * load.scan_hz) + 1
    if window_s is None:
        return episode
    return min(episode, math.ceil(window_s * load.scan_hz) + ISAM2_MARGIN_KEYFRAMES)


def isam2_terms(load: Workload, window_s: float | None) -> list[MemoryTerm]:
    """iSAM2's graph for ``load``: per lane, the smoother's set-up and, per keyframe of its
    window, the variables and factors and two dense blocks over the keyframe's clique (its
    conditional and iSAM2's cached marginal), 15 vehicle states of this keyframe and the next
    and 3 per landmark state: ``16 (30 + 3 L)²`` bytes. Against the growth of the resident
    memory per lane on ``paper_ekf_figure8``: 3 s windows, 13.2 MB estimated for 13.0 MB with
    40 landmarks and 1.1 MB for 1.4 MB on the known map; full iSAM2 after 12 s, 45 MB for
    21 MB (the estimate 0.8 to 2.2 times what was measured).
    """
    b, kf = load.num_lanes, isam2_keyframes(load, window_s)
    slots = 0 if load.known_map else load.landmark_capacity
    per_kf = ISAM2_KEYFRAME_BYTES + 16 * (30 + 3 * slots) ** 2
    need = b * (ISAM2_LANE_BYTES + kf * per_kf)
    key = "estimator.params.window_s" if window_s is not None else "episode.duration_s"
    value = f"{window_s:g} s" if window_s is not None else f"{load.duration_s:g} s (window_s null)"

    def most(room: int) -> str | None:
        keyframes = (room // b - ISAM2_LANE_BYTES) // per_kf
        if window_s is not None:
            longest = (keyframes - ISAM2_MARGIN_KEYFRAMES) / load.scan_hz
            return f"{key} at most {longest:.3g} s" if longest > 0 else None
        longest = (keyframes - 1) / load.scan_hz
        return f"{key} at most {longest:.3g} s, or a window_s" if longest > 0 else None

    what = (
        f"iSAM2's window of {kf} keyframes per lane (B × ({ISAM2_LANE_BYTES // 1024} KiB + K × "
        f"({ISAM2_KEYFRAME_BYTES // 1024} KiB + 16 (30 + 3 L)²)) bytes = {b} × "
        f"({ISAM2_LANE_BYTES // 1024} KiB + {kf} × ({ISAM2_KEYFRAME_BYTES // 1024} KiB + "
        f"16 × {30 + 3 * slots}²)))"
    )
    return [MemoryTerm(need, key, value, what, most)]


def oracle_terms(load: Workload) -> list[MemoryTerm]:
    """The oracle's snapshot of B lanes: five (B, 3) pose arrays and the map by id
    (``B × (120 + 25 Lmax)`` bytes)."""
    b, lmax = load.num_lanes, load.landmark_capacity
    what = f"the oracle's snapshot (B × (120 + 25 Lmax) bytes = {b} × (120 + 25 × {lmax}))"
    return [MemoryTerm(b * (120 + 25 * lmax), LANES, f"{b} lane(s)", what)]
