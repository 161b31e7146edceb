"""Reward from the true state against the reference (DESIGN.md §4).

``reward = alive - w_p ‖ρ - ρ_d‖ - w_v ‖ρ̇ - ρ̇_d‖ - w_ψ |wrap(ψ - ψ_d)| - w_u ‖a - a_hover‖²/4
- penalty·[terminated]``; every term is reported in ``info`` as ``reward_<term>`` and they sum to
the reward.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.config import RewardConfig
from quadslam_env.models.rotations import FloatArray, wrap_angle
from quadslam_env.trajectories import FlatOutputs


def reward_terms(
    cfg: RewardConfig,
    true_pos: FloatArray,
    true_vel_inertial: FloatArray,
    true_yaw: float,
    ref: FlatOutputs,
    action: FloatArray,
    hover_action: FloatArray,
    terminated: bool,
) -> dict[str, float]:
    """Signed reward terms, keyed ``reward_<term>``.

    Args:
        cfg: Weights.
        true_pos: (3,) true position in N, m.
        true_vel_inertial: (3,) true velocity in N, m/s.
        true_yaw: True ψ in rad.
        ref: Reference at the same time.
        action: (4,) normalised action applied this step.
        hover_action: (4,) normalised action that holds hover (effort is measured from it).
        terminated: Whether this step ends the episode by failure.
    """
    effort = float(np.sum((action - hover_action) ** 2)) / 4.0
    return {
        "reward_alive": cfg.alive,
        "reward_pos": -cfg.pos_weight * math.dist(true_pos, ref.pos),
        "reward_vel": -cfg.vel_weight * math.dist(true_vel_inertial, ref.vel),
        "reward_yaw": -cfg.yaw_weight * abs(float(wrap_angle(true_yaw - ref.yaw))),
        "reward_effort": -cfg.effort_weight * effort,
        "reward_termination": -cfg.termination_penalty if terminated else 0.0,
    }


def tilt_angle(euler: FloatArray) -> float:
    """Angle between b3 and n3 in rad: ``acos(cos φ cos θ)``."""
    return math.acos(max(-1.0, min(1.0, math.cos(euler[0]) * math.cos(euler[1]))))
