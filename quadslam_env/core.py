"""The batched simulation: B quadcopter episodes ("lanes") stepped in lockstep (docs/design.md §9).

:class:`SimCore` owns every lane's true vehicle, IMU, LiDAR, landmark map, reference and the
estimator of all lanes, as arrays with a leading batch axis. It is the only place that
sequences a step; the scalar :class:`~quadslam_env.env.QuadSLAMEnv` is its one-lane case and
:class:`~quadslam_env.vector_env.QuadSLAMVectorEnv` the B-lane case, so lane i of a vector env
seeded with s + i is the scalar env seeded with s + i.

Randomness: each lane has its own generator (the scalar env's ``np_random``), which spawns five
children at every reset — landmarks, IMU, LiDAR, estimator, initial estimation error — exactly
as the scalar env always has. The wind (:mod:`quadslam_env.sim.wind`: held over each step, reported
in ``info``, advanced after the step; told to the estimator only with ``wind.inform_estimator``)
spawns its gusts' generator from the world child, and domain randomisation
(:mod:`quadslam_env.sim.randomize`, the truth's parameters scaled per lane and episode; told with
``randomize.inform_estimator``) its generator from the initial-error child, and a fault of
the world (:mod:`quadslam_env.sim.faults`: held over each step, applied before the vehicle flies
it) its generator from the world child after the wind's, so no other stream changes when any of
them is on.

Sensor rates, latency and association (docs/timing.md, docs/design.md §4) are the run-time's:
a control period's IMU samples (:mod:`quadslam_env.runtime.imu_period`; each an average over
its own period, each prediction given the white-noise std per step h, ``σ = ND/√h``,
:attr:`SimCore.imu_input_sigma`), the filter replayed at a slower IMU's instants
(:mod:`quadslam_env.runtime.imu_replay`), a scan applied at its own time after
``lidar.delay_steps`` (:mod:`quadslam_env.runtime.scan_delay`), an action applied
``action.delay_steps`` after the agent gave it
(:class:`~quadslam_env.episode.actions.ActionDelay`; the estimator told the thrust and torque
applied), and the scans, typed by what the estimator is told (:mod:`quadslam_env.sim.scans`),
handed over by the component of ``lidar.association``
(:mod:`quadslam_env.runtime.association`); the step calls each the same way in every mode.
"""

from __future__ import annotations

import copy
import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np

from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.episode.actions import ActionDelay, ActionMap
from quadslam_env.episode.observation import ObservationBuilder
from quadslam_env.episode.reward import REWARD_KEYS, Reward, tracking_errors
from quadslam_env.episode.start import initial_state, settle_time
from quadslam_env.episode.termination import OutputGuard, Termination
from quadslam_env.estimation.health import health_codes, position_std
from quadslam_env.estimation.protocol import BatchEstimator, ReservesLandmarks, UsesTruth
from quadslam_env.estimation.registry import make
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.metrics.episode import EpisodeMetrics, input_columns
from quadslam_env.metrics.step import METRIC_KEYS
from quadslam_env.models.frames import dcm_from_euler_batch, wrap_angle
from quadslam_env.models.imu_noise import white_noise_sigma
from quadslam_env.runtime.association import association_for
from quadslam_env.runtime.imu_period import fast_period_samples, period_sample
from quadslam_env.runtime.integrity import IntegrityTerms
from quadslam_env.runtime.period_log import Sample, predict_samples
from quadslam_env.runtime.scan_delay import copies_for
from quadslam_env.sim.faults import FaultBatch
from quadslam_env.sim.imu import ImuBatch
from quadslam_env.sim.lidar import LidarBatch
from quadslam_env.sim.randomize import Randomizer
from quadslam_env.sim.scans import Scans
from quadslam_env.sim.trajectories import FlatOutputs, Trajectory
from quadslam_env.sim.vehicle import VehicleBatch
from quadslam_env.sim.wind import WindBatch
from quadslam_env.sim.world import landmark_capacity, make_landmarks, put_landmarks
from quadslam_env.types import EUL, POS, RATE, STATE_DIM, FloatArray

# The rows of a step's (K, B) array of per-lane terms: the metrics, then the terms the core
# adds, then the reward terms and the reward. ``info`` maps each key to its row (a contiguous
# (B,) array), and the episode sums read the same rows.
_CORE_KEYS = ("est_nis", "est_ess", "est_n_visible", "track_pos_err_m", "t")
_ROWS = {key: j for j, key in enumerate((*METRIC_KEYS, *_CORE_KEYS, *REWARD_KEYS, "reward"))}
_NIS, _ESS, _N_VISIBLE, _TRACK, _T = (_ROWS[key] for key in _CORE_KEYS)
_NEES_POSE = _ROWS["est_nees_pose"]
_REWARD0, _REWARD = _ROWS[REWARD_KEYS[0]], _ROWS["reward"]
_CORE_ROWS = tuple((key, _ROWS[key]) for key in _CORE_KEYS)
_REWARD_ROWS = tuple((key, _ROWS[key]) for key in REWARD_KEYS)
_EPISODE_ROWS = input_columns(_ROWS)

LaneCheck = Callable[[FloatArray, np.ndarray, np.ndarray, np.ndarray, list[str]], bool]
"""A check across lanes after the termination checks (the team env's collisions): given
the (B, 12) true states, the (B,) bool lanes stepped now, and the (B,) terminated and
truncated flags and the B reasons, which it updates in place, whether a lane that went on
ends here."""


class SimCore:
    """B lanes of the quadcopter-with-estimator simulation.

    Args:
        scenario: The validated scenario (every lane runs the same one).
        num_lanes: B ≥ 1.
        references: The lanes' references (default: the scenario's trajectory in every
            lane; a :class:`~quadslam_env.sim.trajectories.LaneTrajectory` shifts each lane's).
        lane_check: Run after the termination checks of each step (:data:`LaneCheck`).

    Attributes:
        steps: (B,) control steps since each lane's reset.
        t: (B,) lane times in s.
        landmarks: (B, Lmax, 3) true landmark positions (NED, m); lane i uses the first
            ``n_landmarks[i]`` rows, whose ids are their row indices.
        est: The estimator's belief after the last reset or step.
        association: The data-association component (:mod:`quadslam_env.runtime.association`):
            labeled scans, or unlabeled returns and the association bookkeeping.
        last_scan: The scans taken in the last step (:class:`~quadslam_env.sim.scans.Scans`: the
            lanes that scanned, the rows of ``meas`` that hold a return), or ``None`` when no
            lane scanned then; references, not copies (for the renderer).
        last_rates: (B, 3) true body rates in rad/s averaged over the last step (the IMU's
            noise-free gyro input), for analyses along the truth (``estimators.pcrb``).
    """

    def __init__(
        self,
        scenario: ScenarioConfig,
        num_lanes: int,
        references: Trajectory | None = None,
        lane_check: LaneCheck | None = None,
    ) -> None:
        cfg = scenario
        b = int(num_lanes)
        self.scenario = cfg
        self.num_lanes = b
        self.dt = 1.0 / cfg.episode.control_hz
        self.max_steps = cfg.max_steps
        self.vehicle_params = cfg.vehicle.params()
        self.vehicle = VehicleBatch(self.vehicle_params, cfg.vehicle.physics_dt_s, b)
        self.wind = WindBatch(cfg.wind, self.dt, b)
        self.vehicle.wind_n = self.wind.velocity  # None in still air
        self.randomizer = Randomizer(cfg.randomize, self.vehicle_params, b)
        self.imu = ImuBatch(cfg.imu, self.vehicle_params, cfg.imu_rate_hz, b)
        self._imu_per_step, self._steps_per_imu = cfg.imu_per_step, cfg.steps_per_imu
        prop_hz = max(cfg.imu_rate_hz, cfg.episode.control_hz)  # 1/h, the prediction rate
        self.imu_input_sigma = (
            white_noise_sigma(cfg.imu.accel_noise_density, prop_hz),
            white_noise_sigma(cfg.imu.gyro_noise_density, prop_hz),
        )
        """White-noise std (accelerometer m/s², gyro rad/s) of the IMU input per prediction
        step: ``ND √(1/h)`` for the step h = min(dt, T_IMU) (module docstring)."""
        self.lidar = LidarBatch(cfg.lidar, b)
        self.trajectory = Trajectory(cfg.trajectory)
        self.references = self.trajectory if references is None else references
        self.lane_check = lane_check
        capacity = landmark_capacity(cfg.landmarks)
        self.landmarks = np.zeros((b, capacity, 3))
        self.n_landmarks = np.zeros(b, dtype=np.int64)
        self.faults = FaultBatch(cfg, self.trajectory, self.vehicle_params.mass, b)
        capacity += self.faults.extra_landmarks  # the phantom's id, in the estimator's map
        self.estimator = make(
            cfg.estimator.name, b, capacity, vehicle=self.vehicle_params, **cfg.estimator.params
        )
        self._truth: BatchEstimator | None = None  # privileged observations, built on demand
        # A second run of the estimator from copies: the filter at the IMU instants of a
        # slower IMU, or at each lane's newest delivered scan of a delayed LiDAR.
        self._copies = copies_for(cfg, self.estimator, self.vehicle_params)
        self.action_map = ActionMap(cfg.action, self.vehicle_params)
        delay = cfg.action.delay_steps  # a delayed action: the agent's last d in a ring
        self._actions = ActionDelay(delay, b, self.action_map.hover_action) if delay else None
        # A free heading (action.heading): the reference's ψ_d and ψ̇_d are lane state, set by
        # the action's heading channel; None when the trajectory prescribes the heading.
        self._heading: tuple[FloatArray, FloatArray] | None = None
        if cfg.action.heading:
            self._heading = (np.zeros(b), np.zeros(b))
        self._heading0 = math.radians(cfg.trajectory.yaw_deg)
        self.reward = Reward(cfg.reward, self.action_map.hover_action)
        self.observer = ObservationBuilder(cfg.observation, self.references)
        self.steps = np.zeros(b, dtype=np.int64)
        self._all_lanes = np.ones(b, dtype=bool)
        self.t: FloatArray = np.zeros(b)
        self.n_visible = np.zeros(b, dtype=np.int64)
        unlabeled = cfg.lidar.association == "unknown"
        self.association = association_for(cfg.lidar.association, b)
        self._no_lanes = np.zeros(b, dtype=bool)
        self._state0 = initial_state(cfg, self.trajectory, self.vehicle_params.mass)
        self.settle_s = settle_time(cfg, self.trajectory, self._state0)
        """End of the transient, s: the episode's ``*_steady`` summaries cover t > settle_s."""
        self.integrity = IntegrityTerms(cfg.integrity, b, self.settle_s)  # the monitor, if any
        self.integrity.configure((self.estimator,))
        self.episode = EpisodeMetrics(b, association=unlabeled, settle_s=self.settle_s)
        self.termination = Termination(cfg.episode, self.dt, b, self.max_steps)
        self._guard = OutputGuard(_ROWS, cfg.reward.termination_penalty)  # the last defence
        self._max_cov_trace = cfg.episode.max_cov_trace or math.inf  # null (> 0 otherwise)
        self._cov0 = np.diag(cfg.estimator.initial_cov_diag)
        self.last_scan: Scans | None = None
        self.last_rates: FloatArray = np.zeros((b, 3))
        self.est: BatchEstimate = self._snapshot()

    # ------------------------------------------------------------------ reset
    def reset_lanes(
        self,
        lanes: Sequence[int] | np.ndarray,
        rngs: Sequence[np.random.Generator],
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, FloatArray]]:
        """Start new episodes in ``lanes`` (k,).

        Args:
            lanes: Lane indices.
            rngs: Each lane's generator (k,); five children are spawned from it.
            options: Parsed options (:func:`parse_reset_options`) applied to every lane
                (``randomized``: scales pinned, :mod:`quadslam_env.sim.randomize`).

        Returns:
            ``(obs (k, n) float32, info)`` with info values (k,) (NaN where a term does not
            apply).
        """
        cfg = self.scenario
        opts = options or {}
        lanes = np.asarray(lanes, dtype=np.int64)
        k = lanes.shape[0]
        self.randomizer.check_pins(opts.get("randomized"))
        self._prepare_estimator(opts)
        children = [rng.spawn(5) for rng in rngs]  # world, imu, lidar, estimator, initial error
        states0 = np.empty((k, STATE_DIM))
        mean0 = np.empty((k, STATE_DIM))
        sigma0 = np.sqrt(np.diag(self._cov0))
        for j, lane in enumerate(lanes.tolist()):
            rng_world, rng_init = children[j][0], children[j][4]
            if "landmarks" in opts:
                points = opts["landmarks"]
            else:
                points = make_landmarks(cfg.landmarks, self.trajectory.center, rng_world)[1]
            self.landmarks = put_landmarks(self.landmarks, self.n_landmarks, lane, points)
            states0[j] = opts.get("initial_state", self._state0)
            mean0[j] = states0[j]
            if cfg.estimator.sample_initial_error:
                mean0[j] += sigma0 * rng_init.standard_normal(STATE_DIM)
        mean0[:, EUL] = wrap_angle(mean0[:, EUL])
        rand = self.randomizer
        rand.begin(lanes, [c[4] for c in children], opts.get("randomized"), self.vehicle)
        self.vehicle.reset(lanes, states0)
        self.wind.reset(lanes, [c[0] for c in children])
        self.imu.reset(lanes, [c[1] for c in children])
        self.lidar.reset(lanes, [c[2] for c in children])
        rand.finish(self.imu, self.lidar, self.wind)
        worlds = [c[0] for c in children]  # the faults' spawn after the wind's
        self.faults.reset(lanes, worlds, self.landmarks, self.n_landmarks, self.imu)
        if self._steps_per_imu > 1:  # a slower IMU's first sample, held until the next
            vel = self.vehicle.air_velocity()[lanes]
            self.imu.prime(lanes, vel, states0[:, RATE], self.vehicle.applied_thrust[lanes])
        self._reset_estimator(lanes, mean0, [c[3] for c in children])
        if self._actions is not None:
            self._actions.reset(lanes)
        self.steps[lanes] = 0
        self.t[lanes] = 0.0
        if self.last_scan is not None:  # a reset lane's last scan belongs to its old episode
            scanned = self.last_scan.lanes
            kept = scanned[~np.isin(scanned, lanes)]
            self.last_scan = self.last_scan.only(kept) if kept.size else None
        if self._heading is not None:
            self._heading[0][lanes] = self._heading0
            self._heading[1][lanes] = 0.0
        self.n_visible[lanes] = 0
        self.termination.reset(lanes)
        self.episode.reset(lanes)
        est = self._snapshot()
        self.integrity.reset(lanes, est)
        self._associate(est, None, np.isin(np.arange(self.num_lanes), lanes))
        ref = self.reference()
        _, info = self._metrics(est, ref)
        obs = self.observer.build(est, ref, self.t, self.n_visible, self.integrity.levels(info))
        return obs[lanes], {key: value[lanes] for key, value in info.items()}

    def _prepare_estimator(self, opts: dict[str, Any]) -> None:
        """Before a reset changes anything: rebuild the second run from copies if a user
        swapped the estimator, and make room for a map the reset ``opts`` bring (so a map
        that cannot fit fails here)."""
        copies = self._copies
        if copies is not None and copies.output is not self.estimator:  # a user swapped it
            copies = self._copies = copies_for(self.scenario, self.estimator, self.vehicle_params)
        if "landmarks" in opts and isinstance(self.estimator, ReservesLandmarks):
            count = len(opts["landmarks"]) + self.faults.extra_landmarks
            self.estimator.reserve_landmarks(count)
            if copies is not None:
                copies.reserve_landmarks(count)

    def _reset_estimator(
        self, lanes: np.ndarray, mean0: FloatArray, rngs: list[np.random.Generator]
    ) -> None:
        """Reset the estimator's ``lanes`` (k,) (and their copies) at the means ``mean0``
        (k, 12) with the initial covariance, each with its generator of ``rngs`` (k,); with a
        known map, the lanes' true landmarks; first tell them their draw's vehicle if asked."""
        known, n = None, self.n_landmarks
        if self.scenario.estimator.known_map:
            known = [(np.arange(n[i]), self.landmarks[i, : n[i]].copy()) for i in lanes.tolist()]
        cov0 = np.broadcast_to(self._cov0, (lanes.shape[0], STATE_DIM, STATE_DIM)).copy()
        held = () if self._copies is None else self._copies.held
        self.randomizer.inform(lanes, (self.estimator, *held))
        if self._copies is not None:  # rng copies taken before the output's reset draws
            self._copies.reset_lanes(lanes, mean0, cov0, copy.deepcopy(rngs), known)
        self.estimator.reset_lanes(lanes, mean0, cov0, rngs, known)

    # ------------------------------------------------------------------ step
    def step(
        self, action: FloatArray, active: np.ndarray | None = None
    ) -> tuple[np.ndarray, FloatArray, np.ndarray, np.ndarray, dict[str, Any]]:
        """Advance the ``active`` lanes by one control period (``dt`` s).

        Args:
            action: (B, 4) validated actions in [-1, 1] (rows of inactive lanes are ignored).
            active: (B,) bool, lanes to advance (default: all). Inactive lanes keep their
                state; their outputs are meaningless.

        Returns:
            ``(obs (B, n) float32, reward (B,), terminated (B,), truncated (B,), info)``; info
            maps each term to a (B,) float array (NaN where it does not apply, episode
            summaries only in lanes that ended) and ``termination_reason`` to a list of B
            strings (empty where the lane did not fail).
        """
        act = action if active is None else np.where(active[:, None], action, 0.0)
        active = self._all_lanes if active is None else active
        thrust, torque = self._command(act, active)
        t_next = (self.steps + active) * self.dt  # the lanes' times after the step
        self.faults.advance(t_next, active, self.landmarks, self.imu)
        samples = self._fly(thrust, torque, active)
        scans = self._scan(active)
        timed = self.scenario.episode.report_step_time
        tic = time.perf_counter() if timed else 0.0
        refreshed, applied = self._estimate(samples, scans, active)
        est = self._snapshot()
        self._associate(est, applied, refreshed)
        toc = time.perf_counter() if timed else 0.0
        ref = self.reference()
        values, info = self._metrics(est, ref)
        if timed:  # the batch's estimator time per lane stepped
            per_lane = 1e3 * (toc - tic) / max(1, int(active.sum()))
            info["est_step_time_ms"] = np.full(self.num_lanes, per_lane)
        state = self.vehicle.state
        terminated, truncated, reasons, ended = self.termination.check(
            state, values[_TRACK], values[_NEES_POSE],
            health_codes(est, self._max_cov_trace), active, self.steps,
        )  # fmt: skip
        if self.lane_check is not None:  # across lanes: the team env's collisions
            ended = self.lane_check(state, active, terminated, truncated, reasons) or ended
        ended = self.integrity.terminate(info, active, terminated, truncated, reasons) or ended
        std = position_std(est) if self.scenario.reward.pos_std_weight > 0.0 else None
        self.reward.terms(state, ref, act, terminated, values[_REWARD0 : _REWARD + 1], std)
        self.integrity.penalise(values[_REWARD], info)
        obs = self.observer.build(est, ref, self.t, self.n_visible, self.integrity.levels(info))
        ended = self._guard.check(obs, values, active, terminated, truncated, reasons) or ended
        info.update({key: values[row] for key, row in _REWARD_ROWS})
        self.episode.add_columns(values, _EPISODE_ROWS, active)
        self.episode.add_association(info, active)
        self.integrity.add(info, active)
        if ended:
            done = terminated | truncated
            summaries = self.episode.summary() | self.faults.summary() | self.integrity.summary()
            for key, value in summaries.items():
                info[key] = np.where(done, value, math.nan)
        info["termination_reason"] = reasons
        self.wind.advance(active)  # info holds the wind of this step; now the next one's
        return obs, values[_REWARD], terminated, truncated, info

    # ------------------------------------------------------------------ step parts
    def _command(self, act: FloatArray, active: np.ndarray) -> tuple[FloatArray, FloatArray]:
        """The thrust (B,) N and torque (B, 3) N·m of this period from the agent's actions
        ``act`` (B, 4): the delayed ones where ``action.delay_steps`` > 0; a free heading's
        reference turns at the commanded rate."""
        applied = act if self._actions is None else self._actions.apply(act, active, self.steps)
        thrust, torque = self.action_map.inputs(applied, self.est.rates)
        if self._heading is not None:
            heading, rate = self._heading
            np.copyto(rate, self.action_map.heading_rate(applied), where=active)
            np.copyto(heading, wrap_angle(heading + rate * self.dt), where=active)
        return thrust, torque

    def _fly(self, thrust: FloatArray, torque: FloatArray, active: np.ndarray) -> list[Sample]:
        """Integrate the ``active`` lanes over the control period and advance their clocks.

        Returns:
            The period's IMU samples (:data:`~quadslam_env.runtime.period_log.Sample`): one at or
            below the control rate, m with an IMU m times faster.
        """
        vehicle, imu = self.vehicle, self.imu
        if self._imu_per_step == 1:
            self.last_rates = vehicle.step(thrust, torque, self.dt, active)
            self._tick(active)
            rates, every = self.last_rates, self._steps_per_imu
            return [period_sample(vehicle, imu, self.t, rates, self.steps, every, active)]
        samples, self.last_rates = fast_period_samples(
            vehicle, imu, self.t, self.dt, self._imu_per_step, thrust, torque, active
        )
        self._tick(active)
        return samples

    def _tick(self, active: np.ndarray) -> None:
        """Count the period in the ``active`` lanes' steps and times."""
        self.steps += active
        self.t = (self.steps * self.dt).astype(np.float64, copy=False)

    def _scan(self, active: np.ndarray) -> Scans | None:
        """The scans of the ``active`` lanes due to scan at their new step (``None``: none),
        of the kind the association takes (in the world of the fault, and corrupted by it);
        sets :attr:`last_scan` and the lanes' landmark counts in view."""
        state = self.vehicle.state
        scanning = (active & (self.steps % self.scenario.lidar_every == 0)).nonzero()[0]
        self.last_scan = None
        if not scanning.size:
            return None
        pos, dcm = state[:, POS], dcm_from_euler_batch(state[:, EUL])
        points, counts = self.faults.scan_world(pos, dcm, self.landmarks, self.n_landmarks)
        scans = self.association.scan(self.lidar, pos, dcm, points, counts, scanning)
        self.faults.corrupt(scans)
        self.n_visible[scanning] = scans.n_returns[scanning]
        self.last_scan = scans
        return scans

    def _estimate(
        self, samples: list[Sample], scans: Scans | None, active: np.ndarray
    ) -> tuple[np.ndarray, Scans | None]:
        """Run the estimator over the period: a prediction per IMU sample and the scans, or
        through the second run from copies (slow IMU, delayed LiDAR), which may replace it.

        Returns:
            (B,) bool lanes rebuilt from the copies' filter; the scans applied (or ``None``).
        """
        copies = self._copies
        if copies is None:
            h = self.dt / self._imu_per_step
            self.wind.inform(self.estimator)
            predict_samples(self.estimator, samples, self.imu_input_sigma, h, active)
            if scans is not None:
                scans.apply(self.estimator, self.t, self.lidar.sigma)
            return self._no_lanes, scans
        self.estimator = copies.step(
            self.estimator, self.steps, active, samples, self.imu_input_sigma, scans,
            self.lidar.sigma,
        )  # fmt: skip
        return copies.refreshed, copies.applied

    def _associate(self, est: BatchEstimate, scans: Scans | None, changed: np.ndarray) -> None:
        """The association component's ``update`` (``association.Association``), with the truth."""
        truth = (self.vehicle.state, self.landmarks, self.n_landmarks)
        self.association.update(est, self.estimator, scans, changed, *truth)

    # ------------------------------------------------------------------ helpers
    def _snapshot(self) -> BatchEstimate:
        if self.estimator.uses_truth:  # then it UsesTruth (registry.make checks)
            cast(UsesTruth, self.estimator).set_truth(
                self.vehicle.state, self.landmarks, self.n_landmarks
            )
        self.est = self.estimator.estimate()
        return self.est

    def true_observation(self) -> np.ndarray:
        """Observations (B, n) float32 built from the *true* state (the layout of the env's).

        Privileged information for training critics only (``agents.rl.asymmetric``); the env's
        own observations come from the estimate. With ``pos_uncertainty`` its entries are 0,
        the wind blocks hold the true wind (steady plus gust) the simulator holds then."""
        if self._truth is None:
            self._truth = make("oracle", self.num_lanes, self.landmarks.shape[1])
        cast(UsesTruth, self._truth).set_truth(self.vehicle.state, self.landmarks, self.n_landmarks)
        truth, ref = self._truth.estimate(), self.reference()
        return self.observer.build(truth, ref, self.t, self.n_visible, wind=self.wind.current)

    def reference(self, lanes: Sequence[int] | None = None) -> FlatOutputs:
        """Reference of every lane (or of ``lanes``) at its current time; with a free heading
        its ψ_d and ψ̇_d are the lanes' commanded ones."""
        idx = slice(None) if lanes is None else np.asarray(lanes)
        ref = self.references.batch(self.t[idx], lanes)
        if self._heading is None:
            return ref
        heading, rate = self._heading
        return dataclasses.replace(ref, yaw=heading[idx].copy(), yaw_rate=rate[idx].copy())

    def _metrics(self, est: BatchEstimate, ref: FlatOutputs) -> tuple[FloatArray, dict[str, Any]]:
        """The step's per-lane terms: ``(values (K, B), info)``, with the rows of ``values``
        named by ``_ROWS`` (the reward rows left to fill) and ``info`` mapping the terms that
        apply to their rows, then the association's terms. A new array per step: an info dict
        must outlive the step."""
        state = self.vehicle.state
        values = np.empty((len(_ROWS), self.num_lanes))
        keys = self.association.metric_columns(
            state, self.faults.metric_estimate(est), self.landmarks, self.imu.total_bias, values,
            self.wind.velocity,
        )  # fmt: skip
        diagnostics = est.diagnostics
        values[_NIS] = diagnostics.get("nis", math.nan)
        values[_ESS] = diagnostics.get("ess", math.nan)
        values[_N_VISIBLE] = self.n_visible
        tracking_errors(state, ref.pos, values[_TRACK])
        values[_T] = self.t
        info: dict[str, Any] = {key: values[row] for key, row in keys}
        for key, row in _CORE_ROWS:
            info[key] = values[row]
        info.update(self.wind.info())
        info.update(self.randomizer.info())
        info.update(self.association.info())
        info.update(self.faults.info())
        info.update(self.integrity.info(est, state))
        return values, info
