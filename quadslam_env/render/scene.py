"""The data of one frame, gathered from a simulation core lane and its history (NumPy only).

Plot coordinates: the top-down view has east on x and north on y (a map, north up); the side
view has east on x and altitude ``-z`` on y. Everything is in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from quadslam_env.estimation.protocol import ShowsParticles
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.linalg import psd_sqrt
from quadslam_env.render.history import LaneHistory
from quadslam_env.types import EUL, POS, FloatArray

ESTIMATOR_LABELS = {
    "ekf_slam": "EKF-SLAM",
    "fastslam": "FastSLAM",
    "fastslam_kinematic": "FastSLAM 1.0 kinematic",
    "oracle": "oracle (truth)",
}
SIGMA_SCALE = 3.0  # ellipses and bounds are drawn at 3σ
REF_STEP_S = 0.05  # sampling of the drawn reference path
REF_AHEAD_S = 2.0  # reference drawn ahead of the vehicle


@dataclass
class Scene:
    """Everything one frame shows (NED positions in m unless stated).

    Attributes:
        t: Lane time in s.
        label: Estimator name for the text line.
        true_pos: (3,) true position.
        true_heading: Heading of the true body x axis (LiDAR boresight), rad from north.
        est_pos: (3,) estimated position.
        est_heading: Estimated heading, rad from north.
        est_pos_cov: (3, 3) position covariance in m², or ``None`` (no covariance).
        rows: (n, WIDTH) history rows of the shown time span (see :mod:`.history`).
        ref: (m, 3) reference positions over the trail and a little ahead.
        landmarks: (L, 3) true landmarks.
        lm_means: (M, 3) estimated (mapped) landmarks.
        lm_covs: (M, 3, 3) their covariances in m².
        scan_points: (k, 3) the last scan's returns (inverse model at the true pose).
        particles: (P, 3) particle positions (a strided subsample), or ``None``.
        n_particles: Particles in the filter (0 without particles).
        latest: Scalars of the last step (``est_nees_pose``, ``est_n_visible``, …).
    """

    t: float
    label: str
    true_pos: FloatArray
    true_heading: float
    est_pos: FloatArray
    est_heading: float
    est_pos_cov: FloatArray | None
    rows: FloatArray
    ref: FloatArray
    landmarks: FloatArray
    lm_means: FloatArray
    lm_covs: FloatArray
    scan_points: FloatArray
    particles: FloatArray | None
    n_particles: int
    latest: dict[str, float]


def heading_of(euler: FloatArray) -> float:
    """Heading (rad from north, towards east) of the body x axis for Euler angles (3,) rad."""
    dcm = dcm_from_euler(euler)
    return math.atan2(dcm[1, 0], dcm[0, 0])


def estimator_label(scenario: Any) -> str:
    """Text-line name of the scenario's estimator (with ``known map`` when it applies)."""
    name = scenario.estimator.name
    label = ESTIMATOR_LABELS.get(name, name)
    return label + (", known map" if scenario.estimator.known_map else "")


def gather(core: Any, lane: int, history: LaneHistory, span_s: float, max_particles: int) -> Scene:
    """The :class:`Scene` of lane ``lane`` of ``core`` now.

    Args:
        core: The :class:`~quadslam_env.core.SimCore`.
        lane: Lane index.
        history: The lane's recorded history.
        span_s: Time span of paths and strip charts in s.
        max_particles: Most particles to draw.
    """
    t = float(core.t[lane])
    state = core.vehicle.state[lane]
    est = core.estimator.lane_estimate(lane)
    _, lm_means, lm_covs = est.mapped_landmarks()
    times = np.arange(max(0.0, t - span_s), t + REF_AHEAD_S + 1e-9, REF_STEP_S)
    n_lm = int(core.n_landmarks[lane])
    particles, n_particles = None, 0
    if isinstance(core.estimator, ShowsParticles):
        cloud = core.estimator.lane_particles(lane)
        n_particles = cloud.shape[0]
        stride = max(1, math.ceil(n_particles / max_particles)) if max_particles else 0
        particles = cloud[::stride] if stride else cloud[:0]
    return Scene(
        t=t,
        label=estimator_label(core.scenario),
        true_pos=state[POS].copy(),
        true_heading=heading_of(state[EUL]),
        est_pos=est.position[0],
        est_heading=heading_of(est.euler[0]),
        est_pos_cov=None if est.pose_cov is None else est.pose_cov[0, POS, POS],
        rows=history.rows(since=t - span_s),
        ref=core.trajectory.batch(times).pos,
        landmarks=core.landmarks[lane, :n_lm].copy(),
        lm_means=lm_means,
        lm_covs=lm_covs,
        scan_points=history.scan_points,
        particles=particles,
        n_particles=n_particles,
        latest=dict(history.latest),
    )


def ellipse_lines(
    centers: FloatArray, covs: FloatArray, scale: float = SIGMA_SCALE, points: int = 33
) -> tuple[FloatArray, FloatArray]:
    """Outlines of the ``scale``-σ ellipses of 2D Gaussians, as one NaN-separated polyline.

    Args:
        centers: (n, 2) means in plot coordinates.
        covs: (n, 2, 2) covariances in the same coordinates.
        scale: Number of standard deviations.
        points: Points per closed outline.

    Returns:
        ``(x, y)``, each (n · (points + 1),): the outlines with a NaN after each.
    """
    n = centers.shape[0]
    if n == 0:
        return np.zeros(0), np.zeros(0)
    angle = np.linspace(0.0, 2.0 * math.pi, points)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=1)  # (points, 2)
    outline = centers[:, None, :] + scale * circle @ np.swapaxes(psd_sqrt(covs), -1, -2)
    out = np.full((n, points + 1, 2), math.nan)
    out[:, :points] = outline
    flat = out.reshape(-1, 2)
    return flat[:, 0], flat[:, 1]


def plane_cov(cov3: FloatArray, axes: tuple[int, int]) -> FloatArray:
    """(..., 2, 2) block of NED covariances (..., 3, 3) for plot axes given as NED indices,
    with the sign of ``z`` flipped (altitude) where index 2 appears."""
    i, j = axes
    block = cov3[..., [i, j], :][..., :, [i, j]]
    if 2 in axes:  # altitude = -z: the cross terms change sign
        block = block.copy()
        block[..., 0, 1] *= -1.0
        block[..., 1, 0] *= -1.0
    return block


def segments(origin: FloatArray, tips: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Line segments from ``origin`` (2,) to each of ``tips`` (k, 2), NaN-separated ``(x, y)``."""
    k = tips.shape[0]
    out = np.full((k, 3, 2), math.nan)
    out[:, 0] = origin
    out[:, 1] = tips
    flat = out.reshape(-1, 2)
    return flat[:, 0], flat[:, 1]


def wedge(
    center: FloatArray, heading: float, half_width: float, radius: float, points: int = 24
) -> FloatArray:
    """Closed polygon (m, 2) of a horizontal field of view in map coordinates (east, north).

    Args:
        center: (2,) apex (east, north).
        heading: Boresight heading, rad from north.
        half_width: Half-width in rad (π or more: a full disc).
        radius: Drawn range in m.
        points: Points on the arc.
    """
    if half_width >= math.pi:
        angle = np.linspace(-math.pi, math.pi, 2 * points)
        return center + radius * np.stack([np.sin(angle), np.cos(angle)], axis=1)
    angle = heading + np.linspace(-half_width, half_width, points)
    arc = center + radius * np.stack([np.sin(angle), np.cos(angle)], axis=1)
    return np.vstack([center, arc, center])
