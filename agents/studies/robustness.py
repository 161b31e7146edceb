"""``quadslam study robustness``: DF-LQR and residual PPO on EKF-SLAM off the nominal physics.

Three conditions of the same figure-8 on EKF-SLAM (the Rauniyar et al. 2023 vehicle, IMU,
LiDAR and landmarks, the filter with the paper's Table 7 Q), flown on the same held-out seeds:

==============  ===========================================================================
condition       env kwargs
==============  ===========================================================================
``nominal``     ``ekf_figure8_randomized`` with every ``randomize`` range ``[1, 1]``
``randomized``  ``ekf_figure8_randomized``: mass and inertia ±20%, thrust ±10%, IMU and LiDAR
                noise ×0.5–2, drawn per episode (``info["rand_*"]``)
``wind``        ``ekf_figure8_wind``: 2.2 m/s steady wind, Dryden turbulence, rotor and body
                drag
==============  ===========================================================================

The nominal condition is the randomised scenario with its draws pinned to 1: the two differ in
the ``randomize`` section only, and a lane draws the same landmarks, sensor noise and initial
error with or without randomisation (:mod:`quadslam_env.randomize`); the wind scenario differs
from it in the ``wind`` section and the vehicle's drag only. (``ekf_figure8_biased_imu``, the
cost study's scenario, is no twin of these two: another IMU, a zero extra Q and the IMU biases
estimated.)

Rows, each flown on every condition: DF-LQR; residual PPO trained on the nominal condition
(``ppo_nominal``); residual PPO trained on the randomised one (``ppo_randomized``). Both learned
rows use the ``QuadSLAM-EKF-v0`` entry of ``ppo.yaml`` unchanged but for the scenario (the cost
study's ``ppo_ekf``: same hyperparameters and budget, episodes started on the reference in
training only), with seeds ``0 … n-1``; evaluation seeds start at 1000 and are never used in
training, and every row is flown from the scenario's start (take-off climb included). Medians
and spreads as in :mod:`agents.studies.learned_rows`. ``--quick`` trains one seed on a small
budget and flies 5 episodes (a smoke run of the pipeline, not a result). Each episode record
carries the scales its episode drew (``rand_*``, randomised condition only).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from agents.evaluation.episodes import spread_cell
from agents.studies.learned_rows import EKF, Row, box_plot, fly, ppo_job, write_json
from agents.studies.training_pool import train_all
from quadslam_env.config_randomize import SCALE_KEYS
from quadslam_env.randomize import RANDOMIZED_KEYS

__all__ = [
    "CONDITIONS",
    "LEARNED",
    "condition_kwargs",
    "drawn_scales",
    "format_study",
    "plot_study",
    "run_study",
    "write_json",
]

EVAL_SEED0 = 1000
TRAINING_SEEDS = 2
RANDOMIZED, WIND = "ekf_figure8_randomized", "ekf_figure8_wind"
CONDITIONS: dict[str, dict[str, Any]] = {
    "nominal": {"scenario": RANDOMIZED, "randomize": {k: [1.0, 1.0] for k in SCALE_KEYS}},
    "randomized": {"scenario": RANDOMIZED},
    "wind": {"scenario": WIND},
}
"""Each condition's ``gymnasium.make(QuadSLAM-EKF-v0, ...)`` kwargs (module docstring)."""


@dataclass(frozen=True)
class Learned:
    """A learned row: its name, the condition it trains on, its label."""

    name: str
    train_on: str
    label: str


LEARNED = (
    Learned("ppo_nominal", "nominal", "residual PPO"),
    Learned("ppo_randomized", "randomized", "residual PPO, randomised training"),
)


def condition_kwargs(condition: str, duration_s: float | None = None) -> dict[str, Any]:
    """The env kwargs of ``condition`` (a copy), the episode ``duration_s`` long if given."""
    from quadslam_env.config import deep_merge

    extra = {} if duration_s is None else {"episode": {"duration_s": float(duration_s)}}
    return deep_merge(CONDITIONS[condition], extra)


def drawn_scales(kwargs: dict[str, Any], seeds: list[int]) -> list[dict[str, float]]:
    """Each seed's randomised scales (``info["rand_*"]`` at its reset; empty without
    randomisation). A lane of the vector env seeded the same draws the same
    (:mod:`quadslam_env.randomize`), so these are the scales the study's episodes flew."""
    import gymnasium as gym

    env = gym.make(EKF, **kwargs)
    try:
        infos = [env.reset(seed=seed)[1] for seed in seeds]
    finally:
        env.close()
    return [{k: float(v) for k, v in info.items() if k in RANDOMIZED_KEYS} for info in infos]


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    duration_s: float | None = None,
    jobs: int | None = None,
) -> dict[str, Any]:
    """Train the learned rows, fly every row on every condition; ``{"rows", "settings"}``.

    Args:
        out: Folder for the training runs (reused when the study is repeated).
        quick: One training seed, 200,000 steps, 5 episodes (unless set below).
        training_seeds: Training seeds per learned row (default 2, quick 1).
        episodes: Held-out evaluation episodes (default 20, quick 5).
        timesteps: Training budget (default: the ``ppo.yaml`` entry's; quick 200,000).
        duration_s: Episode length in s for training and evaluation (default the scenario's).
        jobs: Trainings at a time, each in a worker process (default: the CPU cores
            available); the trained policies do not depend on it
            (:mod:`agents.studies.training_pool`).
    """
    from agents.io.cpus import available_cpus

    tic = time.perf_counter()
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (200_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    plan = [(cfg, seed) for cfg in LEARNED for seed in range(n_seeds)]
    runs = train_all(
        [
            ppo_job(
                cfg.name, EKF, seed, timesteps, out, {}, condition_kwargs(cfg.train_on, duration_s)
            )
            for cfg, seed in plan
        ],
        jobs,
    )
    trained = {(cfg.name, seed): run for (cfg, seed), run in zip(plan, runs, strict=True)}
    rows: list[Row] = []
    for condition in CONDITIONS:
        # Every row flies the condition's own kwargs: a learned row's training kwargs (the
        # pinned randomize section of ppo_nominal) must not leak into another condition.
        kwargs = condition_kwargs(condition, duration_s)
        scales = drawn_scales(kwargs, seeds)

        def flown(policy: Any, kwargs: dict[str, Any] = kwargs, scales: list = scales) -> list:
            """The episode records of ``policy``, each with its episode's drawn scales."""
            return [
                rec | sc for rec, sc in zip(fly(policy, EKF, kwargs, seeds), scales, strict=True)
            ]

        print(f"DF-LQR on {condition} ...", file=sys.stderr)
        row = Row("dflqr", "DF-LQR", "-", condition)
        row.episodes = flown("dflqr")
        rows.append(row)
        for cfg in LEARNED:
            row = Row(cfg.name, cfg.label, cfg.train_on, condition)
            for seed in range(n_seeds):
                print(f"{cfg.name} seed {seed} on {condition} ...", file=sys.stderr)
                run = trained[cfg.name, seed]
                row.add_seed(flown(run.run), run.wall_s)
            rows.append(row)
    settings = {
        "conditions": CONDITIONS,
        "env_id": EKF,
        "eval_seeds": seeds,
        "training_seeds": list(range(n_seeds)),
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "duration_s": duration_s,
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and evaluate
    }
    return {"settings": settings, "rows": [row.result() for row in rows]}


def format_study(result: dict[str, Any]) -> str:
    """The study table as text, grouped by condition (steady state first)."""
    cell = spread_cell
    head = (
        f"{'condition':<11} {'config':<15} {'track RMSE steady m':<24} {'transient m':<24} "
        f"{'est pos RMSE steady m':<24} {'ended':>6} {'seeds':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in result["rows"]:
        lines.append(
            f"{r['eval_on']:<11} {r['config']:<15} {cell(r['track_pos_rmse_steady_m']):<24} "
            f"{cell(r['track_pos_rmse_transient_m']):<24} "
            f"{cell(r['est_pos_rmse_steady_m']):<24} "
            f"{r['n_ended_early']:>3}/{r['n_episodes']:<2} {r['n_training_seeds']:>5}"
        )
    return "\n".join(lines)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """Box plot of every row's per-episode steady-state tracking RMSE."""
    n = len(result["settings"]["eval_seeds"])
    title = f"Robustness: EKF-SLAM figure-8, nominal / randomised / wind, {n} held-out seeds"
    return box_plot(result, out_dir / "robustness.png", title)
