"""The cost-of-estimation study pipeline on a tiny budget (seconds, not a result)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from agents.cli import main as cli
from agents.cli import study as cli_study
from agents.rl import hyperparams
from agents.rl.hyperparams import load_hyperparams
from agents.studies import cost
from agents.studies.cost import TRAINED, TrainedConfig, run_study, write_json
from agents.studies.training_pool import finished_run, train_all


def _tiny_ppo(*args: Any, **kwargs: Any) -> dict:
    """The shipped entry on 2 lanes, one rollout of 64 steps and one epoch: what the pipeline
    does with a training (save, reload, evaluate, aggregate) does not depend on its size."""
    entry = load_hyperparams(*args, **kwargs)
    return {**entry, "n_envs": 2, "n_steps": 32, "batch_size": 64, "n_epochs": 1}


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path]:
    out = tmp_path_factory.mktemp("study")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        # Two trainings at a time in worker processes: the study's pool path.
        result = run_study(out, training_seeds=2, episodes=2, timesteps=64, duration_s=0.3, jobs=2)
    return result, out


def test_rows_cover_every_configuration_and_target(tiny_study: tuple[dict, Path]) -> None:
    result, _ = tiny_study
    rows = result["rows"]
    want = [("dflqr", t) for t in ("truth", "ekf_slam", "fastslam")] + [
        (cfg.name, t) for cfg in TRAINED for t in cfg.eval_on
    ]
    assert [(r["config"], r["eval_on"]) for r in rows] == want
    for row in rows:
        assert 0.0 <= row["crash_rate"] <= 1.0
        stats = row["track_pos_rmse_m"]
        assert stats["min"] <= stats["median"] <= stats["max"]
        learned = row["config"] != "dflqr"
        assert row["n_training_seeds"] == (2 if learned else 0)
        assert row["n_episodes"] == (4 if learned else 2)
        assert [e["seed"] for e in row["episodes"]] == [1000, 1001] * (2 if learned else 1)
        assert len(row["train_wall_s"]) == (2 if learned else 0)  # one per training run
    assert result["settings"]["jobs"] == 2 and result["settings"]["wall_s"] > 0
    by_key = {(r["config"], r["eval_on"]): r for r in rows}
    # On the truth the estimation error is exactly zero; on a filter it is not.
    assert by_key["dflqr", "truth"]["est_pos_rmse_m"]["max"] == 0.0
    assert by_key["ppo_truth", "truth"]["est_pos_rmse_m"]["max"] == 0.0
    assert by_key["dflqr", "ekf_slam"]["est_pos_rmse_m"]["min"] > 0.0
    assert by_key["ppo_truth", "ekf_slam"]["train_on"] == "truth"


def test_rerun_reuses_finished_trainings(tiny_study: tuple[dict, Path]) -> None:
    _, out = tiny_study
    runs = sorted(out.glob("train/*/s*/*/model.zip"))
    assert len(runs) == 2 * len(TRAINED)
    again = run_study(out, training_seeds=2, episodes=1, timesteps=128, duration_s=0.3, jobs=2)
    assert sorted(out.glob("train/*/s*/*/model.zip")) == runs  # nothing trained again
    assert len(again["rows"]) == 3 + sum(len(cfg.eval_on) for cfg in TRAINED)


def _parameters(run: Path) -> dict[str, Any]:
    """The policy's saved tensors (``policy.pth`` in SB3's ``model.zip``)."""
    import io
    import zipfile

    import torch

    with zipfile.ZipFile(run / "model.zip") as archive:
        return torch.load(io.BytesIO(archive.read("policy.pth")), weights_only=True)


def test_trainings_in_workers_equal_trainings_in_this_process(
    tiny_study: tuple[dict, Path], tmp_path: Path
) -> None:
    """A policy trained in a worker (the fixture: jobs=2) is bit-identical to the same
    training run here, one after the other (jobs=1): it depends on its config and seed only."""
    import torch

    _, out = tiny_study
    cfg = TRAINED[1]
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        short = {"scenario": cost.SCENARIO, "episode": {"duration_s": 0.3}}
        jobs = [cost.train_job(cfg, seed, 64, tmp_path, short, None) for seed in range(2)]
        here = train_all(jobs, 1)
    parallel = [finished_run(out / "train" / cfg.name / f"s{seed}") for seed in range(2)]
    for mine, theirs in zip(here, parallel, strict=True):
        assert theirs is not None
        a, b = _parameters(mine.run), _parameters(theirs.run)
        assert a.keys() == b.keys()
        for key in a:
            assert torch.equal(a[key], b[key]), key
    # The two seeds train different policies: the comparison above can fail.
    first, second = (_parameters(t.run) for t in here)
    assert any(not torch.equal(first[k], second[k]) for k in first)


def test_a_failing_training_raises_with_its_config_and_stops_the_others(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """One configuration with a hyperparameter PPO rejects, the other training side by side:
    the study raises the worker's error naming the configuration, and the other training is
    stopped without leaving a run that a rerun would reuse."""
    broken = TrainedConfig("ppo_broken", cost.EKF, {"n_steps": 0}, ("ekf_slam",), "broken")
    monkeypatch.setattr(cost, "TRAINED", (TRAINED[1], broken))
    with pytest.raises(ValueError, match=r"^training ppo_broken seed 0: hyperparameters rejected"):
        run_study(tmp_path, training_seeds=1, episodes=1, timesteps=10**6, jobs=2)
    assert finished_run(tmp_path / "train" / TRAINED[1].name / "s0") is None


def test_json_has_the_documented_fields(tiny_study: tuple[dict, Path], tmp_path: Path) -> None:
    result, _ = tiny_study
    path = tmp_path / "study.json"
    write_json(result, path)
    data = json.loads(path.read_text())
    for row in data["rows"]:
        for key in ("config", "policy", "train_on", "eval_on", "crash_rate"):
            assert key in row
        assert set(row["track_pos_rmse_m"]) == {"median", "min", "max"}


def test_cli_parses_the_study_command() -> None:
    args = cli.build_parser().parse_args(
        ["study", "cost-of-estimation", "--quick", "--json", "x.json"]
    )
    assert args.func is cli_study.cmd_study_cost and args.quick and args.json == Path("x.json")
    assert args.jobs is None  # run_study's default: the CPU cores available
    for study in ("cost-of-estimation", "active-perception"):
        assert cli.build_parser().parse_args(["study", study, "--jobs", "3"]).jobs == 3
        with pytest.raises(SystemExit):
            cli.build_parser().parse_args(["study", study, "--jobs", "0"])
