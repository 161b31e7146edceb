"""One code path to fly any policy on the env and summarise the episodes (``run``/``evaluate``).

A policy is anything with SB3's ``predict(obs, state, episode_start, deterministic)``: the
DF-LQR baseline and trained SB3 models alike. :func:`run_episodes` flies N seeds as N lanes of
one native vector env (lane i seeded ``seeds[i]``, stopped after its first episode), which gives
the per-episode records of :func:`run_episode` on the scalar env, seed for seed.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.wrappers import OrderEnforcing, PassiveEnvChecker

from agents.evaluation.step_clock import StepClock
from quadslam_env.config.scenario import ScenarioConfig
from quadslam_env.env import lane_info
from quadslam_env.episode.actions import validate_actions
from quadslam_env.estimation.memory import MemoryTerm
from quadslam_env.memory import check_env_memory
from quadslam_env.metrics.episode import phase_key
from quadslam_env.metrics.integrity import SUMMARY_KEYS as INTEGRITY_SUMMARY_KEYS

# Record keys reported over the whole episode and, with the phase in the name
# (``track_pos_rmse_steady_m``, ``track_pos_rmse_transient_m``, …), over each phase.
PHASED_KEYS = (
    "track_pos_rmse_m",
    "est_pos_rmse_m",
    "est_vel_rmse_mps",
    "est_att_rmse_deg",
    "anees_pose",
    "nees_pose_in_bounds",
)
STEADY_KEYS = tuple(phase_key(k, "steady") for k in PHASED_KEYS)
TRANSIENT_KEYS = tuple(phase_key(k, "transient") for k in PHASED_KEYS)
EPISODE_KEYS = (
    "seed",
    "duration_s",
    "terminated",
    "termination_reason",
    *STEADY_KEYS,
    *TRANSIENT_KEYS,
    "est_pos_rmse_m",
    "est_vel_rmse_mps",
    "est_att_rmse_deg",
    "map_rmse_m",
    "track_pos_rmse_m",
    "anees_pose",
    "nees_pose_in_bounds",
    "n_mapped",
    "accel_bias_rel_err",
    "gyro_bias_rel_err",
    "steps_per_s",
)
"""The keys of an episode record; a phase the episode never reached (it ended at or before
``settle_s``, or ``settle_s`` is 0) leaves that phase's keys out of the record."""
SUMMARY_KEYS = tuple(
    k for k in EPISODE_KEYS if k not in ("seed", "terminated", "termination_reason")
)
# Mapping from the env's episode summary (last info) to the JSON episode record.
_WHOLE_FROM_INFO = {
    "est_pos_rmse_m": "episode_est_pos_rmse_m",
    "est_vel_rmse_mps": "episode_est_vel_rmse_mps",
    "est_att_rmse_deg": "episode_est_att_rmse_deg",
    "map_rmse_m": "episode_map_rmse_m",
    "track_pos_rmse_m": "episode_track_pos_rmse_m",
    "anees_pose": "episode_anees_pose",
    "nees_pose_in_bounds": "episode_nees_pose_in_bounds",
    "n_mapped": "episode_n_mapped",
    "accel_bias_rel_err": "episode_accel_bias_rel_err",
    "gyro_bias_rel_err": "episode_gyro_bias_rel_err",
}
_PHASE_FROM_INFO = {
    phase_key(k, phase): phase_key(_WHOLE_FROM_INFO[k], phase)
    for phase in ("steady", "transient")
    for k in PHASED_KEYS
}
# Unknown data association (``lidar.association: unknown``) adds these to the record.
_ASSOCIATION_FROM_INFO = {
    "assoc_wrong_rate": "episode_assoc_wrong_rate",
    "assoc_missed_rate": "episode_assoc_missed_rate",
    "spurious_landmarks": "episode_spurious_landmarks",
}
# An estimator with wind states (EKF-SLAM's ``wind: estimate``) adds these.
_WIND_FROM_INFO = {
    key: phase_key("episode_est_wind_rmse_mps", phase) if phase else "episode_est_wind_rmse_mps"
    for phase, key in (
        ("", "est_wind_rmse_mps"),
        ("steady", "est_wind_rmse_steady_mps"),
        ("transient", "est_wind_rmse_transient_mps"),
    )
}
# The integrity monitor (``integrity.monitor``) adds its summaries (docs/integrity.md "Metrics").
_INTEGRITY_FROM_INFO = {key.removeprefix("episode_"): key for key in INTEGRITY_SUMMARY_KEYS}
_INTEGRITY_FROM_INFO["fault_onset_s"] = "episode_fault_onset_s"  # with a fault of the world
_OPTIONAL_FROM_INFO = {**_ASSOCIATION_FROM_INFO, **_WIND_FROM_INFO, **_INTEGRITY_FROM_INFO}
MAX_LANES = 64  # episodes flown at once by run_episodes
Observer = Callable[[Any, np.ndarray, dict[str, Any]], None]
"""``observer(core, stepped, info)`` of :func:`run_episodes`."""


@dataclass
class Trace:
    """Per-step time series of one episode, for the paper-style figures."""

    t: list[float] = field(default_factory=list)
    true_state: list[np.ndarray] = field(default_factory=list)
    est_pos: list[np.ndarray] = field(default_factory=list)
    est_vel_body: list[np.ndarray] = field(default_factory=list)
    est_euler: list[np.ndarray] = field(default_factory=list)
    pose_cov: list[np.ndarray] = field(default_factory=list)
    ref_pos: list[np.ndarray] = field(default_factory=list)
    landmarks: np.ndarray | None = None
    est_landmark_ids: np.ndarray | None = None
    est_landmarks: np.ndarray | None = None
    est_landmark_std: np.ndarray | None = None

    def record(self, env: Any) -> None:
        """Append the current truth, estimate and reference of ``env.unwrapped``."""
        base = env.unwrapped
        self._append(base.t, base.true_state, base.last_estimate, base.reference().pos)

    def record_lane(self, core: Any, lane: int) -> None:
        """Append the current truth, estimate and reference of lane ``lane`` of a ``SimCore``."""
        t = float(core.t[lane])
        est = core.estimator.lane_estimate(lane)
        self._append(t, core.vehicle.state[lane].copy(), est, core.trajectory(t).pos)

    def _append(self, t: float, true_state: np.ndarray, est: Any, ref_pos: np.ndarray) -> None:
        self.t.append(t)
        self.true_state.append(true_state)
        self.est_pos.append(est.position[0])
        self.est_vel_body.append(est.vel_body[0])
        self.est_euler.append(est.euler[0])
        cov = np.full((9, 9), np.nan) if est.pose_cov is None else np.array(est.pose_cov[0])
        self.pose_cov.append(cov)
        self.ref_pos.append(ref_pos)

    @property
    def pose_std(self) -> np.ndarray:
        """(N, 9) 1σ of the pose (ρ, v_B, Λ) at each recorded step (NaN without covariance)."""
        cov = np.array(self.pose_cov).reshape(-1, 9, 9)
        return np.sqrt(np.clip(np.diagonal(cov, axis1=1, axis2=2), 0.0, None))

    def finish(self, env: Any) -> None:
        """Store the final map (true and estimated, with 1σ per axis)."""
        base = env.unwrapped
        self._finish(base.landmarks, base.last_estimate)

    def finish_lane(self, core: Any, lane: int) -> None:
        """:meth:`finish` for lane ``lane`` of a ``SimCore``."""
        landmarks = core.landmarks[lane, : core.n_landmarks[lane]]
        self._finish(landmarks, core.estimator.lane_estimate(lane))

    def _finish(self, landmarks: np.ndarray, est: Any) -> None:
        self.landmarks = landmarks.copy()
        ids, means, covs = est.mapped_landmarks()
        self.est_landmark_ids = ids
        self.est_landmarks = means
        self.est_landmark_std = np.sqrt(np.clip(np.diagonal(covs, axis1=1, axis2=2), 0.0, None))


def run_episode(
    env: gym.Env,
    policy: Any,
    seed: int,
    trace: Trace | None = None,
    on_step: Callable[[], None] | None = None,
    video: Any | None = None,
    observer: Observer | None = None,
) -> dict[str, Any]:
    """Fly one episode and return its JSON record (keys :data:`EPISODE_KEYS`); ``video``
    (an :class:`agents.evaluation.video.LaneVideo`) records its frames, ``observer`` sees the env's
    one-lane core after the reset and after every step (see :func:`run_episodes`)."""
    obs, info = env.reset(seed=seed)
    lane0 = np.array([True])
    if observer is not None:
        observer(env.unwrapped.core, lane0, info)  # type: ignore[attr-defined]
    if trace is not None:
        trace.record(env)
    if video is not None:
        base: Any = env.unwrapped  # a QuadSLAMEnv
        video.attach(base.core, 0, info)
    state, start = None, np.array([True])
    info = {}
    clock = StepClock()
    while True:
        clock.start()
        action, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
        start = np.array([False])
        obs, _, terminated, truncated, info = env.step(action)
        if observer is not None:
            observer(env.unwrapped.core, lane0, info)  # type: ignore[attr-defined]
        if trace is not None:
            trace.record(env)
        if video is not None:
            video.record(info)
        if on_step is not None:
            on_step()
        clock.stop()
        if terminated or truncated:
            break
    if trace is not None:
        trace.finish(env)
    return episode_record(seed, info, bool(terminated), clock.rate)


def episode_record(
    seed: int, info: dict[str, Any], terminated: bool, steps_per_s: float
) -> dict[str, Any]:
    """The JSON record (keys :data:`EPISODE_KEYS`) of an episode from its last ``info`` and
    its rate ``steps_per_s`` (:attr:`agents.evaluation.step_clock.StepClock.rate`)."""
    record: dict[str, Any] = {
        "seed": int(seed),
        "duration_s": float(info["t"]),
        "terminated": bool(terminated),
        "termination_reason": str(info.get("termination_reason", "")),
    }
    for key, src in _PHASE_FROM_INFO.items():
        value = json_float(info.get(src, math.nan))
        if value is not None:  # a phase the episode never reached has no entry
            record[key] = value
    for key, src in _WHOLE_FROM_INFO.items():
        record[key] = json_float(info.get(src, math.nan))
    for key, src in _OPTIONAL_FROM_INFO.items():
        if src in info:
            record[key] = json_float(info[src])
    record["steps_per_s"] = json_float(steps_per_s)
    return record


def run_episodes(
    env: gym.Env,
    policy: Any,
    seeds: Sequence[int],
    trace: Trace | None = None,
    on_step: Callable[[int], None] | None = None,
    max_lanes: int = MAX_LANES,
    video: Any | None = None,
    observer: Observer | None = None,
) -> list[dict[str, Any]]:
    """Fly one episode per seed, as lanes of the native vector env of ``env``'s id and kwargs.

    Up to ``max_lanes`` episodes run at once (lane i seeded ``seeds[i]``, stopped after its
    first episode); the records equal :func:`run_episode`'s on ``env`` for the same seeds,
    except ``steps_per_s``, which is the rate of its batch's steps until it ended (so it sums
    to the throughput over a batch's episodes), both without the first step and the steps that
    compiled or loaded a kernel (:class:`~agents.evaluation.step_clock.StepClock`). An env
    whose spec has no vector entry point, or that carries wrappers beyond ``gymnasium.make``'s
    own, is flown one episode after another with :func:`run_episode`.

    Args:
        env: The scalar env (from ``gymnasium.make``).
        policy: Anything with SB3's ``predict``; it gets (k, obs_dim) observations.
        seeds: Episode seeds (N,).
        trace: Filled from the first seed's episode if given.
        on_step: Called after each batch step with the number of episode steps completed,
            an episode that ended early counting as ``max_steps``, so the calls add up to
            ``max_steps × N`` (a progress bar's total).
        max_lanes: Most lanes in one vector env.
        video: An :class:`agents.evaluation.video.LaneVideo` that records the first seed's episode.
        observer: Called as ``observer(core, stepped, info)`` after the reset and after every
            batch step, with the :class:`~quadslam_env.core.SimCore` of the lanes, the
            (B,) bool mask of the lanes that were reset or just stepped and the step's
            ``info`` (values (B,) on lanes, scalars one by one) (lane i flies
            ``seeds[first + i]`` of its chunk of ``max_lanes``; one lane per episode on the
            one-by-one path). It may read anything of the core, truth included (analyses
            such as :mod:`agents.lab.estimator_studies.bound`), and must not change it.

    Returns:
        One record per seed, in the order of ``seeds``.
    """
    layer, spec = env, env.spec
    while isinstance(layer, OrderEnforcing | PassiveEnvChecker):
        layer = layer.env
    if spec is None or spec.vector_entry_point is None or layer is not env.unwrapped:
        scalar: Any = env.unwrapped  # a QuadSLAMEnv
        max_steps = scalar.max_steps
        records = []
        for i, seed in enumerate(seeds):
            tick = None if on_step is None else (lambda: on_step(1))
            is_first = i == 0
            rec = run_episode(
                env,
                policy,
                seed,
                trace if is_first else None,
                tick,
                video if is_first else None,
                observer,
            )
            if on_step is not None:
                on_step(max_steps - round(rec["duration_s"] / scalar.dt))
            records.append(rec)
        return records
    records = []
    for first in range(0, len(seeds), max_lanes):
        chunk = [int(s) for s in seeds[first : first + max_lanes]]
        vec = gym.make_vec(
            spec.id, num_envs=len(chunk), vectorization_mode="vector_entry_point", **spec.kwargs
        )
        try:
            records += _run_lanes(
                vec, policy, chunk, trace if first == 0 else None, on_step,
                video if first == 0 else None, observer,
            )  # fmt: skip
        finally:
            vec.close()
    return records


RECORD_BYTES = 8 * 1024
"""Bytes an episode keeps until its command ends, rounded up from 6.4 KiB measured: its seed,
its record (0.9 KiB), its row of the table (1.2 KiB) and its JSON text while it is written."""


def check_episodes_memory(scenario: ScenarioConfig, count: int, key: str = "--seeds") -> None:
    """Refuse ``count`` episodes of ``scenario`` that would not fit in memory, before any is
    flown: the vector env of one chunk (at most :data:`MAX_LANES` lanes: :func:`run_episodes`
    flies the seeds in chunks) and every episode's record (:data:`RECORD_BYTES`).

    Args:
        scenario: The scenario of the env the episodes fly on.
        count: Episodes (seeds).
        key: The option that sets ``count`` (``--seeds``, ``--episodes``, ``seeds_per_job``).

    Raises:
        quadslam_env.estimation.MemoryLimitError: One line naming ``key`` (or the setting
            that dominates), the size and the count that fits.
    """
    n = int(count)

    def most(room: int) -> str:
        return f"{key} at most {room // RECORD_BYTES}"

    what = f"the episode records (N × {RECORD_BYTES // 1024} KiB = {n} × 8 KiB)"
    records = MemoryTerm(n * RECORD_BYTES, key, n, what, most, per_lane=False)
    check_env_memory(scenario, min(n, MAX_LANES), key, [records])


def _run_lanes(
    vec: Any,
    policy: Any,
    seeds: list[int],
    trace: Trace | None,
    on_step: Callable[[int], None] | None,
    video: Any | None = None,
    observer: Observer | None = None,
) -> list[dict[str, Any]]:
    """Fly lane i of ``vec`` with seed ``seeds[i]`` until its first episode ends."""
    core = vec.unwrapped.core
    n = len(seeds)
    obs, info = vec.reset(seed=seeds)
    if observer is not None:
        observer(core, np.ones(n, dtype=bool), info)
    if trace is not None:
        trace.record_lane(core, 0)
    if video is not None:
        video.attach(core, 0, info)
    records: list[dict[str, Any]] = [{} for _ in seeds]
    active = np.ones(n, dtype=bool)
    state, start = None, np.ones(n, dtype=bool)
    steps = 0
    clock = StepClock()
    while active.any():
        clock.start()
        action, state = policy.predict(obs, state=state, episode_start=start, deterministic=True)
        start = np.zeros(n, dtype=bool)
        checked = validate_actions(action, n, core.action_map.dim)
        obs, _, terminated, truncated, info = core.step(checked, active)
        steps += 1
        if observer is not None:
            observer(core, active.copy(), info)
        if trace is not None and active[0]:
            trace.record_lane(core, 0)
        if video is not None and active[0]:
            video.record(info)
        clock.stop()
        ended = np.flatnonzero(active & (terminated | truncated)).tolist()
        for lane in ended:
            lane_dict = lane_info(info, lane)
            records[lane] = episode_record(seeds[lane], lane_dict, terminated[lane], clock.rate)
        if trace is not None and 0 in ended:
            trace.finish_lane(core, 0)
        if on_step is not None:
            on_step(int(active.sum()) + (core.max_steps - steps) * len(ended))
        active[ended] = False
    return records


def summarize(episodes: Sequence[dict[str, Any]]) -> dict[str, dict[str, float | None]]:
    """Median, min and max over episodes of each numeric key, and ``n``, the number of
    episodes they cover (absent, None and NaN values left out; None when none is left)."""
    extra = [k for k in _OPTIONAL_FROM_INFO if episodes and k in episodes[0]]
    return {key: stats([e.get(key) for e in episodes]) for key in (*SUMMARY_KEYS, *extra)}


def spread_cell(spread: dict[str, Any], fmt: str = "{:.3f}") -> str:
    """``median (min–max)`` of a :func:`stats` result for a text table ("–" without values)."""
    if spread["median"] is None:
        return "–"
    lo, mid, hi = (fmt.format(spread[k]) for k in ("min", "median", "max"))
    return f"{mid} ({lo}–{hi})"


def stats(values: Sequence[Any]) -> dict[str, Any]:
    """``median``, ``min``, ``max`` of the finite values (None, NaN left out; None when none
    is left) and ``n``, how many there are."""
    arr = np.array([math.nan if v is None else float(v) for v in values], dtype=float)
    arr = arr[np.isfinite(arr)]
    if not arr.size:
        return {"median": None, "min": None, "max": None, "n": 0}
    return {
        "median": float(np.median(arr)),
        "min": float(arr.min()),
        "max": float(arr.max()),
        "n": int(arr.size),
    }


def format_table(episodes: Sequence[dict[str, Any]], summary: dict[str, Any]) -> str:
    """Plain-text table: one row per episode and a median row."""
    cols = [
        ("seed", "seed", "{:d}"),
        ("track steady m", "track_pos_rmse_steady_m", "{:.4f}"),
        ("est steady m", "est_pos_rmse_steady_m", "{:.4f}"),
        ("track transient m", "track_pos_rmse_transient_m", "{:.4f}"),
        ("pos m", "est_pos_rmse_m", "{:.4f}"),
        ("vel m/s", "est_vel_rmse_mps", "{:.4f}"),
        ("att deg", "est_att_rmse_deg", "{:.3f}"),
        ("map m", "map_rmse_m", "{:.4f}"),
        ("track m", "track_pos_rmse_m", "{:.4f}"),
        ("ANEES", "anees_pose", "{:.2f}"),
        ("in95%", "nees_pose_in_bounds", "{:.2f}"),
        ("mapped", "n_mapped", "{:.0f}"),
        ("steps/s", "steps_per_s", "{:.0f}"),
        ("end", "termination_reason", "{}"),
    ]
    if episodes and "assoc_wrong_rate" in episodes[0]:
        cols[-2:-2] = [
            ("wrong", "assoc_wrong_rate", "{:.3f}"),
            ("missed", "assoc_missed_rate", "{:.3f}"),
            ("spurious", "spurious_landmarks", "{:.0f}"),
        ]
    if episodes and "est_wind_rmse_steady_mps" in episodes[0]:
        cols[7:7] = [("wind steady m/s", "est_wind_rmse_steady_mps", "{:.3f}")]

    def cell(fmt: str, value: Any) -> str:
        if value is None or (isinstance(value, float) and not math.isfinite(value)):
            return "-"
        return fmt.format(value)

    rows = [[name for name, _, _ in cols]]
    for ep in episodes:
        end = ep["termination_reason"] or "time limit"
        rows.append(
            [cell(fmt, end if key == "termination_reason" else ep.get(key)) for _, key, fmt in cols]
        )
    med = ["median"] + [
        cell(fmt, summary[key]["median"]) if key in summary else "" for _, key, fmt in cols[1:]
    ]
    rows.append(med)
    widths = [max(len(r[i]) for r in rows) for i in range(len(cols))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(r, widths, strict=True)) for r in rows]
    lines.insert(1, "-" * len(lines[0]))
    lines.insert(len(lines) - 1, "-" * len(lines[0]))
    return "\n".join(lines)


def json_float(value: Any) -> float | None:
    """``float(value)``, or ``None`` (JSON null) when it is NaN or infinite."""
    value = float(value)
    return value if math.isfinite(value) else None
