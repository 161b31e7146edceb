"""Where an episode starts and when its transient ends.

Most scenarios start the vehicle at rest away from the reference (e.g. 2 m below the
figure-8), so the first seconds are a climb onto it. Its error dwarfs what the estimator costs
in flight, so every episode metric is also reported over two phases (``quadslam_env.metrics``):
the *transient* ``t ≤ settle_s`` and the *steady state* ``t > settle_s``.
``trajectory.start_on_reference`` removes the transient altogether.
"""

from __future__ import annotations

import numpy as np

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.models.flatness import state_on_reference
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.sim.trajectories import Trajectory
from quadslam_env.types import EUL, POS, STATE_DIM, VEL, FloatArray

DEFAULT_SETTLE_S = 10.0
"""The transient of a scenario that starts off the reference, when ``episode.settle_s`` is
null (long enough for the DF-LQR baseline's climb onto the figure-8 and the helix: see the
docs page on metrics)."""
ON_REFERENCE_POS_M = 0.01
"""A start within this distance (m) and speed difference (m/s) of the reference at t = 0 is
*on* it (no transient)."""


def initial_state(scenario: ScenarioConfig, trajectory: Trajectory, mass: float) -> FloatArray:
    """The true state (12,) every episode starts from (before any reset option).

    Args:
        scenario: The validated scenario.
        trajectory: Its reference.
        mass: Vehicle mass, kg.

    Returns:
        ``(ρ m NED, v m/s body, Λ rad, ω rad/s body)``: the reference's own state at t = 0
        with ``trajectory.start_on_reference``, else ``episode.initial_*`` at zero rates.
    """
    if scenario.trajectory.start_on_reference:
        ref = trajectory(0.0)
        return state_on_reference(
            ref.pos, ref.vel, ref.acc, float(ref.yaw), float(ref.yaw_rate), mass
        )
    ep = scenario.episode
    state = np.zeros(STATE_DIM)
    state[POS] = ep.initial_position
    state[VEL] = ep.initial_velocity
    state[EUL] = np.radians(ep.initial_euler_deg)
    return state


def settle_time(scenario: ScenarioConfig, trajectory: Trajectory, state0: FloatArray) -> float:
    """The end of the transient, s (``episode.settle_s``, or its default when null).

    The default is 0 when ``state0`` is on the reference at t = 0 (position and inertial
    velocity within :data:`ON_REFERENCE_POS_M`), else :data:`DEFAULT_SETTLE_S`. An episode that
    ends before it (a short one, or a crash) has no steady phase, and its ``*_steady`` metrics
    are absent.
    """
    if scenario.episode.settle_s is not None:
        return float(scenario.episode.settle_s)
    ref = trajectory(0.0)
    vel_nav = dcm_from_euler(state0[EUL]) @ state0[VEL]
    on_ref = (
        np.linalg.norm(state0[POS] - ref.pos) <= ON_REFERENCE_POS_M
        and np.linalg.norm(vel_nav - ref.vel) <= ON_REFERENCE_POS_M
    )
    return 0.0 if on_ref else DEFAULT_SETTLE_S
