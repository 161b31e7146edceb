"""``quadslam convert-run``: give a run folder saved before the arrays existed its
``policy.npz`` and ``vecnormalize.npz`` (docs/design.md §6).

A run folder of an older ``quadslam train`` holds its models only as SB3's ``model.zip`` and
``vecnormalize.pkl``, pickles that run whatever code they name when read; loading refuses them
unless trusted (:func:`agents.rl.loading.load_model`). :func:`convert_run` reads them once,
knowingly, and writes the arrays beside each saved model (the final one, the best one, every
checkpoint), so that the folder loads without unpickling from then on.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, field
from pathlib import Path

from agents.io.outputs import atomic_produce_all
from agents.rl.hyperparams import parse_normalize
from agents.rl.loading import load_pickled_model, load_pickled_stats, rebuild_model
from agents.rl.saved.manifest import verify_run, write_manifest
from agents.rl.saved.run_folder import read_run_config, safe_paths, vecnormalize_path
from agents.rl.saved.safe_files import read_policy, write_normalization, write_policy


@dataclass
class Conversion:
    """What :func:`convert_run` did.

    Attributes:
        written: The array files written, in order.
        skipped: Saved models left as they were, each with why (one line each).
        manifest: Whether ``manifest.json`` was written again.
    """

    written: list[Path] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    manifest: bool = False


def saved_models(run_dir: Path) -> list[Path]:
    """The model zips of a run folder: ``model.zip``, ``eval/best_model.zip``, checkpoints."""
    found = [run_dir / "model.zip", run_dir / "eval" / "best_model.zip"]
    found += sorted((run_dir / "checkpoints").glob("model_*_steps.zip"))
    return [path for path in found if path.is_file()]


def convert_run(run_dir: str | Path) -> Conversion:
    """Write the arrays of every saved model of ``run_dir`` that lacks them, from its pickles.

    This unpickles the folder's SB3 zips and ``VecNormalize`` files, which runs whatever code
    they name: call it only for a folder you trust. The folder is first checked against its
    manifest (:func:`agents.rl.saved.manifest.verify_run`: a changed file, or a file to be read that
    it does not list, is refused before anything is read; a folder without one is read after a
    warning). Each model's arrays are written atomically and then rebuilt from the run's
    ``config.yaml`` as loading will (:func:`agents.rl.loading.rebuild_model`), so a config
    that does not describe the model is reported here, with the arrays removed again. When
    anything was written, ``manifest.json`` is written anew, listing the new files.

    Args:
        run_dir: A run folder written by ``quadslam train``.

    Returns:
        The files written and the models skipped (a checkpoint whose ``VecNormalize`` file is
        gone, or whose arrays exist already).

    Raises:
        ValueError: Not a run folder, no saved model, or a model that does not load.
        agents.rl.saved.manifest.ManifestError: A file differs from the manifest or is not listed.
    """
    run_dir = Path(run_dir)
    config = read_run_config(run_dir)
    if config is None:
        raise ValueError(
            f"convert-run {str(run_dir)!r}: not a run folder (no readable config.yaml)"
        )
    models = saved_models(run_dir)
    if not models:
        raise ValueError(
            f"convert-run {str(run_dir)!r}: no model.zip, eval/best_model.zip or checkpoint "
            "to convert"
        )
    normalized = parse_normalize(config.get("hyperparams", {}).get("normalize", False)) is not None
    done = Conversion()
    todo: list[tuple[Path, Path | None]] = []
    for zip_path in models:
        pkl = vecnormalize_path(zip_path, run_dir) if normalized else None
        name = zip_path.relative_to(run_dir)
        if all(path.is_file() for path in safe_paths(zip_path, run_dir)[: 2 if normalized else 1]):
            done.skipped.append(f"{name}: its arrays exist already")
        elif pkl is not None and not pkl.is_file():
            done.skipped.append(f"{name}: no {pkl.relative_to(run_dir)} beside it")
        else:
            todo.append((zip_path, pkl))
    # Before anything is unpickled: the files as the training saved them.
    verify_run(run_dir, [run_dir / "config.yaml", *(p for pair in todo for p in pair if p)])
    for zip_path, pkl in todo:
        done.written += _convert_one(run_dir, config, zip_path, pkl)
    if done.written:
        write_manifest(run_dir)
        done.manifest = True
    return done


def _convert_one(run_dir: Path, config: dict, zip_path: Path, pkl: Path | None) -> list[Path]:
    """The arrays of one saved model, written and then loaded back; the files written."""
    model, _ = load_pickled_model(zip_path, config["algo"])
    norm = None if pkl is None else load_pickled_stats(pkl)
    weights, stats = safe_paths(zip_path, run_dir)
    items = [(weights, lambda tmp: write_policy(tmp, model))]
    if norm is not None:
        items.append((stats, lambda tmp: write_normalization(tmp, norm)))
    atomic_produce_all(items)
    written = [path for path, _ in items]
    try:
        rebuild_model(config, read_policy(weights), weights)
    except ValueError:
        for path in written:
            with contextlib.suppress(FileNotFoundError):
                path.unlink()
        raise
    return written
