"""Strip charts over the last ``history_s``: position error against ±3σ, NEES against χ².

The pose NEES (9 DOF: ρ, v_B, Λ) of a consistent filter lies inside the two-sided 95% interval
of χ²(9) (scipy's quantiles) on 95% of the steps; its mean is 9 (dotted line).
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.ticker import LogLocator
from scipy.stats import chi2

from quadslam_env.render import history as h
from quadslam_env.render.layout import FONT, SCAN, Board, box
from quadslam_env.render.scene import SIGMA_SCALE, Scene
from quadslam_env.types import POSE_DIM

AXIS_COLORS = ("tab:blue", "tab:orange", "tab:green")  # north, east, down
NEES_BOUNDS_95 = (float(chi2.ppf(0.025, POSE_DIM)), float(chi2.ppf(0.975, POSE_DIM)))
ERR = (392.0, 218.0, 238.0, 138.0)  # layout pixels: left, bottom, width, height
NEES = (392.0, 38.0, 238.0, 145.0)


class StripCharts:
    """The two strip charts, sharing a time axis of ``history_s`` seconds."""

    def __init__(self, board: Board, history_s: float) -> None:
        self.board = b = board
        self.history_s = history_s
        ax = self.err_ax = b.axes(box(*ERR), nbins=5, xticklabels=False)
        ax.set_title(f"position error ρ̂ − ρ and ±{SIGMA_SCALE:.0f}σ [m]", fontsize=FONT, pad=2)
        b.add(ax, ax.axhline(0.0, color="0.7", lw=0.5))
        self.err = []
        self.sig = []
        for name, color in zip(("north", "east", "down"), AXIS_COLORS, strict=True):
            self.sig.append(b.line(ax, "--", color=color, lw=0.7, alpha=0.8))
            self.err.append(b.line(ax, color=color, lw=1.0, label=name))
        ax.legend(
            loc="upper left", fontsize=FONT - 1, ncol=3, frameon=False, handlelength=1.2,
            columnspacing=0.8, borderaxespad=0.2,
        )  # fmt: skip
        ax = self.nees_ax = b.axes(
            box(*NEES),
            xlabel="time t [s]",
            nbins=5,
            ylocator=LogLocator(subs=(1.0, 2.0, 5.0), numticks=12),
        )
        lo, hi = NEES_BOUNDS_95
        ax.set_title(
            f"pose NEES, 95% χ²({POSE_DIM}) bounds {lo:.1f}–{hi:.1f} (log)", fontsize=FONT, pad=2
        )
        ax.set_yscale("log")
        for bound in (lo, hi):  # dynamic: the y limits follow the NEES
            b.add(ax, ax.axhline(bound, color=SCAN, ls="--", lw=0.8))
        b.add(ax, ax.axhline(POSE_DIM, color="0.6", ls=":", lw=0.8))
        self.nees = b.line(ax, color="black", lw=1.0)
        note = ax.text(
            0.5, 0.5, "", transform=ax.transAxes, ha="center", va="center", fontsize=FONT
        )
        self.note = b.add(ax, note)

    def update(self, s: Scene) -> None:
        """Show the rows of the last ``history_s`` of the scene ``s``."""
        rows = s.rows[s.rows[:, h.T] >= s.t - self.history_s]
        t0 = max(0.0, s.t - self.history_s)
        span = (t0, t0 + self.history_s)
        time = rows[:, h.T]
        err, sig = rows[:, h.ERR], SIGMA_SCALE * rows[:, h.SIGMA]
        gap = np.array([math.nan])
        for i in range(3):
            self.err[i].set_data(time, err[:, i])
            self.sig[i].set_data(
                np.concatenate([time, gap, time]), np.concatenate([sig[:, i], gap, -sig[:, i]])
            )
        top = float(np.nanmax(np.abs(np.concatenate([err.ravel(), sig.ravel(), [1e-3]]))))
        self.board.limits(self.err_ax, span, (-1.2 * top, 1.55 * top))  # room for the legend
        nees = rows[:, h.NEES]
        finite = nees[np.isfinite(nees) & (nees > 0)]
        self.nees.set_data(time, nees)
        lo, hi = NEES_BOUNDS_95
        if finite.size:
            ylim = (min(0.5 * lo, float(finite.min())), max(3.0 * hi, 2.0 * float(finite.max())))
            self.note.set_text("")
        else:
            ylim = (0.5 * lo, 3.0 * hi)
            self.note.set_text("no covariance: no NEES")
        self.board.limits(self.nees_ax, span, ylim)
