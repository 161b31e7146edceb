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
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

import agents.outputs as outputs
import quadslam_env  # noqa: F401  (registers the ids)
from agents.cli import main
from agents.outputs import OutputWriteError, Saver, check_output_dir, check_output_file
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

    import agents.bench
    import agents.evaluation
    import agents.policies
    import agents.study_cost
    import agents.training

    monkeypatch.setattr(agents.evaluation, "run_episodes", forbidden)
    monkeypatch.setattr(agents.policies, "load_policy", forbidden)
    monkeypatch.setattr(agents.bench, "run_bench", forbidden)
    monkeypatch.setattr(agents.study_cost, "run_study", forbidden)
    monkeypatch.setattr(agents.training, "train", forbidden)


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


@pytest.fixture
def temp_root(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> Path:
    """Point the temporary folder (the last fallback) into the test's folder."""
    root = tmp_path / "tmp"
    root.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(root))
    return root


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
    assert line.count("could not write") == 7  # six figures and the video, one line
    assert json.loads((tmp_path / "r.json").read_text())["policy"] == "dflqr"
    fallback = [p for p in temp_root.iterdir() if p.is_dir()]
    assert len(fallback) == 1
    names = sorted(p.name for p in fallback[0].iterdir())
    assert "v.gif" in names and len([n for n in names if n.endswith(".png")]) == 6
    assert (fallback[0] / "v.gif").read_bytes()[:6] == b"GIF89a"


def test_bench_json_that_cannot_be_written_is_kept(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    import agents.bench

    doc = {
        "machine": {"cpu": "test", "cores": 1},
        "wall_time_s": 0.0,
        "results": [],
    }
    monkeypatch.setattr(agents.bench, "run_bench", lambda *a, **k: doc)
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
    import agents.study_cost

    result: dict[str, Any] = {"rows": [], "settings": {"x": float("nan")}}
    monkeypatch.setattr(agents.study_cost, "run_study", lambda *a, **k: result)
    monkeypatch.setattr(agents.study_cost, "format_study", lambda r: "table")
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
    from agents.hyperparams import load_hyperparams

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
    """FastSLAM's landmark filters (N particles × L landmarks × 96 B per lane) are checked
    when the env is built, for every lane of a vector env."""
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(2 * 96 * 500 * 40 * 4))
    kwargs = {"estimator": {"params": {"n_particles": 500}},
              "landmarks": {"layout": "rauniyar2023", "count": 40}}  # fmt: skip
    gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=4, vectorization_mode="vector_entry_point",
                 **kwargs)  # fmt: skip
    with pytest.raises(ValueError, match=r"with FastSLAM, 500 particles, on 5 lane\(s\)") as info:
        gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=5, vectorization_mode="vector_entry_point",
                     **kwargs)  # fmt: skip
    assert "96 × 5 × 500 × 40" in str(info.value) and "at most 32 landmarks" in str(info.value)
