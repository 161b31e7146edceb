"""``QuadSLAMEnv``: the quadcopter simulator with an estimator in the loop (docs/design.md §4).

Coordination only, for one lane of :class:`~quadslam_env.core.SimCore` (which sequences the
physics, sensors, estimator, metrics, reward and observation for B lanes): this class turns the
lane's arrays into Gymnasium's single-env API and draws the frames.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from quadslam_env.config.scenario import ScenarioConfig, load_scenario
from quadslam_env.core import SimCore
from quadslam_env.episode.actions import validate_actions
from quadslam_env.episode.reset_options import parse_reset_options, parse_seed
from quadslam_env.estimation.protocol import BatchEstimator
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.memory import check_env_memory
from quadslam_env.schema import ConfigError
from quadslam_env.sim.trajectories import FlatOutputs
from quadslam_env.types import TEXT_INFO_KEYS, FloatArray

if TYPE_CHECKING:
    from quadslam_env.render.renderer import LaneRenderer

__all__ = ["QuadSLAMEnv", "lane_info", "step_rate"]


def step_rate(scenario: ScenarioConfig) -> int | float:
    """Control steps per second (an int when whole): the env's ``metadata["render_fps"]``."""
    hz = float(scenario.episode.control_hz)
    return int(hz) if hz.is_integer() else hz


def lane_info(info: dict[str, Any], lane: int) -> dict[str, Any]:
    """One lane's ``info`` as floats; terms that do not apply (NaN) are left out."""
    out: dict[str, Any] = {}
    for key, value in info.items():
        if key in TEXT_INFO_KEYS:  # termination_reason, fault_kind: strings
            out[key] = value[lane]
            continue
        v = float(value[lane])
        if not math.isnan(v):
            out[key] = v
    return out


class QuadSLAMEnv(gym.Env[np.ndarray, np.ndarray]):
    """Quadcopter tracking a reference while acting on an embedded estimator's output.

    The agent sees only the estimate (and the reference); reward, termination and the ``est_*``
    accuracy terms in ``info`` are computed from the true state.

    **Observation** (``Box`` float32, clipped to ``±observation.clip``), reference-heading frame
    (rotated by ``C3(ψ_d)ᵀ``):

    ======  ==================  ===========================================  ======
    index   name                meaning                                      unit
    ======  ==================  ===========================================  ======
    0–2     pos_err             ρ̂ − ρ_d                                      m
    3–5     vel_err             C_NB(Λ̂) v̂ − ρ̇_d (inertial velocity)         m/s
    6–7     roll_pitch          φ̂, θ̂                                        rad
    8       yaw_err             wrap(ψ̂ − ψ_d)                               rad
    9–11    rates               ω̂ (body)                                     rad/s
    12–14   acc_ref             ρ̈_d                                          m/s²
    15      yaw_rate_ref        ψ̇_d                                          rad/s
    16+     optional            position std (3), landmark counts (2),
                                look-ahead offsets (3 each), nearest
                                landmarks (4 each), estimated wind (2,
                                N), air velocity (3, B), in that order
    ======  ==================  ===========================================  ======

    **Action** ``Box(-1, 1, (4,))``: ``thrust_torque`` maps ``a0`` to thrust in
    ``[0, max_thrust]`` and ``a1..a3`` to ``±max_torque``; ``thrust_rates`` maps ``a1..a3`` to
    body-rate commands ``±max_rate`` tracked by an inner P loop on the gyro minus the estimated
    bias. Out-of-range actions are clipped; wrong shapes or non-finite values raise
    :class:`~quadslam_env.episode.actions.ActionError`.

    **Episode end**: ``terminated`` on tilt beyond ``max_tilt_deg``, position error beyond
    ``max_pos_err_m``, ground contact (``ground_z_m``), or estimator divergence (non-finite or
    non-PSD covariance, the estimator's flag, or pose NEES above ``nees_threshold`` (if set) for
    ``nees_window_s``); ``info["termination_reason"]`` names it. ``truncated`` when the
    scenario's ``duration_s`` is reached (the env enforces it itself, so overriding the duration
    needs no ``max_episode_steps``).

    Args:
        scenario: Scenario name in ``configs/scenarios``, YAML path, mapping or ``None``.
        render_mode: ``None`` or ``"rgb_array"``.
        estimator_name: Estimator applied before ``overrides`` (used by the registered ids).
        **overrides: Section mappings merged into the scenario, e.g. ``episode={...}``.
    """

    # render_fps: one frame per control step (an instance sets its scenario's control rate),
    # so videos recorded step by step, e.g. by RecordVideo, play in real time.
    metadata = {"render_modes": ["rgb_array"], "render_fps": 100}

    def __init__(
        self,
        scenario: str | dict[str, Any] | None = None,
        render_mode: str | None = None,
        estimator_name: str | None = None,
        **overrides: Any,
    ) -> None:
        if render_mode not in (None, "rgb_array"):
            raise ConfigError(f"render_mode: got {render_mode!r}; allowed: None or 'rgb_array'")
        self.scenario: ScenarioConfig = load_scenario(scenario, overrides, estimator_name)
        self.render_mode = render_mode
        check_env_memory(self.scenario, 1)  # before anything is allocated
        self._core = SimCore(self.scenario, 1)
        core = self._core
        self.dt = core.dt
        self.max_steps = core.max_steps
        self.vehicle_params = core.vehicle_params
        self.trajectory = core.trajectory
        self.observation_space = core.observer.space
        self.action_space = spaces.Box(-1.0, 1.0, shape=(core.action_map.dim,), dtype=np.float32)
        self.hover_action = core.action_map.hover_action
        self.metadata = {**self.metadata, "render_fps": step_rate(self.scenario)}
        self._renderer: LaneRenderer | None = None
        if render_mode is not None:  # nothing is recorded, or imported, without it
            from quadslam_env.render.renderer import LaneRenderer

            self._renderer = LaneRenderer(core, 0)
        # Until the first reset, and again once an episode ends: the core would otherwise go on
        # simulating a crashed or timed-out vehicle, which no Gymnasium user should see.
        self._needs_reset = True
        self._episode_ended = False

    # ------------------------------------------------------------------ properties
    @property
    def core(self) -> SimCore:
        """The one-lane simulation core (its arrays hold the truth: for analysis only)."""
        return self._core

    @property
    def true_state(self) -> FloatArray:
        """(12,) copy of the true state (for analysis and truth-driven controllers only)."""
        return self._core.vehicle.state[0].copy()

    @property
    def landmarks(self) -> FloatArray:
        """(L, 3) true landmark positions of this episode (NED, m)."""
        return self._core.landmarks[0, : self._core.n_landmarks[0]]

    @property
    def landmark_ids(self) -> np.ndarray:
        """(L,) ids of the true landmarks (their row indices)."""
        return np.arange(self._core.n_landmarks[0])

    @property
    def t(self) -> float:
        """Time since the reset in s."""
        return float(self._core.t[0])

    @property
    def steps(self) -> int:
        """Control steps since the reset."""
        return int(self._core.steps[0])

    @property
    def estimator(self) -> BatchEstimator:
        """The estimator (of one lane; a batch estimator with B = 1)."""
        return self._core.estimator

    @estimator.setter
    def estimator(self, value: BatchEstimator) -> None:
        self._core.estimator = value

    @property
    def last_estimate(self) -> BatchEstimate:
        """Snapshot of the estimator's belief after the last reset or step (B = 1, copies,
        with landmark covariances)."""
        return self._core.estimator.lane_estimate(0)

    def reference(self, t: float | None = None) -> FlatOutputs:
        """Flat outputs of the reference at ``t`` (default: now, with a free heading the
        commanded one; at another time the trajectory's own, heading ``yaw_deg``)."""
        if t is not None:
            return self.trajectory(t)
        ref = self._core.reference([0])
        return FlatOutputs(
            pos=ref.pos[0],
            vel=ref.vel[0],
            acc=ref.acc[0],
            yaw=float(ref.yaw[0]),  # type: ignore[index]
            yaw_rate=float(ref.yaw_rate[0]),  # type: ignore[index]
        )

    def observation_from(self, estimate: BatchEstimate) -> np.ndarray:
        """The observation the env would emit now if its estimator had returned ``estimate``.

        For baselines that fly on another estimate than the env's, e.g. the truth through
        :class:`estimators.oracle.OracleBatch` in the consistency runs. ``estimate`` is a
        one-lane snapshot (B = 1). The visible-landmark count in the observation is 0 (it
        belongs to the env's own scans).
        """
        core = self._core
        t = core.t[:1]
        obs = core.observer.build(estimate, core.reference([0]), t, np.zeros(1, int))
        return obs[0]

    def action_to_inputs(self, action: FloatArray) -> tuple[float, FloatArray]:
        """Map a normalised action (4,) to (thrust N, torque (3,) N·m) for the configured mode."""
        core = self._core
        thrust, torque = core.action_map.inputs(np.asarray(action)[None], core.est.rates)
        return float(thrust[0]), torque[0]

    # ------------------------------------------------------------------ reset / step
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; options: ``initial_state`` (12,), ``landmarks`` (L, 3),
        ``randomized`` (domain-randomisation scales to pin, e.g. ``{"mass_scale": 1.2}``).

        Raises:
            ConfigError: ``seed`` is not ``None`` or an integer >= 0 (NumPy integers are
                accepted, bools are not), or bad ``options``.
        """
        opts = parse_reset_options(options)
        super().reset(seed=parse_seed(seed))
        obs, info = self._core.reset_lanes([0], [self.np_random], opts)
        self._needs_reset = self._episode_ended = False
        if self._renderer is not None:
            self._renderer.record(info)
        return obs[0], lane_info(info, 0)

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Advance one control period (``dt`` s).

        Raises:
            gymnasium.error.ResetNeeded: Before the first ``reset()``, or after a step that
                returned ``terminated`` or ``truncated`` (the episode is over).
            ActionError: ``action`` is not a finite (4,) array (5 with ``action.heading``);
                nothing is changed.
        """
        if self._needs_reset:
            why = (
                "the episode ended (terminated or truncated) on the last step"
                if self._episode_ended
                else "no episode was started"
            )
            raise gym.error.ResetNeeded(f"QuadSLAMEnv.step: {why}; call reset() before step()")
        act = validate_actions(action, None, self._core.action_map.dim)
        obs, reward, terminated, truncated, info = self._core.step(act)
        self._needs_reset = self._episode_ended = bool(terminated[0] or truncated[0])
        if self._renderer is not None:
            self._renderer.record(info)
        return obs[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), lane_info(info, 0)

    # ------------------------------------------------------------------ rendering
    def render(self) -> np.ndarray | None:
        """The frame now, (render.height_px, render.width_px, 3) uint8, or ``None`` without
        ``render_mode``.

        Panels: top-down and side views around the vehicle (reference, true and estimated
        paths, estimated pose and landmarks with 3σ ellipses, LiDAR FOV and this scan's
        returns, FastSLAM particles), position error against ±3σ and NEES against its χ²
        bounds over the last ``render.history_s``. At most ``render.fps`` frames are drawn
        per simulated second; calls in between return the last frame (read-only).
        """
        if self._renderer is None:
            return None
        return self._renderer.frame()
