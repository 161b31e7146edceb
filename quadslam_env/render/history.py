"""What the frames need from past steps of one lane, kept in fixed-size ring buffers.

Only an env with ``render_mode`` set makes a :class:`LaneHistory` (NumPy only: matplotlib is
not imported until a frame is drawn), so an env without rendering records nothing per step.
The history reads the simulation core's arrays after each step; it is a consumer of truth and
estimate alike and hands nothing back to the estimator.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.models.lidar import lidar_inverse
from quadslam_env.types import EUL, POS, FloatArray

# Columns of a history row.
T = 0
TRUE = slice(1, 4)  # true position ρ, NED m
EST = slice(4, 7)  # estimated position ρ̂, NED m
ERR = slice(7, 10)  # ρ̂ − ρ, NED m
SIGMA = slice(10, 13)  # √diag of the position covariance, NED m
NEES = 13  # 9-DOF pose NEES
WIDTH = 14

# Scalars of the latest step shown in the text line (info keys of the core).
LATEST_KEYS = ("est_nees_pose", "est_n_visible", "est_n_mapped", "est_ess", "est_pos_err_m")


class LaneHistory:
    """Ring buffers of one lane's truth, estimate and consistency terms, one row per step.

    Args:
        capacity: Rows kept (the longest time span a frame shows times the control rate).

    Attributes:
        episode: Episodes seen (incremented at each reset), so a cached frame of an earlier
            episode is never shown again.
        latest: The :data:`LATEST_KEYS` of the last recorded step (NaN where absent).
        scan_t: Time of the last scan in s (NaN before the first).
        scan_points: (k, 3) NED positions, m, of the last scan's returns (the measurements
            mapped through the inverse LiDAR model at the true pose of that scan).
        scan_ids: (k,) landmark ids of those returns.
    """

    def __init__(self, capacity: int) -> None:
        self.capacity = max(2, int(capacity))
        self._rows = np.full((self.capacity, WIDTH), math.nan)
        self._head = 0  # next row to write
        self._count = 0
        self.episode = 0
        self.latest = dict.fromkeys(LATEST_KEYS, math.nan)
        self._clear_scan()

    def _clear_scan(self) -> None:
        self.scan_t = math.nan
        self.scan_points = np.zeros((0, 3))
        self.scan_ids = np.zeros(0, dtype=np.int64)

    def __len__(self) -> int:
        return self._count

    def record(self, core: Any, lane: int, info: dict[str, Any] | None = None) -> None:
        """Append lane ``lane``'s current step of ``core`` (a :class:`SimCore`).

        A lane at step 0 starts a new episode (the buffers are cleared first); a call that
        finds the lane at the time of the last row (it was not stepped) records nothing.

        Args:
            core: The simulation core after a reset or step.
            lane: Lane index.
            info: The core's info of that reset or step ((B,) arrays), or ``None``.
        """
        t = float(core.t[lane])
        if int(core.steps[lane]) == 0:
            self._head = self._count = 0
            self.episode += 1
            self._clear_scan()
        elif self._count and t == self._rows[(self._head - 1) % self.capacity, T]:
            return
        state = core.vehicle.state[lane]
        est = core.est
        row = self._rows[self._head]
        row[T] = t
        row[TRUE] = state[POS]
        row[EST] = est.position[lane]
        row[ERR] = row[EST] - row[TRUE]
        if est.pose_cov is None:
            row[SIGMA] = math.nan
        else:
            row[SIGMA] = np.sqrt(np.clip(np.diagonal(est.pose_cov[lane])[POS], 0.0, None))
        for key in LATEST_KEYS:  # (B,) arrays of the core, or one lane's floats
            value = info.get(key) if info is not None else None
            if value is not None and np.ndim(value):
                value = value[lane]
            self.latest[key] = math.nan if value is None else float(value)
        row[NEES] = self.latest["est_nees_pose"]
        self._head = (self._head + 1) % self.capacity
        self._count = min(self._count + 1, self.capacity)
        scan = core.last_scan
        if scan is not None and lane in scan.lanes:
            ids = np.flatnonzero(scan.returned[lane])
            self.scan_t = t
            self.scan_ids = ids
            dcm = dcm_from_euler(state[EUL])
            self.scan_points = lidar_inverse(state[POS], dcm, scan.meas[lane, ids])

    def rows(self, since: float = -math.inf) -> FloatArray:
        """(n, :data:`WIDTH`) rows with time ≥ ``since``, oldest first (a copy)."""
        n = self._count
        idx = (self._head - n + np.arange(n)) % self.capacity
        out = self._rows[idx]
        return out[out[:, T] >= since]
