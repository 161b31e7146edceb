"""Reference trajectories given analytically as flat outputs (seed 001 §2.2.1, eq. 4–5).

Each trajectory returns, at any time t, ``ρ_d, ρ̇_d, ρ̈_d`` (NED, m, m/s, m/s²) and
``ψ_d, ψ̇_d`` (rad, rad/s). With ``yaw_mode="tangent"`` the heading follows the horizontal
velocity, ``ψ_d = atan2(ẏ, ẋ)`` and ``ψ̇_d = (ẋÿ - ẏẍ)/(ẋ² + ẏ²)``.

The formulas live once, in a numba kernel over a batch of times (one per lane of the
simulation core); the scalar call is the one-lane case. :class:`LaneTrajectory` is one
trajectory flown by lanes shifted in time and position (a team's vehicles).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from quadslam_env.config.world import TrajectoryConfig
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

KINDS = ("figure8", "circle", "helix", "hover")


@dataclass(frozen=True)
class FlatOutputs:
    """Reference of B lanes (or one instant: shapes without the leading B).

    Attributes:
        pos: (B, 3) ρ_d in N, m.
        vel: (B, 3) ρ̇_d in N, m/s.
        acc: (B, 3) ρ̈_d in N, m/s².
        yaw: (B,) ψ_d in rad.
        yaw_rate: (B,) ψ̇_d in rad/s.
    """

    pos: FloatArray
    vel: FloatArray
    acc: FloatArray
    yaw: FloatArray | float
    yaw_rate: FloatArray | float


@kernel
def _flat_outputs(
    t: FloatArray,
    kind: int,
    center: FloatArray,
    amp_x: float,
    amp_y: float,
    radius: float,
    omega: float,
    climb: float,
    tangent: bool,
    fixed_yaw: float,
    pos: FloatArray,
    vel: FloatArray,
    acc: FloatArray,
    yaw: FloatArray,
    yaw_rate: FloatArray,
) -> None:
    """Fill the (B, 3) and (B,) outputs at the times ``t`` (B,) s (see :class:`Trajectory`)."""
    w = omega
    for i in range(t.shape[0]):
        ti = t[i]
        px = py = pz = vx = vy = vz = ax = ay = 0.0
        if kind == 0:  # figure8
            s1, c1 = math.sin(w * ti), math.cos(w * ti)
            s2, c2 = math.sin(2 * w * ti), math.cos(2 * w * ti)
            px, py = amp_x * s1, amp_y * s2
            vx, vy = amp_x * w * c1, 2 * amp_y * w * c2
            ax, ay = -amp_x * w * w * s1, -4 * amp_y * w * w * s2
        elif kind == 1 or kind == 2:  # circle, helix
            s, c = math.sin(w * ti), math.cos(w * ti)
            rate = climb if kind == 2 else 0.0
            px, py, pz = radius * c, radius * s, -rate * ti
            vx, vy, vz = -radius * w * s, radius * w * c, -rate
            ax, ay = -radius * w * w * c, -radius * w * w * s
        pos[i, 0] = center[0] + px
        pos[i, 1] = center[1] + py
        pos[i, 2] = center[2] + pz
        vel[i, 0], vel[i, 1], vel[i, 2] = vx, vy, vz
        acc[i, 0], acc[i, 1], acc[i, 2] = ax, ay, 0.0
        speed2 = vx * vx + vy * vy
        if tangent and speed2 > 1e-12:
            yaw[i] = math.atan2(vy, vx)
            yaw_rate[i] = (vx * ay - vy * ax) / speed2
        else:
            yaw[i] = fixed_yaw
            yaw_rate[i] = 0.0


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
        self._kind = KINDS.index(cfg.kind)
        self._tangent = cfg.yaw_mode == "tangent"
        self._fixed_yaw = math.radians(cfg.yaw_deg)

    def batch(self, t: FloatArray, lanes: Sequence[int] | np.ndarray | None = None) -> FlatOutputs:
        """Flat outputs at the times ``t`` (B,) in s, as (B, 3) and (B,) arrays.

        ``lanes`` names the lanes the times belong to; every lane flies this reference, so it
        is not read here (:class:`LaneTrajectory` shifts each lane's).
        """
        t = np.ascontiguousarray(t, dtype=float)
        b = t.shape[0]
        out = FlatOutputs(
            pos=np.empty((b, 3)),
            vel=np.empty((b, 3)),
            acc=np.empty((b, 3)),
            yaw=np.empty(b),
            yaw_rate=np.empty(b),
        )
        cfg = self.cfg
        _flat_outputs(
            t,
            self._kind,
            self.center,
            cfg.amplitude_x_m,
            cfg.amplitude_y_m,
            cfg.radius_m,
            self.omega,
            cfg.climb_rate_mps,
            self._tangent,
            self._fixed_yaw,
            out.pos,
            out.vel,
            out.acc,
            out.yaw,  # type: ignore[arg-type]
            out.yaw_rate,  # type: ignore[arg-type]
        )
        return out

    def __call__(self, t: float) -> FlatOutputs:
        """Flat outputs at time ``t`` (s) of lane 0 (every lane's here): pos/vel/acc (3,), yaw
        and yaw rate floats."""
        ref = self.batch(np.array([float(t)]), [0])
        return FlatOutputs(
            pos=ref.pos[0],
            vel=ref.vel[0],
            acc=ref.acc[0],
            yaw=float(ref.yaw[0]),  # type: ignore[index]
            yaw_rate=float(ref.yaw_rate[0]),  # type: ignore[index]
        )


class LaneTrajectory(Trajectory):
    """The trajectory of ``cfg`` flown by B lanes, each shifted in time and position: lane i's
    reference is ``ρ_d,i(t) = ρ_d(t + τ_i) + p_i``, with the velocity, acceleration and
    heading of ``t + τ_i`` (a team's vehicles on phase-shifted copies of one path).

    :meth:`batch` takes the times of all B lanes in lane order, or of ``lanes``; the one-instant
    call is lane 0's reference (the scenario's own when ``τ_0 = 0`` and ``p_0 = 0``).

    Args:
        cfg: Trajectory settings.
        time_offsets_s: (B,) τ_i in s.
        pos_offsets_m: (B, 3) p_i in N, m.

    Raises:
        ValueError: The offsets do not have the shapes (B,) and (B, 3).
    """

    def __init__(
        self, cfg: TrajectoryConfig, time_offsets_s: FloatArray, pos_offsets_m: FloatArray
    ) -> None:
        super().__init__(cfg)
        self.time_offsets_s = np.array(time_offsets_s, dtype=float)
        self.pos_offsets_m = np.array(pos_offsets_m, dtype=float)
        b = self.time_offsets_s.size
        if self.time_offsets_s.shape != (b,) or self.pos_offsets_m.shape != (b, 3):
            raise ValueError(
                f"LaneTrajectory: got offsets of shapes {self.time_offsets_s.shape} and "
                f"{self.pos_offsets_m.shape}; allowed: (B,) and (B, 3)"
            )

    def batch(self, t: FloatArray, lanes: Sequence[int] | np.ndarray | None = None) -> FlatOutputs:
        """Flat outputs of the lanes (all B, or ``lanes`` (k,)) at their times ``t`` (B,) or
        (k,) in s, as (B or k, 3) and (B or k,) arrays."""
        idx = slice(None) if lanes is None else np.asarray(lanes)
        shift = self.time_offsets_s[idx]
        t = np.asarray(t, dtype=float)
        if t.shape != shift.shape:
            raise ValueError(f"LaneTrajectory.batch: got {t.shape} times for {shift.shape} lanes")
        ref = super().batch(t + shift)
        ref.pos[:] += self.pos_offsets_m[idx]
        return ref
