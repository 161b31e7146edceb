"""``quadslam study bound``: each scenario's posterior Cramér–Rao bound next to its estimator.

The scenario is flown as usual (DF-LQR on the scenario's estimator, the seeds as lanes of one
vector env through :func:`agents.evaluation.episodes.run_episodes`), while an observer records each
lane's truth: states, the noise-free IMU input and the landmarks truly visible at each scan.
Along each seed's true trajectory :func:`estimators.pcrb.slam_bound` then computes the PCRB
of EKF-SLAM's model (the SLAM bound with landmark states when the map is unknown, the
localisation bound with a known map), and the study puts the bound's RMSE-equivalent
``√(mean_k trace B_k)`` of the position, inertial velocity and attitude (rotation angle) next
to the estimator's RMSE over the same steps, for the whole episode and its steady state (the
second half, ``t > T/2``).

**The bound's model** is the truth's data model in EKF-SLAM's strapdown form
(:func:`bound_model`): the IMU's white noise as the only process noise (the estimator's extra
Q is a tuning, not part of the simulated world), bias states when the IMU is biased, the
scenario's pose prior and map. It bounds estimators that use the IMU as their input; one that
also uses the applied control through the vehicle's dynamics (the dynamics-based FastSLAM) has
more information and is not bound by it.

**The map** (unknown map, known association): the landmark block of the same bound next to
the estimate's map RMSE, per step and per landmark (:mod:`agents.lab.estimator_studies.bound_map`).

**Reading the numbers.** The PCRB bounds the mean-square error over the prior and the noise, so
compare it with the error pooled over seeds, ``√(mean over seeds of MSE)`` (``pooled``); a
single seed can fall below it (the initial error drawn from P0 is small on some seeds), and
so can the median over seeds.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from agents.lab.estimator_studies.bound_map import MapSeries, landmark_sq_errors, map_series
from estimators.ekf.settings import EkfSlamSettings
from estimators.pcrb import BoundModel, TruthRecord, error_bounds, slam_bound
from quadslam_env.metrics.step import step_metrics
from quadslam_env.models.frames import dcm_from_euler, wrap_angle
from quadslam_env.models.imu_noise import white_noise_sigma
from quadslam_env.types import EUL, POS, POSE_DIM, VEL, FloatArray

BLOCKS = (
    ("pos", "m", 1.0, "pos_m2"),
    ("vel", "mps", 1.0, "vel_m2ps2"),
    ("att", "deg", math.degrees(1.0), "att_rad2"),
)
"""The error blocks: name, unit suffix of the JSON keys, factor from SI (rad → deg), key of
the bound's trace (:func:`estimators.pcrb.error_bounds`)."""


@dataclass
class _Lane:
    """Per-step recordings of one episode."""

    dt: float
    landmarks: FloatArray
    states: list[FloatArray] = field(default_factory=list)
    rates: list[FloatArray] = field(default_factory=list)
    scan_steps: list[int] = field(default_factory=list)
    scan_ids: list[np.ndarray] = field(default_factory=list)
    err_norm: list[FloatArray] = field(default_factory=list)  # pos m, vel m/s, att rad
    err_axes: list[FloatArray] = field(default_factory=list)  # pos (3), vel_N (3), Euler (3)
    filter_var: list[FloatArray] = field(default_factory=list)  # pose-cov diagonal (9)
    map_err2: list[FloatArray] = field(default_factory=list)  # (L,) ‖l̂ − l‖², NaN unmapped

    def truth(self) -> TruthRecord:
        return TruthRecord(
            dt=self.dt,
            state=np.array(self.states),
            rates=np.array(self.rates).reshape(-1, 3),
            landmarks=self.landmarks,
            scan_steps=np.array(self.scan_steps, dtype=np.int64),
            scan_ids=self.scan_ids,
        )


class TruthRecorder:
    """An observer for :func:`agents.evaluation.episodes.run_episodes` that keeps, per episode, what
    the bound needs (the truth) and the estimator's errors, in the order of the seeds."""

    def __init__(self) -> None:
        self.lanes: list[_Lane] = []
        self.core: Any = None
        self._current: dict[int, _Lane] = {}
        self._map_by_id = False

    def __call__(self, core: Any, stepped: np.ndarray, info: dict[str, Any]) -> None:
        if core is not self.core:  # a new vector env (the next chunk of seeds)
            self.core = core
            self._current = {}
            cfg = core.scenario
            self._map_by_id = not cfg.estimator.known_map and cfg.lidar.association == "known"
        state = core.vehicle.state
        est = core.est
        metrics = step_metrics(state, est, core.landmarks, core.imu.total_bias)
        scan = core.last_scan
        scanning = set() if scan is None else set(scan.lanes.tolist())
        for lane in np.flatnonzero(stepped).tolist():
            if core.steps[lane] == 0:  # a reset: a new episode
                n = int(core.n_landmarks[lane])
                rec = _Lane(core.dt, core.landmarks[lane, :n].copy())
                self.lanes.append(rec)
                self._current[lane] = rec
            else:
                rec = self._current[lane]
                rec.rates.append(core.last_rates[lane].copy())
                if scan is not None and lane in scanning:
                    rec.scan_steps.append(len(rec.states))
                    rec.scan_ids.append(np.flatnonzero(scan.returned[lane]))
            x = state[lane]
            rec.states.append(x.copy())
            rec.err_norm.append(
                np.array(
                    [
                        metrics["est_pos_err_m"][lane],
                        metrics["est_vel_err_mps"][lane],
                        math.radians(metrics["est_att_err_deg"][lane]),
                    ]
                )
            )
            rec.err_axes.append(
                np.concatenate(
                    [
                        est.position[lane] - x[POS],
                        est.vel_inertial[lane] - dcm_from_euler(x[EUL]) @ x[VEL],
                        np.asarray(wrap_angle(est.euler[lane] - x[EUL])),
                    ]
                )
            )
            cov = est.pose_cov
            rec.filter_var.append(
                np.full(POSE_DIM, np.nan) if cov is None else np.diagonal(cov[lane]).copy()
            )
            if self._map_by_id:
                means, mapped = est.landmark_means[lane], est.landmark_mapped[lane]
                rec.map_err2.append(landmark_sq_errors(means, mapped, rec.landmarks))


def bound_model(core: Any) -> BoundModel:
    """The data model of the bound for a scenario's core: the truth's (module docstring).

    Process noise: the IMU's white noise only (the simulated truth has no other), whatever
    extra Q the estimator is tuned with. Biases: when the IMU has a constant bias or a drift,
    bias states ``(b_ω, b_az)`` with prior std ``hypot(max |b0|, σ_drift)`` and the random
    walk ``σ_drift √(2/τ)`` of the Gauss–Markov drift's short-term growth. Pose prior: the
    scenario's P0 when the initial error is drawn from it; zero when the estimate starts at
    the true pose (an estimator handed x0 is bound with a zero prior; its P0 is then only its
    belief). Map: known or unknown as in the scenario. The IMU noise enters as white noise of
    density ND per control period, also for an IMU slower than the control (whose held samples
    the bound does not model).
    """
    cfg = core.scenario
    imu = cfg.imu
    b0_accel = max(abs(b) for b in imu.accel_bias)
    b0_gyro = max(abs(b) for b in imu.gyro_bias)
    biased = max(b0_accel, b0_gyro, imu.accel_drift_sigma, imu.gyro_drift_sigma) > 0.0
    walk = math.sqrt(2.0 / imu.drift_tau_s)
    settings = EkfSlamSettings.from_dict(
        {
            "process_noise": [0.0] * POSE_DIM,
            "estimate_imu_bias": bool(biased),
            "gyro_bias_sigma0": math.hypot(b0_gyro, imu.gyro_drift_sigma),
            "accel_bias_sigma0": math.hypot(b0_accel, imu.accel_drift_sigma),
            "gyro_bias_walk": imu.gyro_drift_sigma * walk,
            "accel_bias_walk": imu.accel_drift_sigma * walk,
        }
    )
    est_cfg = cfg.estimator
    cov0 = np.diag(est_cfg.initial_cov_diag)[:POSE_DIM, :POSE_DIM]
    if not est_cfg.sample_initial_error:
        cov0 = np.zeros_like(cov0)
    return BoundModel(
        settings=settings,
        # The IMU noise per control period (the bound's step): ND √f_control, whatever the
        # IMU rate (a faster IMU's m samples per period carry the same information).
        accel_sigma=white_noise_sigma(imu.accel_noise_density, cfg.episode.control_hz),
        gyro_sigma=white_noise_sigma(imu.gyro_noise_density, cfg.episode.control_hz),
        lidar_sigma=np.array(core.lidar.sigma, dtype=float),
        cov0=cov0,
        known_map=bool(est_cfg.known_map),
    )


def _rms(values: FloatArray) -> float:
    return float(np.sqrt(np.mean(values))) if values.size else math.nan


@dataclass
class SeedBound:
    """The bound and the errors of one seed, per step (steps 1 … K)."""

    seed: int
    t: FloatArray
    bound: dict[str, FloatArray]  # error_bounds() terms
    err_norm: FloatArray  # (K, 3)
    err_axes: FloatArray  # (K, 9)
    filter_var: FloatArray  # (K, 9)
    n_landmarks: np.ndarray
    map: MapSeries | None = None  # the map and its bound (unknown map, known association)

    def summary(self, steady_from_s: float) -> dict[str, Any]:
        """RMSE-equivalents of the bound and RMSEs of the estimate, episode and steady."""
        out: dict[str, Any] = {"seed": self.seed, "duration_s": float(self.t[-1])}
        steady = self.t > steady_from_s
        for j, (name, unit, scale, term) in enumerate(BLOCKS):
            b2 = self.bound[term]
            e2 = self.err_norm[:, j] ** 2
            f2 = self._filter_trace(j)
            for span, sel in (("", slice(None)), ("_steady", steady)):
                out[f"bound_{name}_rmse_{unit}{span}"] = scale * _rms(b2[sel])
                out[f"est_{name}_rmse_{unit}{span}"] = scale * _rms(e2[sel])
                if f2 is not None:
                    out[f"filter_{name}_rmse_{unit}{span}"] = scale * _rms(f2[sel])
        out["n_landmarks_in_bound"] = int(self.n_landmarks[-1])
        if self.map is not None:
            out.update(self.map.summary(self.t, steady_from_s))
        return out

    def _filter_trace(self, block: int) -> FloatArray | None:
        """Trace of the filter's own covariance for the position and attitude blocks (its
        claimed mean-square error; velocity is reported in N and the filter's in B)."""
        if block == 0:
            return self.filter_var[:, POS].sum(axis=1)
        if block == 2:  # Euler variances: close to the rotation angle's at small tilt
            return self.filter_var[:, EUL].sum(axis=1)
        return None


def compute_bounds(recorder: TruthRecorder, model: BoundModel, seeds: list[int]) -> list[SeedBound]:
    """The PCRB along each recorded episode."""
    out = []
    for seed, lane in zip(seeds, recorder.lanes, strict=True):
        truth = lane.truth()
        result = slam_bound(truth, model)
        bounds = error_bounds(truth.state[1:], result.pose_cov[1:])
        lm_map = None
        if lane.map_err2 and result.landmark_var is not None:
            lm_map = map_series(np.array(lane.map_err2[1:]), result.landmark_var[1:], lane.dt,
                                truth.scan_steps, truth.scan_ids)  # fmt: skip
        out.append(
            SeedBound(
                seed=seed,
                t=lane.dt * np.arange(1, truth.steps + 1, dtype=float),
                bound=bounds,
                err_norm=np.array(lane.err_norm[1:]),
                err_axes=np.array(lane.err_axes[1:]),
                filter_var=np.array(lane.filter_var[1:]),
                n_landmarks=result.n_landmarks[1:],
                map=lm_map,
            )
        )
    return out


def summarize_seeds(per_seed: list[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """Median, min, max and pooled RMS over seeds of every ``bound_``/``est_``/``filter_``
    key of the :meth:`SeedBound.summary` records."""
    keys = [k for k in per_seed[0] if k.startswith(("bound_", "est_", "filter_"))]
    return {k: _stats([s.get(k, math.nan) for s in per_seed], pooled=True) for k in keys}


def _stats(values: list[float], pooled: bool) -> dict[str, float | None]:
    arr = np.array(values, dtype=float)
    arr = arr[np.isfinite(arr)]
    if not arr.size:
        return {"median": None, "min": None, "max": None, **({"pooled": None} if pooled else {})}
    out: dict[str, float | None] = {
        "median": float(np.median(arr)),
        "min": float(arr.min()),
        "max": float(arr.max()),
    }
    if pooled:  # √(mean over seeds of the mean-square value): what the bound bounds
        out["pooled"] = float(np.sqrt(np.mean(arr**2)))
    return out


@dataclass
class Flight:
    """A scenario's seeds flown (DF-LQR on the estimate) and the bound along each."""

    scenario: Any  # the ScenarioConfig flown
    settle_s: float  # the env's end of the transient, s
    episodes: list[dict[str, Any]]  # run_episodes' records, in the order of the seeds
    model: BoundModel
    series: list[SeedBound]


def fly_and_bound(
    scenario: str,
    seeds: list[int],
    duration_s: float | None = None,
    overrides: dict[str, Any] | None = None,
    estimator: str | None = None,
    recorder: TruthRecorder | None = None,
    max_lanes: int | None = None,
) -> Flight:
    """Fly the scenario's seeds as lanes (at most ``max_lanes`` at once; default
    ``run_episodes``'), recording them with ``recorder`` (a :class:`TruthRecorder`, or a
    subclass that keeps more), and compute the bound along each true trajectory."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.control.dflqr import DFLQRPolicy
    from agents.evaluation.episodes import MAX_LANES, run_episodes
    from quadslam_env.config.files import deep_merge

    kwargs: dict[str, Any] = dict(overrides or {})
    kwargs["scenario"] = scenario
    if estimator is not None:
        kwargs["estimator_name"] = estimator
    if duration_s is not None:
        kwargs = deep_merge(kwargs, {"episode": {"duration_s": float(duration_s)}})
    env = gym.make("QuadSLAM-v0", **kwargs)
    recorder = TruthRecorder() if recorder is None else recorder
    lanes = MAX_LANES if max_lanes is None else max_lanes
    try:
        cfg = env.unwrapped.scenario  # type: ignore[attr-defined]
        print(f"flying {cfg.name} / {cfg.estimator.name} × {len(seeds)} ...", file=sys.stderr)
        policy = DFLQRPolicy.from_env(env)
        episodes = run_episodes(env, policy, seeds, max_lanes=lanes, observer=recorder)
        model = bound_model(recorder.core)
    finally:
        env.close()
    print("computing the bound along each true trajectory ...", file=sys.stderr)
    series = compute_bounds(recorder, model, seeds)
    return Flight(cfg, float(recorder.core.settle_s), episodes, model, series)


def run_bound_study(
    scenario: str,
    seeds: list[int],
    duration_s: float | None = None,
    overrides: dict[str, Any] | None = None,
    estimator: str | None = None,
) -> tuple[dict[str, Any], list[SeedBound]]:
    """Fly the scenario's seeds, compute the bound along each, return ``(result, series)``.

    ``result`` is the JSON document (``summary`` of every per-seed key with median, min, max
    and the pooled RMS over seeds; ``seeds``; ``episodes``, the usual episode records;
    ``settings``); ``series`` the per-step values for :func:`plot_bound`.
    """
    flight = fly_and_bound(scenario, seeds, duration_s, overrides, estimator)
    series, episodes, model = flight.series, flight.episodes, flight.model
    duration = float(flight.scenario.episode.duration_s)
    name, est_name = flight.scenario.name, flight.scenario.estimator.name
    steady_from = 0.5 * duration
    per_seed = [s.summary(steady_from) for s in series]
    for rec, ep in zip(per_seed, episodes, strict=True):
        rec["terminated"] = ep["terminated"]
    summary = summarize_seeds(per_seed)
    s = model.settings
    result = {
        "scenario": name,
        "estimator": est_name,
        "settings": {
            "estimator_override": estimator,
            "seeds": seeds,
            "duration_s": duration,
            "steady_state": f"t > {steady_from:g} s (the second half)",
            "bound_model": {
                "process": "EKF-SLAM strapdown (seed 001 eq. 24); process noise: the IMU white "
                "noise mapped through ∂f/∂λ",
                "bias_states": s.estimate_imu_bias,
                "bias_sigma0": [s.gyro_bias_sigma0, s.accel_bias_sigma0]
                if s.estimate_imu_bias
                else None,
                "bias_walk": [s.gyro_bias_walk, s.accel_bias_walk] if s.estimate_imu_bias else None,
                "map": "known" if model.known_map else "unknown (landmarks enter without prior)",
                "lidar_sigma": model.lidar_sigma.tolist(),
                "pose_prior_diag": np.diag(model.cov0).tolist(),
            },
        },
        "summary": summary,
        "seeds": per_seed,
        "episodes": episodes,
    }
    return result, series
