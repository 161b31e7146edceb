"""``quadslam study cost-of-estimation``: what flying on an estimate costs a controller.

On one scenario (``ekf_figure8_biased_imu``: the figure-8 under the biased, drifting IMU) and
the same held-out seeds, the study flies and tabulates the true tracking RMSE in the steady
state (after ``episode.settle_s``: the headline, since the take-off climb of the transient
would hide the estimator) and in the transient, the crash rate (episodes ended early) and the
estimation error of:

===========================  ==========  ==========  ==========================================
config                       policy      train on    evaluated on
===========================  ==========  ==========  ==========================================
``dflqr``                    DF-LQR      –           truth (Oracle), EKF-SLAM, FastSLAM
``ppo_truth``                res. PPO    truth       truth, and EKF-SLAM (the deployment gap)
``ppo_ekf``                  res. PPO    EKF-SLAM    EKF-SLAM
``ppo_asymmetric``           res. PPO    EKF-SLAM    EKF-SLAM; critic also sees the truth
                                                     (:mod:`agents.rl.asymmetric`)
``ppo_pos_std``              res. PPO    EKF-SLAM    EKF-SLAM; observation + position std
===========================  ==========  ==========  ==========================================

Every trained configuration uses the ``QuadSLAM-EKF-v0`` entry of ``configs/agents/ppo.yaml``
(the same hyperparameters and budget; only the env id, the policy or the observation differ)
and is trained with seeds ``0 … n-1``; evaluation seeds start at 1000 and are never used in
training. The entry trains on episodes that start on the reference
(``trajectory.start_on_reference``: the return is then all steady-state tracking); every row is
evaluated on the scenario's own start, take-off climb included
(:func:`~agents.lab.control_studies.learned_rows.evaluation_kwargs`). Medians and spreads as in
:mod:`agents.lab.control_studies.learned_rows` (a learned row's over its training seeds, a DF-LQR
row's over the episodes); each learned row also carries the IQM and its 95% bootstrap CI over the
training seeds, and the study's claim (:data:`CLAIM_FACTOR`: its steady-state tracking RMSE
at most 0.9 × DF-LQR's on the same estimator) with the number of training seeds it holds on.
``--quick`` trains one seed on a small budget and evaluates 5 episodes (a smoke run of the
whole pipeline, minutes, not a result).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.evaluation.episodes import spread_cell
from agents.lab.control_studies.learned_rows import (
    EKF,
    Row,
    box_plot,
    claim,
    evaluation_kwargs,
    fly,
    ppo_job,
    seed_table,
    training_seed_list,
    write_json,
)
from agents.lab.control_studies.training_pool import TrainJob, train_all

__all__ = [
    "TRAINED",
    "TrainedConfig",
    "format_study",
    "plot_study",
    "run_study",
    "scenario_kwargs",
    "train_job",
    "write_json",
]

SCENARIO = "ekf_figure8_biased_imu"
EVAL_SEED0 = 1000
# Training seeds per learned row by default: five, for an IQM and a bootstrap CI over seeds
# (two give only their mean and an interval between them). 4 configurations × 2 seeds × 1M
# steps took 24.7 min on a 2-core machine, most of it training: estimated, not measured, about
# an hour with 5 seeds at that budget.
TRAINING_SEEDS = 5
CLAIM_FACTOR = 0.9
"""A learned row's claim: its steady-state tracking RMSE at most this × DF-LQR's on the same
estimator and episodes, on each training seed."""
ORACLE, ANY = "QuadSLAM-Oracle-v0", "QuadSLAM-v0"
# FastSLAM on the study's scenario with the settings of the paper_fastslam_helix scenario:
# 500 particles, the at-rest ω anchor, and no NEES termination (FastSLAM 1.0's particle
# covariance is over-confident, so its NEES is no divergence signal).
FASTSLAM_KWARGS: dict[str, Any] = {
    "estimator_name": "fastslam",
    "estimator": {
        "params": {"n_particles": 500},
        "initial_cov_diag": [1e-3] * 6 + [1e-4] * 3 + [1e-8] * 3,
    },
    "episode": {"nees_threshold": None},
}
# How each evaluation target is built: env id and extra gymnasium.make kwargs.
EVAL_ON: dict[str, tuple[str, dict[str, Any]]] = {
    "truth": (ORACLE, {}),
    "ekf_slam": (EKF, {}),
    "fastslam": (ANY, FASTSLAM_KWARGS),
}


@dataclass(frozen=True)
class TrainedConfig:
    """A learned configuration: env id to train on, overrides of the entry, eval targets."""

    name: str
    env_id: str
    overrides: dict[str, Any]
    eval_on: tuple[str, ...]
    label: str


TRAINED = (
    TrainedConfig("ppo_truth", ORACLE, {}, ("truth", "ekf_slam"), "residual PPO"),
    TrainedConfig("ppo_ekf", EKF, {}, ("ekf_slam",), "residual PPO"),
    TrainedConfig(
        "ppo_asymmetric",
        EKF,
        {"policy": "AsymmetricActorCriticPolicy"},
        ("ekf_slam",),
        "residual PPO, privileged critic",
    ),
    TrainedConfig(
        "ppo_pos_std",
        EKF,
        {"env_kwargs": {"observation": {"pos_uncertainty": True}}},
        ("ekf_slam",),
        "residual PPO, obs + position std",
    ),
)


def _evaluate(policy_spec: Any, target: str, env_kwargs: dict[str, Any], seeds: list[int]) -> list:
    """Fly ``policy_spec`` (``"dflqr"`` or a run folder) on ``target`` for ``seeds``."""
    from quadslam_env.config.files import deep_merge

    env_id, extra = EVAL_ON[target]
    return fly(policy_spec, env_id, deep_merge(env_kwargs, extra), seeds)


def scenario_kwargs(duration_s: float | None = None) -> dict[str, Any]:
    """The study's env kwargs (:data:`SCENARIO`), the episode ``duration_s`` long if given."""
    kwargs: dict[str, Any] = {"scenario": SCENARIO}
    if duration_s is not None:
        kwargs["episode"] = {"duration_s": float(duration_s)}
    return kwargs


def train_job(
    cfg: TrainedConfig,
    seed: int,
    timesteps: int | None,
    out: Path,
    env_kwargs: dict[str, Any],
    hyperparams: dict[str, Any] | None,
) -> TrainJob:
    """The training of ``cfg`` with ``seed``
    (:func:`~agents.lab.control_studies.learned_rows.ppo_job`)."""
    return ppo_job(
        cfg.name, cfg.env_id, seed, timesteps, out, cfg.overrides, env_kwargs, hyperparams
    )


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    duration_s: float | None = None,
    jobs: int | None = None,
    hyperparams: dict[str, Any] | None = None,
    first_training_seed: int = 0,
) -> dict[str, Any]:
    """Train and evaluate every configuration; returns ``{"rows": [...], "settings": {...}}``.

    Args:
        out: Folder for the training runs (reused when the study is repeated).
        quick: One training seed, 200,000 steps, 5 episodes (unless set below).
        training_seeds: Training seeds per learned configuration (default
            :data:`TRAINING_SEEDS`, 5; quick 1).
        episodes: Held-out evaluation episodes (default 20, quick 5).
        timesteps: Training budget (default: the ``ppo.yaml`` entry's; quick 200,000).
        duration_s: Episode length in s for training and evaluation (default the scenario's).
        jobs: Trainings at a time, each in a worker process (default: the CPU cores available,
            :func:`agents.io.cpus.available_cpus`; 1 trains in this process, one after the
            other). The trained policies do not depend on it
            (:mod:`agents.lab.control_studies.training_pool`).
        hyperparams: Merged into every configuration's entry (after its own overrides).
        first_training_seed: The training seeds are ``first_training_seed`` on (default 0):
            another first seed keeps the table off the seeds a design choice was made on.

    Raises:
        ValueError: ``first_training_seed`` below 0.
    """
    from agents.io.cpus import available_cpus
    from agents.rl.saved.run_folder import run_config

    tic = time.perf_counter()
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    training = training_seed_list(n_seeds, first_training_seed)
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (200_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    base_kwargs = scenario_kwargs(duration_s)
    # Every training first: they run side by side; the evaluations follow in this process.
    plan = [(cfg, seed) for cfg in TRAINED for seed in training]
    runs = train_all(
        [train_job(cfg, s, timesteps, out, base_kwargs, hyperparams) for cfg, s in plan], jobs
    )
    trained = {(cfg.name, seed): run for (cfg, seed), run in zip(plan, runs, strict=True)}
    rows: list[Row] = []
    for target in ("truth", "ekf_slam", "fastslam"):
        print(f"DF-LQR on {target} ...", file=sys.stderr)
        row = Row("dflqr", "dflqr", "-", target)
        row.episodes = _evaluate("dflqr", target, base_kwargs, seeds)
        rows.append(row)
    for cfg in TRAINED:
        targets = {t: Row(cfg.name, cfg.label, _train_on(cfg), t) for t in cfg.eval_on}
        for seed in training:
            run = trained[cfg.name, seed].run
            print(f"{cfg.name} seed {seed}: evaluating ...", file=sys.stderr)
            env_kwargs = (run_config(run) or {}).get("hyperparams", {}).get("env_kwargs", {})
            env_kwargs = evaluation_kwargs(env_kwargs)
            for target, row in targets.items():
                row.add_seed(
                    _evaluate(run, target, env_kwargs, seeds), trained[cfg.name, seed].wall_s
                )
        rows.extend(targets.values())
    settings = {
        "scenario": SCENARIO,
        "eval_seeds": seeds,
        "training_seeds": training,
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and evaluate
    }
    return {"settings": settings, "rows": _with_claims([row.result() for row in rows])}


def _with_claims(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with each learned row's claim against DF-LQR on its evaluation target."""
    baselines = {r["eval_on"]: r for r in rows if r["config"] == "dflqr"}
    for r in rows:
        if r["config"] != "dflqr":
            text = f"<= {CLAIM_FACTOR:g} x dflqr on {r['eval_on']}"
            r["claims"] = [claim(r, baselines.get(r["eval_on"]), CLAIM_FACTOR, text)]
    return rows


def _train_on(cfg: TrainedConfig) -> str:
    return "truth" if cfg.env_id == ORACLE else "ekf_slam"


def format_study(result: dict[str, Any]) -> str:
    """The study table as text."""
    cell = spread_cell

    head = (
        f"{'config':<16} {'train on':<9} {'eval on':<9} {'track RMSE steady m':<24} "
        f"{'transient m':<24} {'crash':>6} {'est pos RMSE steady m':<24} {'seeds':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in result["rows"]:
        lines.append(
            f"{r['config']:<16} {r['train_on']:<9} {r['eval_on']:<9} "
            f"{cell(r['track_pos_rmse_steady_m']):<24} "
            f"{cell(r['track_pos_rmse_transient_m']):<24} {r['crash_rate']:>6.2f} "
            f"{cell(r['est_pos_rmse_steady_m']):<24} {r['n_training_seeds']:>5}"
        )
    lines += seed_table(result["rows"], lambda r: f"{r['config']} on {r['eval_on']}")
    return "\n".join(lines)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """Box plot of the per-episode steady-state tracking RMSE of every row (same held-out
    seeds)."""
    title = (
        f"Cost of estimation: {result['settings']['scenario']}, "
        f"{len(result['settings']['eval_seeds'])} held-out seeds"
    )
    return box_plot(result, out_dir / "cost_of_estimation.png", title)
