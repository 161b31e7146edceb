"""Outputs on hostile file systems (check before the work, never lose a result): unwritable
or missing output paths end in a one-line error (status 2) before any work; a write that fails
at the end (a full disk, a failed rename) is saved in the documented fallback; targets that are
not files (FIFOs, devices, links, sockets) are written through or refused, never replaced.

Read-only folders are simulated two ways: ``chmod`` (skipped when it does not bind, e.g. as
root) and a monkeypatched probe/writer that fails like a read-only or full file system
(``tests/conftest.py``), so the failure paths are exercised as root too.
"""

from __future__ import annotations

import json
import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import RUN, cli, failing_rename, full_disk, no_temp_files

import agents.io.outputs as outputs
import quadslam_env  # noqa: F401  (registers the ids)
from agents.io.outputs import OutputWriteError, Saver
from agents.io.paths import check_output_dir, check_output_file
from agents.lab.cli.main import main

# ------------------------------------------------------------- output paths, before the work


@pytest.mark.parametrize(
    ("argv_tail", "option"),
    [
        (["--json", "{dir}"], "--json"),
        (["--json", "{file}/x.json"], "--json"),
        (["--plots", "{file}"], "--plots"),
        (["--no-plots", "--video", "{dir}"], "--video"),
        (["--no-plots", "--video", "{ro}/v.gif"], "--video"),
        (["--json", "{ro}/x.json"], "--json"),
        (["--json", "{ro}/sub/x.json"], "--json"),
        (["--plots", "{ro}/figs"], "--plots"),
        (["--plots", "{ro}"], "--plots"),
    ],
)
def test_run_rejects_unwritable_outputs_before_flying(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    read_only: Path,
    no_work: None,
    argv_tail: list[str],
    option: str,
) -> None:
    (tmp_path / "a_file").write_text("x")
    names = {"dir": tmp_path, "file": tmp_path / "a_file", "ro": read_only}
    tail = [a.format(**names) for a in argv_tail]
    code, _, line = cli(capsys, [*RUN, *tail])
    assert code == 2
    assert line.startswith(f"quadslam run: error: {option}:")
    assert repr(tail[-1]) in line or repr(str(Path(tail[-1]).parent)) in line
    assert (tmp_path / "a_file").read_text() == "x"


def test_chmod_read_only_folder(
    capsys: pytest.CaptureFixture[str], chmod_read_only: Path, no_work: None
) -> None:
    target = chmod_read_only / "x.json"
    code, _, line = cli(capsys, [*RUN, "--no-plots", "--json", str(target)])
    assert code == 2 and "--json" in line and "not writable" in line


@pytest.mark.parametrize(
    "argv",
    [
        ["evaluate", "--policy", "dflqr", "--episodes", "1", "--json", "{dir}"],
        ["evaluate", "--policy", "dflqr", "--episodes", "1", "--plots", "{ro}"],
        ["bench", "--quick", "--json", "{dir}"],
        ["bench", "--quick", "--plots", "{file}"],
        ["bench", "--quick", "--json", "{ro}/b.json"],
        ["study", "cost-of-estimation", "--quick", "--out", "{tmp}/s", "--json", "{dir}"],
        ["study", "cost-of-estimation", "--quick", "--out", "{tmp}/s", "--plots", "{ro}/p"],
        ["study", "cost-of-estimation", "--quick", "--out", "{file}"],
        ["train", "--algo", "ppo", "--out", "{file}"],
        ["train", "--algo", "ppo", "--out", "{ro}/runs"],
    ],
)
def test_other_commands_reject_unwritable_outputs_before_the_work(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    read_only: Path,
    no_work: None,
    argv: list[str],
) -> None:
    (tmp_path / "a_file").write_text("x")
    names = {"dir": tmp_path, "file": tmp_path / "a_file", "ro": read_only, "tmp": tmp_path}
    args = [a.format(**names) for a in argv]
    code, _, line = cli(capsys, args)
    assert code == 2
    assert line.startswith(f"quadslam {args[0]}: error: --")


def test_missing_parent_folders_are_created(tmp_path: Path) -> None:
    target = tmp_path / "a" / "b" / "x.json"
    check_output_file(target, "--json")
    assert target.parent.is_dir() and not target.exists()
    check_output_dir(tmp_path / "c" / "d", "--plots")
    assert (tmp_path / "c" / "d").is_dir()
    assert no_temp_files(tmp_path)


# --------------------------------------------------------------- writes that fail at the end


def test_run_json_on_a_full_disk_is_saved_in_the_temp_folder(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    temp_root: Path,
) -> None:
    out = tmp_path / "results"
    out.mkdir()
    full_disk(monkeypatch, out)  # the check passes (empty probe file), every write fails
    plots = tmp_path / "figs"
    code, stdout, line = cli(
        capsys, [*RUN, "--seeds", "2", "--json", str(out / "r.json"), "--plots", str(plots)]
    )
    assert code == 2
    assert line.startswith("quadslam run: error: --json: could not write")
    assert "No space left on device" in line
    saved = Path(line.split("saved to ")[1].split("'")[1])
    assert saved.is_relative_to(temp_root) and saved.name == "r.json"
    result = json.loads(saved.read_text())
    assert [e["seed"] for e in result["episodes"]] == [0, 1]
    assert len(list(plots.glob("*.png"))) == 6  # the other output is unaffected
    assert not list(out.iterdir()) and no_temp_files(tmp_path)
    assert str(saved) in stdout


def test_failed_rename_keeps_the_old_file_and_saves_the_new_one_beside_it(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    target = tmp_path / "r.json"
    target.write_text('{"old": true}')
    failing_rename(monkeypatch, tmp_path)
    code, _, line = cli(capsys, [*RUN, "--no-plots", "--json", str(target)])
    assert code == 2 and "Input/output error" in line
    assert json.loads(target.read_text()) == {"old": True}  # atomic: never half-written
    saved = Path(line.split("saved to ")[1].split("'")[1])
    assert saved.parent == tmp_path and saved.name.startswith("r.recovered-")
    assert json.loads(saved.read_text())["episodes"][0]["seed"] == 0
    assert no_temp_files(tmp_path)


def test_plots_and_video_on_a_full_disk_go_to_one_temp_folder(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    temp_root: Path,
) -> None:
    out = tmp_path / "out"
    full_disk(monkeypatch, out)
    argv = [*RUN, "--plots", str(out / "figs"), "--video", str(out / "v.gif")]
    argv += ["--json", str(tmp_path / "r.json")]
    code, _, line = cli(capsys, argv)
    assert code == 2
    # six figures, the results table (results.txt) and the video, one line
    assert line.count("could not write") == 8
    assert json.loads((tmp_path / "r.json").read_text())["policy"] == "dflqr"
    fallback = [p for p in temp_root.iterdir() if p.is_dir()]
    assert len(fallback) == 1
    names = sorted(p.name for p in fallback[0].iterdir())
    assert "v.gif" in names and len([n for n in names if n.endswith(".png")]) == 6
    assert "results.txt" in names
    assert (fallback[0] / "v.gif").read_bytes()[:6] == b"GIF89a"


def test_bench_json_that_cannot_be_written_is_kept(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import agents.lab.bench.runner

    doc = {
        "machine": {"cpu": "test", "cores": 1},
        "wall_time_s": 0.0,
        "results": [],
    }
    monkeypatch.setattr(agents.lab.bench.runner, "run_bench", lambda *a, **k: doc)
    failing_rename(monkeypatch, tmp_path)
    code, _, line = cli(capsys, ["bench", "--quick", "--json", str(tmp_path / "b.json")])
    assert code == 2 and line.startswith("quadslam bench: error: --json: could not write")
    saved = Path(line.split("saved to ")[1].split("'")[1])
    assert json.loads(saved.read_text()) == doc


def test_study_json_that_cannot_be_written_is_kept(
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
    temp_root: Path,
) -> None:
    import agents.lab.control_studies.cost

    result: dict[str, Any] = {"rows": [], "settings": {"x": float("nan"), "wall_s": 1, "jobs": 1}}
    monkeypatch.setattr(agents.lab.control_studies.cost, "run_study", lambda *a, **k: result)
    monkeypatch.setattr(agents.lab.control_studies.cost, "format_study", lambda r: "table")
    full_disk(monkeypatch, tmp_path / "res")
    target = tmp_path / "res" / "study.json"
    argv = ["study", "cost-of-estimation", "--quick", "--out", str(tmp_path / "runs")]
    code, _, line = cli(capsys, [*argv, "--json", str(target)])
    assert code == 2 and "--json: could not write" in line
    saved = Path(line.split("saved to ")[1].split("'")[1])
    assert json.loads(saved.read_text())["settings"]["x"] is None  # NaN as null, as before


def test_saver_reports_when_nothing_could_be_written(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    full_disk(monkeypatch, tmp_path)
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    (tmp_path / "tmp").mkdir()
    saver = Saver()
    saver.write_text(tmp_path / "x.txt", "data", "--json")
    with pytest.raises(OutputWriteError, match=r"--json: could not write .*nor a copy"):
        saver.check()


def test_saver_writes_atomically_without_leftovers(tmp_path: Path) -> None:
    saver = Saver()
    for i in range(3):
        saver.write_json(tmp_path / "x.json", {"i": i}, "--json")
    saver.check()
    assert json.loads((tmp_path / "x.json").read_text()) == {"i": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]


# ------------------------------------------------------- output targets that are not files


def _fifo_reader(path: Path) -> tuple[Any, list[bytes]]:
    """A thread that reads a FIFO to its end (a writer blocks until a reader opens it)."""
    import threading

    got: list[bytes] = []

    def read() -> None:
        with open(path, "rb") as fh:
            got.append(fh.read())

    thread = threading.Thread(target=read, daemon=True)
    thread.start()
    return thread, got


def test_a_fifo_is_written_through_never_replaced(tmp_path: Path) -> None:
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    thread, got = _fifo_reader(fifo)
    outputs.write_bytes_atomic(fifo, b'{"a": 1}\n')
    thread.join(10)
    assert got == [b'{"a": 1}\n']
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)  # still the FIFO
    check_output_file(fifo, "--json")  # accepted before the work


def test_a_character_device_is_written_through(tmp_path: Path) -> None:
    null = tmp_path / "null"
    try:
        os.mknod(null, stat.S_IFCHR | 0o666, os.makedev(1, 3))  # /dev/null's numbers
    except OSError:
        pytest.skip("cannot create a device node here")
    saver = Saver()
    assert saver.write_json(null, {"x": 1}, "--json") == null
    saver.check()
    assert stat.S_ISCHR(os.lstat(null).st_mode) and no_temp_files(tmp_path)


def test_a_link_to_a_file_stays_and_the_file_is_replaced_atomically(tmp_path: Path) -> None:
    real = tmp_path / "data" / "r.json"
    real.parent.mkdir()
    real.write_text("old")
    link = tmp_path / "r.json"
    link.symlink_to(real)
    check_output_file(link, "--json")
    outputs.write_bytes_atomic(link, b"new")
    assert link.is_symlink() and link.resolve() == real.resolve()
    assert real.read_text() == "new" and no_temp_files(tmp_path)


def test_a_link_to_a_process_descriptor_is_written_through(tmp_path: Path) -> None:
    """``/dev/stdout`` is a link to ``/proc/self/fd/1``: writing means writing to the
    descriptor (a pipe here), whatever it points to."""
    read_end, write_end = os.pipe()
    link = tmp_path / "stdout.json"
    link.symlink_to(f"/proc/self/fd/{write_end}")
    try:
        outputs.write_bytes_atomic(link, b"through the pipe")
        os.close(write_end)
        assert os.read(read_end, 100) == b"through the pipe"
    finally:
        os.close(read_end)
    assert link.is_symlink()


def test_json_to_dev_stdout_appends_to_the_redirected_stdout(
    capfd: pytest.CaptureFixture[str],
) -> None:
    """``--json /dev/stdout`` with stdout redirected to a file (pytest's capture file): the
    document follows the printed table in that file, which is not replaced."""
    code = main([*RUN, "--no-plots", "--json", "/dev/stdout"])
    out, _ = capfd.readouterr()
    assert code == 0
    start = out.index("\n{") + 1
    document, _ = json.JSONDecoder().raw_decode(out[start:])
    assert document["policy"] == "dflqr" and "median" in out[:start]  # the table came first


def _socket_at(path: Path) -> Any:
    import socket

    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(str(path))
    return sock


@pytest.mark.parametrize(
    ("make", "expected"),
    [
        (lambda p: p.symlink_to(p.parent / "missing.json"), "a symbolic link to a missing file"),
        (lambda p: p.mkdir(), "is a folder"),
        (_socket_at, "is a socket"),
    ],
    ids=["dangling_link", "folder", "socket"],
)
def test_targets_that_must_not_be_replaced_are_refused_in_one_line(
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
    no_work: None,
    make: Callable[[Path], Any],
    expected: str,
) -> None:
    target = tmp_path / "out.json"
    keep = make(target)
    code, _, line = cli(capsys, [*RUN, "--no-plots", "--json", str(target)])
    assert code == 2 and line.startswith("quadslam run: error: --json:") and expected in line
    with pytest.raises(outputs.OutputPathError, match=expected):
        outputs.write_bytes_atomic(target, b"x")
    assert os.path.lexists(target) and not target.is_file()  # untouched
    if keep is not None:
        keep.close()


def test_a_scenario_name_cannot_place_the_run_folder_outside_runs(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    for name in ("x/../../escaped", "n" * 300):
        scenario = tmp_path / "evil.yaml"
        scenario.write_text(f"name: {json.dumps(name)}\nepisode: {{duration_s: 0.3}}\n")
        code, stdout, _ = cli(capsys, ["run", "--scenario", str(scenario)])
        assert code == 0, stdout
    folders = sorted(p.name for p in (work / "runs").iterdir())
    assert len(folders) == 2 and all(len(f) < 120 and "/" not in f for f in folders)
    assert any("x_.._.._escaped" in f for f in folders)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["evil.yaml", "work"]  # no escape
    assert [p.name for p in work.iterdir()] == ["runs"]
