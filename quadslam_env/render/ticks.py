"""Tick marks and labels that are cheap to move (``matplotlib.axis`` is not, per frame).

A view that follows the vehicle moves its limits every frame. Matplotlib's own axis then
re-creates, re-positions and measures its tick objects per draw (about two thirds of a frame's
time here). :class:`Ticks` draws the marks as one marker line and pastes the labels into the
finished frame from :class:`~quadslam_env.render.stamps.TextStamps`.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.markers import TICKDOWN, TICKLEFT, MarkerStyle

from quadslam_env.render.stamps import TextStamps

MAX_TICKS = 12


def tick_label(value: float) -> str:
    """A short label: ``%g`` with a typographic minus and no negative zero."""
    text = f"{value:g}"
    return "0" if text == "-0" else text.replace("-", "−")


class Ticks:
    """The ticks of one axis of ``ax``.

    Args:
        ax: The axes.
        which: ``"x"`` (bottom) or ``"y"`` (left).
        locator: A matplotlib locator, used through ``tick_values(vmin, vmax)``.
        stamps: Label font, or ``None`` for marks without labels.
        length: Mark length in points.
        pad: Gap between mark and label in points.
    """

    def __init__(
        self,
        ax: Any,
        which: str,
        locator: Any,
        stamps: TextStamps | None,
        length: float = 2.5,
        pad: float = 1.5,
    ) -> None:
        self.which = which
        self.locator = locator
        self.stamps = stamps
        self.gap_px = (length + pad) * ax.get_figure().dpi / 72.0
        if which == "x":
            self.transform = ax.get_xaxis_transform()
            marker = TICKDOWN
        else:
            self.transform = ax.get_yaxis_transform()
            marker = TICKLEFT
        self.marks = Line2D(
            [], [], ls="none", marker=MarkerStyle(marker), ms=length, mew=0.8, color="black",
            transform=self.transform, animated=True,
        )  # fmt: skip
        ax.add_artist(self.marks)
        self.marks.set_clip_on(False)  # add_artist clips to the axes; marks lie outside
        self.values = np.zeros(0)

    def update(self, vmin: float, vmax: float) -> None:
        """Place the marks for the view limits ``vmin < vmax`` (after the limits are set)."""
        values = np.asarray(self.locator.tick_values(vmin, vmax), dtype=float)
        tol = 1e-9 * (vmax - vmin)
        self.values = values[(values >= vmin - tol) & (values <= vmax + tol)][:MAX_TICKS]
        zeros = np.zeros_like(self.values)
        if self.which == "x":
            self.marks.set_data(self.values, zeros)
        else:
            self.marks.set_data(zeros, self.values)

    def paste_labels(self, frame: np.ndarray) -> None:
        """Blend the labels of the current ticks into the finished ``frame`` (H, W, 3)."""
        if self.stamps is None or not self.values.size:
            return
        height, gap, paste = frame.shape[0], self.gap_px, self.stamps.paste
        zeros = np.zeros_like(self.values)
        if self.which == "x":
            pts = self.transform.transform(np.column_stack([self.values, zeros]))
            for v, (x, y) in zip(self.values.tolist(), pts.tolist(), strict=True):
                paste(frame, tick_label(v), x, height - y + gap, "center", "top")
        else:
            pts = self.transform.transform(np.column_stack([zeros, self.values]))
            for v, (x, y) in zip(self.values.tolist(), pts.tolist(), strict=True):
                paste(frame, tick_label(v), x - gap, height - y, "right", "center")
