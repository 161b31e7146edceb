"""Run folders carry a manifest (every file with its size and SHA-256, written last); the
commands that load a run check it first and refuse a folder whose files differ, and accept
one without a manifest (an older run) with a one-line warning."""

from __future__ import annotations

import hashlib
import json
import shutil
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.main import main
from agents.rl.saved.manifest import MANIFEST, ManifestError, ManifestWarning, verify_run

ENV = "QuadSLAM-Oracle-v0"  # no filter to compile: the fastest training
HP = [
    "n_steps=64", "batch_size=32", "n_epochs=1", "policy_kwargs={net_arch: [8]}",
    "env_kwargs.episode.duration_s=1.0", "eval_freq=64", "n_eval_episodes=1",
    "checkpoint_freq=64", "normalize=true",
]  # fmt: skip
EVALUATE = ["evaluate", "--episodes", "1", "--duration", "0.3", "--seed", "3"]


def train_argv(out: Path, timesteps: int = 128) -> list[str]:
    return [
        "train", "--algo", "ppo", "--env", ENV, "--timesteps", str(timesteps), "--n-envs", "1",
        "--out", str(out), "--no-progress", "--hyperparams", *HP,
    ]  # fmt: skip


def last_line(err: str) -> str:
    lines = [line for line in err.replace("\r", "\n").splitlines() if line.strip()]
    return lines[-1] if lines else ""


@pytest.fixture(scope="module")
def finished(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A finished tiny run (checkpoints, evaluations, VecNormalize statistics)."""
    out = tmp_path_factory.mktemp("runs")
    assert main(train_argv(out)) == 0
    (run,) = out.glob("ppo_*")
    return run


@pytest.fixture
def run(finished: Path, tmp_path: Path) -> Path:
    """A copy of the finished run for one test to damage."""
    return Path(shutil.copytree(finished, tmp_path / finished.name))


def test_manifest_lists_every_file_with_its_size_and_sha256(finished: Path) -> None:
    doc = json.loads((finished / MANIFEST).read_text())
    on_disk = {
        path.relative_to(finished).as_posix(): path
        for path in finished.rglob("*")
        if path.is_file() and path.name != MANIFEST
    }
    assert set(doc["files"]) == set(on_disk)
    for name in ("config.yaml", "model.zip", "vecnormalize.pkl", "timing.json",
                 "policy.npz", "vecnormalize.npz", "eval/best_policy.npz",
                 "learning_curve.png", "eval/best_model.zip", "monitor/lanes.monitor.csv",
                 "checkpoints/model_64_steps.zip"):  # fmt: skip
        assert name in on_disk, name
    for name, path in on_disk.items():
        data = path.read_bytes()
        assert doc["files"][name] == {"size": len(data), "sha256": hashlib.sha256(data).hexdigest()}
    newest = max(path.stat().st_mtime_ns for path in on_disk.values())
    assert (finished / MANIFEST).stat().st_mtime_ns >= newest  # written last


def test_a_finished_run_verifies_and_evaluates(
    capsys: pytest.CaptureFixture[str], finished: Path
) -> None:
    assert verify_run(finished, [finished / "model.zip"]) is True
    assert main([*EVALUATE, "--policy", str(finished)]) == 0
    assert "warning" not in capsys.readouterr().err


def test_a_truncated_model_zip_is_refused_before_it_is_loaded(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, run: Path
) -> None:
    import agents.rl.loading

    def forbidden(*args: Any, **kwargs: Any) -> Any:
        raise AssertionError("the model was loaded before the manifest was checked")

    monkeypatch.setattr(agents.rl.loading, "rebuild_model", forbidden)
    monkeypatch.setattr(agents.rl.loading, "load_pickled_model", forbidden)
    model = run / "model.zip"
    size = model.stat().st_size
    model.write_bytes(model.read_bytes()[: size // 2])  # a torn copy
    code = main([*EVALUATE, "--policy", str(run)])
    line = last_line(capsys.readouterr().err)
    assert code == 2
    assert line.startswith(f"quadslam evaluate: error: {run}: model.zip differs from its manifest")
    assert f"{size // 2:,} bytes, {size:,} recorded" in line


def test_a_tampered_file_of_the_same_size_is_refused(run: Path) -> None:
    stats = run / "vecnormalize.pkl"
    data = bytearray(stats.read_bytes())
    data[-2] ^= 0xFF
    stats.write_bytes(bytes(data))
    env = gym.make(ENV)
    from agents.rl.loading import load_model

    with pytest.raises(ManifestError, match=r"vecnormalize.pkl differs .* another SHA-256"):
        load_model(run / "checkpoints" / "model_64_steps.zip", env)  # any file of the run


def test_a_model_the_manifest_does_not_list_is_refused(run: Path) -> None:
    from agents.rl.loading import load_model

    shutil.copy(run / "model.zip", run / "eval" / "best_model.zip.bak")
    foreign = run / "checkpoints" / "model_9999_steps.zip"
    shutil.copy(run / "model.zip", foreign)
    shutil.copy(run / "vecnormalize.pkl", run / "checkpoints" / "model_vecnormalize_9999_steps.pkl")
    with pytest.raises(ManifestError, match=r"checkpoints/model_9999_steps.zip is not listed"):
        load_model(foreign, gym.make(ENV), trust_pickle=True)  # read from its pickles
    shutil.copy(run / "policy.npz", run / "checkpoints" / "model_policy_9999_steps.npz")
    shutil.copy(run / "vecnormalize.npz", run / "checkpoints" / "model_vecnormalize_9999_steps.npz")
    with pytest.raises(ManifestError, match=r"checkpoints/model_policy_9999_steps.npz is not"):
        load_model(foreign, gym.make(ENV))  # read from its arrays
    assert load_model(run, gym.make(ENV)).algo == "ppo"  # unlisted extras are not read


def test_a_run_without_manifest_loads_with_one_warning_line(run: Path) -> None:
    from agents.lab.cli.warning_lines import one_line_warnings
    from agents.rl.loading import load_model

    (run / MANIFEST).unlink()  # a run saved before manifests existed
    with pytest.warns(ManifestWarning, match=r"has no manifest.json .* not checked") as caught:
        assert load_model(run, gym.make(ENV)).algo == "ppo"
    (record,) = [w for w in caught if w.category is ManifestWarning]
    assert Path(record.filename).name == "loading.py"  # reported where the run is loaded
    with one_line_warnings("evaluate"):  # how the command prints it
        text = warnings.formatwarning(record.message, record.category, record.filename, 1)
        other = warnings.formatwarning("x", UserWarning, "/elsewhere/lib.py", 3)
    assert text == f"quadslam evaluate: warning: {record.message}\n"
    assert text.startswith(f"quadslam evaluate: warning: {run} has no manifest.json")
    assert other.startswith("/elsewhere/lib.py:3: UserWarning: x")  # other libraries' format


def test_resume_checks_the_manifest_of_an_interrupted_run_and_writes_a_new_one(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    from stable_baselines3 import PPO

    learn = PPO.learn

    def interrupted(self: Any, *args: Any, **kwargs: Any) -> Any:
        raise KeyboardInterrupt

    monkeypatch.setattr(PPO, "learn", interrupted)
    out = tmp_path / "runs"
    assert main(train_argv(out)) == 130
    (run,) = out.glob("ppo_*")
    listed = json.loads((run / MANIFEST).read_text())["files"]
    assert {"INTERRUPTED", "model.zip", "vecnormalize.pkl"} <= set(listed)
    monkeypatch.setattr(PPO, "learn", learn)

    model = run / "model.zip"
    good = model.read_bytes()
    model.write_bytes(good + b"\0")  # one byte appended
    code = main(["train", "--resume", str(run), "--no-progress"])
    line = last_line(capsys.readouterr().err)
    assert code == 2 and f"{run}: model.zip differs from its manifest.json" in line
    assert (run / MANIFEST).is_file() and (run / "INTERRUPTED").is_file()  # nothing changed

    model.write_bytes(good)
    assert main(["train", "--resume", str(run), "--no-progress"]) == 0, capsys.readouterr().err
    files = json.loads((run / MANIFEST).read_text())["files"]
    assert "INTERRUPTED" not in files and not (run / "INTERRUPTED").exists()
    new = hashlib.sha256(model.read_bytes()).hexdigest()
    assert files["model.zip"]["sha256"] == new != hashlib.sha256(good).hexdigest()
    assert verify_run(run, [model]) is True
