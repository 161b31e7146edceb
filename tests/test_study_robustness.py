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
from agents.studies.cost import SCENARIO, TRAINED, scenario_kwargs, train_job
from agents.studies.robustness import CONDITIONS, LEARNED, ROWS, condition_kwargs
from quadslam_env.config import load_scenario
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
    configs = ["dflqr", "dflqr_integral", *(cfg.name for cfg in LEARNED)]
    assert [(r["eval_on"], r["config"]) for r in rows] == [
        (c, k) for c in CONDITIONS for k in configs
    ]
    assert result["settings"]["eval_seeds"] == [1000, 1001]
    for row in rows:
        # One training seed (quick): every row's episodes are the seeds 1000 and 1001, in order.
        assert [e["seed"] for e in row["episodes"]] == [1000, 1001]
        assert row["n_training_seeds"] == (0 if row["config"].startswith("dflqr") else 1)
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


def test_ppo_nominal_is_the_cost_studys_ppo_ekf_training(
    quick_run: tuple[dict, Path, Path],
) -> None:
    """The same entry, scenario, seed and budget: the same run (only the folder differs)."""
    _, out, _ = quick_run
    (ppo_ekf,) = (cfg for cfg in TRAINED if cfg.name == "ppo_ekf")
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        job = train_job(ppo_ekf, 0, 64, out, scenario_kwargs(0.3), None)
    (run,) = (out / "train" / "ppo_nominal" / "s0").iterdir()
    saved = run_config(run)
    assert saved is not None and saved["env_id"] == job.env_id and saved["seed"] == job.seed
    # The run records the budget it was given (--timesteps 64) as its n_timesteps.
    assert job.hyperparams is not None
    assert saved["hyperparams"] == {**job.hyperparams, "n_timesteps": job.timesteps}


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
        flown.append(getattr(policy, "__name__", str(policy)))
        return [{"seed": s, "terminated": False} for s in seeds]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(hyperparams, "load_hyperparams", _tiny_ppo)
        patch.setattr(robustness, "fly", fly)
        again = robustness.run_study(out, quick=True, episodes=1, timesteps=64, duration_s=0.3)
    assert sorted(out.glob("train/*/s*/*/model.zip")) == runs
    assert len(again["rows"]) == len(CONDITIONS) * len(ROWS)
    # Each condition flies both DF-LQRs and the runs found in --out, nothing else.
    everything = ["dflqr", "dflqr_integral", *(str(r.parent) for r in runs)]
    assert sorted(flown) == sorted(everything * len(CONDITIONS))


def test_the_dflqr_rows_alone_train_nothing(tmp_path: Path) -> None:
    flown: list[str] = []

    def fly(policy: Any, env_id: str, kwargs: dict[str, Any], seeds: list[int]) -> list:
        flown.append(getattr(policy, "__name__", str(policy)))
        return [{"seed": s, "terminated": False} for s in seeds]

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(robustness, "fly", fly)
        result = robustness.run_study(
            tmp_path, episodes=1, duration_s=0.3, rows=["dflqr", "dflqr_integral"]
        )
    assert not (tmp_path / "train").exists()
    assert [r["config"] for r in result["rows"]] == ["dflqr", "dflqr_integral"] * len(CONDITIONS)
    assert flown == ["dflqr", "dflqr_integral"] * len(CONDITIONS)
    with pytest.raises(ValueError, match="rows"):
        robustness.run_study(tmp_path, rows=["dflqr", "lqr"])


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


def test_the_conditions_are_the_cost_scenario_plus_one_section_each() -> None:
    """Nominal is the cost study's scenario; the others add the randomised scenario's
    ``randomize`` section or the wind scenario's ``wind``, drag and filter Q, read from those
    files."""
    nominal = condition_kwargs("nominal")
    assert nominal == {"scenario": SCENARIO} == scenario_kwargs()
    randomized, wind = condition_kwargs("randomized"), condition_kwargs("wind")
    assert set(randomized) - set(nominal) == {"randomize"}
    assert set(wind) - set(nominal) == {"wind", "vehicle", "estimator"}
    assert {k: randomized[k] for k in nominal} == nominal == {k: wind[k] for k in nominal}
    # The sections as the scenarios themselves load them.
    source = load_scenario(robustness.RANDOMIZED)
    assert load_scenario(SCENARIO, {"randomize": randomized["randomize"]}).randomize == (
        source.randomize
    )
    windy = load_scenario(robustness.WIND)
    flown = load_scenario(SCENARIO, {k: wind[k] for k in ("wind", "vehicle", "estimator")})
    assert flown.wind == windy.wind
    assert flown.vehicle == windy.vehicle  # both the rauniyar2023 vehicle, with the drag
    q = "process_noise"
    assert flown.estimator.params[q] == windy.estimator.params[q]
    assert load_scenario(SCENARIO).estimator.params[q] != windy.estimator.params[q]
    assert load_scenario(SCENARIO).vehicle != windy.vehicle
    with pytest.raises(ValueError, match="condition"):
        condition_kwargs("gusty")


def _observations(condition: str, steps: int, options: dict | None = None) -> np.ndarray:
    """(seeds, steps + 1, obs_dim) observations of three seeds flown with the hover action."""
    env = gym.make(robustness.EKF, **condition_kwargs(condition, 1.0))
    try:
        out = []
        for seed in (1000, 1001, 1002):
            obs = [env.reset(seed=seed, options=options)[0]]
            for _ in range(steps):
                obs.append(env.step(env.unwrapped.hover_action)[0])  # type: ignore[attr-defined]
            out.append(obs)
        return np.array(out)
    finally:
        env.close()


def test_pinned_randomisation_flies_the_nominal_episode_and_wind_starts_from_it() -> None:
    """The randomise section changes nothing but the drawn scales: pinned to 1, a seed's
    episode is the nominal one step for step; with wind, the same start."""
    pinned = {"randomized": {k: 1.0 for k in SCALE_KEYS}}
    nominal = _observations("nominal", 50)
    np.testing.assert_array_equal(_observations("randomized", 50, pinned), nominal)
    np.testing.assert_array_equal(_observations("wind", 0)[:, 0], nominal[:, 0])
    assert len({obs.tobytes() for obs in nominal[:, 0]}) == 3  # the seeds differ


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


def test_bad_rows_are_a_clear_error(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        cli.build_parser().parse_args(["study", "robustness", "--rows", "dflqr,lqr"])
    assert exc.value.code == 2 and "--rows" in capsys.readouterr().err
    args = cli.build_parser().parse_args(["study", "robustness", "--rows", "dflqr,dflqr_integral"])
    assert args.rows == ["dflqr", "dflqr_integral"]


def test_cli_parses_the_study_command() -> None:
    args = cli.build_parser().parse_args(["study", "robustness", "--timesteps", "300000"])
    assert args.func is cli_study.cmd_study_robustness and args.timesteps == 300_000
    assert not args.quick and args.jobs is None and args.training_seeds is None
    assert args.rows is None
