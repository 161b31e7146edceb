"""Loading a run folder never unpickles: the policy is rebuilt from ``config.yaml`` and the
arrays (``policy.npz``, ``vecnormalize.npz``) and acts as SB3's own ``load`` of ``model.zip``
does; crafted pickles in a folder do not run unless the trust flag is given; ``convert-run``
gives an older folder its arrays."""

from __future__ import annotations

import base64
import json
import pickle
import shutil
import warnings
import zipfile
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from stable_baselines3 import PPO, SAC

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.main import main
from agents.rl.loading import load_model
from agents.rl.saved.manifest import MANIFEST, ManifestWarning, write_manifest
from agents.rl.saved.safe_files import SafeFileError, read_normalization, read_policy
from agents.rl.training import train
from agents.rl.wrappers import residual_action

ENV = "QuadSLAM-Oracle-v0"  # no filter to compile: the fastest training
SHORT = {"episode": {"duration_s": 1.0}}
SCENARIO = "ekf_figure8_biased_imu"  # the scenario of the Oracle entries (no mismatch warning)
COMMON = {
    "policy_kwargs": {"net_arch": [8]},
    "env_kwargs": SHORT,
    "eval_freq": 64,
    "n_eval_episodes": 1,
    "checkpoint_freq": 64,
    "normalize": True,
}
EVALUATE = ["evaluate", "--episodes", "1", "--duration", "0.3", "--seed", "3"]
SAFE_FILES = ("policy.npz", "vecnormalize.npz")


@pytest.fixture(autouse=True, scope="module")
def _one_torch_thread() -> Any:
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def _train(out: Path, algo: str, **hyperparams: Any) -> Path:
    return train(algo, ENV, timesteps=128, n_envs=1, seed=1, out_dir=out, progress=False,
                 hyperparams={**COMMON, **hyperparams})  # fmt: skip


@pytest.fixture(scope="module")
def ppo_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A tiny residual PPO run with VecNormalize, checkpoints and a best model."""
    return _train(tmp_path_factory.mktemp("ppo"), "ppo", n_steps=64, batch_size=32, n_epochs=2)


@pytest.fixture
def run(ppo_run: Path, tmp_path: Path) -> Path:
    """A copy of the PPO run for one test to change."""
    return Path(shutil.copytree(ppo_run, tmp_path / ppo_run.name))


def _observations(n: int = 64) -> np.ndarray:
    """Raw observations well spread over and beyond the trained range (clipping included)."""
    return (np.random.default_rng(7).normal(size=(n, 16)) * 3.0).astype(np.float32)


def _pickled_stats(path: Path) -> Any:
    with path.open("rb") as fh:  # this test's own training wrote it
        return pickle.load(fh)


def _assert_acts_as_sb3_load(run: Path, zip_name: str, pkl_name: str, cls: Any) -> None:
    """The rebuilt policy's actions on the same observations are those of ``cls.load(zip)``
    with the pickled ``VecNormalize``: the model's, the statistics' and the whole chain's."""
    env = gym.make(ENV, scenario=SCENARIO, **SHORT)
    safe = load_model(run / zip_name, env)
    ref = cls.load(run / zip_name, device="cpu")
    vec = _pickled_stats(run / pkl_name)
    obs = _observations()
    assert safe.normalization is not None
    np.testing.assert_array_equal(safe.normalization.normalize_obs(obs), vec.normalize_obs(obs))
    model_obs = vec.normalize_obs(obs)
    expected, _ = ref.predict(model_obs, deterministic=True)
    np.testing.assert_array_equal(safe.model.predict(model_obs, deterministic=True)[0], expected)
    assert safe.controller is not None and safe.scale is not None
    base, _ = safe.controller.predict(obs)
    np.testing.assert_array_equal(safe.predict(obs)[0], residual_action(base, expected, safe.scale))
    assert safe.model.num_timesteps == ref.num_timesteps


def test_a_run_folder_holds_its_weights_and_statistics_as_arrays(ppo_run: Path) -> None:
    checkpoints = ppo_run / "checkpoints"
    for path in (
        ppo_run / "policy.npz",
        ppo_run / "vecnormalize.npz",
        ppo_run / "eval" / "best_policy.npz",
        ppo_run / "eval" / "best_vecnormalize.npz",
        checkpoints / "model_policy_64_steps.npz",
        checkpoints / "model_vecnormalize_64_steps.npz",
    ):
        assert path.is_file(), path
        with np.load(path, allow_pickle=False) as data:  # would raise on an object array
            assert all(data[name].dtype.kind != "O" for name in data.files)
    weights = read_policy(ppo_run / "policy.npz")
    assert (weights.algo, weights.policy_class, weights.num_timesteps) == (
        "ppo", "ActorCriticPolicy", 128)  # fmt: skip
    assert weights.observation_space.shape == (16,) and weights.action_space.shape == (4,)
    stats = read_normalization(ppo_run / "vecnormalize.npz")
    vec = _pickled_stats(ppo_run / "vecnormalize.pkl")
    np.testing.assert_array_equal(stats.obs_rms.mean, vec.obs_rms.mean)  # type: ignore[union-attr]
    assert (stats.clip_obs, stats.gamma, stats.norm_reward) == (vec.clip_obs, vec.gamma, True)


@pytest.mark.parametrize(
    ("zip_name", "pkl_name"),
    [
        ("model.zip", "vecnormalize.pkl"),
        ("eval/best_model.zip", "eval/best_vecnormalize.pkl"),
        ("checkpoints/model_64_steps.zip", "checkpoints/model_vecnormalize_64_steps.pkl"),
    ],
)
def test_the_rebuilt_ppo_policy_acts_as_sb3_load(
    ppo_run: Path, zip_name: str, pkl_name: str
) -> None:
    _assert_acts_as_sb3_load(ppo_run, zip_name, pkl_name, PPO)


def test_the_rebuilt_sac_policy_acts_as_sb3_load(tmp_path: Path) -> None:
    sac = _train(tmp_path, "sac", learning_starts=32, batch_size=32, buffer_size=2000)
    assert read_policy(sac / "policy.npz").policy_class == "SACPolicy"
    _assert_acts_as_sb3_load(sac, "model.zip", "vecnormalize.pkl", SAC)


def test_the_rebuilt_privileged_critic_acts_as_sb3_load(tmp_path: Path) -> None:
    run = _train(tmp_path, "ppo", policy="AsymmetricActorCriticPolicy", n_steps=64,
                 batch_size=32, n_epochs=1)  # fmt: skip
    safe = load_model(run, gym.make(ENV, scenario=SCENARIO, **SHORT))
    ref = PPO.load(run / "model.zip", device="cpu")
    vec = _pickled_stats(run / "vecnormalize.pkl")
    obs = _observations()
    model_obs = vec._normalize_obs(obs, vec.obs_rms["obs"]).astype(np.float32)
    np.testing.assert_array_equal(safe.normalization.normalize_obs(obs, "obs"), model_obs)  # type: ignore[union-attr]
    np.testing.assert_array_equal(
        safe.model.policy.actor_action(model_obs), ref.policy.actor_action(model_obs)
    )


# ---------------------------------------------------------------------------- crafted pickles
class _WritesMarker:
    """Unpickled, it opens (creates) the marker file: stands for any code a pickle runs."""

    def __init__(self, marker: Path) -> None:
        self.marker = str(marker)

    def __reduce__(self) -> tuple[Any, tuple[str, str]]:
        return (open, (self.marker, "w"))


def _craft_pickle(path: Path, marker: Path) -> None:
    path.write_bytes(pickle.dumps(_WritesMarker(marker)))


def _craft_zip(path: Path, marker: Path) -> None:
    """SB3's zip with its pickled observation space replaced by the marker-writing pickle."""
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    data = json.loads(members["data"])
    blob = base64.b64encode(pickle.dumps(_WritesMarker(marker))).decode()
    data["observation_space"][":serialized:"] = blob
    members["data"] = json.dumps(data).encode()
    with zipfile.ZipFile(path, "w") as archive:
        for name, content in members.items():
            archive.writestr(name, content)


def _fly_every_way(run: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Evaluate ``run`` as ``quadslam evaluate``, a sweep job and a study do, untrusted."""
    from agents.lab.control_studies.learned_rows import fly
    from agents.lab.sweep.jobs import execute_job

    assert main([*EVALUATE, "--policy", str(run)]) == 0, capsys.readouterr().err
    params = {"env": ENV, "scenario": SCENARIO, "estimator": None, "plots": False, "seeds": [0],
              "overrides": {"episode": {"duration_s": 0.3}}, "policy": str(run)}  # fmt: skip
    assert execute_job("evaluate", params)["result"]["episodes"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ManifestWarning)
        assert fly(str(run), ENV, {"scenario": SCENARIO, "episode": {"duration_s": 0.3}}, [0])


@pytest.mark.parametrize("manifest", ["rewritten", "deleted"])
def test_crafted_pickles_do_not_run_when_the_folder_is_evaluated(
    capsys: pytest.CaptureFixture[str], run: Path, tmp_path: Path, manifest: str
) -> None:
    """A folder whose ``model.zip`` and ``vecnormalize.pkl`` (final, best and checkpoints)
    are crafted: evaluating it runs neither, with a manifest that lists them (its crafter
    wrote one) and without one."""
    marker = tmp_path / "pickle_ran"
    for pkl in [run / "vecnormalize.pkl", *run.rglob("*_vecnormalize*.pkl")]:
        _craft_pickle(pkl, marker)
    for zip_path in [run / "model.zip", *run.rglob("*_model.zip"), *run.rglob("model_*.zip")]:
        _craft_zip(zip_path, marker)
    if manifest == "rewritten":
        write_manifest(run)
    else:
        (run / MANIFEST).unlink()
    _fly_every_way(run, capsys)
    assert main([*EVALUATE, "--policy", str(run / "eval" / "best_model.zip")]) == 0
    assert not marker.exists()


@pytest.mark.parametrize("crafted", ["vecnormalize.pkl", "model.zip"])
@pytest.mark.parametrize("manifest", ["rewritten", "deleted"])
def test_an_older_folder_is_read_from_its_pickles_only_with_the_trust_flag(
    capsys: pytest.CaptureFixture[str], run: Path, tmp_path: Path, crafted: str, manifest: str
) -> None:
    marker = tmp_path / "pickle_ran"
    for name in SAFE_FILES:  # a run saved before the arrays existed
        (run / name).unlink()
    craft = _craft_pickle if crafted.endswith(".pkl") else _craft_zip
    craft(run / crafted, marker)
    if manifest == "rewritten":
        write_manifest(run)
    else:
        (run / MANIFEST).unlink()
    capsys.readouterr()
    assert main([*EVALUATE, "--policy", str(run)]) == 2
    line = capsys.readouterr().err.strip().splitlines()[-1]
    assert line.startswith(f"quadslam evaluate: error: {run}: no policy.npz")
    assert f"quadslam convert-run {run} --trust-pickle" in line
    assert not marker.exists()
    from agents.lab.sweep.jobs import execute_job

    params = {"env": ENV, "scenario": None, "estimator": None, "plots": False,
              "overrides": {}, "policy": str(run), "seeds": [0]}  # fmt: skip
    with pytest.raises(ValueError, match=r"no policy\.npz"):
        execute_job("evaluate", params)
    assert not marker.exists()
    # The flag is what lets the pickle be read: it runs (and is no policy).
    assert main([*EVALUATE, "--policy", str(run), "--trust-pickle"]) == 2
    assert marker.exists()


def test_the_trust_flag_reads_an_older_folder_as_sb3_saved_it(run: Path) -> None:
    env = gym.make(ENV, scenario=SCENARIO, **SHORT)
    safe = load_model(run, env)
    for name in SAFE_FILES:
        (run / name).unlink()
    with pytest.raises(ValueError, match=r"no policy\.npz .* --trust-pickle"):
        load_model(run, env)
    trusted = load_model(run, env, trust_pickle=True)
    obs = _observations()
    np.testing.assert_array_equal(trusted.predict(obs)[0], safe.predict(obs)[0])


def test_a_bare_zip_needs_the_trust_flag(tmp_path: Path) -> None:
    env = gym.make(ENV, scenario=SCENARIO, **SHORT)
    PPO("MlpPolicy", env, policy_kwargs={"net_arch": [4]}, device="cpu").save(tmp_path / "p")
    with pytest.raises(ValueError, match=r"outside a run folder .* --trust-pickle"):
        load_model(tmp_path / "p.zip", env)
    assert load_model(tmp_path / "p.zip", env, trust_pickle=True).algo == "ppo"


def test_an_object_array_in_the_weights_is_refused_unread(run: Path, tmp_path: Path) -> None:
    marker = tmp_path / "pickle_ran"
    with np.load(run / "policy.npz", allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["param/action_net.weight"] = np.array([_WritesMarker(marker)], dtype=object)
    np.savez(run / "policy.npz", **arrays)  # NumPy pickles an object array
    write_manifest(run)
    with pytest.raises(SafeFileError, match=r"policy.npz: cannot read the policy weights"):
        load_model(run, gym.make(ENV, scenario=SCENARIO, **SHORT))
    assert not marker.exists()


def test_weights_that_do_not_fit_the_config_are_refused_in_one_line(run: Path) -> None:
    with np.load(run / "policy.npz", allow_pickle=False) as data:
        arrays = {name: data[name] for name in data.files}
    arrays["param/action_net.weight"] = arrays["param/action_net.weight"][:, :3]
    np.savez(run / "policy.npz", **arrays)
    write_manifest(run)
    with pytest.raises(SafeFileError, match="do not fit the PPO policy") as caught:
        load_model(run, gym.make(ENV, scenario=SCENARIO, **SHORT))
    assert "\n" not in str(caught.value)


# ---------------------------------------------------------------------------- convert-run
def test_convert_run_gives_an_older_folder_its_arrays(
    capsys: pytest.CaptureFixture[str], ppo_run: Path, run: Path
) -> None:
    arrays = sorted(p.relative_to(run) for p in run.rglob("*.npz") if p.name != "evaluations.npz")
    for name in arrays:
        (run / name).unlink()
    write_manifest(run)  # as an older training left it: no arrays, a manifest without them
    capsys.readouterr()
    assert main(["convert-run", str(run)]) == 2
    line = capsys.readouterr().err.strip()
    assert line.startswith("quadslam convert-run: error: convert-run reads") and "\n" not in line
    assert "--trust-pickle" in line and not (run / "policy.npz").exists()

    assert main(["convert-run", str(run), "--trust-pickle"]) == 0
    assert f"{run}: wrote policy.npz, vecnormalize.npz" in capsys.readouterr().out
    assert (
        sorted(p.relative_to(run) for p in run.rglob("*.npz") if p.name != "evaluations.npz")
        == arrays
    )
    listed = json.loads((run / MANIFEST).read_text())["files"]
    assert {"policy.npz", "vecnormalize.npz", "eval/best_policy.npz"} <= set(listed)
    env = gym.make(ENV, scenario=SCENARIO, **SHORT)
    obs = _observations()
    for name in ("", "eval/best_model.zip", "checkpoints/model_64_steps.zip"):
        converted, original = load_model(run / name, env), load_model(ppo_run / name, env)
        np.testing.assert_array_equal(converted.predict(obs)[0], original.predict(obs)[0])
    assert main(["convert-run", str(run), "--trust-pickle"]) == 0  # nothing left to convert
    assert "wrote nothing" in capsys.readouterr().out


def test_convert_run_checks_the_manifest_before_unpickling(
    capsys: pytest.CaptureFixture[str], run: Path, tmp_path: Path
) -> None:
    marker = tmp_path / "pickle_ran"
    (run / "policy.npz").unlink()
    _craft_pickle(run / "vecnormalize.pkl", marker)  # changed since the manifest was written
    capsys.readouterr()
    assert main(["convert-run", str(run), "--trust-pickle"]) == 2
    assert "vecnormalize.pkl differs from its manifest.json" in capsys.readouterr().err
    assert not marker.exists()


def test_a_sweep_asks_for_a_boolean_trust_pickle(ppo_run: Path) -> None:
    from agents.lab.sweep.spec import SweepSpecError, parse_spec

    block = {"kind": "evaluate", "policy": str(ppo_run)}
    (job,) = parse_spec({"jobs": [block]})
    assert "trust_pickle" not in job.params  # unchanged ids for the jobs without it
    (trusted,) = parse_spec({"jobs": [{**block, "trust_pickle": True}]})
    assert trusted.params["trust_pickle"] is True and trusted.job_id != job.job_id
    with pytest.raises(SweepSpecError, match=r"trust_pickle: got 'yes'; allowed: true or false"):
        parse_spec({"jobs": [{**block, "trust_pickle": "yes"}]})
