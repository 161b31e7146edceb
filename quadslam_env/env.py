"""``QuadSLAMEnv``: the quadcopter simulator with an estimator in the loop (DESIGN.md §4).

Coordination only: physics lives in :mod:`quadslam_env.models` / :mod:`quadslam_env.vehicle`,
sensors in :mod:`quadslam_env.sensors`, filters in :mod:`estimators`, metrics in
:mod:`estimators.metrics`.
"""

from __future__ import annotations

import math
import time
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
from gymnasium import spaces

import estimators
from estimators.base import Estimate, health_problem
from estimators.metrics import EpisodeMetrics, step_metrics
from quadslam_env.config import ConfigError, ScenarioConfig, load_scenario
from quadslam_env.measurements import Control, LidarScan
from quadslam_env.models.rotations import FloatArray, dcm_from_euler, wrap_angle
from quadslam_env.observation import ObservationBuilder
from quadslam_env.reward import reward_terms, tilt_angle
from quadslam_env.sensors import Imu, Lidar
from quadslam_env.trajectories import Trajectory
from quadslam_env.vehicle import Vehicle
from quadslam_env.world import make_landmarks

RESET_OPTIONS = ("initial_state", "landmarks")


class ActionError(ValueError):
    """An action of the wrong shape, type or with non-finite entries."""


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
                                look-ahead offsets (3 each), in that order
    ======  ==================  ===========================================  ======

    **Action** ``Box(-1, 1, (4,))``: ``thrust_torque`` maps ``a0`` to thrust in
    ``[0, max_thrust]`` and ``a1..a3`` to ``±max_torque``; ``thrust_rates`` maps ``a1..a3`` to
    body-rate commands ``±max_rate`` tracked by an inner P loop on the gyro minus the estimated
    bias. Out-of-range actions are clipped; wrong shapes or non-finite values raise
    :class:`ActionError`.

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

    metadata: ClassVar[dict[str, Any]] = {"render_modes": ["rgb_array"], "render_fps": 10}

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
        cfg = self.scenario
        self.render_mode = render_mode
        self.dt = 1.0 / cfg.episode.control_hz
        self.max_steps = cfg.max_steps
        self.vehicle_params = cfg.vehicle.params()
        self.vehicle = Vehicle(self.vehicle_params, cfg.vehicle.physics_dt_s)
        self.imu = Imu(cfg.imu, self.vehicle_params, cfg.episode.control_hz)
        self.lidar = Lidar(cfg.lidar)
        self.trajectory = Trajectory(cfg.trajectory)
        self.estimator = estimators.make(
            cfg.estimator.name, vehicle=self.vehicle_params, **cfg.estimator.params
        )
        self._obs_builder = ObservationBuilder(cfg.observation, self.trajectory)
        self.observation_space = self._obs_builder.space
        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self._max_rate = np.radians(cfg.action.max_rate_dps)
        self._rate_gain = np.array(cfg.action.rate_gain_per_s)
        self.hover_action = np.array(
            [
                2.0 * self.vehicle_params.hover_thrust / self.vehicle_params.max_thrust - 1.0,
                0.0,
                0.0,
                0.0,
            ]
        )
        self._nees_window = max(1, round(cfg.episode.nees_window_s / self.dt))
        self._uses_truth = bool(getattr(self.estimator, "uses_truth", False))
        self.landmark_ids = np.zeros(0, dtype=int)
        self.landmarks = np.zeros((0, 3))
        self.t = 0.0
        self.steps = 0
        self.last_estimate: Estimate | None = None
        self.last_step_time_ms = math.nan
        self._history: dict[str, list[FloatArray]] = {"true": [], "est": [], "ref": []}

    # ------------------------------------------------------------------ properties
    @property
    def true_state(self) -> FloatArray:
        """(12,) copy of the true state (for analysis and truth-driven controllers only)."""
        return self.vehicle.state.copy()

    def reference(self, t: float | None = None) -> Any:
        """Flat outputs of the reference at ``t`` (default: now)."""
        return self.trajectory(self.t if t is None else t)

    def observation_from(self, estimate: Estimate) -> np.ndarray:
        """The observation the env would emit now if its estimator had returned ``estimate``.

        For baselines that fly on another estimate than the env's, e.g. the truth through
        :class:`estimators.oracle.OracleEstimator` in the consistency runs. The visible-landmark
        count in the observation is 0 (it belongs to the env's own scans).
        """
        return self._obs_builder.build(estimate, self.reference(), self.t, 0)

    # ------------------------------------------------------------------ reset
    def _parse_options(self, options: dict[str, Any] | None) -> dict[str, Any]:
        if options is None:
            return {}
        if not isinstance(options, dict):
            raise ConfigError(
                f"reset options: got {options!r}; allowed: a dict with keys {list(RESET_OPTIONS)}"
            )
        out: dict[str, Any] = {}
        for key, value in options.items():
            if key not in RESET_OPTIONS:
                raise ConfigError(
                    f"reset options.{key}: unknown key; allowed: {list(RESET_OPTIONS)}"
                )
            arr = np.asarray(value, dtype=float) if _is_numeric(value) else None
            if key == "initial_state":
                if arr is None or arr.shape != (12,) or not np.all(np.isfinite(arr)):
                    raise ConfigError(
                        f"reset options.initial_state: got {value!r}; allowed: 12 "
                        "finite numbers (ρ [m], v_B [m/s], Λ [rad], ω [rad/s])"
                    )
                if abs(arr[7]) >= math.radians(89.0):
                    raise ConfigError(
                        f"reset options.initial_state[7] (pitch): got {arr[7]}; allowed: |θ| < 89°"
                    )
            if key == "landmarks" and (
                arr is None
                or arr.ndim != 2
                or arr.shape[1] != 3
                or arr.shape[0] == 0
                or not np.all(np.isfinite(arr))
            ):
                raise ConfigError(
                    f"reset options.landmarks: got {value!r}; allowed: a non-empty "
                    "(L, 3) list of finite NED positions in m"
                )
            out[key] = arr
        return out

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        """Start an episode; options: ``initial_state`` (12,), ``landmarks`` (L, 3)."""
        opts = self._parse_options(options)
        super().reset(seed=seed)
        cfg = self.scenario
        rng_world, rng_imu, rng_lidar, rng_est, rng_init = self.np_random.spawn(5)
        if "landmarks" in opts:
            self.landmarks = opts["landmarks"]
            self.landmark_ids = np.arange(self.landmarks.shape[0])
        else:
            self.landmark_ids, self.landmarks = make_landmarks(
                cfg.landmarks, self.trajectory.center, rng_world
            )
        if "initial_state" in opts:
            state0 = opts["initial_state"].copy()
        else:
            ep = cfg.episode
            state0 = np.concatenate(
                [
                    ep.initial_position,
                    ep.initial_velocity,
                    np.radians(ep.initial_euler_deg),
                    np.zeros(3),
                ]
            )
        self.vehicle.reset(state0)
        self.imu.reset(rng_imu)
        self.lidar.reset(rng_lidar)
        cov0 = np.diag(cfg.estimator.initial_cov_diag)
        mean0 = state0.copy()
        if cfg.estimator.sample_initial_error:
            mean0 += np.sqrt(np.diag(cov0)) * rng_init.standard_normal(12)
        mean0[6:9] = wrap_angle(mean0[6:9])
        known = (self.landmark_ids, self.landmarks.copy()) if cfg.estimator.known_map else None
        self.estimator.reset(mean0, cov0, rng_est, known_landmarks=known)
        self.t = 0.0
        self.steps = 0
        self._n_visible = 0
        self._nees_run = 0
        self._episode = EpisodeMetrics()
        self._history = {"true": [], "est": [], "ref": []}
        est = self._snapshot()
        ref = self.trajectory(0.0)
        info = self._metrics(est, ref, dcm_from_euler(state0[6:9]))
        self._record(est, ref)
        return self._obs_builder.build(est, ref, 0.0, 0), info

    # ------------------------------------------------------------------ step
    def _validate_action(self, action: Any) -> FloatArray:
        try:
            arr = np.asarray(action)
            if arr.dtype.kind in "cmM":  # complex, timedelta, datetime: not real numbers
                raise TypeError(f"dtype {arr.dtype}")
            arr = arr.astype(float, copy=False)
        except (TypeError, ValueError, OverflowError) as exc:
            raise ActionError(
                f"action: got {action!r}; allowed: 4 finite numbers in [-1, 1]"
            ) from exc
        if arr.shape != (4,):
            raise ActionError(f"action: got shape {arr.shape}; allowed: shape (4,) in [-1, 1]")
        if not np.all(np.isfinite(arr)):
            raise ActionError(
                f"action: got non-finite values {arr.tolist()}; allowed: 4 finite "
                "numbers in [-1, 1]"
            )
        return np.clip(arr, -1.0, 1.0)

    def action_to_inputs(self, action: FloatArray) -> tuple[float, FloatArray]:
        """Map a normalised action to (thrust N, torque (3,) N·m) for the configured mode."""
        p = self.vehicle_params
        thrust = 0.5 * (action[0] + 1.0) * p.max_thrust
        if self.scenario.action.mode == "thrust_torque":
            return thrust, action[1:] * p.max_torque
        # Inner rate loop on the estimate's rates (gyro minus estimated bias for EKF-SLAM).
        rates_cmd = action[1:] * self._max_rate
        rates_hat = self.last_estimate.rates if self.last_estimate is not None else np.zeros(3)
        return thrust, p.inertia @ (self._rate_gain * (rates_cmd - rates_hat))

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        """Advance one control period (``dt`` s)."""
        act = self._validate_action(action)
        thrust, torque = self.action_to_inputs(act)
        mean_rates = self.vehicle.step(thrust, torque, self.dt)
        self.steps += 1
        self.t = self.steps * self.dt
        state = self.vehicle.state
        dcm = dcm_from_euler(state[6:9])
        control = Control(
            thrust=self.vehicle.applied_thrust,
            torque=np.array(self.vehicle.applied_torque, dtype=float),
        )
        imu = self.imu.sample(self.t, state[3:6], mean_rates, control.thrust)
        scan: LidarScan | None = None
        if self.steps % self.scenario.lidar_every == 0:
            scan = self.lidar.scan(self.t, state[0:3], dcm, self.landmark_ids, self.landmarks)
            self._n_visible = scan.count
        tic = time.perf_counter()
        self.estimator.predict(imu, control, self.dt)
        if scan is not None:
            self.estimator.update(scan)
        est = self._snapshot()
        step_ms = 1e3 * (time.perf_counter() - tic)
        ref = self.trajectory(self.t)
        info = self._metrics(est, ref, dcm)
        self.last_step_time_ms = step_ms
        if self.scenario.episode.report_step_time:
            info["est_step_time_ms"] = step_ms
        reason = self._termination_reason(est, info)
        terminated = reason is not None
        truncated = not terminated and self.steps >= self.max_steps
        terms = reward_terms(
            self.scenario.reward,
            state[0:3],
            dcm @ state[3:6],
            state[8],
            ref,
            act,
            self.hover_action,
            terminated,
        )
        info.update(terms)
        info["termination_reason"] = reason or ""
        reward = float(sum(terms.values()))
        self._episode.add(info)
        if terminated or truncated:
            info.update(self._episode.summary())
        self._record(est, ref)
        obs = self._obs_builder.build(est, ref, self.t, self._n_visible)
        return obs, reward, terminated, truncated, info

    # ------------------------------------------------------------------ helpers
    def _snapshot(self) -> Estimate:
        if self._uses_truth:
            self.estimator.set_truth(self.vehicle.state, self.landmark_ids, self.landmarks)
        self.last_estimate = self.estimator.estimate()
        return self.last_estimate

    def _metrics(self, est: Estimate, ref: Any, dcm: FloatArray) -> dict[str, Any]:
        state = self.vehicle.state
        info: dict[str, Any] = step_metrics(
            state, dcm, est, self.landmark_ids, self.landmarks, self.imu.total_bias
        )
        for key, diag in (("est_nis", "nis"), ("est_ess", "ess")):
            value = float(est.diagnostics.get(diag, math.nan))
            if not math.isnan(value):  # absent where it does not apply (see step_metrics)
                info[key] = value
        info["est_n_visible"] = float(self._n_visible)
        dp = state[0:3] - ref.pos
        info["track_pos_err_m"] = math.sqrt(float(dp @ dp))
        info["t"] = self.t
        return info

    def _termination_reason(self, est: Estimate, info: dict[str, Any]) -> str | None:
        ep = self.scenario.episode
        state = self.vehicle.state
        if not np.all(np.isfinite(state)):
            return "vehicle_state_non_finite"
        if tilt_angle(state[6:9]) > math.radians(ep.max_tilt_deg):
            return "tilt_limit"
        if info["track_pos_err_m"] > ep.max_pos_err_m:
            return "position_error_limit"
        if ep.ground_z_m is not None and state[2] > ep.ground_z_m:
            return "ground_contact"
        problem = health_problem(est)
        if problem is not None:
            return f"estimator_diverged: {problem}"
        nees_pose = info.get("est_nees_pose", math.nan)
        if nees_pose == math.inf:
            return "estimator_diverged: pose covariance not positive semi-definite"
        limit = ep.nees_threshold
        self._nees_run = self._nees_run + 1 if limit is not None and nees_pose > limit else 0
        if self._nees_run >= self._nees_window:
            return "estimator_diverged: NEES above threshold"
        return None

    def _record(self, est: Estimate, ref: Any) -> None:
        if self.render_mode is None:
            return
        self._history["true"].append(self.vehicle.state[0:3].copy())
        self._history["est"].append(est.position.copy())
        self._history["ref"].append(ref.pos.copy())

    def render(self) -> np.ndarray | None:
        """An RGB frame (H, W, 3) of paths, landmarks and the LiDAR FOV, or ``None``."""
        if self.render_mode != "rgb_array":
            return None
        from quadslam_env.rendering import render_frame

        est = self.last_estimate  # None before the first reset: an empty frame is drawn
        return render_frame(
            np.array(self._history["true"]).reshape(-1, 3),
            np.array(self._history["est"]).reshape(-1, 3),
            np.array(self._history["ref"]).reshape(-1, 3),
            self.landmarks,
            est.landmark_means if est is not None else np.zeros((0, 3)),
            self.vehicle.state,
            self.scenario.lidar.azimuth_fov_deg,
            min(5.0, self.scenario.lidar.range_max_m),
        )


def _is_numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return True
