"""Why an episode ends (docs/design.md §4), for B lanes in one kernel.

``truncated`` when a lane that did not terminate reaches the episode's step limit.

``terminated`` on a non-finite true state, tilt beyond ``max_tilt_deg``, tracking error beyond
``max_pos_err_m``, ground contact (``ground_z_m``), or estimator divergence: the estimator's
health check (:func:`~quadslam_env.estimation.health.health_codes`: non-finite values, a pose
covariance that is asymmetric, has a negative variance or a correlation beyond ±1, or a trace above
``max_cov_trace``), a pose covariance that is not positive semi-definite (infinite NEES), or
pose NEES above ``nees_threshold`` for ``nees_window_s``.
The first failed check, in that order, names the reason.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.config_episode import EpisodeConfig
from quadslam_env.estimation import HEALTH_PROBLEMS
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

REASONS = (
    "",
    "vehicle_state_non_finite",
    "tilt_limit",
    "position_error_limit",
    "ground_contact",
    "estimator_diverged: {health}",
    "estimator_diverged: pose covariance not positive semi-definite",
    "estimator_diverged: NEES above threshold",
)
"""Reason texts by code (0: the episode goes on; 5 is completed by the health problem)."""


@kernel
def _codes(
    state: FloatArray,
    track_err: FloatArray,
    nees: FloatArray,
    health: np.ndarray,
    active: np.ndarray,
    limits: FloatArray,
    nees_run: np.ndarray,
    window: int,
    steps: np.ndarray,
    max_steps: int,
    out: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
) -> int:
    """Fill ``out`` (B,) with reason codes, ``terminated`` (B,) with ``out != 0`` and
    ``truncated`` (B,) with the active lanes that go on but reached ``max_steps``; ``limits``
    = (max tilt rad, max position error m, ground z m or NaN, NEES threshold or NaN). Updates
    the NEES run counters of active lanes. Returns the number of lanes that ended."""
    max_tilt, max_err, ground_z, nees_limit = limits[0], limits[1], limits[2], limits[3]
    ended = 0
    for b in range(out.shape[0]):
        out[b] = 0
        terminated[b] = truncated[b] = False
        if not active[b]:
            continue
        over = nees_limit == nees_limit and nees[b] > nees_limit  # NaN limit: no check
        nees_run[b] = nees_run[b] + 1 if over else 0
        finite = True
        for i in range(state.shape[1]):
            finite = finite and math.isfinite(state[b, i])
        tilt = math.acos(min(1.0, max(-1.0, math.cos(state[b, 6]) * math.cos(state[b, 7]))))
        if not finite:
            out[b] = 1
        elif tilt > max_tilt:
            out[b] = 2
        elif track_err[b] > max_err:
            out[b] = 3
        elif ground_z == ground_z and state[b, 2] > ground_z:
            out[b] = 4
        elif health[b] != 0:
            out[b] = 5
        elif nees[b] == math.inf:
            out[b] = 6
        elif nees_run[b] >= window:
            out[b] = 7
        terminated[b] = out[b] != 0
        truncated[b] = out[b] == 0 and steps[b] >= max_steps
        if terminated[b] or truncated[b]:
            ended += 1
    return ended


class Termination:
    """Termination checks of one scenario's ``episode`` settings for B lanes.

    Args:
        cfg: Episode settings (limits, ground, NEES threshold and window).
        dt: Control period in s (the NEES window counts steps).
        num_lanes: B.
        max_steps: Steps after which a lane that goes on is truncated.
    """

    def __init__(self, cfg: EpisodeConfig, dt: float, num_lanes: int, max_steps: int) -> None:
        nan = math.nan
        self._max_steps = int(max_steps)
        self._limits = np.array(
            [
                math.radians(cfg.max_tilt_deg),
                cfg.max_pos_err_m,
                nan if cfg.ground_z_m is None else cfg.ground_z_m,
                nan if cfg.nees_threshold is None else cfg.nees_threshold,
            ]
        )
        self._window = max(1, round(cfg.nees_window_s / dt))
        self._nees_run = np.zeros(num_lanes, dtype=np.int64)

    def reset(self, lanes: np.ndarray) -> None:
        """Restart the NEES run counters of ``lanes``."""
        self._nees_run[lanes] = 0

    def check(
        self,
        state: FloatArray,
        track_err: FloatArray,
        nees: FloatArray,
        health: np.ndarray,
        active: np.ndarray,
        steps: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray, list[str], bool]:
        """Which active lanes end now, and why.

        Args:
            state: (B, 12) true states.
            track_err: (B,) true tracking error in m.
            nees: (B,) pose NEES (NaN without a covariance, inf when not PSD).
            health: (B,) :func:`quadslam_env.estimation.health.health_codes` of the estimate.
            active: (B,) bool, lanes stepped now (the others never end).
            steps: (B,) steps since each lane's reset.

        Returns:
            ``(terminated (B,) bool, truncated (B,) bool, reasons, any_ended)``: reasons are B
            strings, empty where the lane did not fail.
        """
        b = state.shape[0]
        codes = np.empty(b, dtype=np.int64)
        terminated, truncated = np.empty(b, dtype=bool), np.empty(b, dtype=bool)
        ended = _codes(
            state, track_err, nees, health, active, self._limits, self._nees_run,
            self._window, steps, self._max_steps, codes, terminated, truncated,
        )  # fmt: skip
        reasons = [""] * b
        if ended:
            for lane in np.flatnonzero(codes).tolist():  # only the (rare) failing lanes
                reasons[lane] = REASONS[codes[lane]].format(health=HEALTH_PROBLEMS[health[lane]])
        return terminated, truncated, reasons, ended > 0
