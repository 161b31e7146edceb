"""The JAX learner backend (``backend: sbx``): what it refuses, the missing-extra error, the
flax → torch layout of ``policy.npz`` (sbx's deterministic actions, through
``TrainedPolicy``), ``quadslam evaluate`` and ``--resume`` of a run, and same-seed runs."""

from __future__ import annotations

import json
import shutil
import sys
import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli import main as cli
from agents.rl import sbx_backend
from agents.rl.hyperparams import load_hyperparams, resolve_settings
from agents.rl.policy_kwargs import ACTIVATIONS
from agents.rl.training import train
from quadslam_env.extras import MissingExtraError
from quadslam_env.schema import ConfigError

ENV = "QuadSLAM-EKF-v0"
SCENARIO = "ekf_figure8_biased_imu"  # the scenario of its PPO entry (no mismatch warning)
# Tiny networks and episodes (as tests/rl/test_training.py), no gSDE (the sbx backend refuses it).
TINY: dict[str, Any] = {
    "use_sde": False,
    "n_steps": 64,
    "batch_size": 32,
    "n_epochs": 2,
    "policy_kwargs": {"net_arch": [8]},
    "env_kwargs": {"episode": {"duration_s": 1.0}},
    "eval_freq": 0,
    "checkpoint_freq": 0,
}
CLI_TINY = ["use_sde=false", "n_steps=64", "batch_size=32", "n_epochs=2"]
CLI_TINY += ["policy_kwargs={net_arch: [8]}", "env_kwargs.episode.duration_s=1.0"]
CLI_TINY += ["eval_freq=128", "n_eval_episodes=1", "checkpoint_freq=128"]


def entry(**extra: Any) -> dict[str, Any]:
    """The shipped ``QuadSLAM-EKF-v0`` PPO entry with the sbx backend and ``extra``."""
    return {**load_hyperparams("ppo", ENV), **TINY, "backend": "sbx", **extra}


# ---------------------------------------------------------------------------- without sbx
def test_missing_sbx_is_one_line_naming_the_extra(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    monkeypatch.setitem(sys.modules, "sbx", None)  # `import sbx` raises ImportError
    with pytest.raises(MissingExtraError, match=r"pip install 'quadslam\[sbx\]'"):
        train("ppo", ENV, timesteps=64, out_dir=tmp_path, progress=False,
              hyperparams=TINY, backend="sbx")  # fmt: skip
    assert not list(tmp_path.iterdir()), "no run folder before the backend is found"
    capsys.readouterr()
    args = ["train", "--algo", "ppo", "--env", ENV, "--backend", "sbx", "--timesteps", "64"]
    args += ["--out", str(tmp_path), "--no-progress", "--hyperparams", "use_sde=false"]
    assert cli.main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "quadslam[sbx]" in err and "backend: sbx" in err


def test_settings_the_backend_does_not_take_are_refused_naming_the_key() -> None:
    with pytest.raises(ConfigError, match=r"use_sde: got True with backend: sbx; allowed: false"):
        resolve_settings("ppo", entry(use_sde=True))
    with pytest.raises(ConfigError, match=r"backend: got 'jax'; allowed: \['sb3', 'sbx'\]"):
        resolve_settings("ppo", entry(backend="jax"))
    a2c = {"n_timesteps": 64, "backend": "sbx"}
    with pytest.raises(ConfigError, match=r"backend: got 'sbx' with algo 'a2c'; allowed: "):
        resolve_settings("a2c", a2c)
    with pytest.raises(ConfigError, match=r"clip_range_vf: got 0.2 with backend: sbx"):
        resolve_settings("ppo", entry(clip_range_vf=0.2))
    kwargs = {"net_arch": [8], "optimizer_kwargs": {"eps": 1e-5}}
    with pytest.raises(ConfigError, match=r"policy_kwargs\.optimizer_kwargs: not taken"):
        resolve_settings("ppo", entry(policy_kwargs=kwargs))
    with pytest.raises(ConfigError, match="policy: got 'AsymmetricActorCriticPolicy'"):
        resolve_settings("ppo", entry(policy="AsymmetricActorCriticPolicy"))
    # The sb3 backend (the default) keeps all of it.
    assert resolve_settings("ppo", {**entry(use_sde=True), "backend": "sb3"})["backend"] == "sb3"
    assert resolve_settings("ppo", load_hyperparams("ppo", ENV))["backend"] == "sb3"


def test_cli_backend_flag_overrides_the_entry(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    seen: dict[str, Any] = {}

    def fake_train(*args: Any, **kwargs: Any) -> Path:
        seen.update(kwargs)
        raise ValueError("stop here")

    monkeypatch.setattr("agents.rl.training.train", fake_train)
    args = ["train", "--algo", "ppo", "--out", str(tmp_path), "--no-progress"]
    assert cli.main([*args, "--backend", "sbx"]) == 2
    assert seen["backend"] == "sbx"
    assert cli.main(args) == 2
    assert seen["backend"] is None  # the entry's backend, else sb3


def test_every_activation_name_has_a_flax_function() -> None:
    assert set(sbx_backend.FLAX_ACTIVATIONS) == set(ACTIVATIONS)


# ---------------------------------------------------------------------------- with sbx
@pytest.fixture(scope="module")
def sbx_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny residual PPO run of the sbx backend through ``quadslam train``, normalised, with
    checkpoints and evaluations at 128 and 256 steps."""
    pytest.importorskip("sbx")
    out = tmp_path_factory.mktemp("sbx_runs")
    args = ["train", "--algo", "ppo", "--env", ENV, "--backend", "sbx", "--timesteps", "256"]
    args += ["--n-envs", "2", "--seed", "3", "--out", str(out), "--no-progress"]
    assert cli.main([*args, "--hyperparams", *CLI_TINY]) == 0
    (run_dir,) = out.glob("ppo_*")
    return run_dir


def test_flax_activations_compute_what_the_torch_modules_do() -> None:
    pytest.importorskip("flax")
    import torch

    x = np.linspace(-4.0, 4.0, 101, dtype=np.float32)
    for name, cls_name in ACTIVATIONS.items():
        flax_fn = sbx_backend.flax_policy_kwargs({"activation_fn": name})["activation_fn"]
        expected = getattr(torch.nn, cls_name)()(torch.as_tensor(x)).numpy()
        np.testing.assert_allclose(np.asarray(flax_fn(x)), expected, atol=1e-6, err_msg=name)


def test_the_algo_kwargs_it_takes_are_sbx_ppo_arguments() -> None:
    sbx = pytest.importorskip("sbx")
    import inspect

    assert set(sbx_backend.ALGO_KWARGS) <= set(inspect.signature(sbx.PPO).parameters)


def _initial_actor(seed: int, **extra: Any) -> dict[str, Any]:
    from agents.rl.building import build_model, make_vec_env

    settings = resolve_settings("ppo", entry(n_envs=1, **extra))
    venv = make_vec_env(ENV, settings, 1, 0, None)
    try:
        model = build_model("ppo", settings, venv, seed)
    finally:
        venv.close()
    return {k: np.asarray(v) for k, v in sbx_backend.torch_layout(model).items()}


def test_ortho_init_defaults_to_true_as_in_sb3_and_the_seed_sets_the_weights() -> None:
    pytest.importorskip("sbx")
    first = _initial_actor(4)
    # SB3's ortho_init: the action layer orthogonal with gain 0.01 and zero bias.
    np.testing.assert_array_equal(first["action_net.bias"], 0.0)
    rows = np.linalg.norm(first["action_net.weight"], axis=1)
    np.testing.assert_allclose(rows, 0.01, rtol=1e-5)
    sbx_default = _initial_actor(4, policy_kwargs={"net_arch": [8], "ortho_init": False})
    assert np.abs(sbx_default["action_net.weight"]).max() > 0.05
    again, other = _initial_actor(4), _initial_actor(5)
    assert all(np.array_equal(first[k], again[k]) for k in first)
    assert not np.array_equal(first["mlp_extractor.policy_net.0.weight"],
                              other["mlp_extractor.policy_net.0.weight"])  # fmt: skip


def _sbx_model(zip_path: Path) -> Any:
    import sbx

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return sbx.PPO.load(zip_path, device="cpu")


def test_policy_npz_reproduces_sbx_deterministic_actions(sbx_run: Path) -> None:
    from agents.rl.loading import load_model
    from agents.rl.wrappers import residual_action

    env = gym.make(ENV, scenario=SCENARIO, **TINY["env_kwargs"])
    rng = np.random.default_rng(0)
    saved = [sbx_run / "model.zip", sbx_run / "eval" / "best_model.zip"]
    saved += sorted((sbx_run / "checkpoints").glob("model_*_steps.zip"))
    assert len(saved) == 4
    for zip_path in saved:
        model = _sbx_model(zip_path)
        policy = load_model(zip_path, env)  # from config.yaml and the arrays: SB3's torch PPO
        assert type(policy.model.policy).__name__ == "ActorCriticPolicy"
        assert policy.model.num_timesteps == model.num_timesteps
        obs = rng.normal(0.0, 2.0, size=(256, 16)).astype(np.float32)
        expected, _ = model.predict(obs, deterministic=True)
        got, _ = policy.model.predict(obs, deterministic=True)
        np.testing.assert_allclose(got, expected, rtol=0, atol=2e-6, err_msg=str(zip_path))
        # Through TrainedPolicy: the saved statistics, sbx's action, the residual on DF-LQR.
        assert policy.normalization is not None and policy.controller is not None
        raw = obs * 0.1
        residual, _ = model.predict(policy.normalization.normalize_obs(raw), deterministic=True)
        base, _ = policy.controller.predict(raw)
        action, _ = policy.predict(raw)
        assert policy.scale is not None
        np.testing.assert_allclose(action, residual_action(base, residual, policy.scale),
                                   rtol=0, atol=2e-6)  # fmt: skip


def test_the_run_folder_records_the_backend_and_evaluates(sbx_run: Path, tmp_path: Path) -> None:
    import yaml

    config = yaml.safe_load((sbx_run / "config.yaml").read_text())
    assert config["hyperparams"]["backend"] == "sbx"
    versions = json.loads((sbx_run / "versions.json").read_text())
    assert {"sbx", "jax", "flax"} <= set(versions)
    out_json = tmp_path / "eval.json"
    args = ["evaluate", "--policy", str(sbx_run), "--env", ENV, "--duration", "1"]
    assert cli.main([*args, "--episodes", "2", "--seed", "7", "--json", str(out_json)]) == 0
    result = json.loads(out_json.read_text())
    assert [ep["seed"] for ep in result["episodes"]] == [7, 8]


def test_resume_continues_an_sbx_run(sbx_run: Path, tmp_path: Path) -> None:
    from agents.rl.loading import load_model
    from agents.rl.saved.checkpoints import latest_checkpoint
    from agents.rl.training import resume

    run = tmp_path / sbx_run.name
    shutil.copytree(sbx_run, run)
    # A crash after the 128-step checkpoint: the later files never got written.
    for name in ("model_256_steps.zip", "model_256_steps.npz", "model_vecnormalize_256_steps.pkl",
                 "model_vecnormalize_256_steps.npz"):  # fmt: skip
        (run / "checkpoints" / name).unlink(missing_ok=True)
    (run / "timing.json").unlink()
    start = latest_checkpoint(run)
    assert start is not None and start.steps == 128
    assert resume(run, progress=False) == run
    assert json.loads((run / "timing.json").read_text())["timesteps"] == 256
    model = _sbx_model(run / "model.zip")
    assert type(model).__module__.startswith("sbx") and model.num_timesteps == 256
    assert (run / "monitor" / "lanes_from_128.monitor.csv").is_file()
    policy = load_model(run, gym.make(ENV, scenario=SCENARIO, **TINY["env_kwargs"]))
    assert policy.model.num_timesteps == 256


def test_same_seed_gives_the_same_sbx_run(sbx_run: Path, tmp_path: Path) -> None:
    """sbx on the CPU is bit-reproducible for the same seed on one machine: the same run as
    the fixture's, by ``train`` in this process, has the same weights and episodes."""
    from agents.rl.saved.safe_files import read_policy

    hp = {**TINY, "eval_freq": 128, "n_eval_episodes": 1, "checkpoint_freq": 128}
    again = train("ppo", ENV, timesteps=256, n_envs=2, seed=3, out_dir=tmp_path, progress=False,
                  hyperparams=hp, backend="sbx")  # fmt: skip
    first, second = read_policy(sbx_run / "policy.npz"), read_policy(again / "policy.npz")
    assert first.tensors.keys() == second.tensors.keys()
    for name in first.tensors:
        np.testing.assert_array_equal(first.tensors[name], second.tensors[name], err_msg=name)

    def episodes(run: Path) -> list[list[str]]:
        lines = (run / "monitor" / "lanes.monitor.csv").read_text().splitlines()[2:]
        return [line.split(",")[:2] for line in lines]

    assert episodes(sbx_run) == episodes(again) and episodes(again)
