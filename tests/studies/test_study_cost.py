"""The cost-of-estimation study pipeline on a tiny budget (seconds, not a result)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from agents.lab.cli import main as cli
from agents.lab.cli import study as cli_study
from agents.lab.control_studies import cost
from agents.lab.control_studies.cost import TRAINED, TrainedConfig, run_study, write_json
from agents.lab.control_studies.learned_rows import HEADLINE, TRACK_KEYS
from agents.lab.control_studies.training_pool import Trained, TrainJob, finished_run, train_all
from agents.rl import hyperparams
from agents.rl.hyperparams import load_hyperparams


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


def test_learned_rows_carry_seed_statistics_and_the_claim(tiny_study: tuple[dict, Path]) -> None:
    """Two real tiny trainings per row: the IQM and CI over the two seeds' medians, and the
    claim undefined where the 0.3 s episodes have no steady state (DF-LQR's included)."""
    result, _ = tiny_study
    for row in result["rows"]:
        if row["config"] == "dflqr":
            assert "seed_stats" not in row and "claims" not in row
            continue
        assert set(row["seed_stats"]) == set(TRACK_KEYS)
        for key in ("track_pos_rmse_transient_m", "track_pos_rmse_m"):
            got = row["seed_stats"][key]
            # the episodes of seed 0, then of seed 1, each on seeds 1000 and 1001
            medians = [np.median([e[key] for e in row["episodes"][2 * i : 2 * i + 2]])
                       for i in range(2)]  # fmt: skip
            assert got["per_seed"] == pytest.approx(medians) and got["n_seeds"] == 2
            assert got["iqm"] == pytest.approx(np.mean(medians))  # 2 seeds: the plain mean
            assert got["iqm_ci"] == pytest.approx(sorted(medians)) and got["undefined"] is None
        steady = row["seed_stats"][HEADLINE]
        assert steady["iqm"] is None and "no value" in steady["undefined"]
        (claim,) = row["claims"]
        assert claim["claim"] == f"<= 0.9 x dflqr on {row['eval_on']}"
        assert claim["holds"] is None and claim["n_seeds"] == 2
    text = cost.format_study(result)
    assert f"over training seeds, {HEADLINE}" in text and "IQM [95% CI]" in text


def _fake_records(seeds: list[int], steady: float) -> list[dict[str, Any]]:
    """Episode records with steady-state errors ``steady`` − 0.01, ``steady``, + 0.01, … and a
    transient twice as large."""
    offsets = [0.0, -0.01, 0.01, -0.02, 0.02]
    return [
        {"seed": s, "terminated": False, HEADLINE: steady + offsets[i % 5],
         "track_pos_rmse_transient_m": 2 * (steady + offsets[i % 5]),
         "track_pos_rmse_m": steady}
        for i, s in enumerate(seeds)
    ]  # fmt: skip


def test_the_claim_counts_the_training_seeds_at_most_0_9_of_dflqr(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """Trainings and flights replaced by known numbers: DF-LQR's median is 0.1 m on every
    target; training seed k of every learned row flies at ``PER_SEED[k]`` (its median over 3
    episodes), so the claim (at most 0.09 m) holds on seeds 0–2, and the IQM is the mean of
    the middle three."""
    per_seed = [0.07, 0.12, 0.085, 0.095, 0.089]

    def train(jobs: list[TrainJob], n_jobs: int) -> list[Trained]:
        return [Trained(job.folder / "run", 1.0) for job in jobs]

    def fly(policy: Any, env_id: str, kwargs: dict[str, Any], seeds: list[int]) -> list:
        if policy == "dflqr":
            return _fake_records(seeds, 0.1)
        return _fake_records(seeds, per_seed[int(Path(policy).parent.name[1:])])

    monkeypatch.setattr(cost, "train_all", train)
    monkeypatch.setattr(cost, "fly", fly)
    result = run_study(tmp_path, episodes=3)  # the default: 5 training seeds
    assert result["settings"]["training_seeds"] == [0, 1, 2, 3, 4]
    learned = [r for r in result["rows"] if r["config"] != "dflqr"]
    assert len(learned) == sum(len(cfg.eval_on) for cfg in TRAINED)
    for row in learned:
        stats = row["seed_stats"][HEADLINE]
        assert stats["per_seed"] == pytest.approx(per_seed) and stats["n_seeds"] == 5
        assert stats["median"] == pytest.approx(0.089)
        assert stats["iqm"] == pytest.approx((0.085 + 0.089 + 0.095) / 3)
        low, high = stats["iqm_ci"]
        assert 0.07 <= low < stats["iqm"] < high <= 0.12
        (claim,) = row["claims"]
        assert claim["baseline"] == pytest.approx(0.1) and claim["factor"] == 0.9
        assert claim["per_seed"] == [True, False, True, False, True]
        assert (claim["holds_on"], claim["n_seeds"], claim["holds"]) == (3, 5, "3/5 seeds")
        assert row["track_pos_rmse_steady_m"]["median"] == stats["median"]  # the old keys
    text = cost.format_study(result)
    assert text.count("3/5 seeds") == len(learned)
    assert f"{stats['iqm']:.3f} [{low:.3f}, {high:.3f}]" in text
    path = tmp_path / "study.json"
    write_json(result, path)
    assert json.loads(path.read_text())["rows"][-1]["claims"][0]["holds"] == "3/5 seeds"


def test_the_training_seeds_can_start_elsewhere(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``first_training_seed`` moves the table off the seeds a design choice was made on."""
    trained: list[TrainJob] = []

    def train(jobs: list[TrainJob], n_jobs: int) -> list[Trained]:
        trained.extend(jobs)
        return [Trained(job.folder / "run", 1.0) for job in jobs]

    monkeypatch.setattr(cost, "train_all", train)
    monkeypatch.setattr(
        cost, "fly", lambda policy, env_id, kwargs, seeds: _fake_records(seeds, 0.1)
    )
    result = run_study(tmp_path, training_seeds=2, episodes=1, first_training_seed=10)
    assert result["settings"]["training_seeds"] == [10, 11]
    assert {(job.seed, job.folder.name) for job in trained} == {(10, "s10"), (11, "s11")}
    with pytest.raises(ValueError, match=r"^first_training_seed: got -1; allowed: an integer >= 0"):
        run_study(tmp_path, first_training_seed=-1)
    args = cli.build_parser().parse_args(["study", "cost-of-estimation"])
    assert args.first_training_seed == 0 and args.training_seeds is None
    for study in ("cost-of-estimation", "active-perception", "robustness"):
        parsed = cli.build_parser().parse_args(["study", study, "--first-training-seed", "10"])
        assert parsed.first_training_seed == 10
        with pytest.raises(SystemExit):
            cli.build_parser().parse_args(["study", study, "--first-training-seed", "-1"])
