"""``rgb_array`` frames of one lane of the simulation core (``render_mode="rgb_array"``).

- :mod:`.history` (NumPy): ring buffers of truth, estimate, ±σ and NEES per step;
- :mod:`.scene` (NumPy): the data of one frame, ellipse and field-of-view geometry;
- :mod:`.figure` (matplotlib, imported on the first frame): the panels, built once;
- :mod:`.renderer`: :class:`LaneRenderer`, which ties them together and caps the drawing rate.

An env without ``render_mode`` never imports this package.
"""

from quadslam_env.render.renderer import LaneRenderer

__all__ = ["LaneRenderer"]
