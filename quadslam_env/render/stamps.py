"""Short texts rasterised once with FreeType and pasted into frames with NumPy.

The labels that change from frame to frame (tick values, the text line) cost more through
matplotlib's ``Text`` artists than the rest of a frame together. Here a string is rendered by
the same FreeType font object matplotlib's Agg backend uses (``matplotlib.font_manager
.get_font``) into an alpha mask, kept in a small cache (tick values repeat), and blended into
the finished RGB frame.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import get_hinting_flag
from matplotlib.font_manager import FontProperties, findfont, get_font

CACHE_SIZE = 1024  # masks kept (the cache is emptied when full)


class TextStamps:
    """Alpha masks of strings in one font, and their blending into (H, W, 3) uint8 frames.

    Args:
        size_pt: Font size in points.
        dpi: Dots per inch of the frame (points → pixels).
        family: Font family (matplotlib's font lookup).
    """

    def __init__(self, size_pt: float, dpi: float, family: str = "DejaVu Sans") -> None:
        self._path = findfont(FontProperties(family=family))
        self.size_pt = float(size_pt)
        self.dpi = float(dpi)
        self._cache: dict[str, tuple[np.ndarray, int]] = {}
        font = self._font()
        font.set_text("0", 0.0, flags=get_hinting_flag())
        self.advance_px = font.get_width_height()[0] / 64.0  # one digit (monospace: any char)

    def _font(self) -> Any:
        font = get_font(self._path)
        font.clear()
        font.set_size(self.size_pt, self.dpi)
        return font

    def mask(self, text: str) -> tuple[np.ndarray, int]:
        """``(alpha (h, w) float32 in [0, 1], descent px)`` of ``text`` (cached)."""
        hit = self._cache.get(text)
        if hit is None:
            font = self._font()
            font.set_text(text, 0.0, flags=get_hinting_flag())
            font.draw_glyphs_to_bitmap(antialiased=True)
            alpha = np.asarray(font.get_image(), dtype=np.float32) / 255.0
            descent = math.ceil(font.get_descent() / 64.0)
            if len(self._cache) >= CACHE_SIZE:
                self._cache.clear()
            hit = self._cache[text] = (alpha, descent)
        return hit

    def paste(
        self,
        frame: np.ndarray,
        text: str,
        x: float,
        y: float,
        ha: str = "left",
        va: str = "baseline",
        color: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """Blend ``text`` into ``frame`` (H, W, 3) uint8 in place.

        Args:
            frame: The image; rows count from the top.
            text: The string.
            x: Anchor column in pixels from the left.
            y: Anchor row in pixels from the top.
            ha: ``left``, ``center`` or ``right`` of the text at ``x``.
            va: ``top``, ``center``, ``baseline`` or ``bottom`` of the text at ``y``.
            color: RGB in [0, 1].
        """
        if not text:
            return
        alpha, descent = self.mask(text)
        h, w = alpha.shape
        left = round(x - {"left": 0.0, "center": w / 2.0, "right": float(w)}[ha])
        top = round(
            y - {"top": 0.0, "center": h / 2.0, "baseline": h - descent, "bottom": float(h)}[va]
        )
        r0, c0 = max(top, 0), max(left, 0)
        r1, c1 = min(top + h, frame.shape[0]), min(left + w, frame.shape[1])
        if r1 <= r0 or c1 <= c0:
            return
        a = alpha[r0 - top : r1 - top, c0 - left : c1 - left, None]
        region = frame[r0:r1, c0:c1]
        ink = np.asarray(color, dtype=np.float32) * 255.0
        region[...] = (region * (1.0 - a) + ink * a + 0.5).astype(np.uint8)
