"""``quadslam study active-perception``: does looking matter, and can an agent learn where to?

On ``active_perception`` (ten landmarks behind the start heading, a slow circle, a free heading
turned by the fifth action component, EKF-SLAM under a biased IMU) and the same held-out seeds,
the study flies and tabulates, for each controller, the true tracking RMSE in the steady state
(after the first :data:`SETTLE_S` s, the search for the first landmarks) and in the transient,
the estimation RMSE in the steady state, the landmarks in view per LiDAR scan and the crash
rate:

=================  ==================================================================
config             controller
=================  ==================================================================
``dflqr_fixed``    DF-LQR, heading held at the start heading (north: nothing in view)
``dflqr_tangent``  DF-LQR, heading along the velocity (``trajectory.yaw_mode: tangent``)
``lookat``         DF-LQR + the look-at heuristic (:mod:`agents.control.lookat`)
``ppo``            residual PPO with the heading channel (``ppo.yaml``'s
                   ``QuadSLAM-ActivePerception-v0`` entry), one row per training seed set
=================  ==================================================================

A learned row's median/min/max are over its training seeds (each seed's median over the
episodes); the other rows' over the episodes. The learned row also carries the IQM and its 95%
bootstrap CI over the training seeds (:mod:`agents.evaluation.seed_stats`) and the study's two
claims (:data:`CLAIMS`: a steady-state tracking RMSE at most 0.8 × the tangent heading's, and
at most the look-at heuristic's) with the number of training seeds each holds on.
``--quick`` trains one seed on a small budget and flies 5 episodes (a smoke run, not a result).
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import Trace, json_float, run_episodes, spread_cell, stats
from agents.evaluation.seed_stats import summary
from agents.io.outputs import atomic_produce, write_text_atomic
from agents.lab.control_studies.learned_rows import claim, seed_table, training_seed_list
from agents.lab.control_studies.training_pool import TrainJob, train_all

ENV_ID = "QuadSLAM-ActivePerception-v0"
EVAL_SEED0 = 1000
SETTLE_S = 5.0
EPISODE = {"episode": {"settle_s": SETTLE_S}}
TANGENT = {"trajectory": {"yaw_mode": "tangent"}, "action": {"heading": False}}
KEYS = ("track_pos_rmse_steady_m", "track_pos_rmse_transient_m", "est_pos_rmse_steady_m")
TRAINING_SEEDS = 5
"""Training seeds of the learned row by default."""
CLAIMS = (("dflqr_tangent", 0.8), ("lookat", 1.0))
"""The learned row's claims: its steady-state tracking RMSE at most the factor × that baseline
row's, on each training seed."""


class ViewCounter:
    """An observer for :func:`agents.evaluation.episodes.run_episodes`: landmarks in view per scan.

    Lane i (seed ``seeds[i]``) counts the landmarks its LiDAR returned on each scan of its
    episode; :meth:`mean` is their average per scan.
    """

    def __init__(self, lanes: int) -> None:
        self.returned = np.zeros(lanes)
        self.scans = np.zeros(lanes)

    def __call__(self, core: Any, stepped: np.ndarray, info: dict[str, Any]) -> None:
        scan = core.last_scan
        if scan is None:
            return
        lanes = scan.lanes[stepped[scan.lanes]]
        self.returned[lanes] += scan.n_returns[lanes]
        self.scans[lanes] += 1

    def mean(self) -> np.ndarray:
        """(lanes,) landmarks in view per scan (NaN for a lane without scans)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return self.returned / self.scans


def fly(
    policy_of: Any, overrides: dict[str, Any], seeds: list[int], trace: Trace | None
) -> list[dict[str, Any]]:
    """Fly the policy built by ``policy_of(env)`` on the scenario with ``overrides``.

    Returns:
        The episode records, each with ``landmarks_per_scan``.
    """
    import gymnasium as gym

    from quadslam_env.config.files import deep_merge

    env = gym.make(ENV_ID, **deep_merge(EPISODE, overrides))
    try:
        views = ViewCounter(len(seeds))
        records = run_episodes(
            env, policy_of(env), seeds, trace=trace, max_lanes=len(seeds), observer=views
        )
    finally:
        env.close()
    for record, value in zip(records, views.mean(), strict=True):
        record["landmarks_per_scan"] = json_float(value)
    return records


def row_result(config: str, label: str, per_seed: list[list[dict[str, Any]]]) -> dict[str, Any]:
    """One table row: stats over training seeds (several groups) or over the episodes."""
    episodes = [e for group in per_seed for e in group]
    out: dict[str, Any] = {"config": config, "controller": label}
    for key in (*KEYS, "landmarks_per_scan"):
        if len(per_seed) > 1:
            medians = [stats([e.get(key) for e in group])["median"] for group in per_seed]
            out[key] = stats(medians)
        else:
            out[key] = stats([e.get(key) for e in episodes])
    out["crash_rate"] = float(np.mean([e["terminated"] for e in episodes]))
    out["spread_over"] = "training seeds" if len(per_seed) > 1 else "episodes"
    out["n_training_seeds"] = len(per_seed) if config == "ppo" else 0
    if config == "ppo":  # each training seed's median over its episodes
        out["seed_stats"] = {
            key: summary([stats([e.get(key) for e in group])["median"] for group in per_seed])
            for key in KEYS[:2]
        }
    out["episodes"] = episodes
    return out


def with_claims(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with the learned row's :data:`CLAIMS` against the baseline rows."""
    by_config = {r["config"]: r for r in rows}
    for r in rows:
        if r.get("seed_stats"):
            r["claims"] = [
                claim(r, by_config.get(base), factor, f"<= {factor:g} x {base}")
                for base, factor in CLAIMS
            ]
    return rows


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    jobs: int | None = None,
    duration_s: float | None = None,
    hyperparams: dict[str, Any] | None = None,
    first_training_seed: int = 0,
    env_overrides: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Fly the baselines, train and fly the learned agent; ``{"rows", "settings", "traces"}``.

    Args:
        out: Folder for the training runs (reused when the study is repeated).
        quick: One training seed, 100,000 steps, 5 episodes (unless set below).
        training_seeds: Training seeds of the learned row (default :data:`TRAINING_SEEDS`, 5;
            quick 1).
        episodes: Held-out episodes (default 20, quick 5).
        timesteps: Training budget (default: the ``ppo.yaml`` entry's; quick 100,000).
        jobs: Trainings at a time, each in a worker process (default: the CPU cores available,
            :func:`agents.io.cpus.available_cpus`; 1 trains in this process, one after the
            other). The trained policies do not depend on it
            (:mod:`agents.lab.control_studies.training_pool`).
        duration_s: Episode length in s for training and flights (default the scenario's).
        hyperparams: Merged into the ``ppo.yaml`` entry (before ``duration_s``).
        first_training_seed: The training seeds are ``first_training_seed`` on (default 0).
        env_overrides: Settings of the env for the training and every flight (e.g. the
            integrity-aware task of :mod:`agents.lab.control_studies.integrity_task`).

    Raises:
        ValueError: ``first_training_seed`` below 0.
    """
    from agents.io.cpus import available_cpus
    from agents.rl.policies import load_policy
    from quadslam_env.config.files import deep_merge

    tic = time.perf_counter()
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    training = training_seed_list(n_seeds, first_training_seed)
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (100_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    length = {} if duration_s is None else {"episode": {"duration_s": float(duration_s)}}
    length = deep_merge(env_overrides or {}, length)
    entry = deep_merge(hyperparams or {}, {"env_kwargs": length}) if length else hyperparams
    # Every training first: they run side by side; the flights follow in this process.
    runs = train_all(
        [
            TrainJob(f"ppo seed {s}", out / "train" / f"s{s}", ENV_ID, s, timesteps, entry)
            for s in training
        ],
        jobs,
    )
    rows, traces = _fly_baselines(seeds, length)
    per_seed = []
    for seed, trained in zip(training, runs, strict=True):
        print(f"ppo seed {seed}: flying ...", file=sys.stderr)
        trace = Trace() if seed == training[0] else None
        run = trained.run
        per_seed.append(fly(lambda env, r=run: load_policy(str(r), env)[0], length, seeds, trace))
        if trace is not None:
            traces["ppo"] = trace
    ppo = row_result("ppo", "residual PPO, heading channel", per_seed)
    ppo["train_wall_s"] = [round(trained.wall_s, 1) for trained in runs]
    rows.append(ppo)
    settings = {
        "env_id": ENV_ID,
        "settle_s": SETTLE_S,
        "eval_seeds": seeds,
        "training_seeds": training,
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "duration_s": duration_s,
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and fly
    }
    return {"settings": settings, "rows": with_claims(rows), "traces": traces}


def _fly_baselines(
    seeds: list[int], length: dict[str, Any]
) -> tuple[list[dict[str, Any]], dict[str, Trace]]:
    """The baseline rows (module docstring) on ``seeds``, episodes with the ``length``
    overrides, and each row's first-seed trace."""
    from agents.control.dflqr import DFLQRPolicy
    from agents.control.lookat import LookAtPolicy
    from quadslam_env.config.files import deep_merge

    rows, traces = [], {}
    baselines: tuple[tuple[str, str, Any, dict[str, Any]], ...] = (
        ("dflqr_fixed", "DF-LQR, fixed heading", DFLQRPolicy.from_env, {}),
        ("dflqr_tangent", "DF-LQR, tangent heading", DFLQRPolicy.from_env, TANGENT),
        ("lookat", "DF-LQR + look-at heuristic", LookAtPolicy, {}),
    )
    for config, label, policy_of, overrides in baselines:
        print(f"{label} ...", file=sys.stderr)
        traces[config] = Trace()
        flown = fly(policy_of, deep_merge(overrides, length), seeds, traces[config])
        rows.append(row_result(config, label, [flown]))
    return rows, traces


def format_study(result: dict[str, Any]) -> str:
    """The study table as text (steady state first)."""
    cell = spread_cell

    head = (
        f"{'config':<14} {'track RMSE steady m':<22} {'transient m':<22} "
        f"{'est RMSE steady m':<22} {'in view/scan':<18} {'crash':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in result["rows"]:
        lines.append(
            f"{r['config']:<14} {cell(r['track_pos_rmse_steady_m']):<22} "
            f"{cell(r['track_pos_rmse_transient_m']):<22} "
            f"{cell(r['est_pos_rmse_steady_m']):<22} "
            f"{cell(r['landmarks_per_scan'], '{:.1f}'):<18} {r['crash_rate']:>5.2f}"
        )
    lines += seed_table(result["rows"], lambda r: r["config"])
    return "\n".join(lines)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """Where each controller looks: the first seed's path with its heading every second, the
    landmarks and the LiDAR's azimuth field of view, one panel per controller."""
    from matplotlib.figure import Figure

    from quadslam_env.config.scenario import load_scenario

    scenario = load_scenario("active_perception")
    fov = np.radians(scenario.lidar.azimuth_fov_deg)
    traces = result["traces"]
    fig = Figure(figsize=(4.0 * len(traces), 4.4), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(traces)))
    for ax, (config, trace) in zip(axes, traces.items(), strict=True):
        states = np.array(trace.true_state)
        if trace.landmarks is not None:
            ax.scatter(trace.landmarks[:, 1], trace.landmarks[:, 0], marker="^", c="k", s=25)
        ax.plot(states[:, 1], states[:, 0], lw=1.0, c="tab:blue")
        for k in range(0, len(states), 100):  # every second: the heading and the FOV edges
            y, x, psi = states[k, 1], states[k, 0], states[k, 8]
            for off, style in ((0.0, "-"), (-fov, ":"), (fov, ":")):
                ax.plot([y, y + 2.0 * np.sin(psi + off)], [x, x + 2.0 * np.cos(psi + off)],
                        style, c="tab:orange", lw=0.6, alpha=0.7)  # fmt: skip
        row = next(r for r in result["rows"] if r["config"] == config)
        steady = row["track_pos_rmse_steady_m"]["median"]
        ax.set_title(f"{config}: steady {steady:.3f} m" if steady is not None else config)
        ax.set_xlabel("east [m]")
        ax.set_xlim(-10.0, 10.0)  # one scale for every panel: the landmarks lie within 9 m
        ax.set_ylim(-10.0, 10.0)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("north [m]")
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "active_perception.png"
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=110))
    return path


def write_json(result: dict[str, Any], path: Path) -> None:
    """Write the study result (NaN as null; traces left out)."""
    clean = {"settings": result["settings"], "rows": result["rows"]}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(clean, indent=2) + "\n")
