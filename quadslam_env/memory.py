"""The bytes of one env of B lanes, estimated from its validated scenario before anything is
allocated, and the one refusal when they cannot fit (docs/reliability.md "Memory").

:func:`env_memory_terms` counts every buffer that grows with a setting: the simulator's lanes
(their state, the IMU's and the wind's pre-drawn noise blocks, the true map and a scan's rows),
the observation, the delayed actions' ring, the estimator's state (asked of its class through
:func:`quadslam_env.estimation.registry.memory_terms`: EKF-SLAM's covariance and map, FastSLAM's
particles, iSAM2's window, the oracle's snapshot), the second run of a slow IMU or a delayed
LiDAR (the estimator's copies and the period log they replay) and a fast IMU's samples of one
period. :func:`check_env_memory` refuses, in one line, settings whose terms exceed
:data:`~quadslam_env.estimation.memory.ENV_MEMORY_SHARE` of the available memory, naming the
setting that dominates, its size and what would fit. The envs call it before they build their
core; the command line calls it with what it adds (a learner's buffers, the episode records).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.episode.observation import observation_size
from quadslam_env.estimation import registry
from quadslam_env.estimation.memory import (
    LANES,
    MemoryTerm,
    Workload,
    format_bytes,
    refuse_unless_fits,
)
from quadslam_env.models.wind import GUST_STATES
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.wind import WindBatch
from quadslam_env.sim.world import landmark_capacity
from quadslam_env.types import IMU_DIM

__all__ = ["check_env_memory", "env_memory_terms", "workload"]

SIM_LANE_BYTES = 8 * 1024
"""Bytes per lane of the simulator besides its noise blocks and its map, rounded up: the
vehicle, sensors, wind, randomisation, termination and episode sums (about 1.6 KiB of arrays),
the lane's generators (its own and the five a reset spawns) and its share of a step's terms
and ``info``."""

NOISE_BLOCK_BYTES = 8 * (ImuBatch.BLOCK * 2 * IMU_DIM + WindBatch.BLOCK * GUST_STATES)
"""Bytes per lane of the IMU's and the wind's normals drawn ahead (float64 blocks)."""

SIM_BYTES_PER_LANDMARK = 128
"""Bytes per lane and landmark id of the simulator, rounded up: the true position, a scan's
rows (true and noisy returns, the mask, the ids) and the association's match arrays."""

OBSERVATION_BYTES_PER_VALUE = 32
"""Bytes per lane and observation entry: the float64 block it is built in, the float32
observation, the vector env's copy and the caller's."""

SAMPLE_BYTES = 88
"""Bytes of one logged IMU sample of one lane: its time, specific force, rates, thrust and
torque (11 float64)."""

LOGGED_SCAN_BYTES = 1024
"""Bytes of one lane's scan kept in a period log besides 32 bytes per landmark id: its
one-lane container and the log's entry for it."""


def workload(scenario: ScenarioConfig, num_lanes: int) -> Workload:
    """What the estimator of ``scenario`` on ``num_lanes`` lanes will be asked to hold."""
    return Workload(
        num_lanes=int(num_lanes),
        landmark_capacity=landmark_capacity(scenario.landmarks) + scenario.faults.extra_landmarks,
        known_map=scenario.estimator.known_map,
        scan_hz=scenario.episode.control_hz / scenario.lidar_every,
        duration_s=scenario.episode.duration_s,
    )


def env_memory_terms(scenario: ScenarioConfig, num_lanes: int) -> list[MemoryTerm]:
    """Every buffer of an env of ``scenario`` on ``num_lanes`` lanes, each with the setting
    that sizes it (module docstring).

    Raises:
        ConfigError: Invalid ``estimator.params`` (as the estimator would say at construction).
        MemoryLimitError: The estimator's own check (a filter's one big buffer above half the
            available memory: EKF-SLAM's covariance, FastSLAM's particles).
    """
    b, lmax = int(num_lanes), landmark_capacity(scenario.landmarks)
    per_lane = SIM_LANE_BYTES + NOISE_BLOCK_BYTES + SIM_BYTES_PER_LANDMARK * lmax
    sim = (
        f"the simulator's lanes (B × ({SIM_LANE_BYTES} + {NOISE_BLOCK_BYTES} + "
        f"{SIM_BYTES_PER_LANDMARK} Lmax) bytes = {b} × ({SIM_LANE_BYTES} + "
        f"{NOISE_BLOCK_BYTES} + {SIM_BYTES_PER_LANDMARK} × {lmax}))"
    )
    dim = observation_size(scenario.observation)
    obs = f"the observations (B × {OBSERVATION_BYTES_PER_VALUE} B × n = {b} × 32 × {dim})"
    cfg = scenario.estimator
    estimator = registry.memory_terms(cfg.name, workload(scenario, b), cfg.params)
    return [
        MemoryTerm(b * per_lane, LANES, f"{b} lane(s)", sim),
        MemoryTerm(b * OBSERVATION_BYTES_PER_VALUE * dim, "observation", f"{dim} values", obs),
        *_action_ring(scenario, b),
        *estimator,
        *_second_run(scenario, b, lmax, estimator),
        *_fast_imu(scenario, b),
    ]


def check_env_memory(
    scenario: ScenarioConfig,
    num_lanes: int,
    lanes_key: str = "num_envs",
    extra: Sequence[MemoryTerm] = (),
) -> int:
    """Refuse an env of ``scenario`` on ``num_lanes`` lanes whose buffers (and the caller's
    ``extra`` ones) would not fit in memory; called before anything is allocated.

    Args:
        scenario: The validated scenario.
        num_lanes: B.
        lanes_key: How the caller sets B (``num_envs``; ``--n-envs``, ``--seeds`` from the
            command line).
        extra: What the caller holds beside the env (a learner's buffers, episode records).

    Returns:
        The estimated bytes of all the terms.

    Raises:
        MemoryLimitError: One line naming the setting that dominates, its size and formula,
            the total against the budget, and what would fit.
        ConfigError: Invalid ``estimator.params``.
    """
    terms = [*env_memory_terms(scenario, num_lanes), *extra]
    return refuse_unless_fits(terms, int(num_lanes), lanes_key)


def _action_ring(scenario: ScenarioConfig, b: int) -> list[MemoryTerm]:
    """The ring of the agent's last ``action.delay_steps`` actions (``ActionDelay``)."""
    d, dim = scenario.action.delay_steps, scenario.action.dim
    if d == 0:
        return []

    def most(room: int) -> str:
        return f"action.delay_steps at most {room // (8 * b * dim)}"

    what = f"the delayed actions (d × B × {dim} × 8 B = {d} × {b} × {dim} × 8)"
    return [MemoryTerm(8 * d * b * dim, "action.delay_steps", d, what, most)]


def _second_run(
    scenario: ScenarioConfig, b: int, lmax: int, estimator: list[MemoryTerm]
) -> list[MemoryTerm]:
    """A delayed LiDAR's or a slow IMU's period log and the estimator's copies run beside it
    (``ScanDelay``, ``LateScans``, ``ImuReplay``: :mod:`quadslam_env.runtime.scan_delay`)."""
    d, m = scenario.lidar.delay_steps, scenario.imu_per_step
    late = d > 0 and registry.estimator_flag(scenario.estimator.name, registry.takes_late_scans)
    if d > 0:  # the log holds d + 1 periods (late scans), or a scan period and d
        extra = 1 if late else scenario.lidar_every
        key, value, slots = "lidar.delay_steps", f"{d}", d + extra
        # A lane's scan on each scan step, kept in its slot.
        scans = b * (LOGGED_SCAN_BYTES + 32 * lmax) / scenario.lidar_every
    elif scenario.steps_per_imu > 1:  # the slow-IMU filter replays its m periods, no scans
        extra, key, slots = 0, "imu.rate_hz", scenario.steps_per_imu
        value, scans = f"{scenario.imu_rate_hz:g} Hz", 0.0
    else:
        return []
    per_slot = b * (1 + SAMPLE_BYTES * m) + 72 + scans  # samples, flags, the slot's entry

    def most(room: int) -> str | None:
        fit = int(room // per_slot)
        if d > 0:
            return f"lidar.delay_steps at most {fit - extra}" if fit > extra else None
        return f"imu.rate_hz at least {scenario.episode.control_hz / fit:.3g} Hz" if fit else None

    log = f"the period log of {slots} control periods (B × {1 + SAMPLE_BYTES * m} B per period)"
    terms = [MemoryTerm(math.ceil(slots * per_slot), key, value, log, most)]
    if not late:  # the lagging filter and the output rebuilt from it, beside the env's
        copies = 2 * sum(t.nbytes for t in estimator)
        what = f"two copies of the estimator run beside it ({format_bytes(copies / 2)} each)"
        terms.append(MemoryTerm(copies, key, value, what))
    return terms


def _fast_imu(scenario: ScenarioConfig, b: int) -> list[MemoryTerm]:
    """An IMU m times faster than the control: the m samples of a period, and their copies."""
    m = scenario.imu_per_step
    if m == 1:
        return []

    def most(room: int) -> str | None:
        fit = room // (2 * SAMPLE_BYTES * b)
        rate = fit * scenario.episode.control_hz
        return f"imu.rate_hz at most {rate:.3g} Hz" if fit >= 1 else None

    what = f"a period's IMU samples (2 × m × B × {SAMPLE_BYTES} B = 2 × {m} × {b} × 88)"
    value = f"{scenario.imu_rate_hz:g} Hz"
    return [MemoryTerm(2 * m * b * SAMPLE_BYTES, "imu.rate_hz", value, what, most)]
