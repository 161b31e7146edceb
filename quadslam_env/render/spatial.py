"""The spatial panels: top-down view following the vehicle, its zoom inset, and the side view.

Plot coordinates (see :mod:`.scene`): top-down x = east, y = north; side view x = east,
y = altitude. Ellipses are 3σ outlines of the marginal covariances in those planes.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.patches import Polygon

from quadslam_env.render import history as h
from quadslam_env.render.layout import (
    EST,
    FONT,
    FOV,
    LM,
    LM_EST,
    PART,
    REF,
    SCAN,
    TRUE,
    Board,
    box,
)
from quadslam_env.render.scene import Scene, ellipse_lines, plane_cov, segments, wedge

MAP = (44.0, 155.0, 290.0, 295.0)  # layout pixels: left, bottom, width, height
SIDE = (44.0, 38.0, 290.0, 92.0)
ZOOM = 90.0  # side of the zoom inset in layout pixels
HEADING = 0.12  # heading tick length as a share of the view radius
EN, EA = (1, 0), (1, 2)  # NED indices of the top-down and side planes


def nice_ceil(value: float) -> float:
    """Smallest 1-2-5 × 10^k at or above ``value`` > 0."""
    base = 10.0 ** math.floor(math.log10(value))
    for step in (1.0, 2.0, 5.0, 10.0):
        if step * base >= value * (1 - 1e-9):
            return step * base
    return 10.0 * base  # pragma: no cover - the loop always returns


class MapView:
    """Top-down view (north up) centred on the true position, ``radius`` m to each side.

    Args:
        board: The figure.
        radius: Half-width of the view in m.
        fov_deg: LiDAR azimuth half-width in degrees (≥ 180: every azimuth, no wedge).
        fov_range: Drawn length of the wedge in m.
        particles: Draw a particle cloud.
    """

    def __init__(
        self, board: Board, radius: float, fov_deg: float, fov_range: float, particles: bool
    ) -> None:
        self.board = b = board
        self.radius = radius
        self.fov = math.radians(fov_deg)
        self.fov_range = fov_range
        self.aspect = (MAP[3] * b.size[0] / 480.0) / (MAP[2] * b.size[1] / 640.0)
        ax = self.ax = b.axes(box(*MAP), ylabel="north [m]", xticklabels=False)
        ax.set_title("top-down (north up), following the vehicle", fontsize=FONT, pad=2)
        self.fov_patch = b.add(
            ax, ax.add_patch(Polygon(np.zeros((3, 2)), closed=True, fc=FOV, ec="none", alpha=0.15))
        )
        self.ref = b.line(ax, "--", color=REF, lw=0.9)
        self.true = b.line(ax, color=TRUE, lw=1.2)
        self.est = b.line(ax, color=EST, lw=1.0)
        self.part = b.line(ax, ".", color=PART, ms=2, alpha=0.6, mec="none") if particles else None
        self.rays = b.line(ax, color=SCAN, lw=0.5, alpha=0.6)
        self.lm = b.line(ax, "^", color=LM, ms=4, mfc="none", mew=0.8)
        self.lm_ell = b.line(ax, color=LM_EST, lw=0.7)
        self.lm_est = b.line(ax, "x", color=LM_EST, ms=3.5, mew=0.9)
        self.scan = b.line(ax, "o", color=SCAN, ms=3, mfc="none", mew=0.8)
        self.true_head = b.line(ax, color=TRUE, lw=1.6)
        self.true_pos = b.line(ax, "o", color=TRUE, ms=4.5)
        self.est_ell = b.line(ax, color=EST, lw=1.0)
        self.est_head = b.line(ax, color=EST, lw=1.2)
        self.est_pos = b.line(ax, "s", color=EST, ms=3.5, mfc="white", mew=1.0)

    def update(self, s: Scene) -> None:
        """Move every artist to the scene ``s``."""
        e, n = s.true_pos[1], s.true_pos[0]
        r = self.radius
        self.board.limits(self.ax, (e - r, e + r), (n - r * self.aspect, n + r * self.aspect))
        if self.fov < math.pi:
            self.fov_patch.set_xy(wedge(np.array([e, n]), s.true_heading, self.fov, self.fov_range))
        else:
            self.fov_patch.set_visible(False)
        rows = s.rows
        self.ref.set_data(s.ref[:, 1], s.ref[:, 0])
        self.true.set_data(rows[:, h.TRUE][:, 1], rows[:, h.TRUE][:, 0])
        self.est.set_data(rows[:, h.EST][:, 1], rows[:, h.EST][:, 0])
        if self.part is not None and s.particles is not None:
            self.part.set_data(s.particles[:, 1], s.particles[:, 0])
        pts = s.scan_points
        self.rays.set_data(*segments(np.array([e, n]), pts[:, [1, 0]]))
        self.scan.set_data(pts[:, 1], pts[:, 0])
        self.lm.set_data(s.landmarks[:, 1], s.landmarks[:, 0])
        self.lm_est.set_data(s.lm_means[:, 1], s.lm_means[:, 0])
        self.lm_ell.set_data(*ellipse_lines(s.lm_means[:, [1, 0]], plane_cov(s.lm_covs, EN)))
        tick = HEADING * r
        self.true_pos.set_data([e], [n])
        self.true_head.set_data(
            [e, e + tick * math.sin(s.true_heading)], [n, n + tick * math.cos(s.true_heading)]
        )
        ee, en = s.est_pos[1], s.est_pos[0]
        self.est_pos.set_data([ee], [en])
        self.est_head.set_data(
            [ee, ee + tick * math.sin(s.est_heading)], [en, en + tick * math.cos(s.est_heading)]
        )
        _set_pose_ellipse(self.est_ell, s, EN)


class ZoomInset:
    """A small top-down inset centred on the true position, scaled so the estimate's error and
    its 3σ ellipse (and the particle cloud) fill it; its half-width is printed in it."""

    def __init__(self, board: Board, particles: bool) -> None:
        self.board = b = board
        left, bottom = MAP[0] + MAP[2] - ZOOM - 2, MAP[1] + MAP[3] - ZOOM - 2
        ax = self.ax = b.axes(box(left, bottom, ZOOM, ZOOM), ticks=False)
        b.add(ax, ax.patch)  # opaque over the map's dynamic artists
        for spine in ax.spines.values():
            b.add(ax, spine)
        self.true = b.line(ax, color=TRUE, lw=1.0)
        self.est = b.line(ax, color=EST, lw=0.9)
        self.part = b.line(ax, ".", color=PART, ms=2, alpha=0.6, mec="none") if particles else None
        self.est_ell = b.line(ax, color=EST, lw=1.0)
        self.true_pos = b.line(ax, "o", color=TRUE, ms=4)
        self.est_pos = b.line(ax, "s", color=EST, ms=3.5, mfc="white", mew=1.0)
        self.anchor = b.pixels(left + 3, bottom + 3)
        self.label = ""
        b.pasters.append(self._paste)

    def update(self, s: Scene) -> None:
        """Centre on the truth; the half-width is a 1-2-5 value above the spread shown."""
        c = s.true_pos[[1, 0]]
        spread = [0.01, *np.abs(s.est_pos[[1, 0]] - c)]
        if s.est_pos_cov is not None:
            spread.extend(3.0 * np.sqrt(np.clip(np.diagonal(s.est_pos_cov)[[1, 0]], 0.0, None)))
        if s.particles is not None and s.particles.shape[0]:
            dev = np.abs(s.particles[:, [1, 0]] - c)
            spread.extend(np.percentile(dev, 90, axis=0))
        half = nice_ceil(1.2 * float(np.nanmax(spread)))
        self.board.limits(self.ax, (c[0] - half, c[0] + half), (c[1] - half, c[1] + half))
        rows = s.rows
        self.true.set_data(rows[:, h.TRUE][:, 1], rows[:, h.TRUE][:, 0])
        self.est.set_data(rows[:, h.EST][:, 1], rows[:, h.EST][:, 0])
        if self.part is not None and s.particles is not None:
            self.part.set_data(s.particles[:, 1], s.particles[:, 0])
        self.true_pos.set_data([c[0]], [c[1]])
        self.est_pos.set_data([s.est_pos[1]], [s.est_pos[0]])
        _set_pose_ellipse(self.est_ell, s, EN)
        self.label = f"zoom ±{half:g} m"

    def _paste(self, frame: np.ndarray) -> None:
        self.board.tick_font.paste(frame, self.label, *self.anchor, "left", "bottom")


class SideView:
    """Side view (looking north): east against altitude, equal scale, centred on the truth."""

    def __init__(self, board: Board, radius: float) -> None:
        self.board = b = board
        self.radius = radius
        self.aspect = (SIDE[3] * b.size[0] / 480.0) / (SIDE[2] * b.size[1] / 640.0)
        ax = self.ax = b.axes(box(*SIDE), xlabel="east [m]", ylabel="altitude [m]", nbins=4)
        ax.set_title("side view (looking north)", fontsize=FONT, pad=2)
        self.ref = b.line(ax, "--", color=REF, lw=0.9)
        self.true = b.line(ax, color=TRUE, lw=1.2)
        self.est = b.line(ax, color=EST, lw=1.0)
        self.lm = b.line(ax, "^", color=LM, ms=4, mfc="none", mew=0.8)
        self.lm_ell = b.line(ax, color=LM_EST, lw=0.7)
        self.lm_est = b.line(ax, "x", color=LM_EST, ms=3.5, mew=0.9)
        self.scan = b.line(ax, "o", color=SCAN, ms=3, mfc="none", mew=0.8)
        self.true_pos = b.line(ax, "o", color=TRUE, ms=4.5)
        self.est_ell = b.line(ax, color=EST, lw=1.0)
        self.est_pos = b.line(ax, "s", color=EST, ms=3.5, mfc="white", mew=1.0)

    def update(self, s: Scene) -> None:
        """Move every artist to the scene ``s``."""
        e, alt = s.true_pos[1], -s.true_pos[2]
        r = self.radius
        half = r * self.aspect
        self.board.limits(self.ax, (e - r, e + r), (alt - half, alt + half))
        rows = s.rows
        self.ref.set_data(s.ref[:, 1], -s.ref[:, 2])
        self.true.set_data(rows[:, h.TRUE][:, 1], -rows[:, h.TRUE][:, 2])
        self.est.set_data(rows[:, h.EST][:, 1], -rows[:, h.EST][:, 2])
        self.lm.set_data(s.landmarks[:, 1], -s.landmarks[:, 2])
        self.lm_est.set_data(s.lm_means[:, 1], -s.lm_means[:, 2])
        means = np.stack([s.lm_means[:, 1], -s.lm_means[:, 2]], axis=1)
        self.lm_ell.set_data(*ellipse_lines(means, plane_cov(s.lm_covs, EA)))
        self.scan.set_data(s.scan_points[:, 1], -s.scan_points[:, 2])
        self.true_pos.set_data([e], [alt])
        self.est_pos.set_data([s.est_pos[1]], [-s.est_pos[2]])
        _set_pose_ellipse(self.est_ell, s, EA)


def _set_pose_ellipse(line: Any, s: Scene, axes: tuple[int, int]) -> None:
    """The estimate's 3σ position ellipse in the plane of NED ``axes`` (none without a
    covariance)."""
    if s.est_pos_cov is None:
        line.set_data([], [])
        return
    center = s.est_pos[list(axes)] * np.array([1.0, -1.0 if axes[1] == 2 else 1.0])
    line.set_data(*ellipse_lines(center[None], plane_cov(s.est_pos_cov[None], axes)))
