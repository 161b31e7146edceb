"""Bad input to the ``quadslam`` CLI (docs/design.md §7): every class of bad argument or file ends
with a non-zero exit status and one line on stderr, starting with ``quadslam``, that names the
offending key or value. Argument-type errors are argparse's (``SystemExit(2)``)."""

from __future__ import annotations

from pathlib import Path

import pytest

from agents.lab.cli.main import main

RUN = ["run", "--duration", "0.5", "--no-plots"]
EVALUATE = ["evaluate", "--duration", "0.5", "--episodes", "1"]


def _one_line_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    """Run the CLI, check the exit status and the stderr shape, return the stderr line."""
    code = main(argv)
    err = capsys.readouterr().err
    assert code != 0
    lines = err.strip("\n").splitlines()
    assert len(lines) == 1, f"expected one stderr line, got {len(lines)}:\n{err}"
    assert lines[0].startswith("quadslam")
    return lines[0]


def _argparse_error(capsys: pytest.CaptureFixture[str], argv: list[str]) -> str:
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    return capsys.readouterr().err.strip().splitlines()[-1]


# ----------------------------------------------------------------------------- scenarios / files


def test_unknown_scenario_name(capsys):
    line = _one_line_error(capsys, [*RUN, "--scenario", "no_such_scenario"])
    assert "scenario" in line
    assert "'no_such_scenario'" in line
    assert "paper_ekf_figure8" in line  # lists what is allowed


def test_missing_yaml_path(capsys, tmp_path):
    missing = tmp_path / "missing.yaml"
    line = _one_line_error(capsys, [*RUN, "--scenario", str(missing)])
    assert str(missing) in line
    assert "cannot be read" in line


def test_malformed_yaml_file(capsys, tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("episode: [1, 2\n  duration_s: : 3\n")
    line = _one_line_error(capsys, [*RUN, "--scenario", str(bad)])
    assert str(bad) in line
    assert "malformed YAML" in line


def test_yaml_with_unknown_key(capsys, tmp_path):
    path = tmp_path / "unknown_key.yaml"
    path.write_text("episode:\n  duration_s: 1.0\n  bogus_key: 3\n")
    line = _one_line_error(capsys, [*RUN, "--scenario", str(path)])
    assert "episode.bogus_key" in line
    assert "duration_s" in line  # the allowed keys are listed


def test_yaml_with_unknown_section(capsys, tmp_path):
    path = tmp_path / "unknown_section.yaml"
    path.write_text("engine:\n  power: 3\n")
    line = _one_line_error(capsys, [*RUN, "--scenario", str(path)])
    assert "engine" in line
    assert "unknown section" in line


def test_yaml_that_is_not_a_mapping(capsys, tmp_path):
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    line = _one_line_error(capsys, [*RUN, "--scenario", str(path)])
    assert str(path) in line
    assert "mapping" in line


def test_yaml_with_wrong_type(capsys, tmp_path):
    path = tmp_path / "wrong_type.yaml"
    path.write_text("lidar:\n  rate_hz: fast\n")
    line = _one_line_error(capsys, [*RUN, "--scenario", str(path)])
    assert "lidar.rate_hz" in line
    assert "'fast'" in line


# ----------------------------------------------------------------------------- --set


def test_set_without_value(capsys):
    line = _one_line_error(capsys, [*RUN, "--set", "foo"])
    assert "--set" in line
    assert "'foo'" in line


def test_set_out_of_range(capsys):
    line = _one_line_error(capsys, ["run", "--no-plots", "--set", "episode.duration_s=-1"])
    assert "episode.duration_s" in line
    assert "-1" in line


def test_set_unknown_key(capsys):
    line = _one_line_error(capsys, [*RUN, "--set", "episode.bogus=1"])
    assert "episode.bogus" in line


def test_set_unknown_estimator_param(capsys):
    line = _one_line_error(capsys, [*RUN, "--set", "estimator.params.foo=1"])
    assert "estimator.params.foo" in line


def test_set_wrong_type_estimator_param(capsys):
    argv = [*RUN, "--estimator", "fastslam", "--set", "estimator.params.n_particles=abc"]
    line = _one_line_error(capsys, argv)
    assert "estimator.params.n_particles" in line
    assert "'abc'" in line


def test_set_malformed_yaml_value(capsys):
    line = _one_line_error(capsys, [*RUN, "--set", "episode.duration_s=[1"])
    assert "episode.duration_s" in line
    assert "[1" in line


# ----------------------------------------------------------------------------- argparse


def test_zero_seeds_is_an_argparse_error(capsys):
    line = _argparse_error(capsys, ["run", "--seeds", "0"])
    assert line.startswith("quadslam run: error:")
    assert "--seeds" in line
    assert "'0'" in line


def test_non_numeric_duration_is_an_argparse_error(capsys):
    line = _argparse_error(capsys, ["run", "--duration", "abc"])
    assert "--duration" in line
    assert "'abc'" in line


def test_negative_duration_is_an_argparse_error(capsys):
    line = _argparse_error(capsys, ["run", "--duration", "-3"])
    assert "--duration" in line
    assert "'-3'" in line


def test_unknown_estimator_names_the_key_and_the_allowed_names(capsys):
    # Any registered estimator (plug-ins too) is accepted, so the config validates the name.
    line = _one_line_error(capsys, ["run", "--estimator", "kalman", "--no-plots"])
    assert "estimator.name" in line and "'kalman'" in line and "ekf_slam" in line


# ----------------------------------------------------------------------------- evaluate --policy


def test_evaluate_missing_policy_path(capsys):
    line = _one_line_error(capsys, [*EVALUATE, "--policy", "/nonexistent/model.zip"])
    assert "--policy" in line
    assert "/nonexistent/model.zip" in line


def test_evaluate_garbage_zip(capsys, tmp_path):
    garbage = tmp_path / "some_file.zip"
    garbage.write_bytes(bytes(range(256)) * 4)
    line = _one_line_error(capsys, [*EVALUATE, "--policy", str(garbage), "--trust-pickle"])
    assert str(garbage) in line
    assert "model" in line


def test_evaluate_zip_header_without_archive(capsys, tmp_path):
    fake = tmp_path / "truncated.zip"
    fake.write_bytes(b"PK\x03\x04" + b"\x00" * 40)
    line = _one_line_error(capsys, [*EVALUATE, "--policy", str(fake), "--trust-pickle"])
    assert str(fake) in line


def test_evaluate_folder_without_model(capsys, tmp_path):
    line = _one_line_error(capsys, [*EVALUATE, "--policy", str(tmp_path)])
    assert str(tmp_path) in line
    assert "model.zip" in line


def test_evaluate_model_of_another_env(capsys, tmp_path):
    """A real SB3 model whose observation space (16 + 3 uncertainty features) differs from the
    evaluation env's (16)."""
    import gymnasium as gym
    from stable_baselines3 import PPO

    import quadslam_env  # noqa: F401  (registers the ids)

    train_env = gym.make(
        "QuadSLAM-Oracle-v0",
        observation={"pos_uncertainty": True},
        episode={"duration_s": 0.5},
    )
    path = Path(tmp_path) / "other_env_model.zip"
    PPO("MlpPolicy", train_env, n_steps=16, batch_size=16, device="cpu").save(path)
    line = _one_line_error(capsys, [*EVALUATE, "--policy", str(path), "--trust-pickle"])
    assert str(path) in line
    assert "(19,)" in line  # the model's observation shape
    assert "(16,)" in line  # the env's


def test_evaluate_unknown_env_id(capsys):
    line = _one_line_error(capsys, [*EVALUATE, "--policy", "dflqr", "--env", "QuadSLAM-Nope-v0"])
    assert "QuadSLAM-Nope-v0" in line


# ----------------------------------------------------------------------------- bounded inputs

LONG = "n" * 300  # a file name beyond the file system's 255 bytes
BOMB = (
    "".join(
        f"{k}: &{k} [{', '.join([f'*{p}'] * 9 if p else ['lol'] * 9)}]\n"
        for p, k in zip(["", *"abcdefgh"], "abcdefghi", strict=True)
    )
    + "episode: *i\n"
)  # 9^9 values once the aliases are expanded ("billion laughs")


def _write(tmp_path: Path, name: str, text: str) -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _big_file(tmp_path: Path) -> str:
    path = tmp_path / "big.yaml"
    with open(path, "wb") as fh:
        fh.truncate(3 << 30)  # 3 GiB, sparse: refused from its size, never read
    return str(path)


def _huge_sweep(tmp_path: Path) -> str:
    return _write(tmp_path, "huge.yaml", "jobs:\n  - {kind: run, seeds: 100000000}\n")


def _two_block_sweep(tmp_path: Path) -> str:
    blocks = "".join(f"  - {{kind: run, seeds: 60000, seed: {i * 60000}}}\n" for i in range(2))
    return _write(tmp_path, "two.yaml", "jobs:\n" + blocks)


BAD_INPUTS = {
    # name: (argv builder, fragments of the one stderr line)
    "scenario_dev_zero": (lambda t: [*RUN, "--scenario", "/dev/zero"], ["is a character device"]),
    "scenario_folder": (lambda t: [*RUN, "--scenario", str(t)], ["is a folder"]),
    "scenario_3_gib": (lambda t: [*RUN, "--scenario", _big_file(t)], ["3 GiB", "at most 1 MiB"]),
    "scenario_alias_bomb": (
        lambda t: [*RUN, "--scenario", _write(t, "bomb.yaml", BOMB)],
        ["bomb.yaml", "more than 100,000 values once its aliases are expanded"],
    ),
    "set_alias_bomb": (
        lambda t: [*RUN, "--set", "episode.duration_s=" + BOMB.replace("\n", ", ")[:-2]],
        ["--set episode.duration_s"],
    ),
    "json_long_name": (
        lambda t: [*RUN, "--json", str(t / LONG / "x.json")],
        ["--json: the name 'nnnnnnnn", "is 300 bytes long", "at most 255 bytes"],
    ),
    "plots_long_name": (
        lambda t: ["run", "--duration", "0.5", "--plots", str(t / LONG)],
        ["--plots: the name", "at most 255 bytes"],
    ),
    "train_out_long_name": (
        lambda t: ["train", "--algo", "ppo", "--out", str(t / LONG)],
        ["--out: the name", "at most 255 bytes"],
    ),
    "train_config_dev_zero": (
        lambda t: ["train", "--algo", "ppo", "--config", "/dev/zero"],
        ["--config '/dev/zero': is a character device"],
    ),
    "sweep_10e8_seeds": (
        lambda t: ["sweep", _huge_sweep(t), "--out", str(t / "o")],
        ["jobs[0]: 100,000,000 jobs", "at most 100,000 jobs per sweep"],
    ),
    "sweep_blocks_add_up": (
        lambda t: ["sweep", _two_block_sweep(t), "--out", str(t / "o")],
        ["jobs[1]: 60,000 jobs", "after 60,000 in the blocks before", "at most 100,000"],
    ),
    "sweep_alias_bomb": (
        lambda t: ["sweep", _write(t, "bomb_spec.yaml", BOMB), "--out", str(t / "o")],
        ["bomb_spec.yaml", "more than 100,000 values"],
    ),
}


@pytest.mark.parametrize("case", sorted(BAD_INPUTS))
def test_unbounded_inputs_end_in_one_line(capsys, tmp_path, case):
    argv, fragments = BAD_INPUTS[case]
    line = _one_line_error(capsys, argv(tmp_path))
    for fragment in fragments:
        assert fragment in line, line
    assert len(line) < 1000  # a bounded message, even for a 300-character name


# ----------------------------------------------------------------------------- what main catches


def _raising(exc: BaseException):
    def command(args):
        raise exc

    return command


def _gym_error() -> Exception:
    import gymnasium.error

    return gymnasium.error.NameNotFound("Environment `Nope` doesn't exist.")


def _disk_full() -> Exception:
    from agents.io.outputs import DiskFullError

    return DiskFullError("no space left on device writing x; resume with: y")


def _terminated() -> BaseException:
    from agents.io.signals import Terminated

    return Terminated()


CAUGHT = [
    # (exception factory, exit status, fragment of the one stderr line)
    (lambda: ValueError("bad value"), 2, "error: bad value"),
    (lambda: FileNotFoundError(2, "No such file or directory", "/x.yaml"), 2,
     "error: No such file or directory: '/x.yaml'"),
    (lambda: OSError(28, "No space left on device", "/full/r.json"), 2,
     "error: No space left on device: '/full/r.json'"),
    (lambda: PermissionError(13, "Permission denied", "/ro"), 2, "Permission denied: '/ro'"),
    (_gym_error, 2, "error: Environment `Nope` doesn't exist."),
    (_disk_full, 2, "error: no space left on device writing x; resume with: y"),
    (lambda: KeyboardInterrupt(), 130, "quadslam scenarios: interrupted"),
    (_terminated, 143, "quadslam scenarios: terminated (SIGTERM)"),
]  # fmt: skip


@pytest.mark.parametrize(("make", "status", "fragment"), CAUGHT)
def test_main_reports_user_errors_and_signals_in_one_line(
    capsys, monkeypatch, make, status, fragment
):
    import agents.lab.cli.main

    monkeypatch.setattr(agents.lab.cli.main, "cmd_scenarios", _raising(make()))
    assert main(["scenarios"]) == status
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], lines
    assert "[Errno" not in lines[0]


@pytest.mark.parametrize("exc", [TypeError("a bug"), KeyError("a bug"), AttributeError("bug")])
def test_main_lets_bugs_show_their_traceback(monkeypatch, exc):
    import agents.lab.cli.main

    monkeypatch.setattr(agents.lab.cli.main, "cmd_scenarios", _raising(exc))
    with pytest.raises(type(exc)):
        main(["scenarios"])


def test_integral_gain_beyond_the_stability_bound(capsys: pytest.CaptureFixture[str]) -> None:
    line = _one_line_error(capsys, [*RUN, "--integral-gain", "0.5"])
    assert "integral_gain" in line and "0.5" in line and "0.1097" in line
    assert "positive number" in _argparse_error(capsys, [*RUN, "--integral-gain", "-1"])


def test_drag_feedforward_needs_lqi_or_se3_and_the_air_velocity(
    capsys: pytest.CaptureFixture[str],
) -> None:
    with pytest.raises(
        SystemExit,
        match=r"--drag-feedforward: only with --policy lqi or se3 "
        r"\(got --policy dflqr\)",
    ):
        main([*RUN, "--drag-feedforward"])
    argv = [*RUN, "--scenario", "ekf_figure8_wind_states", "--policy", "se3", "--drag-feedforward"]
    line = _one_line_error(capsys, argv)
    assert "se3.drag_feedforward: got true with air_velocity_index = None" in line
    assert "observation.air_velocity: true" in line


@pytest.mark.parametrize("name", ["degradation", "imu-instants", "particle-nees", "soak"])
def test_each_analysis_is_a_study_subcommand_with_its_own_options(
    capsys: pytest.CaptureFixture[str], name: str
) -> None:
    with pytest.raises(SystemExit) as done:
        main(["study", name, "--help"])
    assert done.value.code == 0
    assert f"usage: quadslam study {name}" in capsys.readouterr().out
    line = _argparse_error(capsys, ["study", name, "--seed", "0", "--no-such-option"])
    assert line.startswith(f"quadslam study {name}: error: ")
    assert "--no-such-option" in line or "--estimator" in line  # soak asks for it first


def test_options_no_command_knows_are_refused(capsys: pytest.CaptureFixture[str]) -> None:
    assert "unrecognized arguments: --bogus" in _argparse_error(capsys, [*RUN, "--bogus"])
