"""A study's reuse of finished trainings (``agents.lab.control_studies.training_pool``): a run's
``timing.json`` that is not the one ``train()`` writes is refused in one line naming the file,
before anything is trained."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from agents.lab.control_studies.training_pool import (
    TrainJob,
    finished_run,
    recorded_wall_s,
    train_all,
)


def _run(folder: Path, timing: str | bytes) -> Path:
    run = folder / "ppo_run"
    run.mkdir(parents=True)
    path = run / "timing.json"
    if isinstance(timing, bytes):
        path.write_bytes(timing)
    else:
        path.write_text(timing)
    return path


def test_a_finished_run_is_reused_with_its_wall_time(tmp_path: Path) -> None:
    timing = {"timesteps": 128, "learn_s": 1.5, "wall_s": 2.25, "steps_per_s": 85.3}
    path = _run(tmp_path, json.dumps(timing))
    found = finished_run(tmp_path)
    assert found is not None and found.run == path.parent and found.wall_s == 2.25
    (path.parent / "INTERRUPTED").write_text("64\n")  # stopped early: trained again
    assert finished_run(tmp_path) is None


@pytest.mark.parametrize(
    ("text", "problem"),
    [
        ("{}", "has no 'wall_s'"),
        ('{"wall_s": "12"}', "has 'wall_s' '12', not a finite number"),
        ('{"wall_s": true}', "has 'wall_s' True, not a finite number"),
        ('{"wall_s": -1.0}', "has 'wall_s' -1.0, not a finite number"),
        ('{"wall_s": NaN}', "has 'wall_s' nan, not a finite number"),
        ('{"wall_s": 1' + "0" * 400 + "}", "has 'wall_s' " + "1" + "0" * 36 + "..., not"),
        ("[1, 2]", "holds list, not a JSON object"),
        ("wall_s: 12\n", "is not JSON"),
        ('{"wall_s": 1', "is not JSON"),
        (b"\xff\xfe{}", "is not JSON"),
    ],
)
def test_a_timing_file_train_did_not_write_is_a_one_line_error_naming_it(
    tmp_path: Path, text: str | bytes, problem: str
) -> None:
    path = _run(tmp_path, text)
    with pytest.raises(ValueError) as err:
        finished_run(tmp_path)
    message = str(err.value)
    assert message.startswith(f"{path}: {problem}")
    assert len(message.splitlines()) == 1 and str(path.parent) in message
    with pytest.raises(ValueError, match="to train it again"):
        recorded_wall_s(path)


def test_a_study_rerun_stops_on_such_a_file_before_training(tmp_path: Path) -> None:
    _run(tmp_path / "train", "{}")
    job = TrainJob("ppo_ekf seed 0", tmp_path / "train", "QuadSLAM-EKF-v0", seed=0)
    with pytest.raises(ValueError, match=r"timing\.json: has no 'wall_s'"):
        train_all([job], 1)
    assert sorted(p.name for p in (tmp_path / "train").iterdir()) == ["ppo_run"]
