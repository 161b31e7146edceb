"""Ordinary mistakes and hostile file systems (issue "check before the work, never lose a
result"): each case ends in a one-line error naming what is wrong (status 2) before any work,
or in the documented fallback after it, and no finished result is lost.

Read-only folders are simulated two ways: ``chmod`` (skipped when it does not bind, e.g. as
root) and a monkeypatched probe/writer that fails like a read-only or full file system, so
the failure paths are exercised as root too. The divergence cases are in
``test_divergence.py``.
"""

from __future__ import annotations

import errno
import json
import os
import signal
import stat
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

import agents.io.outputs as outputs
import quadslam_env  # noqa: F401  (registers the ids)
from agents.cli.main import main
from agents.io.outputs import OutputWriteError, Saver
from agents.io.paths import check_output_dir, check_output_file
from quadslam_env.config import ConfigError, load_scenario
from quadslam_env.config_files import available_scenarios

RUN = ["run", "--duration", "0.3"]


def cli(capsys: pytest.CaptureFixture[str], argv: list[str]) -> tuple[int, str, str]:
    """Run the CLI; return (status, stdout, last stderr line)."""
    code = main(argv)
    out, err = capsys.readouterr()
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
    return code, out, lines[-1] if lines else ""


@pytest.fixture
def no_work(monkeypatch: pytest.MonkeyPatch) -> None:
    """Any flight, benchmark, study or training fails the test: errors must come first."""

    def forbidden(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the work started before the output paths were checked")

    import agents.bench.runner
    import agents.evaluation.episodes
    import agents.rl.policies
    import agents.rl.training
    import agents.studies.cost

    monkeypatch.setattr(agents.evaluation.episodes, "run_episodes", forbidden)
    monkeypatch.setattr(agents.rl.policies, "load_policy", forbidden)
    monkeypatch.setattr(agents.bench.runner, "run_bench", forbidden)
    monkeypatch.setattr(agents.studies.cost, "run_study", forbidden)
    monkeypatch.setattr(agents.rl.training, "train", forbidden)


def _inside(path: Any, folder: Path) -> bool:
    return Path(os.path.abspath(path)).is_relative_to(folder.resolve())


@pytest.fixture
def read_only(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """A folder that refuses new files, even for root (the probe fails like EACCES)."""
    folder = tmp_path / "ro"
    folder.mkdir()
    real: Any = tempfile.mkstemp

    def mkstemp(*args: Any, dir: Any = None, **kwargs: Any) -> Any:
        if dir is not None and _inside(dir, folder):
            raise PermissionError(errno.EACCES, "Permission denied")
        return real(*args, dir=dir, **kwargs)

    monkeypatch.setattr(outputs.tempfile, "mkstemp", mkstemp)
    return folder


@pytest.fixture
def chmod_read_only(tmp_path: Path) -> Iterator[Path]:
    folder = tmp_path / "chmod_ro"
    folder.mkdir()
    folder.chmod(stat.S_IRUSR | stat.S_IXUSR)
    if os.access(folder, os.W_OK):
        folder.chmod(0o700)
        pytest.skip("chmod does not make folders read-only here (running as root)")
    yield folder
    folder.chmod(0o700)


def full_disk(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """Writing any file inside ``folder`` fails with ENOSPC (a full file system): files can
    still be created (the early check passes), but no data can be written to them."""
    import builtins
    import io

    real = builtins.open

    def guarded(file: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        writing = any(c in mode for c in "wax+")
        if writing and isinstance(file, str | os.PathLike) and _inside(file, folder):
            raise OSError(errno.ENOSPC, "No space left on device")
        return real(file, mode, *args, **kwargs)

    monkeypatch.setattr(builtins, "open", guarded)
    monkeypatch.setattr(io, "open", guarded)  # pathlib's write_text opens through io


def failing_rename(monkeypatch: pytest.MonkeyPatch, folder: Path) -> None:
    """``os.replace`` into ``folder`` fails (the last step of every atomic write)."""
    real = os.replace

    def replace(src: Any, dst: Any) -> None:
        if _inside(dst, folder):
            raise OSError(errno.EIO, "Input/output error")
        real(src, dst)

    monkeypatch.setattr(outputs.os, "replace", replace)


def no_temp_files(folder: Path) -> bool:
    return not [p for p in folder.rglob(".*") if ".tmp-" in p.name or "probe" in p.name]


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
    import agents.bench.runner

    doc = {
        "machine": {"cpu": "test", "cores": 1},
        "wall_time_s": 0.0,
        "results": [],
    }
    monkeypatch.setattr(agents.bench.runner, "run_bench", lambda *a, **k: doc)
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
    import agents.studies.cost

    result: dict[str, Any] = {"rows": [], "settings": {"x": float("nan"), "wall_s": 1, "jobs": 1}}
    monkeypatch.setattr(agents.studies.cost, "run_study", lambda *a, **k: result)
    monkeypatch.setattr(agents.studies.cost, "format_study", lambda r: "table")
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


# ---------------------------------------------------------------------- configuration files


@pytest.mark.parametrize("value", [5, 3.5, ["paper_ekf_figure8"], True, ""])
def test_scenario_of_the_wrong_type_names_the_key(value: Any) -> None:
    with pytest.raises(ConfigError, match=r"^scenario: got"):
        gym.make("QuadSLAM-v0", scenario=value)


def test_estimator_name_of_the_wrong_type_names_the_key() -> None:
    with pytest.raises(ConfigError, match=r"^estimator_name: got 3"):
        gym.make("QuadSLAM-v0", estimator_name=3)


SCENARIO_FILES: dict[str, tuple[bytes, str]] = {
    "latin1": ("episode:\n  duration_s: 5 # \xb5s\n".encode("latin-1"), "not UTF-8"),
    "empty": (b"", "empty"),
    "comments_only": (b"# nothing here\n", "empty"),
    "dup_section": (b"episode:\n  duration_s: 5\nepisode:\n  control_hz: 50\n", "'episode'"),
    "dup_key": (b"imu:\n  preset: ideal\n  preset: rauniyar2023\n", "'preset'"),
    "dup_flow": (b"episode: {duration_s: 5, duration_s: 6}\n", "'duration_s'"),
}


@pytest.mark.parametrize("name", sorted(SCENARIO_FILES))
def test_bad_scenario_files_name_the_file(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, no_work: None, name: str
) -> None:
    content, expected = SCENARIO_FILES[name]
    path = tmp_path / f"{name}.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert str(path) in str(info.value) and expected in str(info.value)
    code, _, line = cli(capsys, [*RUN, "--no-plots", "--scenario", str(path)])
    assert code == 2 and str(path) in line and expected in line


def test_explicit_empty_mapping_still_means_defaults(tmp_path: Path) -> None:
    path = tmp_path / "defaults.yaml"
    path.write_text("{}\n")
    assert load_scenario(path).episode.duration_s == 50.0


def test_duplicate_key_in_an_agent_yaml_names_key_and_file(tmp_path: Path) -> None:
    from agents.rl.hyperparams import load_hyperparams

    path = tmp_path / "ppo.yaml"
    path.write_text("QuadSLAM-EKF-v0:\n  n_steps: 64\n  n_steps: 128\n")
    with pytest.raises(ValueError, match=r"ppo\.yaml.*duplicate key 'n_steps' at line 3"):
        load_hyperparams("ppo", "QuadSLAM-EKF-v0", path)


@pytest.mark.parametrize(
    ("sets", "expected"),
    [
        (["episode.duration_s=1", "episode.duration_s=2"], "--set episode.duration_s: given"),
        (
            ["estimator.params={gate_probability: 0.9, gate_probability: 0.5}"],
            "duplicate key 'gate_probability'",
        ),
    ],
)
def test_duplicate_set_keys(
    capsys: pytest.CaptureFixture[str], no_work: None, sets: list[str], expected: str
) -> None:
    argv = [*RUN, "--no-plots"]
    for item in sets:
        argv += ["--set", item]
    code, _, line = cli(capsys, argv)
    assert code == 2 and expected in line


@pytest.mark.parametrize(
    ("scenario", "overrides", "key"),
    [
        ("paper_fastslam_helix", {"landmarks": {"count": 2000}}, "landmarks.count"),
        ("paper_fastslam_helix", {"landmarks": {"range_m": [1, 2]}}, "landmarks.range_m"),
        ("paper_ekf_figure8", {"landmarks": {"pole_spacing_m": 3.0}}, "landmarks.pole_spacing_m"),
        (
            "paper_ekf_figure8",
            {"landmarks": {"positions": [[1.0, 2.0, -3.0]]}},
            "landmarks.positions",
        ),
        ("paper_ekf_figure8", {"trajectory": {"radius_m": 3.0}}, "trajectory.radius_m"),
        ("hover", {"trajectory": {"period_s": 10.0}}, "trajectory.period_s"),
        ("paper_ekf_figure8", {"action": {"max_rate_dps": [90, 90, 45]}}, "action.max_rate_dps"),
    ],
)
def test_settings_the_layout_ignores_are_errors(
    scenario: str, overrides: dict[str, Any], key: str
) -> None:
    with pytest.raises(ConfigError, match=rf"^{key}: got .* ignores; allowed"):
        load_scenario(scenario, overrides)


def test_every_shipped_scenario_round_trips_through_its_resolved_form() -> None:
    for name in available_scenarios():
        scenario = load_scenario(name)
        assert load_scenario(scenario.to_dict()) == scenario


def test_layout_check_from_the_cli_comes_before_flying(
    capsys: pytest.CaptureFixture[str], no_work: None
) -> None:
    argv = [*RUN, "--scenario", "paper_fastslam_helix", "--set", "landmarks.count=2000"]
    code, _, line = cli(capsys, argv)
    assert code == 2
    assert "landmarks.count: got 2000" in line and "'poles4'" in line


# --------------------------------------------------------------------- memory of the EKF map


def test_ekf_map_that_cannot_fit_is_rejected_with_its_size() -> None:
    with pytest.raises(ValueError, match=r"landmarks: a map of 100000 landmarks") as info:
        gym.make("QuadSLAM-EKF-v0", landmarks={"count": 100000})
    message = str(info.value)
    assert "670.6 GiB" in message and "8 × 1 × 300009²" in message
    assert "allowed: at most" in message


def test_ekf_memory_limit_counts_the_lanes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(2 * 8 * 8 * 129**2))
    gym.make_vec("QuadSLAM-EKF-v0", num_envs=8, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match=r"on 9 lane\(s\).*at most 37 landmarks per lane"):
        gym.make_vec("QuadSLAM-EKF-v0", num_envs=9, vectorization_mode="vector_entry_point")


def test_ekf_map_growing_beyond_memory_is_rejected_at_reset(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A reset option with more landmarks than the scenario's grows the map: the growth is
    checked at that reset, like the first allocation, before any step."""
    env = gym.make("QuadSLAM-EKF-v0", landmarks={"count": 10})
    env.reset(seed=0, options={"landmarks": [[5.0 + 0.01 * i, 0.0, -2.0] for i in range(30)]})
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", "1000000")
    points = [[5.0 + 0.01 * i, 0.0, -2.0] for i in range(200)]  # in front of the vehicle
    with pytest.raises(ValueError, match=r"a map of \d+ landmarks with EKF-SLAM"):
        env.reset(seed=0, options={"landmarks": points})
    monkeypatch.delenv("QUADSLAM_MEMORY_LIMIT_BYTES")
    env.step(env.action_space.sample() * 0.0)  # the failed reset changed nothing
    assert env.unwrapped.core.n_landmarks[0] == 30


def test_fastslam_map_that_cannot_fit_is_rejected_with_its_size(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """FastSLAM's particles and landmark filters (N particles × (512 B + L landmarks × 96 B)
    per lane) are checked when the env is built, for every lane of a vector env."""
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(2 * 4 * 500 * (512 + 96 * 40)))
    kwargs = {"estimator": {"params": {"n_particles": 500}},
              "landmarks": {"layout": "rauniyar2023", "count": 40}}  # fmt: skip
    gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=4, vectorization_mode="vector_entry_point",
                 **kwargs)  # fmt: skip
    with pytest.raises(ValueError, match=r"500 particles .* on 5 lane\(s\) \(num_envs\)") as info:
        gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=5, vectorization_mode="vector_entry_point",
                     **kwargs)  # fmt: skip
    message = str(info.value)
    assert "5 × 500 × (512 + 96 × 40)" in message and "a map of 40 landmarks" in message
    # Half the limit, 8,704,000 B, for 5 × 500 particles: 3481 B each, 512 B for the state.
    assert "at most 30 landmarks" in message and "at most 400 particles" in message
    assert "at most 4 lanes" in message


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


# --------------------------------------------------------------- training: kill, disk, SIGTERM

TRAIN_HP = [
    "n_steps=64",
    "batch_size=32",
    "n_epochs=1",
    "policy_kwargs={net_arch: [8]}",
    "env_kwargs.episode.duration_s=1.0",
    "eval_freq=0",
    "checkpoint_freq=64",
]


def train_argv(out: Path, timesteps: int) -> list[str]:
    return [
        "train", "--algo", "ppo", "--env", "QuadSLAM-EKF-v0", "--timesteps", str(timesteps),
        "--n-envs", "1", "--out", str(out), "--no-progress", "--hyperparams", *TRAIN_HP,
    ]  # fmt: skip


def _default_signals() -> None:
    """In the child, SIGINT and SIGTERM as a terminal delivers them: a test runner started in
    the background (or under a nohup-like wrapper) passes them on ignored, and an ignored
    signal stays ignored in Python."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def start_cli(argv: list[str]) -> subprocess.Popen[str]:
    """``python -m agents.cli.main ARGV`` in a child process with the default signal handling."""
    return subprocess.Popen(
        [sys.executable, "-m", "agents.cli.main", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=_default_signals,
    )


def wait_for(check: Callable[[], Any], proc: subprocess.Popen[str], timeout: float) -> Any:
    """Poll ``check()`` until it is truthy; fail if the child ends or time runs out first."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        found = check()
        if found:
            return found
        if proc.poll() is not None:
            _, err = proc.communicate()
            pytest.fail(f"the child ended first (status {proc.returncode}): {err[-2000:]}")
        time.sleep(0.02)
    proc.kill()
    pytest.fail("timed out waiting for the child")


def checkpoints(out: Path) -> list[Path]:
    found = out.glob("ppo_*/checkpoints/model_*_steps.zip")
    return sorted(found, key=lambda p: int(p.stem.split("_")[1]))


def test_kill_9_mid_training_then_resume_finishes_past_a_truncated_checkpoint(
    capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    from stable_baselines3 import PPO

    out = tmp_path / "runs"
    proc = start_cli(train_argv(out, 1024))
    wait_for(lambda: len(checkpoints(out)) >= 2, proc, 240)
    proc.kill()  # SIGKILL: no handler runs, nothing is saved on the way out
    proc.communicate(timeout=60)
    (run,) = out.glob("ppo_*")
    assert not (run / "timing.json").exists()  # does not look finished
    saved = checkpoints(out)
    newest = saved[-1]
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])  # a torn save
    code = main(["train", "--resume", str(run), "--no-progress"])
    err = capsys.readouterr().err
    assert code == 0, err
    assert f"skipped {newest.name} is truncated" in err
    assert f"continuing from checkpoints/{saved[-2].name}" in err
    assert (run / "timing.json").is_file() and not (run / "INTERRUPTED").exists()
    assert json.loads((run / "timing.json").read_text())["timesteps"] >= 1024
    assert PPO.load(run / "model.zip", device="cpu").num_timesteps >= 1024
    assert not list(run.rglob(".*.tmp-*"))


def test_resume_keeps_the_interrupted_marker_until_its_save_has_landed(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """A resumed session that crashes, or finds the disk full when saving, leaves the run
    marked INTERRUPTED with its previous model intact; the next resume finishes it."""
    from stable_baselines3 import PPO

    learn = PPO.learn
    calls = {"n": 0}

    def stopped_learn(self: Any, *args: Any, **kwargs: Any) -> Any:
        calls["n"] += 1
        if calls["n"] == 1:
            raise KeyboardInterrupt  # the first session: Ctrl-C at once
        raise RuntimeError("a crash in the second session")

    monkeypatch.setattr(PPO, "learn", stopped_learn)
    out = tmp_path / "runs"
    assert main(train_argv(out, 256)) == 130
    (run,) = out.glob("ppo_*")
    marker, model = (run / "INTERRUPTED").read_text(), (run / "model.zip").read_bytes()
    assert "--resume" in capsys.readouterr().err

    with pytest.raises(RuntimeError, match="a crash"):
        main(["train", "--resume", str(run), "--no-progress"])
    assert (run / "INTERRUPTED").read_text() == marker  # still marked, the finished look
    code = main(["evaluate", "--policy", str(run), "--episodes", "1", "--duration", "0.3"])
    assert code == 0 and "did not finish training at 0 steps" in capsys.readouterr().err

    monkeypatch.setattr(PPO, "learn", learn)
    real_save = PPO.save

    def full_save(self: Any, path: Any, *args: Any, **kwargs: Any) -> None:
        if Path(path).parent == run:  # the final model.zip (checkpoints still fit)
            raise OSError(errno.ENOSPC, "No space left on device")
        real_save(self, path, *args, **kwargs)

    monkeypatch.setattr(PPO, "save", full_save)
    code, _, line = cli(capsys, ["train", "--resume", str(run), "--no-progress"])
    assert code == 2 and line.startswith("quadslam train: error: no space left on device")
    assert f"quadslam train --resume {run}" in line and "model_256_steps.zip" in line
    assert (run / "model.zip").read_bytes() == model  # never truncated
    assert (run / "INTERRUPTED").read_text() == marker
    assert not list(run.rglob(".*.tmp-*"))

    monkeypatch.setattr(PPO, "save", real_save)
    code = main(["train", "--resume", str(run), "--no-progress"])
    assert code == 0, capsys.readouterr().err
    assert not (run / "INTERRUPTED").exists() and (run / "timing.json").is_file()


def test_train_on_a_full_disk_exits_2_naming_the_last_good_checkpoint(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from stable_baselines3 import PPO

    real_save = PPO.save
    saves = {"n": 0}

    def save(self: Any, path: Any, *args: Any, **kwargs: Any) -> None:
        saves["n"] += 1
        if saves["n"] > 1:  # the first checkpoint fits, nothing after it does
            with open(path, "wb") as fh:
                fh.write(b"PK\x03\x04 half a zip")  # what a full disk leaves behind
            raise OSError(errno.ENOSPC, "No space left on device")
        real_save(self, path, *args, **kwargs)

    monkeypatch.setattr(PPO, "save", save)
    out = tmp_path / "runs"
    code = main(train_argv(out, 256))
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1, err  # one line, no traceback
    (run,) = out.glob("ppo_*")
    assert err[0].startswith("quadslam train: error: no space left on device writing")
    assert "checkpoints/model_64_steps.zip, 64 of 256 steps" in err[0]
    assert err[0].endswith(f"quadslam train --resume {run}")
    names = sorted(p.name for p in (run / "checkpoints").iterdir())
    assert names == [  # nothing torn
        "model_64_steps.zip", "model_policy_64_steps.npz",
        "model_vecnormalize_64_steps.npz", "model_vecnormalize_64_steps.pkl",
    ]  # fmt: skip
    assert not (run / "model.zip").exists() and not list(run.rglob(".*.tmp-*"))

    monkeypatch.setattr(PPO, "save", real_save)
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0
    assert json.loads((run / "timing.json").read_text())["timesteps"] >= 256


def test_sigterm_stops_training_saves_it_and_exits_143(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    proc = start_cli(train_argv(out, 100_000))
    wait_for(lambda: checkpoints(out), proc, 240)
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    (run,) = out.glob("ppo_*")
    steps = int((run / "INTERRUPTED").read_text())
    assert steps >= 64 and (run / "model.zip").is_file() and (run / "timing.json").is_file()
    last = err.strip().splitlines()[-1]
    assert f"interrupted at {steps:,} steps" in last
    assert last.endswith(f"resume with: quadslam train --resume {run}")


def test_sigterm_while_saving_is_held_until_the_run_folder_is_complete(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """SIGTERM during training (in-process, as ``study`` calls train()), then another during
    the learning-curve plot: the folder is completed, then the command ends with 143."""
    from stable_baselines3 import PPO

    import agents.rl.training

    def terminated_learn(self: Any, *args: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), signal.SIGTERM)

    plot = agents.rl.training.plot_learning_curve

    def plot_with_sigterm(run_dir: Path) -> None:
        os.kill(os.getpid(), signal.SIGTERM)  # held until timing.json is written
        plot(run_dir)

    monkeypatch.setattr(PPO, "learn", terminated_learn)
    monkeypatch.setattr(agents.rl.training, "plot_learning_curve", plot_with_sigterm)
    before = signal.getsignal(signal.SIGTERM)
    out = tmp_path / "runs"
    assert main(train_argv(out, 256)) == 143
    (run,) = out.glob("ppo_*")
    for name in ("model.zip", "INTERRUPTED", "timing.json", "learning_curve.png"):
        assert (run / name).is_file(), name
    err = capsys.readouterr().err
    assert "please wait" in err and f"quadslam train --resume {run}" in err
    assert signal.getsignal(signal.SIGTERM) is before  # restored


def test_sigterm_stops_a_study_after_its_training_saved(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``study`` dispatch: train() saves on SIGTERM and passes it on, so the study stops
    (exit 143, one line) instead of going on to its next training."""
    from stable_baselines3 import PPO

    import agents.studies.cost
    from agents.rl.training import train

    def terminated_learn(self: Any, *args: Any, **kwargs: Any) -> None:
        os.kill(os.getpid(), signal.SIGTERM)

    trained: list[Path] = []

    def study(out: Path, *args: Any, **kwargs: Any) -> Any:
        for seed in range(2):  # a study's trainings, one after the other
            hp = {"n_steps": 64, "batch_size": 32, "eval_freq": 0, "checkpoint_freq": 0,
                  "env_kwargs": {"episode": {"duration_s": 1.0}}}  # fmt: skip
            trained.append(train("ppo", "QuadSLAM-EKF-v0", timesteps=128, n_envs=1, seed=seed,
                                 out_dir=out, progress=False, hyperparams=hp))  # fmt: skip
        raise AssertionError("the study went on after SIGTERM")

    monkeypatch.setattr(PPO, "learn", terminated_learn)
    monkeypatch.setattr(agents.studies.cost, "run_study", study)
    argv = ["study", "cost-of-estimation", "--quick", "--out", str(tmp_path / "s")]
    code, _, line = cli(capsys, argv)
    assert code == 143 and not trained
    assert line.startswith("quadslam study: terminated (SIGTERM); finished training runs")
    (run,) = (tmp_path / "s").glob("ppo_*")
    assert (run / "INTERRUPTED").is_file() and (run / "model.zip").is_file()


def test_sigterm_ends_run_in_one_line_with_143(tmp_path: Path) -> None:
    proc = start_cli(["run", "--seeds", "50", "--no-plots"])
    err: list[str] = []

    def progress() -> bool:
        assert proc.stderr is not None
        err.append(os.read(proc.stderr.fileno(), 4096).decode(errors="replace"))
        return "".join(err).count("step") >= 2  # the bar redrawn: flying, handler in place

    wait_for(progress, proc, 120)
    proc.send_signal(signal.SIGTERM)
    _, rest = proc.communicate(timeout=60)
    assert proc.returncode == 143
    lines = [x for x in ("".join(err) + rest).replace("\r", "\n").splitlines() if x.strip()]
    assert lines[-1] == "quadslam run: terminated (SIGTERM)"
    assert "Traceback" not in rest


def test_sigterm_stops_a_study_training_in_worker_processes(tmp_path: Path) -> None:
    """``--jobs 2``: a SIGTERM to the study's process reaches the trainings in its workers.
    Each saves its run folder marked ``INTERRUPTED`` (a rerun trains it again), and the
    command ends in one line with 143."""
    from agents.studies.training_pool import finished_run

    out = tmp_path / "s"
    argv = ["study", "cost-of-estimation", "--quick", "--training-seeds", "1", "--jobs", "2"]
    proc = start_cli([*argv, "--out", str(out)])

    def learning() -> list[Path]:  # both workers past their first update (progress.csv row)
        logs = [p for p in out.glob("train/*/s0/*/logs/progress.csv") if p.stat().st_size]
        return logs if len(logs) == 2 else []

    runs = [log.parent.parent for log in wait_for(learning, proc, 300)]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err[-2000:]
    lines = [x for x in err.replace("\r", "\n").splitlines() if x.strip()]
    assert lines[-1].startswith("quadslam study: terminated (SIGTERM); finished training runs")
    assert "Traceback" not in err
    for run in runs:
        assert (run / "INTERRUPTED").is_file() and (run / "model.zip").is_file(), run
    assert all(finished_run(folder) is None for folder in out.glob("train/*/s0"))


def test_sigterm_as_request_sets_its_event_instead_of_raising() -> None:
    """Inside ``sigterm_as_request`` a SIGTERM only sets the event (the training polls it
    between steps); around it, ``sigterm_as_interrupt`` raises again once the block ends."""
    from agents.io.signals import (
        Terminated,
        sigterm_as_interrupt,
        sigterm_as_request,
        sigterm_received,
    )

    with pytest.raises(Terminated), sigterm_as_interrupt():
        with sigterm_as_request() as asked:
            signal.raise_signal(signal.SIGTERM)  # handled at once, in this thread
            assert asked.is_set() and sigterm_received()
        signal.raise_signal(signal.SIGTERM)
