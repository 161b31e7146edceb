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
evaluated on the scenario's own start, take-off climb included (:func:`evaluation_kwargs`).
A learned row's median/min/max are over its training seeds (each seed's median over
the episodes); a DF-LQR row's over the episodes. ``--quick`` trains one seed on a small budget
and evaluates 5 episodes (a smoke run of the whole pipeline, minutes, not a result).
"""

from __future__ import annotations

import copy
import json
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float, run_episodes, spread_cell
from agents.io.outputs import atomic_produce, write_text_atomic
from agents.studies.training_pool import TrainJob, train_all

SCENARIO = "ekf_figure8_biased_imu"
EVAL_SEED0 = 1000
# Training seeds per learned row by default: 4 configurations × 2 seeds × 1M steps keep the
# full study within ~30 min on a 2-core machine (3 seeds took ~38 min).
TRAINING_SEEDS = 2
ORACLE, EKF, ANY = "QuadSLAM-Oracle-v0", "QuadSLAM-EKF-v0", "QuadSLAM-v0"
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
# Tracking RMSE columns (steady state first: the headline), spread over training seeds for the
# learned rows; estimation columns, over episodes.
TRACK_KEYS = ("track_pos_rmse_steady_m", "track_pos_rmse_transient_m", "track_pos_rmse_m")
EST_KEYS = ("est_pos_rmse_steady_m", "est_pos_rmse_m", "anees_pose_steady", "anees_pose")
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


@dataclass
class Row:
    """One line of the table: a policy evaluated on one target, over its training seeds."""

    config: str
    policy: str
    train_on: str
    eval_on: str
    episodes: list[dict[str, Any]] = field(default_factory=list)
    per_seed: list[list[dict[str, Any]]] = field(default_factory=list)  # learned rows
    train_wall_s: list[float] = field(default_factory=list)

    def result(self) -> dict[str, Any]:
        """The JSON row (see the module docstring for what median/min/max are over)."""
        out: dict[str, Any] = {
            "config": self.config,
            "policy": self.policy,
            "train_on": self.train_on,
            "eval_on": self.eval_on,
            "spread_over": "training seeds" if self.per_seed else "episodes",
        }
        for key in TRACK_KEYS:
            out[key] = self._spread(key)
        out["crash_rate"] = float(np.mean([e["terminated"] for e in self.episodes]))
        for key in EST_KEYS:
            out[key] = _stats([e.get(key) for e in self.episodes])
        out["n_steady_episodes"] = sum(
            e.get("track_pos_rmse_steady_m") is not None for e in self.episodes
        )
        out.update(
            n_training_seeds=len(self.per_seed),
            n_episodes=len(self.episodes),
            train_wall_s=self.train_wall_s,
            episodes=self.episodes,
        )
        return out

    def _spread(self, key: str) -> dict[str, float | None]:
        """Stats of ``key`` over the training seeds' medians (learned) or the episodes."""
        if self.per_seed:
            return _stats([_nanmedian([e.get(key) for e in eps]) for eps in self.per_seed])
        return _stats([e.get(key) for e in self.episodes])


def _nanmedian(values: list[Any]) -> float:
    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
    return float(np.nanmedian(arr)) if np.isfinite(arr).any() else float("nan")


def _stats(values: list[Any]) -> dict[str, float | None]:
    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
    arr = arr[np.isfinite(arr)]
    if not arr.size:
        return {"median": None, "min": None, "max": None}
    return {"median": float(np.median(arr)), "min": float(arr.min()), "max": float(arr.max())}


def _evaluate(policy_spec: Any, target: str, env_kwargs: dict[str, Any], seeds: list[int]) -> list:
    """Fly ``policy_spec`` (``"dflqr"`` or a run folder) on ``target`` for ``seeds``."""
    import gymnasium as gym

    from agents.rl.policies import load_policy
    from quadslam_env.config import deep_merge

    env_id, extra = EVAL_ON[target]
    env = gym.make(env_id, **deep_merge(env_kwargs, extra))
    try:
        with warnings.catch_warnings():  # evaluating off the training setup is the point here
            warnings.filterwarnings("ignore", "evaluating on a different setup than training")
            policy, _ = load_policy(str(policy_spec), env)
        return run_episodes(env, policy, seeds)
    finally:
        env.close()


def _train_job(
    cfg: TrainedConfig,
    seed: int,
    timesteps: int | None,
    out: Path,
    env_kwargs: dict[str, Any],
    hyperparams: dict[str, Any] | None,
) -> TrainJob:
    """The training of ``cfg`` with ``seed``: the ``QuadSLAM-EKF-v0`` entry with the
    configuration's overrides, then ``hyperparams``, on ``env_kwargs``; in
    ``out/train/<config>/s<seed>``."""
    from agents.rl.hyperparams import load_hyperparams
    from quadslam_env.config import deep_merge

    entry = deep_merge(deep_merge(load_hyperparams("ppo", EKF), cfg.overrides), hyperparams or {})
    entry["env_kwargs"] = deep_merge(entry.get("env_kwargs", {}), env_kwargs)
    folder = out / "train" / cfg.name / f"s{seed}"
    return TrainJob(f"{cfg.name} seed {seed}", folder, cfg.env_id, seed, timesteps, entry)


def run_study(
    out: Path,
    quick: bool = False,
    training_seeds: int | None = None,
    episodes: int | None = None,
    timesteps: int | None = None,
    duration_s: float | None = None,
    jobs: int | None = None,
    hyperparams: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Train and evaluate every configuration; returns ``{"rows": [...], "settings": {...}}``.

    Args:
        out: Folder for the training runs (reused when the study is repeated).
        quick: One training seed, 200,000 steps, 5 episodes (unless set below).
        training_seeds: Training seeds per learned configuration (default
            :data:`TRAINING_SEEDS`, quick 1).
        episodes: Held-out evaluation episodes (default 20, quick 5).
        timesteps: Training budget (default: the ``ppo.yaml`` entry's; quick 200,000).
        duration_s: Episode length in s for training and evaluation (default the scenario's).
        jobs: Trainings at a time, each in a worker process (default: the CPU cores available,
            :func:`agents.io.cpus.available_cpus`; 1 trains in this process, one after the
            other). The trained policies do not depend on it
            (:mod:`agents.studies.training_pool`).
        hyperparams: Merged into every configuration's entry (after its own overrides).
    """
    from agents.io.cpus import available_cpus
    from agents.rl.run_folder import run_config

    tic = time.perf_counter()
    jobs = jobs or available_cpus()
    n_seeds = training_seeds or (1 if quick else TRAINING_SEEDS)
    n_eps = episodes or (5 if quick else 20)
    timesteps = timesteps or (200_000 if quick else None)
    seeds = list(range(EVAL_SEED0, EVAL_SEED0 + n_eps))
    base_kwargs: dict[str, Any] = {"scenario": SCENARIO}
    if duration_s is not None:
        base_kwargs["episode"] = {"duration_s": float(duration_s)}
    # Every training first: they run side by side; the evaluations follow in this process.
    plan = [(cfg, seed) for cfg in TRAINED for seed in range(n_seeds)]
    runs = train_all(
        [_train_job(cfg, s, timesteps, out, base_kwargs, hyperparams) for cfg, s in plan], jobs
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
        for seed in range(n_seeds):
            run = trained[cfg.name, seed].run
            print(f"{cfg.name} seed {seed}: evaluating ...", file=sys.stderr)
            env_kwargs = (run_config(run) or {}).get("hyperparams", {}).get("env_kwargs", {})
            env_kwargs = evaluation_kwargs(env_kwargs)
            for target, row in targets.items():
                eps = _evaluate(run, target, env_kwargs, seeds)
                row.per_seed.append(eps)
                row.episodes += eps
                row.train_wall_s.append(round(trained[cfg.name, seed].wall_s, 1))
        rows.extend(targets.values())
    settings = {
        "scenario": SCENARIO,
        "eval_seeds": seeds,
        "training_seeds": list(range(n_seeds)),
        "timesteps": timesteps if timesteps is not None else "the ppo.yaml budget",
        "quick": quick,
        "jobs": jobs,
        "wall_s": round(time.perf_counter() - tic, 1),  # the whole study: train and evaluate
    }
    return {"settings": settings, "rows": [row.result() for row in rows]}


def evaluation_kwargs(train_kwargs: dict[str, Any]) -> dict[str, Any]:
    """The env kwargs a learned row is evaluated with: its training ``env_kwargs`` without
    the training-only ``trajectory.start_on_reference`` (every row flies the same take-off)."""
    out = copy.deepcopy(train_kwargs)
    trajectory = out.get("trajectory")
    if isinstance(trajectory, dict):
        trajectory.pop("start_on_reference", None)
        if not trajectory:
            del out["trajectory"]
    return out


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
    return "\n".join(lines)


def plot_study(result: dict[str, Any], out_dir: Path) -> Path:
    """Box plot of the per-episode steady-state tracking RMSE of every row (same held-out
    seeds)."""
    from matplotlib.figure import Figure

    rows = result["rows"]
    data = [
        [e["track_pos_rmse_steady_m"] for e in r["episodes"] if "track_pos_rmse_steady_m" in e]
        for r in rows
    ]
    labels = [f"{r['config']}\n{r['train_on']} → {r['eval_on']}" for r in rows]
    fig = Figure(figsize=(max(8.0, 1.2 * len(rows)), 5.0), layout="constrained")
    ax = fig.subplots()
    ax.boxplot(data, tick_labels=labels, showfliers=True)
    for i, r in enumerate(rows, start=1):
        if r["crash_rate"] > 0:
            ax.annotate(
                f"{r['crash_rate']:.0%} ended early",
                (i, ax.get_ylim()[1]),
                ha="center",
                va="top",
                fontsize=7,
                color="tab:red",
            )
    ax.set_ylabel("true tracking RMSE per episode, steady state [m]")
    ax.set_title(
        f"Cost of estimation: {result['settings']['scenario']}, "
        f"{len(result['settings']['eval_seeds'])} held-out seeds"
    )
    ax.tick_params(axis="x", labelsize=7)
    ax.grid(axis="y", alpha=0.3)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "cost_of_estimation.png"
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=120))
    return path


def write_json(result: dict[str, Any], path: Path) -> None:
    """Write the study result (NaN as null)."""

    def clean(value: Any) -> Any:
        if isinstance(value, dict):
            return {k: clean(v) for k, v in value.items()}
        if isinstance(value, list):
            return [clean(v) for v in value]
        if isinstance(value, float):
            return json_float(value)
        return value

    path.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(path, json.dumps(clean(result), indent=2) + "\n")
