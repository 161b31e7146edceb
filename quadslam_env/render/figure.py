"""The frame: a text line on top; a top-down view following the vehicle (with a zoom inset)
and a side view below it on the left; the legend and two strip charts on the right.

Built once per renderer (:mod:`.layout` explains how a frame is redrawn quickly).
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from quadslam_env.render.layout import (
    BASE_H,
    BASE_W,
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
)
from quadslam_env.render.scene import SIGMA_SCALE, Scene
from quadslam_env.render.spatial import MapView, SideView, ZoomInset
from quadslam_env.render.stamps import TextStamps
from quadslam_env.render.strips import StripCharts

SEPARATOR = " | "


class FrameFigure:
    """One figure with its artists; :meth:`draw` turns a :class:`Scene` into an RGB array.

    Args:
        width_px: Frame width in pixels.
        height_px: Frame height in pixels.
        view_radius_m: Half-width of the top-down view in m.
        history_s: Time span of the strip charts in s.
        azimuth_fov_deg: LiDAR azimuth half-width in degrees (the drawn wedge).
        lidar_range_m: LiDAR maximum range in m (the wedge is cut beyond the view).
        particles: Whether the estimator has particles (adds the cloud and its legend entry).
    """

    def __init__(
        self,
        width_px: int,
        height_px: int,
        view_radius_m: float,
        history_s: float,
        azimuth_fov_deg: float,
        lidar_range_m: float,
        particles: bool,
    ) -> None:
        self.board = b = Board(width_px, height_px)
        fov_range = min(float(lidar_range_m), 1.5 * float(view_radius_m))
        self.map = MapView(b, float(view_radius_m), azimuth_fov_deg, fov_range, particles)
        self.zoom = ZoomInset(b, particles)
        self.side = SideView(b, float(view_radius_m))
        self.strips = StripCharts(b, float(history_s))
        self._legend(azimuth_fov_deg, particles)
        self.line_font = TextStamps(FONT + 1, b.fig.dpi, family="DejaVu Sans Mono")
        self.text_fields: list[str] = []
        b.pasters.append(self._paste_text)

    def _legend(self, azimuth_fov_deg: float, particles: bool) -> None:
        sigma = f"{SIGMA_SCALE:.0f}σ"
        fov = (
            "LiDAR FOV: all azimuths"
            if azimuth_fov_deg >= 180.0
            else f"LiDAR FOV ±{azimuth_fov_deg:g}° az."
        )
        handles = [
            Line2D([], [], ls="--", color=REF, lw=0.9, label="reference"),
            Line2D([], [], color=TRUE, marker="o", ms=4, lw=1.2, label="true path, pose"),
            Line2D([], [], color=EST, marker="s", mfc="white", ms=3.5, label="estimate"),
            Line2D([], [], color=EST, lw=1.0, label=f"{sigma} position"),
            Line2D([], [], ls="none", marker="^", mfc="none", color=LM, label="landmark (true)"),
            Line2D([], [], color=LM_EST, marker="x", lw=0.7, label=f"mapped, {sigma}"),
            Line2D([], [], color=SCAN, marker="o", mfc="none", lw=0.5, label="this scan's returns"),
            Patch(fc=FOV, alpha=0.3 if azimuth_fov_deg < 180.0 else 0.0, label=fov),
        ]
        if particles:
            handles.append(Line2D([], [], ls="none", marker=".", color=PART, label="particles"))
        self.board.fig.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(372 / BASE_W, 1 - 24 / BASE_H),
            ncol=2,
            fontsize=FONT - 0.5,
            frameon=False,
            handlelength=1.6,
            columnspacing=0.8,
            borderaxespad=0.0,
            labelspacing=0.3,
        )

    def draw(self, scene: Scene) -> np.ndarray:
        """Update every panel from ``scene`` and return the frame, (H, W, 3) uint8."""
        self.text_fields = text_fields(scene)
        self.map.update(scene)
        self.zoom.update(scene)
        self.side.update(scene)
        self.strips.update(scene)
        return self.board.render()

    def _paste_text(self, frame: np.ndarray) -> None:
        """The text line, field by field at monospace columns (unchanged fields are cached)."""
        x0, y0 = self.board.pixels(8.0, BASE_H - 15.0)
        col = 0
        for i, field in enumerate(self.text_fields):
            text = field if i == 0 else SEPARATOR + field
            self.line_font.paste(frame, text, x0 + col * self.line_font.advance_px, y0)
            col += len(text)


def text_fields(s: Scene) -> list[str]:
    """The text line's fields: time, estimator, landmark counts, NEES (and ESS)."""
    lat = s.latest
    nees = lat["est_nees_pose"]
    fields = [
        f"t = {s.t:5.1f} s",
        s.label,
        f"landmarks {_count(lat['est_n_visible'])} visible, "
        f"{_count(lat['est_n_mapped'])}/{s.landmarks.shape[0]} mapped",
        f"NEES {nees:.1f}" if math.isfinite(nees) else "NEES -",
    ]
    if s.n_particles:
        fields.append(f"ESS {_count(lat['est_ess'])}/{s.n_particles}")
    return fields


def _count(value: float) -> str:
    return f"{value:.0f}" if math.isfinite(value) else "-"
