"""Reward from the true state against the reference (DESIGN.md §4), for B lanes at once.

``reward = alive - w_p ‖ρ - ρ_d‖ - w_v ‖ρ̇ - ρ̇_d‖ - w_ψ |wrap(ψ - ψ_d)| - w_u ‖a - a_hover‖²/4
- penalty·[terminated]``; every term is reported in ``info`` as ``reward_<term>`` and they sum to
the reward.
"""

from __future__ import annotations

import numpy as np

from quadslam_env.config import RewardConfig
from quadslam_env.models.rotations import FloatArray, wrap_angle
from quadslam_env.trajectories import FlatOutputs


def reward_terms(
    cfg: RewardConfig,
    true_pos: FloatArray,
    true_vel_inertial: FloatArray,
    true_yaw: FloatArray,
    ref: FlatOutputs,
    action: FloatArray,
    hover_action: FloatArray,
    terminated: np.ndarray,
) -> dict[str, FloatArray]:
    """Signed reward terms of B lanes, keyed ``reward_<term>``, each (B,).

    Args:
        cfg: Weights.
        true_pos: (B, 3) true position in N, m.
        true_vel_inertial: (B, 3) true velocity in N, m/s.
        true_yaw: (B,) true ψ in rad.
        ref: Reference of the lanes at the same time ((B, 3) and (B,) arrays).
        action: (B, 4) normalised action applied this step.
        hover_action: (4,) normalised action that holds hover (effort is measured from it).
        terminated: (B,) bool, whether this step ends the lane's episode by failure.
    """
    effort = np.sum((action - hover_action) ** 2, axis=1) / 4.0
    return {
        "reward_alive": np.full(terminated.shape, float(cfg.alive)),
        "reward_pos": -cfg.pos_weight * _norm(true_pos - ref.pos),
        "reward_vel": -cfg.vel_weight * _norm(true_vel_inertial - ref.vel),
        "reward_yaw": -cfg.yaw_weight * np.abs(wrap_angle(true_yaw - ref.yaw)),
        "reward_effort": -cfg.effort_weight * effort,
        "reward_termination": np.where(terminated, -cfg.termination_penalty, 0.0),
    }


def tilt_angle(euler: FloatArray) -> FloatArray:
    """Angle between b3 and n3 in rad, ``acos(cos φ cos θ)``, for Euler angles (..., 3)."""
    return np.arccos(np.clip(np.cos(euler[..., 0]) * np.cos(euler[..., 1]), -1.0, 1.0))


def _norm(vec: FloatArray) -> FloatArray:
    """Row norms of (B, 3) vectors."""
    return np.sqrt(np.einsum("ij,ij->i", vec, vec))
