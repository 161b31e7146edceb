"""The matplotlib figure of a frame, built once and updated in place (Agg, no display).

Layout (fractions of the frame, drawn for 640×480 and scaled with it): a text line on top; a
top-down view that follows the vehicle (left), a side view below it sharing its east axis;
on the right the legend, then strip charts of the position error against ±3σ and of the pose
NEES against its χ² bounds.

Speed: every artist is created once. What never changes (axes frames, titles, axis labels,
legends, bound lines) is drawn once into a background image; a frame restores that image,
moves the data of the dynamic artists (``set_data``, ``set_xy``, limits) and draws only those
and the axes' ticks (blitting, as matplotlib's animations do).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Polygon
from matplotlib.ticker import LogLocator, MaxNLocator
from scipy.stats import chi2

from quadslam_env.render import history as h
from quadslam_env.render.scene import (
    SIGMA_SCALE,
    Scene,
    ellipse_lines,
    plane_cov,
    segments,
    wedge,
)
from quadslam_env.render.stamps import TextStamps
from quadslam_env.render.ticks import Ticks
from quadslam_env.types import POSE_DIM

BASE_W, BASE_H = 640.0, 480.0  # the layout below is in pixels of this size
FONT = 7.0
# Colours (matplotlib's default cycle) by meaning, the same in every panel.
REF, TRUE, EST, LM, LM_EST, SCAN, FOV, PART = (
    "0.45", "tab:blue", "tab:orange", "0.15", "tab:green", "tab:red", "tab:cyan", "tab:purple",
)  # fmt: skip
AXIS_COLORS = ("tab:blue", "tab:orange", "tab:green")  # north, east, down errors
NEES_BOUNDS_95 = (float(chi2.ppf(0.025, POSE_DIM)), float(chi2.ppf(0.975, POSE_DIM)))
HEADING_M = 0.12  # heading tick length as a share of the view radius


def _box(left: float, bottom: float, width: float, height: float) -> list[float]:
    """A rectangle given in base pixels as figure fractions."""
    return [left / BASE_W, bottom / BASE_H, width / BASE_W, height / BASE_H]


class FrameFigure:
    """One figure with its artists; :meth:`draw` turns a :class:`Scene` into an RGB array.

    Args:
        width_px: Frame width in pixels.
        height_px: Frame height in pixels.
        view_radius_m: Half-width of the top-down view in m.
        history_s: Time span of the strip charts in s.
        azimuth_fov_deg: LiDAR azimuth half-width in degrees (the drawn wedge).
        lidar_range_m: LiDAR maximum range in m (the wedge is cut at the view's edge).
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
        self.size = (int(height_px), int(width_px))
        scale = min(width_px / BASE_W, height_px / BASE_H)
        dpi = 100.0 * scale
        self.fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
        self.canvas = FigureCanvasAgg(self.fig)
        self.radius = float(view_radius_m)
        self.history_s = float(history_s)
        self.fov = math.radians(azimuth_fov_deg)
        self.fov_range = min(float(lidar_range_m), 1.5 * self.radius)
        self._dynamic: list[tuple[Any, Any]] = []  # (axes or figure, artist) drawn per frame
        self._ticks: dict[Any, tuple[Ticks, Ticks]] = {}
        self.scale = scale
        self.tick_font = TextStamps(FONT - 0.5, dpi)
        self.line_font = TextStamps(FONT + 1, dpi, family="DejaVu Sans Mono")
        self._background: Any = None
        self._build_text()
        self._build_map(particles)
        self._build_side()
        self._build_strips()
        # Equal scale in the spatial views: the data aspect follows the axes' pixel aspect.
        self.map_aspect = (295.0 * height_px / BASE_H) / (290.0 * width_px / BASE_W)
        self.side_aspect = (92.0 * height_px / BASE_H) / (290.0 * width_px / BASE_W)

    # ------------------------------------------------------------------ construction
    def _axes(
        self,
        box: list[float],
        xlabel: str = "",
        ylabel: str = "",
        nbins: int = 6,
        xticklabels: bool = True,
        ylocator: Any = None,
    ) -> Any:
        """Axes at ``box`` with per-frame :class:`Ticks`; its labels go to the background."""
        ax = self.fig.add_axes(box)
        ax.xaxis.set_visible(False)
        ax.yaxis.set_visible(False)
        ticks = (
            Ticks(ax, "x", MaxNLocator(nbins=nbins), self.tick_font if xticklabels else None),
            Ticks(ax, "y", ylocator or MaxNLocator(nbins=nbins), self.tick_font),
        )
        self._ticks[ax] = ticks
        self._dynamic.extend((ax, t.marks) for t in ticks)
        left, bottom, width, height = box
        if xlabel:
            self.fig.text(
                left + width / 2, bottom - 27 / BASE_H, xlabel, fontsize=FONT, ha="center"
            )
        if ylabel:
            self.fig.text(
                left - 36 / BASE_W, bottom + height / 2, ylabel, fontsize=FONT, rotation=90,
                va="center", ha="center",
            )  # fmt: skip
        return ax

    def _line(self, ax: Any, style: str = "-", **kwargs: Any) -> Line2D:
        (line,) = ax.plot([], [], style, animated=True, **kwargs)
        self._dynamic.append((ax, line))
        return line

    def _build_text(self) -> None:
        self.text_fields: list[str] = []  # pasted at the top (see _paste_text)

    def _build_map(self, particles: bool) -> None:
        ax = self.map = self._axes(_box(44, 155, 290, 295), ylabel="north [m]", xticklabels=False)
        ax.set_title("top-down, following the vehicle", fontsize=FONT, pad=2)
        self.fov_patch = Polygon(
            np.zeros((3, 2)), closed=True, fc=FOV, ec="none", alpha=0.15, animated=True
        )
        ax.add_patch(self.fov_patch)
        self._dynamic.append((ax, self.fov_patch))
        self.m_ref = self._line(ax, "--", color=REF, lw=0.9)
        self.m_true = self._line(ax, color=TRUE, lw=1.2)
        self.m_est = self._line(ax, color=EST, lw=1.0)
        self.m_part = (
            self._line(ax, ".", color=PART, ms=1.5, alpha=0.5, mec="none") if particles else None
        )
        self.m_rays = self._line(ax, color=SCAN, lw=0.5, alpha=0.6)
        self.m_lm = self._line(ax, "^", color=LM, ms=4, mfc="none", mew=0.8)
        self.m_lm_ell = self._line(ax, color=LM_EST, lw=0.7)
        self.m_lm_est = self._line(ax, "x", color=LM_EST, ms=3.5, mew=0.9)
        self.m_scan = self._line(ax, "o", color=SCAN, ms=3, mfc="none", mew=0.8)
        self.m_true_head = self._line(ax, color=TRUE, lw=1.6)
        self.m_true_pos = self._line(ax, "o", color=TRUE, ms=4.5)
        self.m_est_ell = self._line(ax, color=EST, lw=1.0)
        self.m_est_head = self._line(ax, color=EST, lw=1.2)
        self.m_est_pos = self._line(ax, "s", color=EST, ms=3.5, mfc="white", mew=1.0)
        handles = [
            Line2D([], [], ls="--", color=REF, lw=0.9, label="reference"),
            Line2D([], [], color=TRUE, marker="o", ms=4, lw=1.2, label="true path, pose"),
            Line2D([], [], color=EST, marker="s", mfc="white", ms=3.5, label="estimate"),
            Line2D([], [], color=EST, lw=1.0, label=f"{SIGMA_SCALE:.0f}σ position"),
            Line2D([], [], ls="none", marker="^", mfc="none", color=LM, label="landmark (true)"),
            Line2D([], [], color=LM_EST, marker="x", lw=0.7, label=f"mapped, {SIGMA_SCALE:.0f}σ"),
            Line2D([], [], color=SCAN, marker="o", mfc="none", lw=0.5, label="this scan's returns"),
            Polygon(np.zeros((3, 2)), fc=FOV, alpha=0.3, label="LiDAR azimuth FOV"),
        ]
        if particles:
            handles.append(Line2D([], [], ls="none", marker=".", color=PART, label="particles"))
        self.fig.legend(
            handles=handles,
            loc="upper left",
            bbox_to_anchor=(372 / BASE_W, 1 - 22 / BASE_H),
            ncol=2,
            fontsize=FONT - 0.5,
            frameon=False,
            handlelength=1.6,
            columnspacing=0.8,
            borderaxespad=0.0,
            labelspacing=0.3,
        )

    def _build_side(self) -> None:
        ax = self.side = self._axes(
            _box(44, 38, 290, 92), xlabel="east [m]", ylabel="altitude [m]", nbins=4
        )
        ax.set_title("side view (looking north)", fontsize=FONT, pad=2)
        self.s_ref = self._line(ax, "--", color=REF, lw=0.9)
        self.s_true = self._line(ax, color=TRUE, lw=1.2)
        self.s_est = self._line(ax, color=EST, lw=1.0)
        self.s_lm = self._line(ax, "^", color=LM, ms=4, mfc="none", mew=0.8)
        self.s_lm_ell = self._line(ax, color=LM_EST, lw=0.7)
        self.s_lm_est = self._line(ax, "x", color=LM_EST, ms=3.5, mew=0.9)
        self.s_scan = self._line(ax, "o", color=SCAN, ms=3, mfc="none", mew=0.8)
        self.s_true_pos = self._line(ax, "o", color=TRUE, ms=4.5)
        self.s_est_ell = self._line(ax, color=EST, lw=1.0)
        self.s_est_pos = self._line(ax, "s", color=EST, ms=3.5, mfc="white", mew=1.0)

    def _build_strips(self) -> None:
        ax = self.err = self._axes(_box(392, 222, 238, 110), nbins=5, xticklabels=False)
        ax.set_title(f"position error ρ̂ − ρ and ±{SIGMA_SCALE:.0f}σ [m]", fontsize=FONT, pad=2)
        ax.axhline(0.0, color="0.7", lw=0.5)
        self.e_err = []
        self.e_sig = []
        for name, color in zip(("north", "east", "down"), AXIS_COLORS, strict=True):
            self.e_sig.append(self._line(ax, "--", color=color, lw=0.7, alpha=0.8))
            self.e_err.append(self._line(ax, color=color, lw=1.0, label=name))
        ax.legend(
            loc="upper left", fontsize=FONT - 1, ncol=3, frameon=False, handlelength=1.2,
            columnspacing=0.8, borderaxespad=0.2,
        )  # fmt: skip
        ax = self.nees = self._axes(
            _box(392, 38, 238, 150),
            xlabel="time t [s]",
            nbins=5,
            ylocator=LogLocator(subs=(1.0, 2.0, 5.0), numticks=12),
        )
        lo, hi = NEES_BOUNDS_95
        ax.set_title(f"pose NEES and 95% χ²({POSE_DIM}) bounds (log)", fontsize=FONT, pad=2)
        ax.set_yscale("log")
        for bound in (lo, hi):
            ax.axhline(bound, color=SCAN, ls="--", lw=0.8)
        ax.axhline(POSE_DIM, color="0.6", ls=":", lw=0.8)
        self.n_line = self._line(ax, color="black", lw=1.0)
        self.n_note = ax.text(
            0.5, 0.5, "", transform=ax.transAxes, ha="center", va="center", fontsize=FONT,
            animated=True,
        )  # fmt: skip
        self._dynamic.append((ax, self.n_note))

    # ------------------------------------------------------------------ per frame
    def draw(self, scene: Scene) -> np.ndarray:
        """Update every artist from ``scene``, redraw, and return an (H, W, 3) uint8 copy."""
        self._draw_text(scene)
        self._draw_map(scene)
        self._draw_side(scene)
        self._draw_strips(scene)
        if self._background is None:
            self.canvas.draw()  # everything not animated: the static layer
            self._background = self.canvas.copy_from_bbox(self.fig.bbox)
        else:
            self.canvas.restore_region(self._background)
        for owner, artist in self._dynamic:
            owner.draw_artist(artist)
        rgb = np.asarray(self.canvas.buffer_rgba())[..., :3]
        frame = np.array(rgb[: self.size[0], : self.size[1]])
        if frame.shape[:2] != self.size:  # Agg rounds the canvas size down by at most a pixel
            frame = np.pad(
                frame,
                ((0, self.size[0] - frame.shape[0]), (0, self.size[1] - frame.shape[1]), (0, 0)),
                mode="edge",
            )
        for ticks in self._ticks.values():
            for t in ticks:
                t.paste_labels(frame)
        self._paste_text(frame)
        return frame

    def _paste_text(self, frame: np.ndarray) -> None:
        """The text line, field by field (monospace columns, so unchanged fields are cached)."""
        col = 0
        x0, y0 = 8.0 * self.scale, 14.0 * self.scale
        sep = "  |  "
        for i, field in enumerate(self.text_fields):
            text = field if i == 0 else sep + field
            self.line_font.paste(frame, text, x0 + col * self.line_font.advance_px, y0)
            col += len(text)

    def _limits(self, ax: Any, xlim: tuple[float, float], ylim: tuple[float, float]) -> None:
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        xt, yt = self._ticks[ax]
        xt.update(*xlim)
        yt.update(*ylim)

    def _draw_text(self, s: Scene) -> None:
        lat = s.latest
        nees = lat["est_nees_pose"]
        parts = [
            f"t = {s.t:5.1f} s",
            s.label,
            f"landmarks {_count(lat['est_n_visible'])} visible, "
            f"{_count(lat['est_n_mapped'])}/{s.landmarks.shape[0]} mapped",
            f"NEES {nees:.1f}" if math.isfinite(nees) else "NEES -",
        ]
        if s.n_particles:
            parts.append(f"ESS {lat['est_ess']:.0f}/{s.n_particles}")
        self.text_fields = parts

    def _draw_map(self, s: Scene) -> None:
        e, n = s.true_pos[1], s.true_pos[0]
        r = self.radius
        self._limits(self.map, (e - r, e + r), (n - r * self.map_aspect, n + r * self.map_aspect))
        self.fov_patch.set_xy(wedge(np.array([e, n]), s.true_heading, self.fov, self.fov_range))
        rows = s.rows
        self.m_ref.set_data(s.ref[:, 1], s.ref[:, 0])
        self.m_true.set_data(rows[:, h.TRUE][:, 1], rows[:, h.TRUE][:, 0])
        self.m_est.set_data(rows[:, h.EST][:, 1], rows[:, h.EST][:, 0])
        if self.m_part is not None:
            cloud = s.particles if s.particles is not None else np.zeros((0, 3))
            self.m_part.set_data(cloud[:, 1], cloud[:, 0])
        pts = s.scan_points
        self.m_rays.set_data(*segments(np.array([e, n]), pts[:, [1, 0]]))
        self.m_scan.set_data(pts[:, 1], pts[:, 0])
        self.m_lm.set_data(s.landmarks[:, 1], s.landmarks[:, 0])
        self.m_lm_est.set_data(s.lm_means[:, 1], s.lm_means[:, 0])
        self.m_lm_ell.set_data(*ellipse_lines(s.lm_means[:, [1, 0]], plane_cov(s.lm_covs, (1, 0))))
        tick = HEADING_M * r
        self.m_true_pos.set_data([e], [n])
        self.m_true_head.set_data(
            [e, e + tick * math.sin(s.true_heading)], [n, n + tick * math.cos(s.true_heading)]
        )
        ee, en = s.est_pos[1], s.est_pos[0]
        self.m_est_pos.set_data([ee], [en])
        self.m_est_head.set_data(
            [ee, ee + tick * math.sin(s.est_heading)], [en, en + tick * math.cos(s.est_heading)]
        )
        if s.est_pos_cov is None:
            self.m_est_ell.set_data([], [])
        else:
            self.m_est_ell.set_data(
                *ellipse_lines(s.est_pos[None, [1, 0]], plane_cov(s.est_pos_cov[None], (1, 0)))
            )

    def _draw_side(self, s: Scene) -> None:
        e, alt = s.true_pos[1], -s.true_pos[2]
        r = self.radius
        half = r * self.side_aspect
        self._limits(self.side, (e - r, e + r), (alt - half, alt + half))
        rows = s.rows
        self.s_ref.set_data(s.ref[:, 1], -s.ref[:, 2])
        self.s_true.set_data(rows[:, h.TRUE][:, 1], -rows[:, h.TRUE][:, 2])
        self.s_est.set_data(rows[:, h.EST][:, 1], -rows[:, h.EST][:, 2])
        self.s_lm.set_data(s.landmarks[:, 1], -s.landmarks[:, 2])
        self.s_lm_est.set_data(s.lm_means[:, 1], -s.lm_means[:, 2])
        side_means = np.stack([s.lm_means[:, 1], -s.lm_means[:, 2]], axis=1)
        self.s_lm_ell.set_data(*ellipse_lines(side_means, plane_cov(s.lm_covs, (1, 2))))
        self.s_scan.set_data(s.scan_points[:, 1], -s.scan_points[:, 2])
        self.s_true_pos.set_data([e], [alt])
        self.s_est_pos.set_data([s.est_pos[1]], [-s.est_pos[2]])
        if s.est_pos_cov is None:
            self.s_est_ell.set_data([], [])
        else:
            center = np.array([[s.est_pos[1], -s.est_pos[2]]])
            self.s_est_ell.set_data(*ellipse_lines(center, plane_cov(s.est_pos_cov[None], (1, 2))))

    def _draw_strips(self, s: Scene) -> None:
        rows = s.rows[s.rows[:, h.T] >= s.t - self.history_s]
        t0 = max(0.0, s.t - self.history_s)
        span = (t0, t0 + self.history_s)
        time = rows[:, h.T]
        err, sig = rows[:, h.ERR], SIGMA_SCALE * rows[:, h.SIGMA]
        gap = np.array([math.nan])
        for i in range(3):
            self.e_err[i].set_data(time, err[:, i])
            self.e_sig[i].set_data(
                np.concatenate([time, gap, time]), np.concatenate([sig[:, i], gap, -sig[:, i]])
            )
        top = np.nanmax(np.abs(np.concatenate([err.ravel(), sig.ravel(), [1e-3]])))
        self._limits(self.err, span, (-1.25 * top, 1.6 * top))  # headroom for the legend
        nees = rows[:, h.NEES]
        finite = nees[np.isfinite(nees) & (nees > 0)]
        self.n_line.set_data(time, nees)
        lo, hi = NEES_BOUNDS_95
        if finite.size:
            ylim = (min(0.5 * lo, finite.min()), max(3.0 * hi, 2.0 * finite.max()))
            self.n_note.set_text("")
        else:
            ylim = (0.5 * lo, 3.0 * hi)
            self.n_note.set_text("no covariance: no NEES")
        self._limits(self.nees, span, ylim)


def _count(value: float) -> str:
    return f"{value:.0f}" if math.isfinite(value) else "-"
