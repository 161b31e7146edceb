"""``quadslam study robustness``: DF-LQR and residual PPO on EKF-SLAM off the nominal physics.

Three conditions of the cost study's figure-8 on EKF-SLAM (:data:`agents.studies.cost.SCENARIO`,
``ekf_figure8_biased_imu``: the Rauniyar et al. 2023 vehicle, LiDAR and landmarks, the biased,
drifting IMU whose biases the filter estimates), flown on the same held-out seeds:

==============  ===========================================================================
condition       env kwargs
==============  ===========================================================================
``nominal``     ``ekf_figure8_biased_imu`` as it is
``randomized``  the same plus the ``randomize`` section of ``ekf_figure8_randomized``: mass
                and inertia ±20%, thrust ±10%, IMU and LiDAR noise ×0.5–2, drawn per
                episode (``info["rand_*"]``)
``wind``        the same plus the ``wind`` section, the vehicle's drag keys
                (:data:`DRAG_KEYS`) and the filter's ``process_noise`` of
                ``ekf_figure8_wind``: 2.2 m/s steady wind, Dryden turbulence, rotor and
                body drag, and the paper's Table 7 Q for the drag the filter does not model
==============  ===========================================================================

The sections are read from those scenario files when the study runs (one source); the
conditions differ in them only. The wind condition needs the filter's Q: with the nominal
filter (no extra process noise) the unmodelled drag drives the pose NEES past the env's
divergence threshold within ~4 s and every episode ends there, whatever the controller
(docs/robustness.md). Rows, each flown on every condition: DF-LQR; DF-LQR with
integral action (``dflqr_integral``: :data:`INTEGRAL_GAIN`, frozen during the climb); residual
PPO trained on the nominal condition (``ppo_nominal``: the cost study's ``ppo_ekf`` training,
the same entry, scenario and seeds, so the same runs); residual PPO trained on the randomised
one (``ppo_randomized``: the same with the ``randomize`` section added), with seeds
``0 … n-1``. Evaluation seeds start at 1000 and are never used in training; every row is flown
from the scenario's start (take-off climb included). Medians and spreads as in
:mod:`agents.studies.learned_rows`. ``--quick`` trains one seed on a small budget and flies 5
episodes (a smoke run of the pipeline, not a result). Each episode record carries the scales its
episode drew (``rand_*``, randomised condition only).
"""

from __future__ import annotations

import copy
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from agents.evaluation.episodes import spread_cell
from agents.studies.cost import TRAINED, scenario_kwargs, train_job
from agents.studies.learned_rows import EKF, Row, box_plot, fly, write_json
from agents.studies.training_pool import train_all
from quadslam_env.randomize import AXIS_INFO_KEYS, RANDOMIZED_KEYS

__all__ = [
    "CONDITIONS",
    "DFLQR_ROWS",
    "LEARNED",
    "ROWS",
    "condition_kwargs",
    "dflqr_integral",
    "drawn_scales",
    "format_study",
    "plot_study",
    "run_study",
    "write_json",
]

EVAL_SEED0 = 1000
TRAINING_SEEDS = 2
RANDOMIZED, WIND = "ekf_figure8_randomized", "ekf_figure8_wind"
DRAG_KEYS = ("drag_per_s", "drag_quadratic_per_m")
"""The vehicle keys of the wind scenario that the wind condition takes (the drag the wind acts
through)."""
CONDITIONS = ("nominal", "randomized", "wind")
INTEGRAL_GAIN, INTEGRAL_HOLD_S = 0.05, 10.0
"""``dflqr_integral``'s ``k_i`` in s⁻³ (below the stability bound 0.11) and the time in s its
integral stays frozen after the start: the take-off climb, the scenarios' 10 s settle phase
(docs/robustness.md: how they were chosen, on other seeds than the study's)."""


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
DFLQR_ROWS = {"dflqr": "DF-LQR", "dflqr_integral": "DF-LQR + integral"}
ROWS = (*DFLQR_ROWS, *(cfg.name for cfg in LEARNED))
_PPO_EKF = next(cfg for cfg in TRAINED if cfg.name == "ppo_ekf")


def _scenario_sections(name: str) -> dict[str, Any]:
    """The sections of ``configs/scenarios/<name>.yaml`` as the config loader reads them."""
    from quadslam_env.config_files import config_dir, load_yaml

    return load_yaml(config_dir() / "scenarios" / f"{name}.yaml")


def condition_kwargs(condition: str, duration_s: float | None = None) -> dict[str, Any]:
    """The ``gymnasium.make(QuadSLAM-EKF-v0, ...)`` kwargs of ``condition`` (module
    docstring), the episode ``duration_s`` long if given.

    Raises:
        ValueError: ``condition`` is not one of :data:`CONDITIONS`.
    """
    kwargs = scenario_kwargs(duration_s)
    if condition == "randomized":
        kwargs["randomize"] = _scenario_sections(RANDOMIZED)["randomize"]
    elif condition == "wind":
        wind = _scenario_sections(WIND)
        kwargs["wind"] = wind["wind"]
        kwargs["vehicle"] = {key: wind["vehicle"][key] for key in DRAG_KEYS}
        noise = wind["estimator"]["params"]["process_noise"]
        kwargs.setdefault("estimator", {}).setdefault("params", {})["process_noise"] = noise
    elif condition != "nominal":
        raise ValueError(f"condition: got {condition!r}; allowed: one of {CONDITIONS}")
    return copy.deepcopy(kwargs)


def dflqr_integral(env: Any) -> Any:
    """DF-LQR with integral action (:data:`INTEGRAL_GAIN`, :data:`INTEGRAL_HOLD_S`) for
    ``env``."""
    from agents.control.dflqr import DFLQRPolicy

    return DFLQRPolicy.from_env(env, integral_gain=INTEGRAL_GAIN, integral_hold_s=INTEGRAL_HOLD_S)


_DFLQR_SPECS: dict[str, Any] = {"dflqr": "dflqr", "dflqr_integral": dflqr_integral}


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
    keys = (*RANDOMIZED_KEYS, *AXIS_INFO_KEYS)
    return [{k: float(v) for k, v in info.items() if k in keys} for info in infos]


def _train(
    learned: list[Learned],
    n_seeds: int,
    timesteps: int | None,
    out: Path,
    duration_s: float | None,
    jobs: int,
) -> dict[tuple[str, int], Any]:
    """Train every learned row: the cost study's ``ppo_ekf`` job (the same entry and seeds) on
    the row's condition, in ``out/train/<name>/s<seed>``; ``{(name, seed): TrainResult}``."""
    plan = [(cfg, seed) for cfg in learned for seed in range(n_seeds)]
    jobs_ = [
        train_job(
            replace(_PPO_EKF, name=cfg.name),
            seed,
            timesteps,
            out,
            condition_kwargs(cfg.train_on, duration_s),
            None,
        )
        for cfg, seed in plan
    ]
    runs = train_all(jobs_, jobs) if jobs_ else []
    return {(cfg.name, seed): run for (cfg, seed), run in zip(plan, runs, strict=True)}


def _fly_condition(
    condition: str,
    chosen: list[str],
    learned: list[Learned],
    trained: dict[tuple[str, int], Any],
    n_seeds: int,
    seeds: list[int],
    duration_s: float | None,
) -> list[Row]:
    """The rows ``chosen`` flown on ``condition`` for ``seeds`` (the learned ones from their
    ``trained`` runs), each episode record with the scales its episode drew."""
    # Every row flies the condition's own kwargs: a learned row's training kwargs (the
    # randomize section of ppo_randomized) must not leak into another condition.
    kwargs = condition_kwargs(condition, duration_s)
    scales = drawn_scales(kwargs, seeds)

    def flown(policy: Any) -> list:
        return [rec | sc for rec, sc in zip(fly(policy, EKF, kwargs, seeds), scales, strict=True)]

    rows: list[Row] = []
    for name, label in DFLQR_ROWS.items():
        if name in chosen:
            print(f"{name} on {condition} ...", file=sys.stderr)
            row = Row(name, label, "-", condition)
            row.episodes = flown(_DFLQR_SPECS[name])
            rows.append(row)
    for cfg in learned:
        row = Row(cfg.name, cfg.label, cfg.train_on, condition)
        for seed in range(n_seeds):
            print(f"{cfg.name} seed {seed} on {condition} ...", file=sys.stderr)
            run = trained[cfg.name, seed]
            row.add_seed(flown(run.run), run.wall_s)
        rows.append(row)
    return rows


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    duration_s: float | None = None,
    jobs: int | None = None,
    rows: Sequence[str] | None = None,
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
        rows: The rows to fly, a subset of :data:`ROWS` (default all); only the learned ones
            among them are trained.

    Raises:
        ValueError: A row not in :data:`ROWS`.
    """
    from agents.io.cpus import available_cpus

    tic = time.perf_counter()
    chosen = list(ROWS) if rows is None else list(rows)
    if not chosen or any(name not in ROWS for name in chosen):
        raise ValueError(f"rows: got {chosen!r}; allowed: a non-empty subset of {ROWS}")
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (200_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    learned = [cfg for cfg in LEARNED if cfg.name in chosen]
    trained = _train(learned, n_seeds, timesteps, out, duration_s, jobs)
    table: list[Row] = []
    for condition in CONDITIONS:
        table += _fly_condition(condition, chosen, learned, trained, n_seeds, seeds, duration_s)
    settings = {
        "conditions": {c: condition_kwargs(c, duration_s) for c in CONDITIONS},
        "env_id": EKF,
        "rows": chosen,
        "integral_gain": INTEGRAL_GAIN,
        "integral_hold_s": INTEGRAL_HOLD_S,
        "eval_seeds": seeds,
        "training_seeds": list(range(n_seeds)) if learned else [],
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "duration_s": duration_s,
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and evaluate
    }
    return {"settings": settings, "rows": [row.result() for row in table]}


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
