"""What one sweep job does, in whatever process runs it (a Ray worker, or this one).

:func:`execute_job` runs a job of :mod:`agents.lab.sweep.spec` through the same code as the CLI
command it stands for — ``run`` and ``evaluate`` fly :func:`agents.evaluation.episodes.run_episodes`
on the env ``quadslam run``/``evaluate`` would build, ``train`` calls
:func:`agents.rl.training.train` and evaluates the run folder as ``quadslam evaluate`` does — in
a fresh temporary folder, and returns the result document and every file the job wrote as
bytes. The sweep's driver writes them under ``OUT/jobs/<job id>/``, so a job needs no file
system shared with the driver (a cluster node, or a ``ray://`` client far away).
"""

from __future__ import annotations

import json
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

RESULT_FILE = "result.json"


def execute_job(kind: str, params: dict[str, Any]) -> dict[str, Any]:
    """Run one job and return ``{"result": document, "files": {relative path: bytes}}``.

    Args:
        kind: ``run``, ``evaluate`` or ``train``.
        params: The job's parameters (:attr:`agents.lab.sweep.spec.Job.params`).

    Returns:
        ``result`` is the JSON document of ``quadslam run/evaluate --json`` (``scenario``,
        ``estimator``, ``policy``, ``episodes``, ``summary``; train jobs add ``run_dir`` and
        ``timing``) plus ``wall_s``, the job's wall time in s; ``files`` holds the figures or
        the training run folder.

    Raises:
        Exception: Whatever the job raised (the sweep reports it and goes on).
    """
    runners: dict[str, Callable[[dict[str, Any], Path], dict[str, Any]]] = {
        "run": _run,
        "evaluate": _evaluate,
        "train": _train,
    }
    tic = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="quadslam-job-") as tmp:
        folder = Path(tmp)
        result = runners[kind](params, folder)
        files = {
            path.relative_to(folder).as_posix(): path.read_bytes()
            for path in sorted(folder.rglob("*"))
            if path.is_file()
        }
    result["wall_s"] = round(time.perf_counter() - tic, 3)
    return {"result": result, "files": files}


def make_env(env_id: str, scenario: Any, estimator: str | None, overrides: dict) -> Any:
    """``gymnasium.make`` with the arguments ``agents.lab.cli.fly.make_env`` gives it."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)

    kwargs: dict[str, Any] = json.loads(json.dumps(overrides))  # a deep copy of plain data
    if scenario is not None:
        kwargs["scenario"] = scenario
    if estimator is not None:
        kwargs["estimator_name"] = estimator
    return gym.make(env_id, **kwargs)


def fly(env: Any, policy: Any, name: str, seeds: list[int], plots: Path | None) -> dict[str, Any]:
    """The result document of ``quadslam run/evaluate`` (:func:`agents.lab.cli.fly.fly`),
    unprinted."""
    from agents.evaluation.episodes import Trace, run_episodes, summarize

    base = env.unwrapped
    trace = Trace() if plots is not None else None
    episodes = run_episodes(env, policy, seeds, trace=trace)
    if plots is not None and trace is not None:
        from agents.evaluation.plots import write_figures
        from agents.io.outputs import Saver

        title = f"{base.scenario.name} / {base.scenario.estimator.name} / seed {seeds[0]}"
        saver = Saver()
        write_figures(trace, plots, title, saver)
        saver.check()
    return {
        "scenario": base.scenario.name,
        "estimator": base.scenario.estimator.name,
        "policy": name,
        "episodes": episodes,
        "summary": summarize(episodes),
    }


def _run(params: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``quadslam run --seed S --seeds K`` (DF-LQR; the job's K seeds as lanes)."""
    from agents.control.dflqr import DFLQRPolicy

    env = make_env(params["env"], params["scenario"], params["estimator"], params["overrides"])
    try:
        plots = folder / "plots" if params["plots"] else None
        return fly(env, DFLQRPolicy.from_env(env), "dflqr", params["seeds"], plots)
    finally:
        env.close()


def _evaluate(params: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``quadslam evaluate --policy P --seed S --episodes K`` (env resolved by the spec;
    ``--drag-feedforward``, ``--thrust-adaptation`` when the job sets them)."""
    from agents.control.named import OPTIONS
    from agents.rl.policies import load_policy

    env = make_env(params["env"], params["scenario"], params["estimator"], params["overrides"])
    try:
        trust = bool(params.get("trust_pickle", False))
        options = {key: True for key in OPTIONS if params.get(key)}
        policy, name = load_policy(params["policy"], env, trust_pickle=trust, options=options)
        plots = folder / "plots" if params["plots"] else None
        return fly(env, policy, name, params["seeds"], plots)
    finally:
        env.close()


def _train(params: dict[str, Any], folder: Path) -> dict[str, Any]:
    """``quadslam train``, then ``quadslam evaluate --policy RUN`` on held-out seeds."""
    from agents.rl.policies import load_policy
    from agents.rl.saved.run_folder import run_config
    from agents.rl.training import train

    run = train(
        params["algo"],
        params["env"],
        config_path=params["config"],
        timesteps=params["timesteps"],
        n_envs=params["n_envs"],
        seed=params["seed"],
        out_dir=folder,
        progress=False,
        hyperparams=params["hyperparams"],
    )
    timing = json.loads((run / "timing.json").read_text())
    cfg = run_config(run) or {}
    env = make_env(cfg["env_id"], cfg.get("scenario"), None, {})
    try:
        first = params["eval_seed"]
        seeds = list(range(first, first + params["episodes"]))
        if seeds:
            policy, _ = load_policy(str(run), env)
            result = fly(env, policy, run.name, seeds, None)
        else:
            base = env.unwrapped
            result = {
                "scenario": base.scenario.name,
                "estimator": base.scenario.estimator.name,
                "policy": run.name,
                "episodes": [],
                "summary": None,
            }
    finally:
        env.close()
    return {**result, "run_dir": run.name, "timing": timing}


def read_result(folder: Path) -> dict[str, Any] | None:
    """A finished job's result document (``None`` while the job has not finished)."""
    path = folder / RESULT_FILE
    try:
        data = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None
