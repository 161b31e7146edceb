"""Reward from the true state against the reference (docs/design.md §4), for B lanes at once.

``reward = alive - w_p ‖ρ - ρ_d‖ - w_v ‖ρ̇ - ρ̇_d‖ - w_ψ |wrap(ψ - ψ_d)|
- w_u ‖a - a_hover‖²/4 - penalty·[terminated] - w_σ √trace(P_ρ)``, the last term on the
estimator's own position covariance P_ρ (its confidence, not the truth: a reward for looking
where it learns); every term is reported in ``info`` as ``reward_<term>`` and they sum to
the reward.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.config.episode import RewardConfig
from quadslam_env.models.frames import dcm_from_trig, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.sim.trajectories import FlatOutputs
from quadslam_env.types import FloatArray

REWARD_KEYS = (
    "reward_alive",
    "reward_pos",
    "reward_vel",
    "reward_yaw",
    "reward_effort",
    "reward_termination",
    "reward_pos_std",
)


@kernel
def _squared_position_error(x: FloatArray, ref_pos: FloatArray) -> float:
    """‖ρ − ρ_d‖² (m²) of one lane's true state ``x`` (12,) and reference position (3,)."""
    dp = 0.0
    for r in range(3):
        dp += (x[r] - ref_pos[r]) ** 2
    return dp


@kernel
def tracking_errors(state: FloatArray, ref_pos: FloatArray, out: FloatArray) -> None:
    """``out`` (B,) = the true tracking error ‖ρ − ρ_d‖ in m of states (B, 12), refs (B, 3)."""
    for b in range(out.shape[0]):
        out[b] = math.sqrt(_squared_position_error(state[b], ref_pos[b]))


@kernel
def _reward_lanes(
    weights: FloatArray,
    state: FloatArray,
    ref_pos: FloatArray,
    ref_vel: FloatArray,
    ref_yaw: FloatArray,
    action: FloatArray,
    hover_action: FloatArray,
    terminated: np.ndarray,
    pos_std: FloatArray,
    out: FloatArray,
) -> None:
    """Fill the rows of ``out`` (8, B) with the terms of :data:`REWARD_KEYS` and their sum
    (see :class:`Reward`); the sum adds the terms in key order."""
    alive, w_pos, w_vel, w_yaw, w_effort, penalty, w_std = (
        weights[0], weights[1], weights[2], weights[3], weights[4], weights[5], weights[6]
    )  # fmt: skip
    for b in range(out.shape[1]):
        x = state[b]
        c = dcm_from_trig(
            math.cos(x[6]), math.sin(x[6]), math.cos(x[7]), math.sin(x[7]),
            math.cos(x[8]), math.sin(x[8]),
        )  # fmt: skip
        dp = _squared_position_error(x, ref_pos[b])
        dv = 0.0
        for r in range(3):
            v = c[3 * r] * x[3] + c[3 * r + 1] * x[4] + c[3 * r + 2] * x[5]  # C_NB v
            dv += (v - ref_vel[b, r]) ** 2
        effort = 0.0
        for i in range(4):
            effort += (action[b, i] - hover_action[i]) ** 2
        out[0, b] = alive
        out[1, b] = -w_pos * math.sqrt(dp)
        out[2, b] = -w_vel * math.sqrt(dv)
        out[3, b] = -w_yaw * abs(wrap_pi(x[8] - ref_yaw[b]))
        out[4, b] = -w_effort * effort / 4.0
        out[5, b] = -penalty if terminated[b] else 0.0
        out[6, b] = -w_std * pos_std[b] if w_std > 0.0 else 0.0
        total = out[0, b]
        for j in range(1, 7):
            total += out[j, b]
        out[7, b] = total


class Reward:
    """The reward of one scenario's ``reward`` weights for B lanes.

    Args:
        cfg: Weights.
        hover_action: (4,) normalised action that holds hover (effort is measured from it).
    """

    def __init__(self, cfg: RewardConfig, hover_action: FloatArray) -> None:
        self._weights = np.array(
            [cfg.alive, cfg.pos_weight, cfg.vel_weight, cfg.yaw_weight, cfg.effort_weight,
             cfg.termination_penalty, cfg.pos_std_weight]
        )  # fmt: skip
        self._hover = np.ascontiguousarray(hover_action, dtype=float)

    def terms(
        self,
        state: FloatArray,
        ref: FlatOutputs,
        action: FloatArray,
        terminated: np.ndarray,
        out: FloatArray | None = None,
        pos_std: FloatArray | None = None,
    ) -> FloatArray:
        """Signed reward terms of B lanes and the reward.

        Args:
            state: (B, 12) true states (ρ N m, v_B m/s, Λ rad, ω rad/s).
            ref: Reference of the lanes at the same time ((B, 3) and (B,) arrays).
            action: (B, 4) normalised action applied this step.
            terminated: (B,) bool, whether this step ends the lane's episode by failure.
            out: (8, B) C-contiguous array to write into (default: a new one).
            pos_std: (B,) the estimate's √trace(P_ρ) in m (default 0: no covariance).

        Returns:
            (8, B): the terms of :data:`REWARD_KEYS` in order, one row each, then the reward
            (their sum).
        """
        if out is None:
            out = np.empty((len(REWARD_KEYS) + 1, state.shape[0]))
        yaw = np.asarray(ref.yaw, dtype=float)  # (B,) already; asarray only narrows the type
        std = np.zeros(state.shape[0]) if pos_std is None else pos_std
        _reward_lanes(self._weights, state, ref.pos, ref.vel, yaw, action, self._hover,
                      terminated, std, out)  # fmt: skip
        return out
