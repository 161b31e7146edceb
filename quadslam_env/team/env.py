"""``TeamParallelEnv``: N vehicles in one world of landmarks as a PettingZoo ``ParallelEnv``
(docs/team.md).

Coordination only, for the N lanes of one :class:`~quadslam_env.core.SimCore`: lane i is
``vehicle_i``, with the single env's IMU, LiDAR, estimator, observation, action, reward and
termination; the lanes share the landmark field (vehicle 0's draw, given to the other lanes at
each reset) and differ in their references, starts and streams (:mod:`quadslam_env.team.world`).
With ``team.fusion: independent`` nothing passes between the vehicles, so ``vehicle_0`` is the
single env (``gymnasium.make("QuadSLAM-v0")`` with the same seed), step for step, bit for bit.
With ``ci`` or ``naive`` the vehicles send their landmark estimates
(:class:`~quadslam_env.team.comms.Comms`: sent at the end of a step, fused by the estimator at
the start of a later one). With ``team.ranges`` the vehicles measure their distances
(:class:`~quadslam_env.team.ranging.Ranges`: at the end of a range epoch's step, fused with
``range_fusion: ci`` at the start of the next). With ``centralised`` the vehicles' estimators are
one (:meth:`~quadslam_env.estimation.lane_loop.LaneLoop.join_team`: iSAM2's vehicles share one
factor graph and one map), and what the vehicles send is their measurements
(:class:`~quadslam_env.team.comms.Uplink`). The team's map terms are read from the lane
snapshots (:class:`~quadslam_env.team.map_metrics.MapMetrics`).
The core's check across lanes ends two vehicles that collide
(:class:`~quadslam_env.team.collision.Collisions`). A vehicle that ends leaves ``agents``
(PettingZoo's convention); its lane is no longer stepped.
"""

from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Mapping
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from quadslam_env.config.scenario import ScenarioConfig, load_scenario
from quadslam_env.core import SimCore
from quadslam_env.env import lane_info, step_rate
from quadslam_env.episode.actions import ActionError, validate_actions
from quadslam_env.episode.reset_options import parse_reset_options, parse_seed
from quadslam_env.estimation.lane_loop import LaneLoop
from quadslam_env.extras import require
from quadslam_env.memory import check_env_memory
from quadslam_env.schema import ConfigError
from quadslam_env.team.collision import Collisions
from quadslam_env.team.comms import Comms, Uplink
from quadslam_env.team.config import SHARING, TeamConfig, parse_vehicles
from quadslam_env.team.map_metrics import MapMetrics
from quadslam_env.team.metrics import TeamMetrics
from quadslam_env.team.ranging import Ranges
from quadslam_env.team.world import start_states, team_references, vehicle_generators
from quadslam_env.types import POS, FloatArray

require("pettingzoo", "team", "quadslam_env.team (the team env)")  # a missing extra: one line
from pettingzoo import ParallelEnv  # noqa: E402

TEAM_RESET_OPTIONS = ("landmarks", "randomized")
"""The reset options the team env reads, applied to every vehicle (the single env's
``landmarks``: the shared field; ``randomized``: the scales to pin)."""

Step = tuple[
    dict[str, np.ndarray],
    dict[str, float],
    dict[str, bool],
    dict[str, bool],
    dict[str, dict[str, Any]],
]


class TeamParallelEnv(ParallelEnv):
    """N quadcopters with their estimators in one world (module docstring).

    Agents ``vehicle_0`` … ``vehicle_{N-1}``; each one's observation and action spaces are the
    single env's, and so are its reward, termination, truncation and ``info`` terms, to which
    the team's are added (:mod:`quadslam_env.team.metrics`).

    Args:
        n_vehicles: N ≥ 1.
        scenario: Scenario name, YAML path, mapping or ``None`` (as for ``gymnasium.make``).
        team: The ``team`` settings (:class:`~quadslam_env.team.config.TeamConfig`).
        render_mode: ``None`` (the team env draws no frames yet).
        estimator_name: Estimator applied before ``overrides``.
        **overrides: Section mappings merged into the scenario, e.g. ``episode={...}``.

    Raises:
        ConfigError: A bad ``n_vehicles``, ``team`` setting, ``render_mode`` or scenario.
        MemoryLimitError: N lanes whose buffers would not fit in memory (naming
            ``n_vehicles`` and what fits, :mod:`quadslam_env.memory`).
    """

    metadata = {"render_modes": [], "name": "quadslam_team_v0", "is_parallelizable": True}

    def __init__(
        self,
        n_vehicles: int = 3,
        scenario: str | dict[str, Any] | None = None,
        team: dict[str, Any] | None = None,
        render_mode: str | None = None,
        estimator_name: str | None = None,
        **overrides: Any,
    ) -> None:
        n = parse_vehicles(n_vehicles)
        if render_mode is not None:
            raise ConfigError(f"render_mode: got {render_mode!r}; allowed: None (no frames yet)")
        self.scenario: ScenarioConfig = load_scenario(scenario, overrides, estimator_name)
        self.team: TeamConfig = TeamConfig.from_dict(team)
        self.team.check(n, self.scenario)
        check_env_memory(self.scenario, n, lanes_key="n_vehicles")  # before any allocation
        self.references = team_references(self.scenario, self.team, n)
        radius = self.team.collision_radius_m
        check = None if radius is None else Collisions(radius)
        self._core = SimCore(self.scenario, n, self.references, check)
        core = self._core
        if self.team.fusion == "centralised":  # the check has refused estimators that cannot
            _join(core.estimator)
        self._starts = start_states(self.scenario, self.references, core.vehicle_params.mass)
        self.n_vehicles = n
        self.render_mode = None
        self.dt = core.dt
        self.metadata = {**self.metadata, "render_fps": step_rate(self.scenario)}
        self.possible_agents = [f"vehicle_{i}" for i in range(n)]
        self.agents: list[str] = []
        self._lanes = {agent: i for i, agent in enumerate(self.possible_agents)}
        box = spaces.Box(-1.0, 1.0, shape=(core.action_map.dim,), dtype=np.float32)
        self.observation_spaces = {a: copy.deepcopy(core.observer.space) for a in self._lanes}
        self.action_spaces = {a: copy.deepcopy(box) for a in self._lanes}
        self._rngs: list[np.random.Generator] | None = None
        self._live = np.zeros(n, dtype=bool)  # the lanes of the agents still in the episode
        self._metrics = TeamMetrics(n)
        self._maps = MapMetrics(n)
        self._comms: Comms | None = None
        if self.team.fusion in SHARING:
            control_hz = self.scenario.episode.control_hz
            self._comms = Comms(self.team, n, self.scenario.lidar_every, control_hz)
        self._uplink: Uplink | None = None
        if self.team.fusion == "centralised":
            self._uplink = Uplink(self.scenario.imu_per_step)
        self._ranges: Ranges | None = None
        if self.team.ranges:
            self._ranges = Ranges(self.team, n, self.scenario.episode.control_hz)
        self._steps_done = 0

    @property
    def core(self) -> SimCore:
        """The simulation core of the N lanes (its arrays hold the truth: for analysis only)."""
        return self._core

    def observation_space(self, agent: str) -> spaces.Box:
        """``agent``'s observation space (the single env's; the same object on every call)."""
        return self.observation_spaces[self._agent(agent)]

    def action_space(self, agent: str) -> spaces.Box:
        """``agent``'s action space (the single env's; the same object on every call)."""
        return self.action_spaces[self._agent(agent)]

    def _agent(self, agent: Any) -> str:
        if agent not in self._lanes:
            raise ConfigError(f"agent: got {agent!r}; allowed: one of {self.possible_agents}")
        return str(agent)

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Start an episode of every vehicle: vehicle 0's exactly as the single env's reset
        with ``seed``, then the others in the landmark field it drew.

        Args:
            seed: ``None`` (keep the vehicles' generators) or an integer >= 0.
            options: ``landmarks`` (L, 3), the shared field, and ``randomized``, both applied
                to every vehicle; other keys are not read (a warning names them).

        Returns:
            ``(observations, infos)`` of every agent.

        Raises:
            ConfigError: A bad seed or option, or ``initial_state`` (the starts are the team's).
        """
        opts = _reset_options(options)
        seed = parse_seed(seed)
        if seed is not None or self._rngs is None:
            self._rngs = vehicle_generators(seed, self.n_vehicles)
        core = self._core
        obs, info = core.reset_lanes([0], self._rngs[:1], opts)
        rows, infos = [obs[0]], [lane_info(info, 0)]
        shared = {**opts, "landmarks": core.landmarks[0, : core.n_landmarks[0]].copy()}
        for lane in range(1, self.n_vehicles):
            start = {**shared, "initial_state": self._starts[lane]}
            obs, info = core.reset_lanes([lane], self._rngs[lane : lane + 1], start)
            rows.append(obs[0])
            infos.append(lane_info(info, 0))
        self.agents = list(self.possible_agents)
        self._live[:] = True
        self._steps_done = 0
        self._metrics.reset()
        self._maps.reset()
        if self._comms is not None:
            self._comms.reset(self._rngs)
        if self._uplink is not None:
            self._uplink.reset()
        if self._ranges is not None:  # spawned after the messages' generators
            self._ranges.reset(self._rngs)
        err = np.array([row.get("est_pos_err_m", math.nan) for row in infos])
        team = self._metrics.terms(err, core.vehicle.state, self._live)
        anees, team = self._map_terms(team, self._live)
        vehicle = {"est_landmark_anees": anees} | self._range_terms()
        for i, row in enumerate(infos):
            row |= _applying({key: float(value[i]) for key, value in vehicle.items()})
        team = _applying(team)
        observations = {agent: rows[i] for i, agent in enumerate(self.agents)}
        return observations, {agent: {**infos[i], **team} for i, agent in enumerate(self.agents)}

    def _truth(self) -> FloatArray:
        """(L, 3) the shared true landmark field, m, N frame (for the metrics only)."""
        core = self._core
        return core.landmarks[0, : core.n_landmarks[0]]

    def _map_terms(
        self, team: dict[str, float], lanes: np.ndarray
    ) -> tuple[FloatArray, dict[str, float]]:
        """Each vehicle's landmark ANEES (N,) and ``team`` with the map terms and the message
        counts of the vehicles ``lanes`` (N,) bool."""
        truth = self._truth()
        anees = self._maps.observe(self._core.estimator, truth, truth.shape[0], lanes)
        return anees, team | self._maps.terms(truth, lanes) | self._link_terms()

    def _link_terms(self) -> dict[str, float]:
        """The episode's message counts so far and the bytes of the ranges' broadcasts (in
        ``team_bytes_sent``); empty with neither."""
        out = {} if self._comms is None else self._comms.terms()
        if self._uplink is not None:
            out["team_bytes_sent"] = float(self._uplink.bytes_sent)
        ranges = self._ranges
        if ranges is not None and ranges.fusion in ("ci", "factor"):
            out["team_bytes_sent"] = out.get("team_bytes_sent", 0.0) + float(ranges.bytes_sent)
        return out

    def _range_terms(self) -> dict[str, FloatArray]:
        """Each vehicle's range terms (N,) (:data:`~quadslam_env.team.ranging.VEHICLE_KEYS`;
        none without ranges)."""
        return {} if self._ranges is None else self._ranges.vehicle_terms()

    def step(self, actions: Any) -> Step:
        """Advance every live vehicle one control period (``dt`` s).

        Args:
            actions: A mapping of each live agent to its action, (4,) in [-1, 1] ((5,) with
                ``action.heading``).

        Returns:
            ``(observations, rewards, terminations, truncations, infos)`` of the agents live
            at the step; those that ended then leave ``agents``.

        Raises:
            gymnasium.error.ResetNeeded: No live agent (before the first reset, or after the
                last vehicle ended).
            ActionError: An agent's action is missing, not finite or of the wrong shape, or an
                action names an agent that is not live; nothing is changed.
        """
        if not self.agents:
            raise gym.error.ResetNeeded(
                "TeamParallelEnv.step: no live agent (no episode was started, or every "
                "vehicle's ended); call reset() before step()"
            )
        act = self._actions(actions)
        core, live, comms, ranges = self._core, self._live.copy(), self._comms, self._ranges
        if comms is not None:  # the messages due now, fused before the step
            comms.deliver(core.estimator, self._steps_done, live)
        if ranges is not None:  # the last epoch's ranges, fused before the step (ci)
            ranges.deliver(core.estimator, live)
        obs, reward, terminated, truncated, info = core.step(act, live)
        if self._uplink is not None:  # the step's measurements, to the one estimator
            self._uplink.send(live, core.last_scan)
        self._steps_done += 1
        err = info["est_pos_err_m"]
        self._metrics.add(err, live)
        team = self._metrics.terms(err, core.vehicle.state, live)
        self._live &= ~(terminated | truncated)
        if comms is not None:  # the live vehicles due to send, from their new estimates
            comms.send(core.estimator, core.steps, self._live, core.vehicle.state[:, POS])
        if ranges is not None:  # the ranges of the live vehicles, if the step ends an epoch
            ranges.measure(core.vehicle.state[:, POS], core.est, self._live, self._steps_done)
        info["est_landmark_anees"], team = self._map_terms(team, live)
        info |= self._range_terms()
        if not self._live.any():  # the last vehicles end: the team's episode summary
            team |= self._metrics.summary() | self._maps.summary(self._truth())
            team |= {f"team_episode_{k[5:]}": v for k, v in self._link_terms().items()}
        team = _applying(team)
        out: Step = ({}, {}, {}, {}, {})
        for agent in self.agents:
            lane = self._lanes[agent]
            out[0][agent] = obs[lane]
            out[1][agent] = float(reward[lane])
            out[2][agent] = bool(terminated[lane])
            out[3][agent] = bool(truncated[lane])
            out[4][agent] = {**lane_info(info, lane), **team}
        self.agents = [agent for agent in self.agents if self._live[self._lanes[agent]]]
        return out

    def _actions(self, actions: Any) -> FloatArray:
        """The (N, dim) actions of the lanes from ``actions`` (zeros in the lanes not live).

        Raises:
            ActionError: Naming the agent, what it got and what is allowed.
        """
        allowed = f"a dict with one action per live agent {self.agents}"
        if not isinstance(actions, Mapping):
            raise ActionError(f"actions: got {type(actions).__name__}; allowed: {allowed}")
        for key in actions:
            if key not in self.agents:
                why = "is done" if key in self._lanes else "is not an agent of this env"
                raise ActionError(f"actions[{key!r}]: {key!r} {why}; allowed: {allowed}")
        missing = [agent for agent in self.agents if agent not in actions]
        if missing:
            raise ActionError(f"actions: no action for {missing}; allowed: {allowed}")
        dim = self._core.action_map.dim
        out = np.zeros((self.n_vehicles, dim))
        for agent in self.agents:
            try:
                out[self._lanes[agent]] = validate_actions(actions[agent], None, dim)[0]
            except ActionError as err:  # "action: ..." → "actions['vehicle_1']: ..."
                text = str(err).removeprefix("action")
                raise ActionError(f"actions[{agent!r}]{text}") from None
        return out

    def render(self) -> None:
        """No frames yet (``render_mode`` is ``None``)."""
        return None

    def close(self) -> None:
        """Nothing to release."""


def parallel_env(**kwargs: Any) -> TeamParallelEnv:
    """The team env (PettingZoo's ``parallel_env`` factory): ``parallel_env(n_vehicles=N,
    scenario=..., team={...}, **overrides)``; the arguments of :class:`TeamParallelEnv`."""
    return TeamParallelEnv(**kwargs)


def _reset_options(options: Any) -> dict[str, Any]:
    """The parsed options of :data:`TEAM_RESET_OPTIONS` in ``options``; other keys warned of.

    Raises:
        ConfigError: Not ``None`` or a dict, ``initial_state``, or a bad value.
    """
    if options is None:
        return {}
    allowed = f"None or a dict with keys {list(TEAM_RESET_OPTIONS)}"
    if not isinstance(options, dict):
        raise ConfigError(f"reset options: got {options!r}; allowed: {allowed}")
    if "initial_state" in options:
        raise ConfigError(
            f"reset options.initial_state: not taken by the team env; allowed: {allowed} (the "
            "vehicles' starts come from the team settings)"
        )
    unread = [key for key in options if key not in TEAM_RESET_OPTIONS]
    if unread:
        warnings.warn(
            f"TeamParallelEnv.reset: options {unread} are not read; the team env reads "
            f"{list(TEAM_RESET_OPTIONS)}",
            stacklevel=3,
        )
    return parse_reset_options({k: v for k, v in options.items() if k in TEAM_RESET_OPTIONS})


def _join(estimator: Any) -> None:
    """Make the lanes' estimators one estimator of the team (``team.fusion: centralised``).

    Raises:
        ConfigError: A batched estimator (its lanes are one object already, not vehicles that
            can join), or more vehicles than one estimator of the team holds.
    """
    if not isinstance(estimator, LaneLoop):
        raise ConfigError(
            f"team.fusion: got 'centralised' with the batched {type(estimator).__name__}; "
            "allowed: a one-vehicle estimator with joins_team = True (isam2)"
        )
    try:
        estimator.join_team()
    except ValueError as err:  # the estimator's own limit, e.g. iSAM2's vehicles per graph
        raise ConfigError(
            f"n_vehicles: got {estimator.num_lanes} with team.fusion 'centralised'; {err}"
        ) from None


def _applying(terms: dict[str, float]) -> dict[str, float]:
    """The terms that apply (NaN: does not apply, left out as in the single env's info)."""
    return {key: value for key, value in terms.items() if not math.isnan(value)}
