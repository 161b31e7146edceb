"""The tidy table of a sweep: one row per job and episode, as CSV and Parquet.

Columns, in order: ``job_id``, ``kind``, ``name`` (the job block's), ``status`` (``ok`` or
``failed``), ``scenario`` and ``estimator`` (resolved names), ``env``, ``algo`` (train jobs),
``policy``, ``seed`` (the episode's seed; a train job's training seed), ``episode_seed`` (the
episode's seed, also for train jobs' held-out episodes), then one column per ``set`` key
(``lidar.sigma_range_m``) and ``hyperparams.<key>``, then the per-episode metrics of
``quadslam run --json`` (:data:`agents.evaluation.episodes.EPISODE_KEYS`:
``track_pos_rmse_steady_m``, ``est_pos_rmse_steady_m``, the transient's, ``est_pos_rmse_m``,
``anees_pose``, …; empty where an episode never reached a phase), and ``job_wall_s``,
``train_wall_s``, ``run_dir`` (train jobs) and ``error`` (failed jobs). A train job without
evaluation episodes has one row with empty metrics; a job that has not run (an interrupted
sweep) has none.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from agents.evaluation.episodes import EPISODE_KEYS
from agents.lab.sweep.jobs import read_result
from agents.lab.sweep.spec import Job

ID_COLUMNS = (
    "job_id",
    "kind",
    "name",
    "status",
    "scenario",
    "estimator",
    "env",
    "algo",
    "policy",
    "seed",
    "episode_seed",
)
METRICS = tuple(k for k in EPISODE_KEYS if k != "seed")
TAIL_COLUMNS = ("job_wall_s", "train_wall_s", "run_dir", "error")
#: Metrics drawn and printed in the summaries.
SUMMARY_METRICS = (
    "track_pos_rmse_steady_m",
    "est_pos_rmse_steady_m",
    "track_pos_rmse_m",
    "est_pos_rmse_m",
    "anees_pose",
    "map_rmse_m",
)


def setting_columns(jobs: list[Job]) -> list[str]:
    """The ``set``/``hyperparams`` columns of the jobs, in first-seen order."""
    out: dict[str, None] = {}
    for job in jobs:
        for key in job.columns:
            if key not in ID_COLUMNS:
                out[key] = None
    return list(out)


def table_rows(
    jobs: list[Job], out: Path, failed: dict[str, str] | None = None
) -> list[dict[str, Any]]:
    """One row per finished job × episode and per failed job (see the module docstring).

    Args:
        jobs: The spec's jobs (the table follows their order).
        out: The sweep's output folder (results are read from ``OUT/jobs``).
        failed: One-line errors of this session's failed jobs; earlier failures are read
            from their ``error.txt``.
    """
    failed = failed or {}
    rows = []
    for job in jobs:
        folder = out / "jobs" / job.job_id
        base: dict[str, Any] = {"job_id": job.job_id, "kind": job.kind, **job.columns}
        result = read_result(folder)
        if result is None:
            error = failed.get(job.job_id) or _error_from_file(folder / "error.txt")
            if error is not None:
                seeds = [job.seed] if job.kind == "train" else list(job.seeds)
                rows += [{**base, "status": "failed", "seed": s, "error": error} for s in seeds]
            continue
        extra = {"job_wall_s": result.get("wall_s")}
        if job.kind == "train":
            extra["train_wall_s"] = (result.get("timing") or {}).get("wall_s")
            extra["run_dir"] = f"jobs/{job.job_id}/{result.get('run_dir')}"
        episodes = result.get("episodes") or [{}]
        for ep in episodes:
            seed = job.seed if job.kind == "train" else ep.get("seed")
            row = {**base, "status": "ok", "seed": seed, "episode_seed": ep.get("seed")}
            row.update({k: ep.get(k) for k in METRICS})
            rows.append({**row, **extra})
    return rows


def _error_from_file(path: Path) -> str | None:
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip()]
    except OSError:
        return None
    return lines[-1].strip() if lines else "failed"


def build_table(jobs: list[Job], out: Path, failed: dict[str, str] | None = None) -> Any:
    """The table as a ``pandas.DataFrame`` with the columns in their documented order.

    A setting column whose values mix strings and numbers is stored as text (Parquet needs
    one type per column).
    """
    import pandas as pd

    rows = table_rows(jobs, out, failed)
    columns = [*ID_COLUMNS, *setting_columns(jobs), *METRICS, *TAIL_COLUMNS]
    df = pd.DataFrame(rows, columns=columns)
    for col in setting_columns(jobs):
        kinds = {_kind(v) for v in df[col] if v is not None and not _is_nan(v)}
        if len(kinds) > 1:
            df[col] = [None if v is None or _is_nan(v) else str(v) for v in df[col]]
    for col in METRICS:
        if col not in ("terminated", "termination_reason"):
            df[col] = pd.to_numeric(df[col], errors="coerce")
    return df


def _kind(value: Any) -> str:
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int | float):
        return "number"
    return type(value).__name__


def _text(value: Any) -> str:
    return "-" if value is None or _is_nan(value) else str(value)


def _is_nan(value: Any) -> bool:
    return isinstance(value, float) and math.isnan(value)


def write_table(df: Any, out: Path, saver: Any) -> list[Path]:
    """``OUT/results.csv`` and ``OUT/results.parquet``, each written atomically."""
    csv = saver.produce(out / "results.csv", "--out", lambda t: df.to_csv(t, index=False))
    parquet = saver.produce(
        out / "results.parquet", "--out", lambda t: df.to_parquet(t, index=False)
    )
    return [csv, parquet]


def varying_columns(df: Any, candidates: list[str]) -> list[str]:
    """The columns among ``candidates`` that take more than one value in ``df``."""
    return [c for c in candidates if c in df and df[c].nunique(dropna=False) > 1]


def summary_text(df: Any, jobs: list[Job]) -> str:
    """Median metrics per group of the swept settings (what varies besides the seed)."""
    ok = df[df["status"] == "ok"]
    if ok.empty:
        return "no finished job"
    candidates = ["kind", "name", "scenario", "estimator", "env", "algo", "policy"]
    groups = varying_columns(ok, [*candidates, *setting_columns(jobs)]) or ["scenario"]
    metrics = [m for m in SUMMARY_METRICS if ok[m].notna().any()]
    # A setting that a block does not set is blank (not NaN, which groupby would drop).
    keyed = ok.assign(**{g: [_text(v) for v in ok[g]] for g in groups})
    table = keyed.groupby(groups, sort=False).agg(
        episodes=("job_id", "size"), **{m: (m, "median") for m in metrics}
    )
    table = table.rename(columns={m: f"{m} (median)" for m in metrics})
    return str(table.to_string(float_format=lambda v: f"{v:.4g}"))
