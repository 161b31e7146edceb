"""Faults that must not cost work or memory (the remaining cases of "every fault keeps the
work"): FastSLAM lanes that cannot fit fail before they are built, the analyses' ``--json``
files are written atomically and kept on a full disk. The fault injection (a full disk, the
CLI runner) is the one of ``tests/conftest.py``.
"""

from __future__ import annotations

import errno
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from conftest import full_disk

import quadslam_env  # noqa: F401  (registers the ids)

# ------------------------------------------------------------ FastSLAM lanes that cannot fit


def test_fastslam_lanes_that_cannot_fit_fail_before_the_lanes_are_built(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """``num_envs=100000`` FastSLAM lanes fail in one line before any lane is built (the env
    asks the class for its particles' size first), instead of allocating the particles of
    lane after lane; a filter built directly still checks its own particles."""
    from estimators.fastslam.dynamic import DynamicFastSLAM
    from quadslam_env.config.scenario import load_scenario
    from quadslam_env.estimation import registry

    built: list[int] = []

    class Counted(DynamicFastSLAM):
        def __init__(self, *args: Any, **kwargs: Any) -> None:
            built.append(1)
            super().__init__(*args, **kwargs)

    registry.associates_unlabeled("fastslam")  # imports the module that registers the name
    monkeypatch.setitem(registry._REGISTRY, "fastslam", Counted)
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(8 << 30))  # half: 4 GiB per filter
    kwargs = {"estimator": {"params": {"n_particles": 200}},
              "landmarks": {"layout": "rauniyar2023", "count": 10}}  # fmt: skip
    with pytest.raises(ValueError) as info:
        gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=100_000,
                     vectorization_mode="vector_entry_point", **kwargs)  # fmt: skip
    assert built == []  # no lane: the env asked the class first
    message = str(info.value)
    assert "\n" not in message
    assert "200 particles (estimator.params.n_particles)" in message
    assert "a map of 10 landmarks" in message and "on 100000 lane(s) (num_envs)" in message
    need = 100_000 * 200 * (8 * 64 + 8 * 12 * 10)  # B × N × (state + L landmark EKFs)
    assert f"would need {need / 2**30:.1f} GiB" in message and "more than the 4.0 GiB" in message
    with pytest.raises(ValueError, match=r"FastSLAM with 10000000000 particles .* on one lane"):
        gym.make("QuadSLAM-FastSLAM-v0", estimator={"params": {"n_particles": 10**10}})
    assert built == []
    vehicle = load_scenario("paper_fastslam_helix").vehicle.params()
    with pytest.raises(ValueError, match=r"\(estimator.params.n_particles\) on one lane"):
        registry.make("fastslam", vehicle=vehicle, n_particles=10**10)
    assert built == [1]  # the filter checked its own particles before allocating them


# --------------------------------------------------------- the analyses' --json, atomically

RESULT = {"scenario": "x", "values": [1.5, 2.5], "nested": {"ok": True}}


def _saved_to(err: str) -> Path:
    """The fallback path named in a one-line ``could not write …; saved to '…'`` error."""
    return Path(err.split("saved to ")[1].split("'")[1])


def test_analysis_json_on_a_full_disk_is_kept_elsewhere(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    temp_root: Path,
) -> None:
    from agents.lab.estimator_studies.degradation import save_json

    out = tmp_path / "results"
    out.mkdir()
    full_disk(monkeypatch, out)
    assert save_json(out / "r.json", RESULT, "quadslam study degradation") == 2
    captured = capsys.readouterr()
    (line,) = [x for x in captured.err.splitlines() if x.strip()]
    assert line.startswith("quadslam study degradation: error: --json: could not write")
    assert "No space left on device" in line
    saved = _saved_to(line)
    assert saved.is_relative_to(temp_root) and json.loads(saved.read_text()) == RESULT
    assert f"json: {saved}" in captured.out
    assert not list(out.iterdir())  # nothing half-written where the file was asked for


class _Torn:
    """A file that takes half of what is written, then reports a full disk."""

    def __init__(self, fh: Any) -> None:
        self.fh = fh

    def __enter__(self) -> _Torn:
        return self

    def __exit__(self, *exc: object) -> None:
        self.fh.close()

    def write(self, data: bytes) -> int:
        self.fh.write(data[: len(data) // 2])
        self.fh.flush()
        raise OSError(errno.ENOSPC, "No space left on device")

    def __getattr__(self, name: str) -> Any:
        return getattr(self.fh, name)


def torn_writes(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """Every file opened for writing in ``folder`` takes half of its data, then the disk is
    full (what a plain ``open(path, "w")`` leaves behind as a truncated result)."""
    import builtins
    import io

    real_open = builtins.open

    def torn_open(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        fh = real_open(file, mode, *args, **kwargs)
        if "w" in mode and isinstance(file, str | Path) and Path(file).parent == folder:
            return _Torn(fh)
        return fh

    monkeypatch.setattr(builtins, "open", torn_open)
    monkeypatch.setattr(io, "open", torn_open)  # pathlib's write_text opens through io


def test_imu_instants_json_torn_by_a_full_disk_keeps_the_old_file(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    temp_root: Path,
) -> None:
    """A write that fails halfway (ENOSPC after half the data) leaves the previous result
    whole: the new one is written under another name and renamed into place only when
    complete; the result itself goes to the temporary folder."""
    import agents.lab.estimator_studies.imu_instants

    monkeypatch.setattr(
        agents.lab.estimator_studies.imu_instants, "split_at_instants", lambda *a, **k: {"steps": 7}
    )
    target = tmp_path / "r.json"
    target.write_text('{"old": true}\n')
    torn_writes(monkeypatch, tmp_path)
    code = agents.lab.estimator_studies.imu_instants.main(["--seeds", "1", "--json", str(target)])
    assert code == 2
    assert json.loads(target.read_text()) == {"old": True}  # never truncated
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert err.startswith("quadslam study imu-instants: error: --json: could not write")
    saved = _saved_to(err)
    assert saved.is_relative_to(temp_root) and json.loads(saved.read_text())["steps"] == 7
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.json", "tmp"]  # no leftovers


@pytest.mark.parametrize(
    "module",
    ["control_studies.active", "control_studies.cost", "estimator_studies.association"],
)
def test_a_study_json_torn_by_a_full_disk_keeps_the_old_file(
    module: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """The studies' ``write_json``, called directly (the CLI also goes through its saver),
    writes atomically: a write that fails halfway leaves the previous file whole."""
    import importlib

    write_json = importlib.import_module(f"agents.lab.{module}").write_json
    target = tmp_path / "study.json"
    target.write_text('{"old": true}\n')
    torn_writes(monkeypatch, tmp_path)
    with pytest.raises(OSError, match="No space left on device"):
        write_json({"settings": {"x": 1.0}, "rows": [], "clutter": []}, target)
    assert json.loads(target.read_text()) == {"old": True}
    assert [p.name for p in tmp_path.iterdir()] == ["study.json"]  # no torn temporary file
