"""The team's world: each vehicle's reference and start, and each vehicle's random stream
(docs/team.md).

The N vehicles are N lanes of one :class:`~quadslam_env.core.SimCore`. Vehicle i flies the
scenario's trajectory shifted by its time offset τ_i and position offset p_i
(:class:`~quadslam_env.sim.trajectories.LaneTrajectory`), and starts where vehicle 0 would start
relative to its own reference: on it with ``trajectory.start_on_reference``, else at the
scenario's start moved by ``ρ_d,i(0) − ρ_d,0(0)``. Vehicle 0 has no offset, so it is the
single env's vehicle.

Streams: vehicle 0's generator is the single env's (``gymnasium.utils.seeding.np_random(s)``,
whose children the core spawns at each reset exactly as the single env's); vehicle i ≥ 1 draws
from ``SeedSequence([s, i])``, the seed with the vehicle's index appended, a stream of its own.
"""

from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.episode.start import initial_state
from quadslam_env.models.flatness import state_on_reference
from quadslam_env.sim.trajectories import LaneTrajectory
from quadslam_env.team.config import TeamConfig
from quadslam_env.types import POS, FloatArray


def team_references(scenario: ScenarioConfig, team: TeamConfig, n_vehicles: int) -> LaneTrajectory:
    """The N vehicles' references: the scenario's trajectory shifted by each vehicle's offsets
    (``team.time_offsets_s``, ``team.position_offsets_m``; defaults in
    :meth:`TeamConfig.offsets`)."""
    times, positions = team.offsets(n_vehicles, scenario.trajectory.period_s)
    return LaneTrajectory(scenario.trajectory, times, positions)


def start_states(scenario: ScenarioConfig, references: LaneTrajectory, mass: float) -> FloatArray:
    """Each vehicle's start (N, 12) (module docstring); row 0 is the single env's.

    Args:
        scenario: The validated scenario.
        references: The vehicles' references (N lanes).
        mass: Vehicle mass, kg.

    Returns:
        ``(ρ m NED, v m/s body, Λ rad, ω rad/s body)`` per vehicle.
    """
    base = initial_state(scenario, references, mass)  # lane 0's reference: the single env's
    n = references.time_offsets_s.shape[0]
    ref = references.batch(np.zeros(n))
    if not scenario.trajectory.start_on_reference:
        states = np.tile(base, (n, 1))
        states[:, POS] += ref.pos - ref.pos[0]
        return states
    yaw, rate = np.asarray(ref.yaw), np.asarray(ref.yaw_rate)
    return np.stack(
        [
            state_on_reference(ref.pos[i], ref.vel[i], ref.acc[i], yaw[i], rate[i], mass)
            for i in range(n)
        ]
    )


def vehicle_generators(seed: int | None, n_vehicles: int) -> list[np.random.Generator]:
    """The N vehicles' generators for ``seed`` (module docstring; ``None``: fresh entropy)."""
    first = seeding.np_random(seed)[0]
    rest = [
        np.random.Generator(
            np.random.PCG64(np.random.SeedSequence(None if seed is None else [seed, i]))
        )
        for i in range(1, n_vehicles)
    ]
    return [first, *rest]
