"""The figure, its fixed layout and the fast redraw shared by every panel (matplotlib, Agg).

Positions are given in pixels of a 640×480 frame (:func:`box`) and scale with the frame.

Speed: every artist is created once. What never changes (axes frames, titles, axis labels,
legends, bound lines) is drawn once into a background image; a frame restores that image,
draws only the artists registered as dynamic (blitting, as matplotlib's animations do), and
pastes tick labels and the text line from cached FreeType masks (:mod:`.stamps`). No figure
or artist is created per frame.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from quadslam_env.render.stamps import TextStamps
from quadslam_env.render.ticks import Ticks

BASE_W, BASE_H = 640.0, 480.0  # layout units: pixels of a 640×480 frame
FONT = 7.0  # points at 640×480
# Colours (matplotlib's default cycle) by meaning, the same in every panel.
REF, TRUE, EST, LM, LM_EST, SCAN, FOV, PART = (
    "0.45", "tab:blue", "tab:orange", "0.15", "tab:green", "tab:red", "tab:cyan", "tab:purple",
)  # fmt: skip


def box(left: float, bottom: float, width: float, height: float) -> list[float]:
    """A rectangle in layout pixels (origin bottom left) as figure fractions."""
    return [left / BASE_W, bottom / BASE_H, width / BASE_W, height / BASE_H]


class Board:
    """The figure, its Agg canvas and the registry of what is redrawn per frame.

    Args:
        width_px: Frame width in pixels.
        height_px: Frame height in pixels.
    """

    def __init__(self, width_px: int, height_px: int) -> None:
        self.size = (int(height_px), int(width_px))
        self.scale = min(width_px / BASE_W, height_px / BASE_H)
        dpi = 100.0 * self.scale
        self.fig = Figure(figsize=(width_px / dpi, height_px / dpi), dpi=dpi, facecolor="white")
        self.canvas = FigureCanvasAgg(self.fig)
        self.tick_font = TextStamps(FONT - 0.5, dpi)
        self.dynamic: list[tuple[Any, Any]] = []  # (axes or figure, artist), in drawing order
        self.ticks: dict[Any, tuple[Ticks, Ticks]] = {}
        self.pasters: list[Any] = []  # callables frame -> None, after the canvas is copied
        self._background: Any = None

    def pixels(self, x: float, y: float) -> tuple[float, float]:
        """Layout pixels (origin bottom left) → frame pixels (column, row from the top)."""
        return x * self.size[1] / BASE_W, self.size[0] - y * self.size[0] / BASE_H

    def axes(
        self,
        rect: list[float],
        xlabel: str = "",
        ylabel: str = "",
        nbins: int = 6,
        xticklabels: bool = True,
        ylocator: Any = None,
        ticks: bool = True,
    ) -> Any:
        """Axes at ``rect`` (figure fractions) with per-frame :class:`Ticks` (if ``ticks``);
        the axis labels are static text."""
        ax = self.fig.add_axes((rect[0], rect[1], rect[2], rect[3]))
        ax.xaxis.set_visible(False)
        ax.yaxis.set_visible(False)
        if ticks:
            pair = (
                Ticks(ax, "x", MaxNLocator(nbins=nbins), self.tick_font if xticklabels else None),
                Ticks(ax, "y", ylocator or MaxNLocator(nbins=nbins), self.tick_font),
            )
            self.ticks[ax] = pair
            self.dynamic.extend((ax, t.marks) for t in pair)
        left, bottom, width, height = rect
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

    def line(self, ax: Any, style: str = "-", **kwargs: Any) -> Line2D:
        """An empty dynamic line of ``ax``."""
        (line,) = ax.plot([], [], style, animated=True, **kwargs)
        self.dynamic.append((ax, line))
        return line

    def add(self, ax: Any, artist: Any) -> Any:
        """Register ``artist`` (already in ``ax`` or the figure) as dynamic."""
        artist.set_animated(True)
        self.dynamic.append((ax, artist))
        return artist

    def limits(self, ax: Any, xlim: tuple[float, float], ylim: tuple[float, float]) -> None:
        """Set the view limits of ``ax`` and move its ticks."""
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        if ax in self.ticks:
            xt, yt = self.ticks[ax]
            xt.update(*xlim)
            yt.update(*ylim)

    def render(self) -> np.ndarray:
        """Draw the dynamic artists over the background: an (H, W, 3) uint8 copy."""
        if self._background is None:
            self.canvas.draw()  # everything not animated: the static layer
            self._background = self.canvas.copy_from_bbox(self.fig.bbox)
        else:
            self.canvas.restore_region(self._background)
        for owner, artist in self.dynamic:
            owner.draw_artist(artist)
        rgb = np.asarray(self.canvas.buffer_rgba())[..., :3]
        frame = np.array(rgb[: self.size[0], : self.size[1]])
        if frame.shape[:2] != self.size:  # Agg may round the canvas down by a pixel
            pad = ((0, self.size[0] - frame.shape[0]), (0, self.size[1] - frame.shape[1]), (0, 0))
            frame = np.pad(frame, pad, mode="edge")
        for pair in self.ticks.values():
            for t in pair:
                t.paste_labels(frame)
        for paste in self.pasters:
            paste(frame)
        return frame
