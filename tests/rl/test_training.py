"""SB3 training/evaluation pipeline: configs, smoke runs, loading, CLI, determinism, wrapper."""

from __future__ import annotations

import csv
import json
import math
import zipfile
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml
from stable_baselines3 import PPO, SAC
from stable_baselines3.common.logger import Logger
from stable_baselines3.common.vec_env import VecNormalize
from training_cases import (
    SHORT,
    _one_torch_thread,  # noqa: F401  (an autouse fixture: one torch thread)
    config_entries,
    main_env,
    read_monitor,
    skip_unless_available,
    tiny,
)

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import (
    EPISODE_KEYS,
    STEADY_KEYS,
    SUMMARY_KEYS,
    TRANSIENT_KEYS,
    run_episode,
)
from agents.lab.cli import main as cli
from agents.rl.building import make_vec_env
from agents.rl.callbacks import EstimationMetricsCallback
from agents.rl.hyperparams import (
    load_hyperparams,
)
from agents.rl.loading import TrainedPolicy, load_model
from agents.rl.policies import load_policy
from agents.rl.saved.run_folder import run_config
from agents.rl.training import train
from agents.rl.wrappers import ResidualDFLQRWrapper, make_wrapped_env, residual_action


# ---------------------------------------------------------------------------- wrapper
def test_residual_wrapper_with_zero_residual_flies_dflqr_exactly() -> None:
    env_id = main_env()
    plain = gym.make(env_id, **SHORT)
    wrapped = make_wrapped_env(env_id, SHORT, {"name": "residual_dflqr", "scale": 0.3})
    assert isinstance(wrapped, ResidualDFLQRWrapper)
    dflqr = DFLQRPolicy.from_env(plain)
    obs_p, _ = plain.reset(seed=3)
    obs_w, _ = wrapped.reset(seed=3)
    zero = np.zeros(4, dtype=np.float32)
    for _ in range(60):
        np.testing.assert_array_equal(obs_w, obs_p)
        action, _ = dflqr.predict(obs_p)
        obs_w, rew_w, term_w, trunc_w, info_w = wrapped.step(zero)
        np.testing.assert_array_equal(wrapped.last_action, action)
        np.testing.assert_array_equal(info_w["dflqr_action"], action)
        obs_p, rew_p, term_p, trunc_p, _ = plain.step(action)
        assert rew_w == rew_p and term_w == term_p and trunc_w == trunc_p
    np.testing.assert_array_equal(obs_w, obs_p)


def test_residual_is_scaled_per_component_and_clipped() -> None:
    base = np.array([0.5, -0.95, 0.0, 0.2], dtype=np.float32)
    scale = np.array([0.1, 0.2, 0.3, 0.4], dtype=np.float32)
    out = residual_action(base, np.array([1.0, -1.0, 5.0, -0.5]), scale)
    np.testing.assert_allclose(out, [0.6, -1.0, 0.3, 0.0], atol=1e-7)
    assert out.dtype == np.float32
    env = gym.make(main_env(), **SHORT)
    with pytest.raises(ValueError, match=r"residual_dflqr\.scale"):
        ResidualDFLQRWrapper(env, scale=[0.1, 0.2])
    with pytest.raises(gym.error.ResetNeeded):
        ResidualDFLQRWrapper(env).step(np.zeros(4))
    rates = gym.make(main_env(), action={"mode": "thrust_rates"}, **SHORT)
    with pytest.raises(ValueError, match="thrust_torque"):
        ResidualDFLQRWrapper(rates)


# ---------------------------------------------------------------------------- callbacks
def test_metrics_callback_averages_finite_info_values_and_counts_failures() -> None:
    logger = Logger(folder=None, output_formats=[])
    callback = EstimationMetricsCallback()
    # A model whose env is not the adapter (no step_info): the per-lane path.
    model = SimpleNamespace(logger=logger, get_env=SimpleNamespace)
    callback.model = model  # type: ignore[assignment]
    infos = [
        {"est_pos_err_m": 1.0, "est_nees_pose": math.nan, "t": 0.1, "termination_reason": ""},
        {"est_pos_err_m": 3.0, "est_nees_pose": 2.0, "track_pos_err_m": 0.5, "residual": [0]},
    ]
    callback.locals = {"infos": infos, "dones": np.array([False, False])}
    callback._on_step()
    last = {
        "est_pos_err_m": 5.0,
        "episode_est_pos_rmse_m": 2.5,
        "termination_reason": "estimator_diverged: NEES above threshold",
    }
    callback.locals = {"infos": [last], "dones": np.array([True])}
    callback._on_step()
    callback._on_rollout_end()
    values = logger.name_to_value
    assert values["quadslam/est_pos_err_m"] == pytest.approx(3.0)
    assert values["quadslam/est_nees_pose"] == pytest.approx(2.0)  # NaN ignored
    assert values["quadslam/track_pos_err_m"] == pytest.approx(0.5)
    assert values["quadslam_episode/est_pos_rmse_m"] == pytest.approx(2.5)
    assert values["quadslam_episode/failure_rate"] == pytest.approx(1.0)
    assert values["quadslam_episode/n_estimator_diverged_nees_above_threshold"] == 1
    assert "quadslam/t" not in values and "quadslam/residual" not in values


def test_metrics_callback_reads_the_adapter_arrays_as_it_reads_the_lane_infos() -> None:
    """The batched path (``step_info`` arrays) logs the same means as the per-lane dicts."""
    from agents.rl.vec_adapter import QuadSLAMVecEnv

    env_kwargs = {"episode": {"duration_s": 0.3}}
    adapter = QuadSLAMVecEnv(main_env(), 3, seed=4, **env_kwargs)
    loggers = [Logger(folder=None, output_formats=[]) for _ in range(2)]
    callbacks = [EstimationMetricsCallback(), EstimationMetricsCallback()]
    for callback, logger, env in zip(callbacks, loggers, (adapter, SimpleNamespace()), strict=True):
        model = SimpleNamespace(logger=logger, get_env=lambda env=env: env)
        callback.model = model  # type: ignore[assignment]
    adapter.reset()
    actions = np.zeros((3, 4), dtype=np.float32)
    for _ in range(45):  # past one episode end (30 steps) in every lane
        _, _, dones, infos = adapter.step(actions)
        for callback in callbacks:
            callback.locals = {"infos": infos, "dones": dones}
            callback._on_step()
    for callback in callbacks:
        callback._on_rollout_end()
    batched, per_lane = (logger.name_to_value for logger in loggers)
    assert "quadslam_episode/est_pos_rmse_m" in batched
    assert batched.keys() == per_lane.keys()
    for key, value in per_lane.items():
        assert batched[key] == pytest.approx(value, rel=1e-12), key
    adapter.close()


# ---------------------------------------------------------------------------- training
@pytest.mark.parametrize(("algo", "env_id"), config_entries())
def test_smoke_training_with_shipped_config_loads_and_evaluates(
    algo: str, env_id: str, tmp_path: Path
) -> None:
    entry = load_hyperparams(algo, env_id)
    skip_unless_available(env_id, entry["env_kwargs"])
    run_dir = train(
        algo,
        env_id,
        timesteps=256,
        n_envs=1,
        seed=1,
        out_dir=tmp_path,
        progress=False,
        hyperparams=tiny(algo),
    )
    for name in ("config.yaml", "seed.txt", "versions.json", "model.zip", "learning_curve.png"):
        assert (run_dir / name).is_file(), name
    normalized = entry["normalize"] not in (False, None)
    assert (run_dir / "vecnormalize.pkl").is_file() == normalized
    assert (run_dir / "policy.npz").is_file()  # the weights as arrays, loaded without pickle
    assert (run_dir / "vecnormalize.npz").is_file() == normalized
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert run_config(run_dir) == config == run_config(run_dir / "eval" / "best_model.zip")
    assert config["algo"] == algo and config["env_id"] == env_id and config["seed"] == 1
    assert config["hyperparams"]["n_timesteps"] == 256
    assert config["scenario"]["episode"]["duration_s"] == 1.0
    versions = json.loads((run_dir / "versions.json").read_text())
    assert {"python", "numpy", "torch", "sb3", "gymnasium", "quadslam"} <= set(versions)
    assert (run_dir / "eval" / "evaluations.npz").is_file()
    assert list((run_dir / "checkpoints").glob("model_*_steps.zip"))
    with (run_dir / "logs" / "progress.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    logged = [float(r["quadslam/track_pos_err_m"]) for r in rows if r["quadslam/track_pos_err_m"]]
    assert logged and all(math.isfinite(v) for v in logged)
    assert list((run_dir / "logs").glob("events.out.tfevents.*"))

    env = gym.make(env_id, **{**entry["env_kwargs"], **SHORT})
    policy, name = load_policy(str(run_dir), env)
    assert isinstance(policy, TrainedPolicy) and policy.algo == algo and name == str(run_dir)
    assert (policy.normalization is not None) == normalized
    wrapped = entry["wrapper"] not in (None, "none")
    assert (policy.controller is not None) == wrapped
    record = run_episode(env, policy, seed=5)
    # A phase the episode never reached has no keys (absent, not NaN).
    settle, duration = env.unwrapped.core.settle_s, SHORT["episode"]["duration_s"]
    missing = (set() if settle > 0 else set(TRANSIENT_KEYS)) | (
        set() if duration > settle else set(STEADY_KEYS)
    )
    no_cov = {k for k in (*STEADY_KEYS, *TRANSIENT_KEYS) if "nees" in k}  # the Oracle's
    assert set(EPISODE_KEYS) - missing - no_cov <= set(record) <= set(EPISODE_KEYS) - missing
    assert record["duration_s"] > 0.0
    # Checkpoints and the best model load with their own VecNormalize statistics.
    for other in [run_dir / "eval" / "best_model.zip", *(run_dir / "checkpoints").glob("*.zip")]:
        loaded = load_model(other, env)
        assert loaded.algo == algo and (loaded.normalization is not None) == normalized


@pytest.fixture(scope="module")
def cli_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny PPO run made through ``quadslam train`` on the main env."""
    out = tmp_path_factory.mktemp("cli_runs")
    args = ["train", "--algo", "ppo", "--env", main_env(), "--timesteps", "128"]
    args += ["--n-envs", "1", "--seed", "2", "--out", str(out), "--no-progress", "--hyperparams"]
    args += ["n_steps=64", "batch_size=32", "n_epochs=1", "policy_kwargs={net_arch: [8]}"]
    args += ["env_kwargs.episode.duration_s=1.0", "eval_freq=0", "checkpoint_freq=0"]
    assert cli.main(args) == 0
    (run_dir,) = out.glob("ppo_*")
    return run_dir


def test_cli_train_prints_run_folder_and_evaluate_json_matches_schema(
    cli_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    env_id = main_env()
    scenario = load_hyperparams("ppo", env_id)["env_kwargs"]["scenario"]
    out_json = tmp_path / "eval.json"
    args = ["evaluate", "--policy", str(cli_run), "--env", env_id, "--scenario", scenario]
    args += ["--duration", "1", "--episodes", "2", "--seed", "7", "--json", str(out_json)]
    assert cli.main(args) == 0
    result = json.loads(out_json.read_text())
    assert set(result) == {"scenario", "estimator", "policy", "episodes", "summary"}
    assert result["scenario"] == scenario
    assert result["policy"] == str(cli_run)
    assert [ep["seed"] for ep in result["episodes"]] == [7, 8]
    for ep in result["episodes"]:
        assert set(ep) == set(EPISODE_KEYS) - set(STEADY_KEYS)  # 1 s: transient only
        for key in set(SUMMARY_KEYS) - set(STEADY_KEYS):
            assert ep[key] is None or isinstance(ep[key], (int, float))
    assert set(result["summary"]) == set(SUMMARY_KEYS)
    for key, stats in result["summary"].items():
        assert set(stats) == {"median", "min", "max", "n"}
        assert stats["n"] == (0 if key in STEADY_KEYS else 2) or stats["median"] is None
        if stats["median"] is not None:
            assert stats["min"] <= stats["median"] <= stats["max"]


def test_cli_train_reports_bad_input_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    args = ["train", "--algo", "ppo", "--env", main_env(), "--out", str(tmp_path)]
    code = cli.main([*args, "--hyperparams", "n_stepz=3"])
    err = capsys.readouterr().err
    assert code == 2
    assert "n_stepz: unknown hyperparameter for PPO" in err and len(err.strip().splitlines()) == 1


@pytest.mark.parametrize(
    ("override", "reason"), [("n_steps=0", "PPO"), ("learning_rate=fast", "PPO")]
)
def test_values_sb3_rejects_fail_before_the_run_folder(
    override: str, reason: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    capsys.readouterr()
    out = tmp_path / "runs"
    args = ["train", "--algo", "ppo", "--env", main_env(), "--out", str(out)]
    code = cli.main([*args, "--hyperparams", override, "n_envs=2"])
    err = capsys.readouterr().err
    assert code == 2 and len(err.strip().splitlines()) == 1
    assert f"hyperparameters rejected by {reason}" in err
    assert not out.exists() or not any(out.iterdir())  # no run folder was made


def test_interrupted_training_exits_130(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    import agents.rl.training

    run = tmp_path / "run"
    run.mkdir()
    (run / "INTERRUPTED").write_text("4096\n")
    monkeypatch.setattr(agents.rl.training, "train", lambda *a, **k: run)
    code = cli.main(["train", "--algo", "ppo", "--out", str(tmp_path)])
    assert code == 130 and "partial" in capsys.readouterr().err


def test_a_second_interrupt_while_saving_leaves_a_complete_run_folder(
    tmp_path: Path,
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    request: pytest.FixtureRequest,
) -> None:
    """Ctrl-C stops training; a second Ctrl-C during the learning-curve plot is held until the
    run folder is complete: status 130, the model, INTERRUPTED, the curve and timing.json."""
    import os
    import signal

    from stable_baselines3 import PPO

    import agents.rl.training

    def interrupted_learn(self: Any, *args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt

    plot = agents.rl.training.plot_learning_curve

    def plot_with_second_interrupt(run_dir: Path) -> None:
        os.kill(os.getpid(), signal.SIGINT)  # delivered here, in the main thread
        plot(run_dir)

    # Ctrl-C as a terminal delivers it: a test runner started in the background (no job
    # control) inherits SIGINT ignored, and an ignored signal is rightly left alone.
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    request.addfinalizer(lambda: signal.signal(signal.SIGINT, previous))
    monkeypatch.setattr(PPO, "learn", interrupted_learn)
    monkeypatch.setattr(agents.rl.training, "plot_learning_curve", plot_with_second_interrupt)
    out = tmp_path / "runs"
    args = ["train", "--algo", "ppo", "--env", main_env(), "--timesteps", "128", "--n-envs", "1"]
    args += ["--out", str(out), "--no-progress", "--hyperparams", "n_steps=64", "batch_size=32"]
    args += ["env_kwargs.episode.duration_s=1.0", "eval_freq=0", "checkpoint_freq=0"]
    assert cli.main(args) == 130
    (run_dir,) = out.glob("ppo_*")
    for name in ("model.zip", "INTERRUPTED", "timing.json", "config.yaml"):
        assert (run_dir / name).exists(), name
    assert "please wait" in capsys.readouterr().err
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # restored


def test_trained_policy_reproduces_training_time_actions(cli_run: Path) -> None:
    # The actions the env received inside the training pipeline (VecNormalize + residual on
    # the lanes + model) must equal TrainedPolicy.predict on the raw env.
    from agents.rl.hyperparams import resolve_settings as _resolve

    config = yaml.safe_load((cli_run / "config.yaml").read_text())
    settings = _resolve("ppo", config["hyperparams"])
    venv = make_vec_env(config["env_id"], settings, 1, 11, None, info_keys=None)
    venv = VecNormalize.load(str(cli_run / "vecnormalize.pkl"), venv)
    venv.training, venv.norm_reward = False, False
    model = PPO.load(cli_run / "model.zip", device="cpu")
    env = gym.make(config["env_id"], **settings["env_kwargs"])
    scale = ResidualDFLQRWrapper(env, **settings["wrapper"][1]).scale
    obs = venv.reset()
    sent = []
    for _ in range(40):
        act, _ = model.predict(obs, deterministic=True)
        obs, _, _, infos = venv.step(act)
        # The lane reports the DF-LQR action and the residual it composed the action from.
        sent.append(residual_action(infos[0]["dflqr_action"], infos[0]["residual"], scale))

    policy = load_model(cli_run, env)
    raw, _ = env.reset(seed=11)
    for expected in sent:
        action, _ = policy.predict(raw)
        np.testing.assert_array_equal(action, expected)
        raw, *_ = env.step(action)


def _first_actions(run_dir: Path, env_id: str, n: int = 30) -> np.ndarray:
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    env = gym.make(env_id, **config["hyperparams"]["env_kwargs"])
    policy = load_model(run_dir, env)
    obs, _ = env.reset(seed=0)
    actions = []
    for _ in range(n):
        action, _ = policy.predict(obs)
        actions.append(action)
        obs, *_ = env.step(action)
    return np.array(actions)


def test_same_seed_gives_identical_training(tmp_path: Path) -> None:
    env_id = main_env()
    hp = {**tiny("ppo"), "eval_freq": 0, "checkpoint_freq": 0}
    runs = [
        train(
            "ppo",
            env_id,
            timesteps=192,
            n_envs=1,
            seed=s,
            out_dir=tmp_path / f"{i}",
            progress=False,
            hyperparams=hp,
        )
        for i, s in enumerate((4, 4, 5))
    ]
    same = [_first_actions(r, env_id) for r in runs]
    np.testing.assert_array_equal(same[0], same[1])
    assert read_monitor(runs[0]) == read_monitor(runs[1])
    assert not np.array_equal(same[0], same[2])


# ---------------------------------------------------------------------------- loading errors
def test_model_for_another_observation_space_raises_naming_both_shapes(tmp_path: Path) -> None:
    env_id = main_env()
    other = gym.make(env_id, observation={"lookahead_s": [0.5]}, **SHORT)
    assert other.observation_space.shape == (19,)
    PPO("MlpPolicy", other, policy_kwargs={"net_arch": [4]}, device="cpu").save(tmp_path / "m")
    env = gym.make(env_id, **SHORT)
    with pytest.raises(ValueError, match=r"\(19,\).*\(16,\)"):
        load_policy(str(tmp_path / "m.zip"), env, trust_pickle=True)  # a bare SB3 zip
    args = ["evaluate", "--policy", str(tmp_path / "m.zip"), "--env", env_id, "--trust-pickle"]
    assert cli.main(args) == 2


def test_bare_zips_are_detected_as_ppo_or_sac(tmp_path: Path) -> None:
    env = gym.make(main_env(), **SHORT)
    SAC("MlpPolicy", env, policy_kwargs={"net_arch": [4]}, device="cpu").save(tmp_path / "s")
    PPO("MlpPolicy", env, policy_kwargs={"net_arch": [4]}, device="cpu").save(tmp_path / "p")
    sac = load_model(tmp_path / "s.zip", env, trust_pickle=True)  # bare zips: SB3's pickles
    ppo = load_model(tmp_path / "p.zip", env, trust_pickle=True)
    assert (sac.algo, ppo.algo) == ("sac", "ppo")
    assert sac.normalization is None and sac.controller is None
    obs, _ = env.reset(seed=0)
    assert sac.predict(obs)[0].shape == (4,)


def test_unreadable_files_give_clear_errors(tmp_path: Path) -> None:
    env = gym.make(main_env(), **SHORT)
    junk = tmp_path / "junk.zip"
    junk.write_bytes(b"not a zip at all")
    with pytest.raises(ValueError, match="not a stable-baselines3 model"):
        load_model(junk, env, trust_pickle=True)
    empty = tmp_path / "empty.zip"
    with zipfile.ZipFile(empty, "w") as archive:
        archive.writestr("hello.txt", "hi")
    with pytest.raises(ValueError, match="cannot load as a stable-baselines3 model"):
        load_model(empty, env, trust_pickle=True)
    with pytest.raises(FileNotFoundError, match=r"run folder without policy\.npz or model\.zip"):
        load_model(tmp_path, env)
    with pytest.raises(FileNotFoundError):
        load_policy(str(tmp_path / "missing"), env)
    assert run_config(tmp_path) is None and run_config(junk) is None


def test_parallel_envs_run_as_lanes_and_restore_torch_threads(tmp_path: Path) -> None:
    import torch

    threads = torch.get_num_threads()
    hp = {**tiny("ppo"), "eval_freq": 128, "checkpoint_freq": 0}
    run_dir = train(
        "ppo",
        main_env(),
        timesteps=256,
        n_envs=2,
        seed=0,
        out_dir=tmp_path,
        progress=False,
        hyperparams=hp,
    )
    assert torch.get_num_threads() == threads
    assert sorted(p.name for p in (run_dir / "monitor").iterdir()) == ["lanes.monitor.csv"]
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    assert config["hyperparams"]["n_envs"] == 2
    assert (run_dir / "model.zip").is_file()


def test_sac_collects_from_several_lanes(tmp_path: Path) -> None:
    """SAC on lanes: each vector step stores one transition per lane, then takes its
    ``gradient_steps`` (``train_freq`` counts vector steps)."""
    from stable_baselines3 import SAC

    hp = tiny("sac", eval_freq=0, checkpoint_freq=0, train_freq=1, gradient_steps=2)
    run_dir = train("sac", main_env(), timesteps=160, n_envs=4, out_dir=tmp_path,
                    progress=False, hyperparams=hp)  # fmt: skip
    model = SAC.load(run_dir / "model.zip", device="cpu")
    assert model.num_timesteps == 160 and model.n_envs == 4
    # 40 vector steps, of which the first 8 (32 transitions) only fill the buffer.
    assert model._n_updates == 2 * (40 - 8)
    assert yaml.safe_load((run_dir / "config.yaml").read_text())["hyperparams"]["n_envs"] == 4
