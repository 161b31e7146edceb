"""What the studies that train residual PPO rows share: their trainings, their flights on
held-out seeds and their table rows.

A learned row is residual PPO with the ``QuadSLAM-EKF-v0`` entry of ``configs/agents/ppo.yaml``
(:func:`ppo_job`: the entry with a configuration's overrides, trained with seeds ``0 … n-1``
or from another first seed (:func:`training_seed_list`),
each run in a folder of its own where a finished run is reused); a row's median/min/max are over
its training seeds, each seed's value being its median over the episodes, and a DF-LQR row's over
the episodes (:class:`Row`). A learned row also reports, per tracking column, the median, the
interquartile mean and its 95% bootstrap confidence interval over the training seeds
(``seed_stats``, :mod:`agents.evaluation.seed_stats`), and on how many seeds the study's claim
holds (``claims``, :func:`claim`; :func:`seed_table` prints both). Used by
:mod:`agents.lab.control_studies.cost`, :mod:`agents.lab.control_studies.robustness` and
:mod:`agents.lab.control_studies.active`.
"""

from __future__ import annotations

import copy
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float, run_episodes
from agents.evaluation.seed_stats import ci_cell, claim_at_most, summary
from agents.io.outputs import atomic_produce, write_text_atomic
from agents.lab.control_studies.training_pool import TrainJob

EKF = "QuadSLAM-EKF-v0"
"""The env id whose ``ppo.yaml`` entry every learned row trains with."""
# Tracking RMSE columns (steady state first: the headline), spread over training seeds for the
# learned rows; estimation columns, over episodes.
TRACK_KEYS = ("track_pos_rmse_steady_m", "track_pos_rmse_transient_m", "track_pos_rmse_m")
HEADLINE = TRACK_KEYS[0]
"""The column the studies' claims are about: the true tracking RMSE in the steady state."""
EST_KEYS = (
    "est_pos_rmse_steady_m",
    "est_pos_rmse_m",
    "est_att_rmse_steady_deg",
    "est_wind_rmse_steady_mps",
    "anees_pose_steady",
    "anees_pose",
)


@dataclass
class Row:
    """One line of a table: a policy flown on one target, over its training seeds."""

    config: str
    policy: str
    train_on: str
    eval_on: str
    estimator: str = ""  # the estimator flown on, where a study sets it apart from eval_on
    episodes: list[dict[str, Any]] = field(default_factory=list)
    per_seed: list[list[dict[str, Any]]] = field(default_factory=list)  # learned rows
    train_wall_s: list[float] = field(default_factory=list)

    def add_seed(self, episodes: list[dict[str, Any]], train_wall_s: float) -> None:
        """Add one training seed's flights (a learned row)."""
        self.per_seed.append(episodes)
        self.episodes += episodes
        self.train_wall_s.append(round(train_wall_s, 1))

    def result(self) -> dict[str, Any]:
        """The JSON row (see the module docstring for what median/min/max are over)."""
        out: dict[str, Any] = {
            "config": self.config,
            "policy": self.policy,
            "train_on": self.train_on,
            "eval_on": self.eval_on,
            **({"estimator": self.estimator} if self.estimator else {}),
            "spread_over": "training seeds" if self.per_seed else "episodes",
        }
        for key in TRACK_KEYS:
            out[key] = self._spread(key)
        ended = [e["terminated"] for e in self.episodes]
        out["crash_rate"] = float(np.mean(ended))
        out["n_ended_early"] = int(sum(ended))
        for key in EST_KEYS:
            out[key] = _stats([e.get(key) for e in self.episodes])
        out["n_steady_episodes"] = sum(
            e.get("track_pos_rmse_steady_m") is not None for e in self.episodes
        )
        out.update(n_training_seeds=len(self.per_seed), n_episodes=len(self.episodes))
        if self.per_seed:
            out["seed_stats"] = {key: summary(self.seed_values(key)) for key in TRACK_KEYS}
        out.update(train_wall_s=self.train_wall_s, episodes=self.episodes)
        return out

    def seed_values(self, key: str) -> list[float | None]:
        """Each training seed's median of ``key`` over its episodes (``None``: no episode of
        that seed has a value)."""
        return [json_float(_nanmedian([e.get(key) for e in eps])) for eps in self.per_seed]

    def _spread(self, key: str) -> dict[str, float | None]:
        """Stats of ``key`` over the training seeds' medians (learned) or the episodes."""
        if self.per_seed:
            return _stats(self.seed_values(key))
        return _stats([e.get(key) for e in self.episodes])


def claim(
    row: dict[str, Any], baseline: dict[str, Any] | None, factor: float, text: str
) -> dict[str, Any]:
    """The claim that learned ``row``'s :data:`HEADLINE` score (a training seed's median over
    the episodes) is at most ``factor`` × ``baseline``'s (its median over the same episodes),
    on each training seed (:func:`agents.evaluation.seed_stats.claim_at_most`); undefined
    without a baseline row (``None``: not flown) or value."""
    base = baseline[HEADLINE]["median"] if baseline is not None else None
    per_seed = row["seed_stats"][HEADLINE]["per_seed"]
    return {"metric": HEADLINE} | claim_at_most(text, per_seed, base, factor)


def seed_table(rows: list[dict[str, Any]], name: Any) -> list[str]:
    """Text lines of the learned ``rows`` over their training seeds: the :data:`HEADLINE`'s
    median and IQM [95% CI], and each claim's ``k/n seeds`` (``name(row)`` labels a row)."""
    learned = [r for r in rows if r.get("seed_stats")]
    if not learned:
        return []
    head = (
        f"{'learned row':<34} {'seeds':>5} {'median':>7}  {'IQM [95% CI]':<26} "
        f"{'claim':<34} {'holds'}"
    )
    lines = ["", f"over training seeds, {HEADLINE} (a seed: its median over the episodes)"]
    lines += [head, "-" * len(head)]
    for r in learned:
        stats = r["seed_stats"][HEADLINE]
        median = "–" if stats["median"] is None else f"{stats['median']:.3f}"
        cells = f"{name(r):<34} {stats['n_seeds']:>5} {median:>7}  {ci_cell(stats):<26}"
        for c in r.get("claims") or [{"claim": "", "holds": None}]:
            lines.append(f"{cells} {c['claim']:<34} {c['holds'] or '–'}")
            cells = " " * len(cells)
        if stats["undefined"]:
            lines.append(f"{'':<34} ({stats['undefined']})")
    return lines


def _nanmedian(values: list[Any]) -> float:
    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
    return float(np.nanmedian(arr)) if np.isfinite(arr).any() else float("nan")


def _stats(values: list[Any]) -> dict[str, float | None]:
    arr = np.array([np.nan if v is None else v for v in values], dtype=float)
    arr = arr[np.isfinite(arr)]
    if not arr.size:
        return {"median": None, "min": None, "max": None}
    return {"median": float(np.median(arr)), "min": float(arr.min()), "max": float(arr.max())}


def fly(policy_spec: Any, env_id: str, env_kwargs: dict[str, Any], seeds: list[int]) -> list:
    """Fly ``policy_spec`` (``"dflqr"``, a run folder, or a callable building the policy from
    the env) on ``gymnasium.make(env_id, **env_kwargs)`` for ``seeds``
    (:func:`agents.evaluation.episodes.run_episodes`)."""
    import gymnasium as gym

    from agents.rl.policies import load_policy

    env = gym.make(env_id, **env_kwargs)
    try:
        with warnings.catch_warnings():  # evaluating off the training setup is the point here
            warnings.filterwarnings("ignore", "evaluating on a different setup than training")
            if callable(policy_spec):
                policy = policy_spec(env)
            else:
                policy, _ = load_policy(str(policy_spec), env)
        return run_episodes(env, policy, seeds)
    finally:
        env.close()


def ppo_job(
    name: str,
    env_id: str,
    seed: int,
    timesteps: int | None,
    out: Path,
    overrides: dict[str, Any],
    env_kwargs: dict[str, Any],
    hyperparams: dict[str, Any] | None = None,
) -> TrainJob:
    """The training of configuration ``name`` with ``seed`` on ``env_id``: the
    :data:`EKF` entry with ``overrides``, then ``hyperparams``, its ``env_kwargs`` merged with
    ``env_kwargs``; in ``out/train/<name>/s<seed>``."""
    from agents.rl.hyperparams import load_hyperparams
    from quadslam_env.config.files import deep_merge

    entry = deep_merge(deep_merge(load_hyperparams("ppo", EKF), overrides), hyperparams or {})
    entry["env_kwargs"] = deep_merge(entry.get("env_kwargs", {}), env_kwargs)
    folder = out / "train" / name / f"s{seed}"
    return TrainJob(f"{name} seed {seed}", folder, env_id, seed, timesteps, entry)


def training_seed_list(n_seeds: int, first: int = 0) -> list[int]:
    """The training seeds of a learned row: ``n_seeds`` from ``first`` on.

    Raises:
        ValueError: ``first`` below 0 (numpy, torch and the lanes take seeds from 0 on).
    """
    if isinstance(first, bool) or not isinstance(first, int) or first < 0:
        raise ValueError(f"first_training_seed: got {first!r}; allowed: an integer >= 0")
    return list(range(first, first + n_seeds))


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


def write_json(result: dict[str, Any], path: Path) -> None:
    """Write a study result (NaN as null)."""

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


def box_plot(result: dict[str, Any], path: Path, title: str) -> Path:
    """Box plot of the per-episode steady-state tracking RMSE of every row of ``result`` (the
    same held-out seeds), the share of episodes ended early above a row that has any; the PNG
    written to ``path``."""
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
    ax.set_title(title)
    ax.tick_params(axis="x", labelsize=7)
    ax.grid(axis="y", alpha=0.3)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=120))
    return path
