"""Training and studies interrupted: ``kill -9`` then resume, a full disk, SIGTERM during a
training, a save, a study or a run: each finishes, stops cleanly or names what it kept, and no
finished result is lost."""

from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import cli

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.main import main

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
    """``python -m agents.lab.cli.main ARGV`` in a child process with the default signal
    handling."""
    return subprocess.Popen(
        [sys.executable, "-m", "agents.lab.cli.main", *argv],
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

    import agents.lab.control_studies.cost
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
    monkeypatch.setattr(agents.lab.control_studies.cost, "run_study", study)
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
    from agents.lab.control_studies.training_pool import finished_run

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
