"""The saved points of a run folder (checkpoints, an interrupted run's model) and whether each
still loads: where ``quadslam train --resume`` continues (docs/design.md §7).
"""

from __future__ import annotations

import pickle
import zipfile
from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class Checkpoint:
    """Where a resumed run continues: a model zip, its VecNormalize statistics, its step."""

    model: Path
    vecnormalize: Path | None
    steps: int


def saved_points(run_dir: Path) -> list[Checkpoint]:
    """Every saved point of a run, furthest first: its checkpoints and an interrupted run's
    model (``model.zip`` with the step count in ``INTERRUPTED``)."""
    found: list[Checkpoint] = []
    for path in (run_dir / "checkpoints").glob("model_*_steps.zip"):
        steps = path.stem[len("model_") : -len("_steps")]
        if steps.isdigit():
            pkl = path.parent / f"model_vecnormalize_{steps}_steps.pkl"
            found.append(Checkpoint(path, pkl if pkl.is_file() else None, int(steps)))
    marker = run_dir / "INTERRUPTED"
    if marker.is_file() and (run_dir / "model.zip").is_file():
        text = marker.read_text().strip()
        if text.isdigit():
            pkl = run_dir / "vecnormalize.pkl"
            found.append(
                Checkpoint(run_dir / "model.zip", pkl if pkl.is_file() else None, int(text))
            )
    # At equal steps the interrupted model first: it was saved after the checkpoint.
    return sorted(found, key=lambda c: (c.steps, c.model.parent == run_dir), reverse=True)


def latest_checkpoint(run_dir: Path) -> Checkpoint | None:
    """The furthest saved point of a run: a checkpoint, or an interrupted run's model."""
    points = saved_points(run_dir)
    return points[0] if points else None


def checkpoint_problem(point: Checkpoint, needs_vecnormalize: bool) -> str | None:
    """Why ``point`` cannot be loaded (a truncated or damaged file), or ``None``.

    The model zip is read through (every member's CRC is checked); the ``VecNormalize``
    statistics, when the run normalises, must unpickle.
    """
    try:
        with zipfile.ZipFile(point.model) as archive:
            if "data" not in archive.namelist():  # e.g. the torch zip inside a torn one
                return f"{point.model.name} is truncated or damaged (no 'data' member)"
            bad = archive.testzip()
        if bad is not None:
            return f"{point.model.name}: {bad} is damaged"
    except (OSError, EOFError, zipfile.BadZipFile) as exc:
        return f"{point.model.name} is truncated or damaged ({exc})"
    if needs_vecnormalize:
        if point.vecnormalize is None:
            return f"{point.model.name} has no VecNormalize file"
        try:
            with open(point.vecnormalize, "rb") as fh:
                pickle.load(fh)  # the run's own file, as VecNormalize.load reads it
        except Exception as exc:  # any unpickling error means "cannot be used"
            return f"{point.vecnormalize.name} is truncated or damaged ({type(exc).__name__})"
    return None
