"""Resuming a training from its run folder: from the latest checkpoint, after a stop whose marker
is gone, and the refusals of a folder that cannot be resumed."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from stable_baselines3 import PPO
from training_cases import (
    _one_torch_thread,  # noqa: F401  (an autouse fixture: one torch thread)
    main_env,
    tiny,
)

import quadslam_env  # noqa: F401  (registers the ids)
from agents.rl.training import train


def test_resume_continues_from_the_latest_checkpoint(tmp_path: Path) -> None:
    from agents.rl.saved.checkpoints import latest_checkpoint
    from agents.rl.training import resume

    hp = tiny("ppo", checkpoint_freq=64, eval_freq=0)
    run = train("ppo", main_env(), timesteps=128, n_envs=2, out_dir=tmp_path, progress=False,
                hyperparams=hp)  # fmt: skip
    with pytest.raises(ValueError, match="finished: its model trained 128 steps of its budget"):
        resume(run, progress=False)
    # A crash after the 64-step checkpoint: the later files never got written.
    for name in ("model_128_steps.zip", "model_vecnormalize_128_steps.pkl"):
        (run / "checkpoints" / name).unlink(missing_ok=True)
    (run / "timing.json").unlink()
    start = latest_checkpoint(run)
    assert start is not None and start.steps == 64
    assert resume(run, progress=False) == run
    timing = json.loads((run / "timing.json").read_text())
    # PPO collects whole rollouts (64 steps × 2 lanes): from 64, one rollout passes 128.
    assert timing["timesteps"] == 64 + 128
    assert PPO.load(run / "model.zip", device="cpu").num_timesteps == 64 + 128
    assert (run / "monitor" / "lanes_from_64.monitor.csv").is_file()
    assert (run / "logs" / "from_64" / "progress.csv").is_file()


def test_resume_continues_a_run_stopped_early_whose_marker_is_gone(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    """A run stopped at 128 of its 256 steps, its INTERRUPTED marker removed: timing.json
    alone is no proof that it finished, so resume continues from its model.zip."""
    from stable_baselines3 import PPO

    from agents.rl.training import resume

    real_learn = PPO.learn

    def learn_then_stop(self: Any, total_timesteps: int, **kwargs: Any) -> Any:
        real_learn(self, total_timesteps=1, **kwargs)  # one rollout: 64 steps × 2 lanes
        raise KeyboardInterrupt

    hp = tiny("ppo", checkpoint_freq=0, eval_freq=0)
    with monkeypatch.context() as patch:
        patch.setattr(PPO, "learn", learn_then_stop)
        run = train("ppo", main_env(), timesteps=256, n_envs=2, out_dir=tmp_path,
                    progress=False, hyperparams=hp)  # fmt: skip
    assert (run / "INTERRUPTED").read_text().strip() == "128"
    assert json.loads((run / "timing.json").read_text())["timesteps"] == 128
    (run / "INTERRUPTED").unlink()
    capsys.readouterr()
    assert resume(run, progress=False) == run
    assert "continuing from model.zip (128 of 256 steps)" in capsys.readouterr().err
    assert json.loads((run / "timing.json").read_text())["timesteps"] == 256
    assert PPO.load(run / "model.zip", device="cpu").num_timesteps == 256
    assert (run / "monitor" / "lanes_from_128.monitor.csv").is_file()
    with pytest.raises(ValueError, match="finished: its model trained 256 steps of its budget"):
        resume(run, progress=False)


def test_resume_refuses_a_timing_file_that_says_no_step_count(tmp_path: Path) -> None:
    from agents.rl.saved.checkpoints import ended_short

    (tmp_path / "timing.json").write_text('{"wall_s": 1.0}')
    with pytest.raises(ValueError, match=r"timing\.json has 'timesteps' None, not a step count"):
        ended_short(tmp_path, 100)
    (tmp_path / "timing.json").write_text("not json")
    with pytest.raises(ValueError, match=r"timing\.json cannot be read as JSON"):
        ended_short(tmp_path, 100)
    (tmp_path / "INTERRUPTED").write_text("50\n")  # a marked stop: the saved points decide
    assert ended_short(tmp_path, 100) is None


def test_resume_needs_a_run_folder_with_something_saved(tmp_path: Path) -> None:
    from agents.rl.training import resume

    with pytest.raises(ValueError, match="not a run folder"):
        resume(tmp_path, progress=False)
