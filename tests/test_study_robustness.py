"""The robustness study: its conditions, and the whole ``--quick`` command on a tiny budget
(seconds, not a result)."""

from __future__ import annotations

import functools
import json
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

from agents.cli import main as cli
from agents.cli import study as cli_study
from agents.rl import hyperparams
from agents.rl.hyperparams import load_hyperparams
from agents.rl.run_folder import run_config
from agents.studies import robustness
from agents.studies.robustness import CONDITIONS, LEARNED, condition_kwargs
from quadslam_env.config_randomize import SCALE_KEYS


def _tiny_ppo(*args: Any, **kwargs: Any) -> dict:
    """The shipped entry on 2 lanes, one rollout of 64 steps and one epoch: what the pipeline
    does with a training (save, reload, fly, aggregate) does not depend on its size."""
    entry = load_hyperparams(*args, **kwargs)
    return {**entry, "n_envs": 2, "n_steps": 32, "batch_size": 64, "n_epochs": 1}


@pytest.fixture(scope="module")
def quick_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path, Path]:
    """``quadslam study robustness --quick`` with 64 training steps, 2 episodes of 0.3 s."""
    tmp = tmp_path_factory.mktemp("robust")
    out, json_path, plots = tmp / "runs", tmp / "robustness.json", tmp / "plots"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        short = functools.partial(robustness.run_study, duration_s=0.3)
        patch.setattr(robustness, "run_study", short)
        argv = ["study", "robustness", "--quick", "--timesteps", "64", "--episodes", "2"]
        argv += ["--jobs", "1", "--out", str(out), "--json", str(json_path), "--plots", str(plots)]
        assert cli.main(argv) == 0
    return json.loads(json_path.read_text()), out, plots


def test_every_row_flies_every_condition_on_the_same_held_out_seeds(
    quick_run: tuple[dict, Path, Path],
) -> None:
    result, _, plots = quick_run
    rows = result["rows"]
    configs = ["dflqr", *(cfg.name for cfg in LEARNED)]
    assert [(r["eval_on"], r["config"]) for r in rows] == [
        (c, k) for c in CONDITIONS for k in configs
    ]
    assert result["settings"]["eval_seeds"] == [1000, 1001]
    for row in rows:
        # One training seed (quick): every row's episodes are the seeds 1000 and 1001, in order.
        assert [e["seed"] for e in row["episodes"]] == [1000, 1001]
        assert row["n_training_seeds"] == (0 if row["config"] == "dflqr" else 1)
        assert row["n_ended_early"] == sum(e["terminated"] for e in row["episodes"])
        assert row["crash_rate"] == row["n_ended_early"] / 2
    assert (plots / "robustness.png").stat().st_size > 0


def test_rows_on_a_condition_fly_the_same_physics(quick_run: tuple[dict, Path, Path]) -> None:
    """On the randomised condition every row's episode of a seed drew the same scales, and the
    two seeds drew different ones; the other conditions draw none."""
    result, _, _ = quick_run
    keys = [f"rand_{k}" for k in SCALE_KEYS]
    for row in result["rows"]:
        drawn = [{k: e[k] for k in keys if k in e} for e in row["episodes"]]
        if row["eval_on"] != "randomized":
            assert drawn == [{}, {}]
            continue
        first = next(r for r in result["rows"] if r["eval_on"] == "randomized")
        assert drawn == [{k: e[k] for k in keys} for e in first["episodes"]]
        assert drawn[0]["rand_mass_scale"] != drawn[1]["rand_mass_scale"]


def test_each_learned_row_trained_on_its_condition(quick_run: tuple[dict, Path, Path]) -> None:
    _, out, _ = quick_run
    for cfg in LEARNED:
        (run,) = (out / "train" / cfg.name / "s0").iterdir()
        saved = run_config(run)
        assert saved is not None and saved["env_id"] == robustness.EKF
        env_kwargs = saved["hyperparams"]["env_kwargs"]
        want = condition_kwargs(cfg.train_on, 0.3)
        assert {k: env_kwargs[k] for k in want} == want
        assert env_kwargs["trajectory"] == {"start_on_reference": True}  # the entry's own


def test_rerun_reuses_the_trainings(quick_run: tuple[dict, Path, Path]) -> None:
    """A second run trains nothing (its flights, already covered above, are stubbed here)."""
    _, out, _ = quick_run
    runs = sorted(out.glob("train/*/s*/*/model.zip"))
    assert len(runs) == len(LEARNED)
    flown: list[str] = []

    def fly(policy: Any, env_id: str, kwargs: dict[str, Any], seeds: list[int]) -> list:
        flown.append(str(policy))
        return [{"seed": s, "terminated": False} for s in seeds]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        patch.setattr(robustness, "fly", fly)
        again = robustness.run_study(out, quick=True, episodes=1, timesteps=64, duration_s=0.3)
    assert sorted(out.glob("train/*/s*/*/model.zip")) == runs
    assert len(again["rows"]) == len(CONDITIONS) * (1 + len(LEARNED))
    # Each condition flies DF-LQR and the runs found in --out, nothing else.
    assert sorted(flown) == sorted(["dflqr", *(str(r.parent) for r in runs)] * len(CONDITIONS))


def _reset_infos(condition: str, seeds: range) -> list[dict[str, Any]]:
    env = gym.make(robustness.EKF, **condition_kwargs(condition, 0.1))
    try:
        return [env.reset(seed=seed)[1] for seed in seeds]
    finally:
        env.close()


def test_only_the_randomised_condition_draws_the_physics_per_episode() -> None:
    seeds = range(1000, 1006)
    randomized = _reset_infos("randomized", seeds)
    masses = np.array([info["rand_mass_scale"] for info in randomized])
    assert len(np.unique(masses)) == len(seeds)  # a new vehicle each episode
    assert np.all((masses >= 0.8) & (masses <= 1.2))  # the scenario's range
    noise = np.array([info["rand_imu_noise_scale"] for info in randomized])
    assert np.all((noise >= 0.5) & (noise <= 2.0)) and len(np.unique(noise)) == len(seeds)
    for condition in ("nominal", "wind"):
        for info in _reset_infos(condition, seeds):
            assert all(info.get(f"rand_{k}", 1.0) == 1.0 for k in SCALE_KEYS), condition


def test_the_nominal_condition_is_the_randomised_one_without_draws() -> None:
    """Same scenario; only the ``randomize`` section differs, pinned to 1 (the twin)."""
    from quadslam_env.config import load_scenario

    nominal, randomized = CONDITIONS["nominal"], CONDITIONS["randomized"]
    assert nominal["scenario"] == randomized["scenario"]
    assert set(nominal) - set(randomized) == {"randomize"}
    drawn = load_scenario(randomized["scenario"]).randomize
    assert any(tuple(getattr(drawn, k)) != (1.0, 1.0) for k in SCALE_KEYS)
    assert all(nominal["randomize"][k] == [1.0, 1.0] for k in SCALE_KEYS)


@pytest.mark.parametrize(
    ("option", "value"), [("--episodes", "0"), ("--timesteps", "-5"), ("--jobs", "x")]
)
def test_bad_cli_input_is_a_clear_error(
    option: str, value: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args(["study", "robustness", option, value])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert option in err and f"expected a positive integer, got '{value}'" in err


def test_cli_parses_the_study_command() -> None:
    args = cli.build_parser().parse_args(["study", "robustness", "--timesteps", "300000"])
    assert args.func is cli_study.cmd_study_robustness and args.timesteps == 300_000
    assert not args.quick and args.jobs is None and args.training_seeds is None
