"""Why an episode ends (docs/design.md §4), for B lanes in one kernel.

``truncated`` when a lane that did not terminate reaches the episode's step limit.

``terminated`` on a non-finite true state, tilt beyond ``max_tilt_deg``, tracking error beyond
``max_pos_err_m``, ground contact (``ground_z_m``), or estimator divergence: the estimator's
health check (:func:`~quadslam_env.estimation.health.health_codes`: non-finite values, a pose
covariance that is asymmetric, has a negative variance or a correlation beyond ±1, or a trace above
``max_cov_trace``), a pose covariance that is not positive semi-definite (infinite NEES), or
pose NEES above ``nees_threshold`` for ``nees_window_s``.
The first failed check, in that order, names the reason.

The last line of defence (:class:`OutputGuard`), after the reward and the observation: an
active lane whose observation or reward is not finite, or whose step terms hold ±inf (NaN
there means "does not apply"), ends with ``non_finite_output: <which>`` unless a check above
ended it already; its non-finite observation entries are returned as 0 (as the observation's
own rule for a non-finite estimate) and its reward as the termination penalty alone.
"""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np

from quadslam_env.config.episode import EpisodeConfig
from quadslam_env.episode.reward import REWARD_KEYS
from quadslam_env.estimation.health import HEALTH_PROBLEMS
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


NON_FINITE = "non_finite_output: {which}"
"""The reason of a lane ended by :class:`OutputGuard`; ``which`` is ``observation``,
``reward`` or the ``info`` key of the first step term that is ±inf."""


@kernel
def _guard_lanes(
    obs: np.ndarray,
    values: FloatArray,
    rows: np.ndarray,
    penalty: float,
    active: np.ndarray,
    terminated: np.ndarray,
    truncated: np.ndarray,
    out: np.ndarray,
) -> int:
    """Fill ``out`` (B,) with what is not finite in each active lane (0: all finite, 1: the
    observation (B, n), 2: the reward, 3 + k: row k of ``values`` (K, B) is ±inf) and make the
    lane's outputs finite; ``rows`` = (first reward term, termination term, reward) rows of
    ``values``. A lane with such an output, or already terminated with a non-finite reward,
    gets the reward −``penalty`` (that term alone, the other terms 0) and non-finite
    observation entries 0; a lane that went on is terminated (not truncated). Returns the
    number of lanes that went on and end here."""
    first, term, reward = rows[0], rows[1], rows[2]
    ended = 0
    for b in range(out.shape[0]):
        out[b] = 0
        if not active[b]:
            continue
        code = 0
        for j in range(obs.shape[1]):
            if not math.isfinite(obs[b, j]):
                obs[b, j] = 0.0
                code = 1
        finite_reward = math.isfinite(values[reward, b])
        if code == 0 and not finite_reward:
            code = 2
        k = 0
        while code == 0 and k < values.shape[0]:
            if math.isinf(values[k, b]):
                code = 3 + k
            k += 1
        if code == 0 or (terminated[b] and finite_reward):
            continue  # finite, or ended already with a finite reward: left as it is
        for k in range(first, reward):
            values[k, b] = 0.0
        values[term, b] = -penalty
        values[reward, b] = -penalty
        if terminated[b]:
            continue  # an earlier check ended it: its reason stands
        out[b] = code
        terminated[b] = True
        truncated[b] = False
        ended += 1
    return ended


class OutputGuard:
    """The last line of defence (module docstring): no active lane returns a non-finite
    observation or reward, and one whose outputs are not finite ends.

    Args:
        rows: The row of each term's ``info`` key in the step's terms (K, B), in row order:
            the reward terms (:data:`~quadslam_env.episode.reward.REWARD_KEYS`) in a block, then
            ``reward``.
        penalty: ``reward.termination_penalty``.
    """

    def __init__(self, rows: Mapping[str, int], penalty: float) -> None:
        self._names = ("", "observation", "reward", *rows)
        reward_rows = (REWARD_KEYS[0], "reward_termination", "reward")
        self._rows = np.array([rows[key] for key in reward_rows], dtype=np.int64)
        self._penalty = float(penalty)

    def check(
        self,
        obs: np.ndarray,
        values: FloatArray,
        active: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        reasons: list[str],
    ) -> bool:
        """Make the step's outputs finite in place and end the lanes whose were not.

        Args:
            obs: (B, n) observations. values: (K, B) the step's terms, the reward's included.
            active: (B,) bool, lanes stepped now. terminated, truncated: (B,) bool, updated.
            reasons: B termination reasons, updated.

        Returns:
            Whether a lane that went on ends here.
        """
        codes = np.empty(obs.shape[0], dtype=np.int64)
        ended = _guard_lanes(
            obs, values, self._rows, self._penalty, active, terminated, truncated, codes
        )
        if ended:
            for lane in np.flatnonzero(codes).tolist():
                reasons[lane] = NON_FINITE.format(which=self._names[codes[lane]])
        return ended > 0
