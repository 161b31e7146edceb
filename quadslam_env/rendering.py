"""``rgb_array`` frames with matplotlib (lazy import, Agg backend: no display needed)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.types import FloatArray


def render_frame(
    true_path: FloatArray,
    est_path: FloatArray,
    ref_path: FloatArray,
    landmarks: FloatArray,
    est_landmarks: FloatArray,
    pose: FloatArray,
    az_fov_deg: float,
    range_m: float,
    size_px: int = 480,
) -> np.ndarray:
    """Draw a 3D view (NED shown with altitude up) and return an (H, W, 3) uint8 image.

    Args:
        true_path: (n, 3) true positions, NED m.
        est_path: (n, 3) estimated positions.
        ref_path: (n, 3) reference positions.
        landmarks: (L, 3) true landmarks.
        est_landmarks: (M, 3) estimated landmarks.
        pose: (12,) true state (for the LiDAR FOV wedge).
        az_fov_deg: LiDAR azimuth half-width in degrees.
        range_m: Length of the FOV wedge lines in m.
        size_px: Image side in pixels.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(size_px / 100, size_px / 100), dpi=100)
    canvas = FigureCanvasAgg(fig)
    ax: Any = fig.add_subplot(projection="3d")

    def up(p: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        return p[:, 0], p[:, 1], -p[:, 2]

    ax.plot(*up(ref_path), "k--", lw=0.8, label="reference")
    ax.plot(*up(true_path), "b-", lw=1.2, label="true")
    ax.plot(*up(est_path), "r-", lw=1.0, label="estimate")
    ax.scatter(*up(landmarks), c="g", marker="^", s=12, label="landmarks")
    if est_landmarks.size:
        ax.scatter(*up(est_landmarks), c="m", marker="x", s=12, label="mapped")
    dcm = dcm_from_euler(pose[6:9])
    for az in (-az_fov_deg, az_fov_deg):
        a = math.radians(az)
        tip = pose[0:3] + dcm @ (range_m * np.array([math.cos(a), math.sin(a), 0.0]))
        ax.plot(*up(np.stack([pose[0:3], tip])), "c-", lw=0.8)
    ax.set_xlabel("north [m]")
    ax.set_ylabel("east [m]")
    ax.set_zlabel("altitude [m]")
    ax.legend(loc="upper left", fontsize=6)
    canvas.draw()
    img = np.asarray(canvas.buffer_rgba())[..., :3].copy()
    return img


def render_lane(
    core: Any, lane: int, paths: dict[str, list[FloatArray]] | None = None
) -> np.ndarray:
    """Frame of one lane of a :class:`~quadslam_env.core.SimCore`.

    Args:
        core: The simulation core.
        lane: Lane index.
        paths: Recorded ``true``/``est``/``ref`` positions (lists of (3,)); ``None`` draws the
            current positions only.
    """
    est, n = core.est, int(core.n_landmarks[lane])
    now = {
        "true": core.vehicle.state[lane, 0:3],
        "est": est.position[lane],
        "ref": core.reference([lane]).pos[0],
    }
    path = {key: np.array(paths[key] if paths else [now[key]]).reshape(-1, 3) for key in now}
    return render_frame(
        path["true"],
        path["est"],
        path["ref"],
        core.landmarks[lane, :n],
        est.landmark_means[lane, est.landmark_mapped[lane]],
        core.vehicle.state[lane],
        core.scenario.lidar.azimuth_fov_deg,
        min(5.0, core.scenario.lidar.range_max_m),
    )
