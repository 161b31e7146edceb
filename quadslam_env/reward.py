"""Reward from the true state against the reference (DESIGN.md §4), for B lanes at once.

``reward = alive - w_p ‖ρ - ρ_d‖ - w_v ‖ρ̇ - ρ̇_d‖ - w_ψ |wrap(ψ - ψ_d)| - w_u ‖a - a_hover‖²/4
- penalty·[terminated]``; every term is reported in ``info`` as ``reward_<term>`` and they sum to
the reward.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.config import RewardConfig
from quadslam_env.models.frames import dcm_from_trig, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.trajectories import FlatOutputs
from quadslam_env.types import FloatArray

REWARD_KEYS = (
    "reward_alive",
    "reward_pos",
    "reward_vel",
    "reward_yaw",
    "reward_effort",
    "reward_termination",
)


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
    out: FloatArray,
) -> None:
    """Fill ``out`` (B, 6) with the terms of :data:`REWARD_KEYS` (see :func:`reward_terms`)."""
    alive, w_pos, w_vel, w_yaw, w_effort, penalty = (
        weights[0], weights[1], weights[2], weights[3], weights[4], weights[5]
    )  # fmt: skip
    for b in range(out.shape[0]):
        x = state[b]
        c = dcm_from_trig(
            math.cos(x[6]), math.sin(x[6]), math.cos(x[7]), math.sin(x[7]),
            math.cos(x[8]), math.sin(x[8]),
        )  # fmt: skip
        dp = dv = 0.0
        for r in range(3):
            dp += (x[r] - ref_pos[b, r]) ** 2
            v = c[3 * r] * x[3] + c[3 * r + 1] * x[4] + c[3 * r + 2] * x[5]  # C_NB v
            dv += (v - ref_vel[b, r]) ** 2
        effort = 0.0
        for i in range(4):
            effort += (action[b, i] - hover_action[i]) ** 2
        out[b, 0] = alive
        out[b, 1] = -w_pos * math.sqrt(dp)
        out[b, 2] = -w_vel * math.sqrt(dv)
        out[b, 3] = -w_yaw * abs(wrap_pi(x[8] - ref_yaw[b]))
        out[b, 4] = -w_effort * effort / 4.0
        out[b, 5] = -penalty if terminated[b] else 0.0


def reward_terms(
    cfg: RewardConfig,
    state: FloatArray,
    ref: FlatOutputs,
    action: FloatArray,
    hover_action: FloatArray,
    terminated: np.ndarray,
) -> dict[str, FloatArray]:
    """Signed reward terms of B lanes, keyed ``reward_<term>``, each (B,).

    Args:
        cfg: Weights.
        state: (B, 12) true states (ρ N m, v_B m/s, Λ rad, ω rad/s).
        ref: Reference of the lanes at the same time ((B, 3) and (B,) arrays).
        action: (B, 4) normalised action applied this step.
        hover_action: (4,) normalised action that holds hover (effort is measured from it).
        terminated: (B,) bool, whether this step ends the lane's episode by failure.
    """
    weights = np.array(
        [cfg.alive, cfg.pos_weight, cfg.vel_weight, cfg.yaw_weight, cfg.effort_weight,
         cfg.termination_penalty]
    )  # fmt: skip
    out = np.empty((state.shape[0], len(REWARD_KEYS)))
    yaw = np.asarray(ref.yaw, dtype=float)  # (B,) already; asarray only narrows the type
    _reward_lanes(weights, state, ref.pos, ref.vel, yaw, action, hover_action, terminated,
                  out)  # fmt: skip
    return {key: out[:, j] for j, key in enumerate(REWARD_KEYS)}
