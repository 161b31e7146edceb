"""``quadslam study robustness``: the baselines and residual PPO off the nominal physics, each
controller flown on the true state (Oracle) and on every estimator, so a reader can tell a
controller's failure from an estimator's.

Four conditions of the cost study's figure-8 (:data:`agents.lab.control_studies.cost.SCENARIO`,
``ekf_figure8_biased_imu``: the Rauniyar et al. 2023 vehicle, LiDAR and landmarks, the biased,
drifting IMU), flown on the same held-out seeds:

=================  ========================================================================
condition          env kwargs
=================  ========================================================================
``nominal``        ``ekf_figure8_biased_imu`` as it is
``randomized``     plus the ``randomize`` section of ``ekf_figure8_randomized``: mass and
                   inertia ±20%, thrust ±10%, IMU and LiDAR noise ×0.5–2, drawn per episode
``wind``           plus the ``wind`` section and the vehicle's drag keys (:data:`DRAG_KEYS`)
                   of ``ekf_figure8_wind``: 2.2 m/s steady wind, Dryden turbulence
                   (W20 = 3 m/s), rotor and body drag
``wind_moderate``  the same steady wind and drag with the standard's ``moderate`` Dryden
                   turbulence (W20 = 15.4 m/s)
=================  ========================================================================

The sections are read from those scenario files when the study runs (one source). Estimators
(:data:`ESTIMATORS`): ``oracle`` (the true state), ``ekf_thrust_axis`` (EKF-SLAM with seed 001
eq. 25's thrust-axis model; in the windy conditions with the paper's Table 7 Q, without which
its NEES leaves the divergence bound within 4 s), ``ekf_full`` (EKF-SLAM with the whole
specific force, no extra Q), ``ekf_wind`` (EKF-SLAM estimating the horizontal wind with the
vehicle's drag model, the settings of ``ekf_figure8_wind_states``; in the windy conditions
only, since without drag the wind is unobservable and the model refused) and ``isam2`` (the
smoother with the scenario's bias states and no extra Q, extra ``gtsam``; left out without it;
it flies the LQI only, :data:`ISAM2_ROWS`).
Controllers (:data:`CONTROLLER_ROWS`): DF-LQR with the paper's gains, the LQI, the LQI with its
thrust adaptation (:data:`OPTION_ROWS`) and the SE(3) controller with integral action
(:mod:`agents.control`). The learned row ``ppo_lqi`` is
residual PPO on the LQI (the ``QuadSLAM-EKF-v0`` entry of ``ppo.yaml`` with ``wrapper.base:
lqi``), trained on the nominal condition on ``ekf_full`` with seeds ``0 … n-1`` and flown on
``ekf_full`` in every condition. Evaluation seeds start at 1000 and are never used in training;
every row is flown from the scenario's start (take-off climb included). Medians and spreads as
in :mod:`agents.lab.control_studies.learned_rows`; the learned row also carries the IQM and its 95%
bootstrap CI over the training seeds, and on each condition the claim (:data:`CLAIM_FACTOR`)
that its steady-state tracking RMSE is at most 0.9 × the LQI's on ``ekf_full``, with the
number of training seeds it holds on. ``--quick`` trains one seed on a small budget and flies
5 episodes (a smoke run of the pipeline, not a result).
"""

from __future__ import annotations

import copy
import functools
import importlib.util
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from agents.evaluation.episodes import spread_cell
from agents.lab.control_studies.cost import ANY, ORACLE, SCENARIO, scenario_kwargs
from agents.lab.control_studies.learned_rows import (
    EKF,
    Row,
    claim,
    fly,
    ppo_job,
    seed_table,
    training_seed_list,
    write_json,
)
from agents.lab.control_studies.training_pool import train_all
from quadslam_env.sim.randomize import AXIS_INFO_KEYS, RANDOMIZED_KEYS

__all__ = [
    "CONDITIONS",
    "CONTROLLER_ROWS",
    "ESTIMATORS",
    "ROWS",
    "cell_kwargs",
    "condition_kwargs",
    "drawn_scales",
    "format_study",
    "plot_study",
    "run_study",
    "write_json",
]

EVAL_SEED0 = 1000
TRAINING_SEEDS = 5
"""Training seeds of the learned row by default
(:data:`agents.lab.control_studies.cost.TRAINING_SEEDS`)."""
RANDOMIZED, WIND = "ekf_figure8_randomized", "ekf_figure8_wind"
DRAG_KEYS = ("drag_per_s", "drag_quadratic_per_m")
"""The vehicle keys of the wind scenario that the windy conditions take (the drag the wind
acts through)."""
CONDITIONS = ("nominal", "randomized", "wind", "wind_moderate")
WINDY = ("wind", "wind_moderate")
ESTIMATORS = ("oracle", "ekf_thrust_axis", "ekf_full", "ekf_wind", "isam2")
WIND_STATES = "ekf_figure8_wind_states"
"""The scenario whose ``estimator.params`` the ``ekf_wind`` cell takes (wind states)."""
CONTROLLER_ROWS = {
    "dflqr": "DF-LQR (paper gains)",
    "lqi": "LQI",
    "lqi_adapt": "LQI + thrust adaptation",
    "se3": "SE(3) + integral",
}
OPTION_ROWS: dict[str, tuple[str, dict[str, Any]]] = {
    "lqi_adapt": ("lqi", {"thrust_adaptation": True})
}
"""The rows that fly a controller with options (:data:`agents.control.named.OPTIONS`): the
LQI with its thrust-scale adaptation (:mod:`agents.control.adaptation`), the feed-forward
scaled by the thrust ratio its vertical integral measures, for the randomised mass and thrust."""
ISAM2_ROWS = ("lqi",)
"""The rows flown on ``isam2``: the best baseline only (a smoother's step costs ~10 EKF-SLAM
steps, and the Oracle and EKF rows already separate the controllers)."""
LEARNED, LEARNED_BASE, LEARNED_ESTIMATOR = "ppo_lqi", "lqi", "ekf_full"
ROWS = (*CONTROLLER_ROWS, LEARNED)
RESIDUAL = {"wrapper": {"name": "residual_dflqr", "scale": 0.2, "base": LEARNED_BASE}}
"""The learned row's override of the entry: its residual sits on the LQI."""
CLAIM_FACTOR = 0.9
"""The learned row's claim on a condition: its steady-state tracking RMSE at most this × that
of the LQI it sits on, both on ``ekf_full``, on each training seed."""


def _scenario_sections(name: str) -> dict[str, Any]:
    """The sections of ``configs/scenarios/<name>.yaml`` as the config loader reads them."""
    from quadslam_env.config.files import config_dir, load_yaml

    return load_yaml(config_dir() / "scenarios" / f"{name}.yaml")


def condition_kwargs(condition: str, duration_s: float | None = None) -> dict[str, Any]:
    """The physics of ``condition`` as env kwargs (module docstring), without the estimator,
    the episode ``duration_s`` long if given.

    Raises:
        ValueError: ``condition`` is not one of :data:`CONDITIONS`.
    """
    if condition not in CONDITIONS:
        raise ValueError(f"condition: got {condition!r}; allowed: one of {CONDITIONS}")
    kwargs = scenario_kwargs(duration_s)
    if condition == "randomized":
        kwargs["randomize"] = _scenario_sections(RANDOMIZED)["randomize"]
    elif condition in WINDY:
        wind = _scenario_sections(WIND)
        kwargs["wind"] = copy.deepcopy(wind["wind"])
        kwargs["vehicle"] = {key: wind["vehicle"][key] for key in DRAG_KEYS}
        if condition == "wind_moderate":
            kwargs["wind"].pop("w20_mps")
            kwargs["wind"]["preset"] = "moderate"
    return copy.deepcopy(kwargs)


def cell_kwargs(
    condition: str, estimator: str, duration_s: float | None = None
) -> tuple[str, dict[str, Any]]:
    """``(env id, env kwargs)`` of ``condition`` flown on ``estimator`` (module docstring).

    Raises:
        ValueError: An unknown condition or estimator.
    """
    from estimators.ekf.settings import PAPER_Q_UNKNOWN

    kwargs = condition_kwargs(condition, duration_s)
    if estimator == "oracle":
        return ORACLE, kwargs
    params: dict[str, Any]
    if estimator == "isam2":  # with the scenario's settings (bias states, no extra Q), which
        # another estimator's name would otherwise drop
        params = _scenario_sections(SCENARIO)["estimator"]["params"]
        return ANY, {**kwargs, "estimator": {"name": "isam2", "params": params}}
    if estimator == "ekf_wind":
        if condition not in WINDY:
            raise ValueError(f"estimator: ekf_wind needs a windy condition, got {condition!r}")
        params = dict(_scenario_sections(WIND_STATES)["estimator"]["params"])
    elif estimator == "ekf_full":
        params = {"specific_force": "full"}
    elif estimator == "ekf_thrust_axis":
        params = {"specific_force": "thrust_axis"}
        if condition in WINDY:
            params["process_noise"] = list(PAPER_Q_UNKNOWN)
    else:
        raise ValueError(f"estimator: got {estimator!r}; allowed: one of {ESTIMATORS}")
    return EKF, {**kwargs, "estimator": {"params": params}}


def drawn_scales(kwargs: dict[str, Any], seeds: list[int]) -> list[dict[str, float]]:
    """Each seed's randomised scales (``info["rand_*"]`` at its reset; empty without
    randomisation). Every estimator's env of a condition, and every lane of a vector env seeded
    the same, draws the same (:mod:`quadslam_env.sim.randomize`)."""
    import gymnasium as gym

    env = gym.make(ORACLE, **kwargs)
    try:
        infos = [env.reset(seed=seed)[1] for seed in seeds]
    finally:
        env.close()
    keys = (*RANDOMIZED_KEYS, *AXIS_INFO_KEYS)
    return [{k: float(v) for k, v in info.items() if k in keys} for info in infos]


def available_estimators() -> tuple[str, ...]:
    """:data:`ESTIMATORS` that can run here (``isam2`` needs the ``gtsam`` extra)."""
    has_gtsam = importlib.util.find_spec("gtsam") is not None
    return tuple(e for e in ESTIMATORS if e != "isam2" or has_gtsam)


def _train(training: list[int], timesteps: int | None, out: Path, duration_s: float | None,
           jobs: int) -> list[Any]:  # fmt: skip
    """The learned row's trainings (module docstring) in ``out/train/ppo_lqi/s<seed>``."""
    env_id, kwargs = cell_kwargs("nominal", LEARNED_ESTIMATOR, duration_s)
    plan = [ppo_job(LEARNED, env_id, s, timesteps, out, RESIDUAL, kwargs) for s in training]
    return train_all(plan, jobs) if plan else []


def _builder(name: str) -> Any:
    """A callable that builds row ``name``'s controller from an env (for :func:`fly`), with
    the row's options (:data:`OPTION_ROWS`) checked as ``--policy`` checks them."""
    from agents.control.named import build_controller

    base, options = OPTION_ROWS.get(name, (name, {}))
    return functools.partial(build_controller, base, **options)


def _fly_condition(
    condition: str,
    chosen: list[str],
    estimators: Sequence[str],
    trained: dict[int, Any],
    seeds: list[int],
    duration_s: float | None,
) -> list[Row]:
    """Every chosen controller on every estimator, then the learned row, on ``condition``;
    each episode record carries the scales its episode drew."""
    scales = drawn_scales(condition_kwargs(condition, duration_s), seeds)
    rows: list[Row] = []
    for estimator in estimators:
        if estimator == "ekf_wind" and condition not in WINDY:
            continue  # no drag in the truth or the model there: the wind is unobservable
        env_id, kwargs = cell_kwargs(condition, estimator, duration_s)
        names = ISAM2_ROWS if estimator == "isam2" else tuple(CONTROLLER_ROWS)
        for name in (n for n in names if n in chosen):
            print(f"{name} on {estimator}, {condition} ...", file=sys.stderr)
            row = Row(name, CONTROLLER_ROWS[name], "-", condition, estimator=estimator)
            flown = fly(_builder(name), env_id, kwargs, seeds)
            row.episodes = [rec | sc for rec, sc in zip(flown, scales, strict=True)]
            rows.append(row)
    if trained:
        env_id, kwargs = cell_kwargs(condition, LEARNED_ESTIMATOR, duration_s)
        row = Row(LEARNED, "residual PPO on LQI", "nominal", condition, LEARNED_ESTIMATOR)
        for seed, run in trained.items():
            print(f"{LEARNED} seed {seed} on {condition} ...", file=sys.stderr)
            flown = fly(run.run, env_id, kwargs, seeds)
            row.add_seed([rec | sc for rec, sc in zip(flown, scales, strict=True)], run.wall_s)
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
    estimators: Sequence[str] | None = None,
    first_training_seed: int = 0,
) -> dict[str, Any]:
    """Train the learned row, fly every row on every condition and estimator;
    ``{"rows", "settings"}``.

    Args:
        out: Folder for the training runs (reused when the study is repeated).
        quick: One training seed, 200,000 steps, 5 episodes (unless set below).
        training_seeds: Training seeds of the learned row (default :data:`TRAINING_SEEDS`,
            5; quick 1).
        episodes: Held-out evaluation episodes (default 20, quick 5).
        timesteps: Training budget (default: the ``ppo.yaml`` entry's; quick 200,000).
        duration_s: Episode length in s for training and evaluation (default the scenario's).
        jobs: Trainings at a time, each in a worker process (default: the CPU cores).
        rows: The rows to fly, a subset of :data:`ROWS` (default all); the learned one is
            trained only when listed.
        estimators: A subset of :data:`ESTIMATORS` (default those that can run here).
        first_training_seed: The learned row's training seeds are ``first_training_seed`` on
            (default 0).

    Raises:
        ValueError: A row or an estimator not allowed, or ``first_training_seed`` below 0.
    """
    from agents.io.cpus import available_cpus

    tic = time.perf_counter()
    chosen = list(ROWS) if rows is None else list(rows)
    if not chosen or any(name not in ROWS for name in chosen):
        raise ValueError(f"rows: got {chosen!r}; allowed: a non-empty subset of {ROWS}")
    can = available_estimators()
    flown_on = list(can) if estimators is None else list(estimators)
    if not flown_on or any(e not in can for e in flown_on):
        raise ValueError(f"estimators: got {flown_on!r}; allowed: a non-empty subset of {can}")
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    training = training_seed_list(n_seeds, first_training_seed) if LEARNED in chosen else []
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (200_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    trained = dict(zip(training, _train(training, timesteps, out, duration_s, jobs), strict=True))
    table: list[Row] = []
    for condition in CONDITIONS:
        table += _fly_condition(condition, chosen, flown_on, trained, seeds, duration_s)
    settings = {
        "conditions": {c: condition_kwargs(c, duration_s) for c in CONDITIONS},
        "estimators": {e: cell_kwargs("wind", e, duration_s)[0] for e in flown_on},
        "rows": chosen,
        "learned_override": RESIDUAL,
        "eval_seeds": seeds,
        "training_seeds": training,
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "duration_s": duration_s,
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and evaluate
    }
    return {"settings": settings, "rows": _with_claims([row.result() for row in table])}


def _with_claims(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """``rows`` with the learned row's claim on each condition against the LQI on
    ``ekf_full`` (undefined where that row was not flown)."""
    flown = [r for r in rows if (r["config"], r["estimator"]) == (LEARNED_BASE, LEARNED_ESTIMATOR)]
    base = {r["eval_on"]: r for r in flown}
    text = f"<= {CLAIM_FACTOR:g} x {LEARNED_BASE} on {LEARNED_ESTIMATOR}"
    for r in rows:
        if r["config"] == LEARNED:
            r["claims"] = [claim(r, base.get(r["eval_on"]), CLAIM_FACTOR, text)]
    return rows


def format_study(result: dict[str, Any]) -> str:
    """The study table as text, grouped by condition and estimator (steady state first)."""
    cell = spread_cell
    head = (
        f"{'condition':<14} {'estimator':<16} {'config':<8} {'track RMSE steady m':<24} "
        f"{'transient m':<24} {'est pos steady m':<24} {'att steady deg':<24} {'ended':>6} "
        f"{'seeds':>5}"
    )
    lines = [head, "-" * len(head)]
    for r in result["rows"]:
        lines.append(
            f"{r['eval_on']:<14} {r['estimator']:<16} {r['config']:<8} "
            f"{cell(r['track_pos_rmse_steady_m']):<24} {cell(r['track_pos_rmse_transient_m']):<24} "
            f"{cell(r['est_pos_rmse_steady_m']):<24} {cell(r['est_att_rmse_steady_deg']):<24} "
            f"{r['n_ended_early']:>3}/{r['n_episodes']:<2} {r['n_training_seeds']:>5}"
        )
    lines += seed_table(result["rows"], lambda r: f"{r['config']} {r['eval_on']} {r['estimator']}")
    return "\n".join(lines)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """One panel per condition: each estimator's group of rows, the median steady-state
    tracking RMSE as a bar with its min–max (log scale), to ``out_dir/robustness.png``."""
    from matplotlib.figure import Figure

    from agents.io.outputs import atomic_produce

    rows = result["rows"]
    conditions = [c for c in CONDITIONS if any(r["eval_on"] == c for r in rows)]
    configs = list(dict.fromkeys(r["config"] for r in rows))
    fig = Figure(figsize=(4.0 * len(conditions), 4.5), layout="constrained")
    axes = fig.subplots(1, len(conditions), sharey=True, squeeze=False)[0]
    width = 0.8 / max(len(configs), 1)
    drawn = False
    for ax, condition in zip(axes, conditions, strict=True):
        here = [r for r in rows if r["eval_on"] == condition]
        groups = list(dict.fromkeys(r["estimator"] for r in here))
        for k, config in enumerate(configs):
            xs: list[float] = []
            mid: list[float] = []
            err: list[list[float]] = [[], []]
            for g, estimator in enumerate(groups):
                r = next((r for r in here if (r["config"], r["estimator"]) == (config, estimator)),
                         None)  # fmt: skip
                spread = r["track_pos_rmse_steady_m"] if r else {"median": None}
                if spread["median"] is None:
                    continue
                xs.append(g + (k - (len(configs) - 1) / 2) * width)
                mid.append(spread["median"])
                err[0].append(spread["median"] - spread["min"])
                err[1].append(spread["max"] - spread["median"])
            ax.bar(xs, mid, width, yerr=err, label=config, capsize=2)
            drawn |= any(m > 0.0 for m in mid)
        ax.set_xticks(range(len(groups)), groups, rotation=20, fontsize=8)
        ax.set_title(condition)
        ax.grid(axis="y", alpha=0.3, which="both")
    if drawn:  # (episodes too short for a steady state draw no bars)
        axes[0].set_yscale("log")
    axes[0].set_ylabel("true tracking RMSE, steady state [m] (median, min–max)")
    axes[-1].legend(fontsize=8)
    n = len(result["settings"]["eval_seeds"])
    fig.suptitle(f"Robustness: controllers on the Oracle and on each estimator, {n} held-out seeds")
    path = out_dir / "robustness.png"
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=120))
    return path
