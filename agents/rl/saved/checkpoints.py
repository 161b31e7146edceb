"""The saved points of a run folder (checkpoints, an interrupted run's model) and whether each
still loads: where ``quadslam train --resume`` continues (docs/design.md §7).
"""

from __future__ import annotations

import json
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


def saved_points(run_dir: Path, ended_at: int | None = None) -> list[Checkpoint]:
    """Every saved point of a run, furthest first: its checkpoints and an interrupted run's
    model (``model.zip`` with the step count in ``INTERRUPTED``), or with ``ended_at`` the
    model of a session that ended short of its budget without that marker
    (:func:`ended_short`), at ``ended_at`` steps."""
    found: list[Checkpoint] = []
    final, pkl = run_dir / "model.zip", run_dir / "vecnormalize.pkl"
    if ended_at is not None and final.is_file():
        found.append(Checkpoint(final, pkl if pkl.is_file() else None, ended_at))
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


def ended_short(run_dir: Path, budget: int) -> int | None:
    """The step count of a run whose last session ended (``timing.json``, written last, and
    no ``INTERRUPTED`` marker) short of ``budget``: it stopped early without its marker (one
    removed by hand), so its ``model.zip`` is where it continues.

    Args:
        run_dir: The run folder.
        budget: Its ``n_timesteps``.

    Returns:
        The steps ``timing.json`` records when below ``budget``; ``None`` when the last
        session did not end that way (no ``timing.json``, or an ``INTERRUPTED`` marker: the
        saved points say where the run continues).

    Raises:
        ValueError: The run reached its budget (finished: nothing to resume), or its
            ``timing.json`` does not say how far it got (naming the file).
    """
    timing = run_dir / "timing.json"
    if not timing.is_file() or (run_dir / "INTERRUPTED").exists():
        return None
    steps = -1  # the recorded step count, once read
    try:
        data = json.loads(timing.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # unreadable, not UTF-8, not JSON
        problem = f"cannot be read as JSON ({type(exc).__name__}: {' '.join(str(exc).split())})"
    else:
        value = data.get("timesteps") if isinstance(data, dict) else None
        if isinstance(value, int) and not isinstance(value, bool) and value >= 0:
            steps, problem = value, ""
        else:
            shown = repr(value) if len(repr(value)) <= 40 else f"{repr(value)[:37]}..."
            problem = f"has 'timesteps' {shown}, not a step count"
    if problem:
        raise ValueError(
            f"{timing} {problem}, so whether the run finished is unknown; allowed: the "
            "timing.json training writes, with the model's step count as 'timesteps'"
        )
    if steps >= budget:
        raise ValueError(
            f"finished: its model trained {steps:,} steps of its budget of {budget:,} "
            "(n_timesteps), nothing to resume; train a new run to train for longer"
        )
    return steps


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
