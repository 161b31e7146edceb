"""Run folders written by :func:`agents.rl.training.train`, and finding them again.

A run folder (``<out_dir>/<algo>_<env_id>_s<seed>_<time>``) holds ``config.yaml`` (the resolved
entry, the algorithm, env id, seed and the env's full resolved scenario), ``seed.txt``,
``versions.json``, ``policy.npz`` (+ ``vecnormalize.npz``: the weights and statistics as arrays,
which load without running code, :mod:`agents.rl.saved.safe_files`), SB3's own ``model.zip`` (+
``vecnormalize.pkl``: pickles, read only when trusted), ``learning_curve.png`` (returns vs env
steps and vs wall-clock time), ``timing.json`` (wall clock, steps/s; after the model and curve),
``monitor/`` (``lanes.monitor.csv``: every lane's episodes), ``logs/`` (TensorBoard events +
``progress.csv``; the ``quadslam/*`` scalars are the env's ``est_*``/``track_*``/``reward_*``
metrics), ``eval/`` (``evaluations.npz``, ``best_model.zip`` and its files as arrays),
``checkpoints/`` (each zip with its files as arrays, :func:`safe_paths`) and, written
after everything else, ``manifest.json`` (every other file with its size and SHA-256, checked
before the run is loaded: :mod:`agents.rl.saved.manifest`). A run's ``config.yaml`` can be passed
back as ``config_path`` to repeat it.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import platform
import time
from pathlib import Path
from typing import Any

import yaml

from quadslam_env.config.files import parse_yaml, read_text_file


def versions() -> dict[str, str]:
    """Versions of Python and the packages that determine a run's result."""
    out = {"python": platform.python_version(), "platform": platform.platform()}
    for dist, key in (
        ("numpy", "numpy"),
        ("scipy", "scipy"),
        ("torch", "torch"),
        ("stable-baselines3", "sb3"),
        ("gymnasium", "gymnasium"),
        ("quadslam", "quadslam"),
    ):
        try:
            out[key] = importlib.metadata.version(dist)
        except importlib.metadata.PackageNotFoundError:
            out[key] = "unknown"
    # The sbx backend's (agents.rl.sbx_backend), when installed.
    for dist in ("sbx-rl", "jax", "jaxlib", "flax", "optax"):
        with contextlib.suppress(importlib.metadata.PackageNotFoundError):
            out[dist.removesuffix("-rl")] = importlib.metadata.version(dist)
    return out


def new_run_dir(out_dir: str | Path | None, algo: str, env_id: str, seed: int) -> Path:
    """Create ``<out_dir>/<algo>_<env_id>_s<seed>_<time>[-i]`` and return it.

    Race-free: the folder is claimed by ``mkdir`` itself (``exist_ok=False``), so two trainings
    started in the same second get different folders. The name is made of letters, digits,
    ``._-`` only (:func:`agents.io.paths.safe_name`).
    """
    from agents.io.paths import safe_name

    parent = Path(out_dir) if out_dir is not None else Path("runs")
    parent.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%d-%H%M%S")
    # Gymnasium ids may hold a namespace ("ns/Env-v0"): one folder name, never a sub-path.
    base = parent / safe_name(f"{algo}_{env_id}_s{seed}_{stamp}", limit=160)
    for i in range(10_000):
        run_dir = base if i == 0 else base.with_name(f"{base.name}-{i}")
        try:
            run_dir.mkdir()
        except FileExistsError:
            continue
        return run_dir
    raise FileExistsError(f"--out {str(parent)!r}: 10,000 run folders named {base.name}[-i] exist")


def read_run_config(folder: Path) -> dict[str, Any] | None:
    """``folder/config.yaml`` if it is a run config written by :func:`train`, else ``None``."""
    cfg = folder / "config.yaml"
    if not cfg.is_file():
        return None
    try:
        data = parse_yaml(read_text_file(cfg, "run config"))  # size-capped
    except (ValueError, yaml.YAMLError):  # ConfigError: unreadable, too large, not UTF-8
        return None
    if isinstance(data, dict) and "algo" in data and "hyperparams" in data:
        return data
    return None


def find_run_dir(zip_path: Path) -> Path | None:
    """The run folder a model zip belongs to (its folder or that folder's parent)."""
    for cand in (zip_path.parent, zip_path.parent.parent):
        if read_run_config(cand) is not None:
            return cand
    return None


def run_config(path: str | Path) -> dict[str, Any] | None:
    """The resolved ``config.yaml`` of the run a folder or model zip belongs to.

    Useful to rebuild the training env for evaluation, e.g.
    ``gymnasium.make(cfg["env_id"], **cfg["hyperparams"]["env_kwargs"])``.

    Returns:
        The config mapping, or ``None`` for anything that is not part of a run folder.
    """
    path = Path(path)
    if path.is_dir():
        return read_run_config(path)
    run_dir = find_run_dir(path) if path.is_file() else None
    return None if run_dir is None else read_run_config(run_dir)


def vecnormalize_path(zip_path: Path, run_dir: Path) -> Path:
    """The ``VecNormalize`` statistics saved with a given model zip of a run."""
    if zip_path.parent == run_dir / "checkpoints":  # model_<N>_steps.zip
        stem = zip_path.stem
        if stem.startswith("model_") and stem.endswith("_steps"):
            steps = stem[len("model_") : -len("_steps")]
            return zip_path.parent / f"model_vecnormalize_{steps}_steps.pkl"
    if zip_path.parent == run_dir / "eval":
        return run_dir / "eval" / "best_vecnormalize.pkl"
    return run_dir / "vecnormalize.pkl"


def safe_paths(zip_path: Path, run_dir: Path) -> tuple[Path, Path]:
    """The policy weights and ``VecNormalize`` statistics saved as arrays with a given model
    zip of a run (:mod:`agents.rl.saved.safe_files`): ``policy.npz`` and ``vecnormalize.npz`` beside
    ``model.zip``, ``eval/best_policy.npz`` and ``eval/best_vecnormalize.npz`` beside the best
    model, ``model_policy_<N>_steps.npz`` and ``model_vecnormalize_<N>_steps.npz`` beside a
    checkpoint."""
    stats = vecnormalize_path(zip_path, run_dir).with_suffix(".npz")
    return stats.with_name(stats.name.replace("vecnormalize", "policy", 1)), stats
