"""Reference trajectories given analytically as flat outputs (seed 001 §2.2.1, eq. 4–5).

Each trajectory returns, at any time t, ``ρ_d, ρ̇_d, ρ̈_d`` (NED, m, m/s, m/s²) and
``ψ_d, ψ̇_d`` (rad, rad/s). With ``yaw_mode="tangent"`` the heading follows the horizontal
velocity, ``ψ_d = atan2(ẏ, ẋ)`` and ``ψ̇_d = (ẋÿ - ẏẍ)/(ẋ² + ẏ²)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from quadslam_env.config import TrajectoryConfig
from quadslam_env.models.rotations import FloatArray


@dataclass(frozen=True)
class FlatOutputs:
    """Reference at one instant: position/velocity/acceleration in N and heading."""

    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    yaw: float
    yaw_rate: float


class Trajectory:
    """Analytic reference built from :class:`TrajectoryConfig`.

    Shapes (with centre c, ω = 2π / period):
        ``figure8``: x = cx + A sin ωt, y = cy + B sin 2ωt, z = cz.
        ``circle``:  x = cx + R cos ωt, y = cy + R sin ωt, z = cz (starts at (cx + R, cy)).
        ``helix``:   the circle with z = cz - climb_rate · t (climbing in NED).
        ``hover``:   constant c.
    """

    def __init__(self, cfg: TrajectoryConfig) -> None:
        self.cfg = cfg
        self.center = np.array(cfg.center, dtype=float)
        self.omega = 2.0 * math.pi / cfg.period_s
        self._fixed_yaw = math.radians(cfg.yaw_deg)

    def _translation(self, t: float) -> tuple[list[float], list[float], list[float]]:
        cfg, w = self.cfg, self.omega
        if cfg.kind == "figure8":
            a, b = cfg.amplitude_x_m, cfg.amplitude_y_m
            s1, c1 = math.sin(w * t), math.cos(w * t)
            s2, c2 = math.sin(2 * w * t), math.cos(2 * w * t)
            return (
                [a * s1, b * s2, 0.0],
                [a * w * c1, 2 * b * w * c2, 0.0],
                [-a * w * w * s1, -4 * b * w * w * s2, 0.0],
            )
        if cfg.kind in ("circle", "helix"):
            r = cfg.radius_m
            s, c = math.sin(w * t), math.cos(w * t)
            climb = cfg.climb_rate_mps if cfg.kind == "helix" else 0.0
            return (
                [r * c, r * s, -climb * t],
                [-r * w * s, r * w * c, -climb],
                [-r * w * w * c, -r * w * w * s, 0.0],
            )
        return [0.0] * 3, [0.0] * 3, [0.0] * 3

    def __call__(self, t: float) -> FlatOutputs:
        """Flat outputs at time ``t`` (s)."""
        p, v, a = self._translation(t)
        speed2 = v[0] * v[0] + v[1] * v[1]
        if self.cfg.yaw_mode == "tangent" and speed2 > 1e-12:
            yaw = math.atan2(v[1], v[0])
            yaw_rate = (v[0] * a[1] - v[1] * a[0]) / speed2
        else:
            yaw, yaw_rate = self._fixed_yaw, 0.0
        return FlatOutputs(
            pos=self.center + np.array(p),
            vel=np.array(v),
            acc=np.array(a),
            yaw=yaw,
            yaw_rate=yaw_rate,
        )
