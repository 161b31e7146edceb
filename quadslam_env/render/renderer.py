"""``LaneRenderer``: the history and the frames of one lane of a simulation core."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from quadslam_env.estimation.protocol import ShowsParticles
from quadslam_env.extras import require
from quadslam_env.render.history import LaneHistory

if TYPE_CHECKING:  # matplotlib is imported on the first frame only
    from quadslam_env.render.figure import FrameFigure


class LaneRenderer:
    """Records lane ``lane`` of ``core`` after every reset and step, and draws its frames.

    Frames are drawn at most ``render.fps`` times per simulated second: :meth:`frame` called
    sooner than ``1/fps`` after the last drawn frame (same episode) returns that frame again
    (the same read-only array), so a recorder that asks for a frame every control step, as
    ``gymnasium.wrappers.RecordVideo`` does, pays for ``fps`` drawings per simulated second.

    Args:
        core: The :class:`~quadslam_env.core.SimCore`.
        lane: The lane drawn.
    """

    def __init__(self, core: Any, lane: int = 0) -> None:
        # The figure imports matplotlib on the first frame; a missing one is said at make().
        require("matplotlib", "plots", "render_mode='rgb_array'")
        self.core = core
        self.lane = int(lane)
        self.cfg = core.scenario.render
        self.span_s = max(self.cfg.trail_s, self.cfg.history_s)
        self.history = LaneHistory(math.ceil(self.span_s / core.dt) + 2)
        self._figure: FrameFigure | None = None
        self._frame: np.ndarray | None = None
        self._frame_key = (-1, -math.inf)  # (episode, t) of the cached frame

    def record(self, info: dict[str, Any] | None = None) -> None:
        """Append the lane's current state; call after every reset and step of the core.

        Args:
            info: The core's info of that reset or step ((B,) arrays), for NEES and counts.
        """
        self.history.record(self.core, self.lane, info)

    def frame(self) -> np.ndarray:
        """The lane's frame now: (height_px, width_px, 3) uint8, read-only."""
        t = float(self.core.t[self.lane])
        episode, last_t = self._frame_key
        fps = self.cfg.fps
        if (
            self._frame is not None
            and fps is not None
            and episode == self.history.episode
            and 0.0 <= t - last_t < 1.0 / fps - 0.5 * self.core.dt
        ):
            return self._frame
        frame = self.draw()
        frame.flags.writeable = False
        self._frame, self._frame_key = frame, (self.history.episode, t)
        return frame

    def draw(self) -> np.ndarray:
        """Draw a new frame now, whatever the frame rate: (height_px, width_px, 3) uint8."""
        from quadslam_env.render.scene import gather

        scene = gather(self.core, self.lane, self.history, self.span_s, self.cfg.max_particles)
        return self.figure.draw(scene)

    @property
    def figure(self) -> FrameFigure:
        """The matplotlib figure (built, and matplotlib imported, on first use)."""
        if self._figure is None:
            from quadslam_env.render.figure import FrameFigure

            core, cfg = self.core, self.cfg
            self._figure = FrameFigure(
                cfg.width_px,
                cfg.height_px,
                cfg.view_radius_m,
                cfg.history_s,
                core.scenario.lidar.azimuth_fov_deg,
                core.scenario.lidar.range_max_m,
                isinstance(core.estimator, ShowsParticles),
            )
        return self._figure
