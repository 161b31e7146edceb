"""``policy_kwargs`` is plain data: config text is never evaluated, names resolve from an
allow-list, and every path that reads a config (agent YAML, ``--hyperparams``, sweep specs,
``--resume``) runs the same validator."""

from __future__ import annotations

import ast
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import yaml
from torch import nn

import quadslam_env  # noqa: F401  (registers the ids)
from agents.lab.cli.main import main
from agents.lab.sweep.spec import SweepSpecError, parse_spec
from agents.rl.building import build_model, make_vec_env
from agents.rl.hyperparams import load_hyperparams, parse_normalize, resolve_settings
from agents.rl.policy_kwargs import (
    ACTIVATIONS,
    ASYMMETRIC,
    build_policy_kwargs,
    validate_policy_kwargs,
)
from agents.rl.training import resume, train
from quadslam_env.schema import ConfigError

ROOT = Path(__file__).resolve().parents[2]
ENV = "QuadSLAM-Oracle-v0"  # no estimator: the cheapest env to build


def _attacks(target: Path) -> list[str]:
    """``policy_kwargs`` strings that would create ``target`` if they were evaluated."""
    return [
        f"dict(net_arch=[8], x=torch.os.system('touch {target}'))",
        f"dict(net_arch=[8], x=th.os.system('touch {target}'))",
        f"__import__('os').system('touch {target}')",
    ]


def _assert_rejected(message: str) -> None:
    assert "policy_kwargs" in message
    assert "allowed: a mapping" in message
    assert "not evaluated" in message
    assert str(list(ACTIVATIONS)) in message  # names the allowed activations
    assert "\n" not in message


def _zoo_file(tmp_path: Path, policy_kwargs: Any) -> Path:
    entry = load_hyperparams("ppo", ENV)
    entry["policy_kwargs"] = policy_kwargs
    path = tmp_path / "zoo.yaml"
    path.write_text(yaml.safe_dump({ENV: entry}, sort_keys=False))
    return path


# ------------------------------------------------------------------------- the attack string
def test_attack_string_is_rejected_by_the_validator_and_never_runs(tmp_path: Path) -> None:
    target = tmp_path / "pwned"
    for attack in _attacks(target):
        with pytest.raises(ConfigError) as info:
            validate_policy_kwargs(attack)
        _assert_rejected(str(info.value))
        assert repr(attack) in str(info.value)  # names the value
        entry = {**load_hyperparams("ppo", ENV), "policy_kwargs": attack}
        with pytest.raises(ValueError, match="policy_kwargs: got"):
            resolve_settings("ppo", entry)
    assert not target.exists()


def test_attack_string_in_an_agent_yaml_fails_train_before_any_folder(tmp_path: Path) -> None:
    target = tmp_path / "pwned"
    config = _zoo_file(tmp_path, _attacks(target)[0])
    out = tmp_path / "runs"
    with pytest.raises(ConfigError) as info:
        train("ppo", ENV, config_path=config, out_dir=out, progress=False)
    _assert_rejected(str(info.value))
    assert not target.exists()
    assert not out.exists()


def test_attack_string_on_the_command_line_exits_2_in_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "pwned"
    out = tmp_path / "runs"
    for args in (
        ["--config", str(_zoo_file(tmp_path, _attacks(target)[0]))],
        ["--hyperparams", f"policy_kwargs={_attacks(target)[0]}"],
    ):
        code = main(["train", "--algo", "ppo", "--env", ENV, "--out", str(out), *args])
        err = capsys.readouterr().err.strip("\n").splitlines()
        assert code == 2
        assert len(err) == 1 and err[0].startswith("quadslam train: error: policy_kwargs: got")
        _assert_rejected(err[0])
    assert not target.exists()
    assert not out.exists() or not any(out.iterdir())  # --out may exist; no run folder


def test_attack_string_in_a_sweep_spec_is_rejected_on_the_driver(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "pwned"
    spec = {
        "jobs": [
            {
                "kind": "train",
                "algo": "ppo",
                "env": ENV,
                "hyperparams": {"policy_kwargs": _attacks(target)[0]},
            }
        ]
    }
    with pytest.raises(SweepSpecError) as info:
        parse_spec(spec)
    _assert_rejected(str(info.value))
    assert "jobs[0]" in str(info.value)
    path = tmp_path / "spec.yaml"
    path.write_text(yaml.safe_dump(spec, sort_keys=False))
    out = tmp_path / "out"
    code = main(["sweep", str(path), "--out", str(out)])
    err = capsys.readouterr().err.strip("\n").splitlines()
    assert code == 2 and len(err) == 1 and "policy_kwargs: got" in err[0]
    assert not target.exists()
    assert not out.exists()


def test_attack_string_in_a_run_config_is_rejected_by_resume(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    target = tmp_path / "pwned"
    run = tmp_path / "run"
    run.mkdir()
    hyperparams = {**load_hyperparams("ppo", ENV), "policy_kwargs": _attacks(target)[0]}
    config = {"algo": "ppo", "env_id": ENV, "seed": 0, "hyperparams": hyperparams}
    (run / "config.yaml").write_text(yaml.safe_dump(config, sort_keys=False))
    with pytest.raises(ConfigError) as info:
        resume(run, progress=False)
    _assert_rejected(str(info.value))
    code = main(["train", "--resume", str(run), "--no-progress"])
    err = capsys.readouterr().err.strip("\n").splitlines()
    assert code == 2 and len(err) == 1 and "policy_kwargs: got" in err[0]
    # A run config is also accepted as --config: the same validator.
    with pytest.raises(ConfigError, match="policy_kwargs: got"):
        train("ppo", ENV, config_path=run / "config.yaml", out_dir=tmp_path / "o", progress=False)
    assert not target.exists()
    assert sorted(p.name for p in run.iterdir()) == ["config.yaml"]


# ---------------------------------------------------------------------------- the mapping form
@pytest.mark.parametrize("name", ["tanh", "Tanh", "nn.Tanh", "TANH"])
def test_activation_names_resolve_to_the_torch_class_when_the_model_is_built(
    name: str,
) -> None:
    settings = resolve_settings(
        "ppo",
        {
            **load_hyperparams("ppo", ENV),
            "n_envs": 1,
            "n_steps": 32,
            "batch_size": 32,
            "policy_kwargs": {"net_arch": {"pi": [8], "vf": [8]}, "activation_fn": name},
        },
    )
    assert settings["policy_kwargs"] == {
        "net_arch": {"pi": [8], "vf": [8]},
        "activation_fn": "tanh",
    }
    assert build_policy_kwargs(settings["policy_kwargs"])["activation_fn"] is nn.Tanh
    venv = make_vec_env(ENV, settings, 1, 0, None)
    try:
        model = build_model("ppo", settings, venv, 0)
    finally:
        venv.close()
    assert model.policy.activation_fn is nn.Tanh
    assert any(isinstance(m, nn.Tanh) for m in model.policy.mlp_extractor.modules())


def test_every_allowed_activation_is_a_torch_module() -> None:
    for snake, cls_name in ACTIVATIONS.items():
        for name in (snake, cls_name):
            cls = build_policy_kwargs({"activation_fn": name})["activation_fn"]
            assert cls is getattr(nn, cls_name) and issubclass(cls, nn.Module)


@pytest.mark.parametrize(
    ("policy_kwargs", "expected"),
    [
        ({"activation_fn": "softmax"}, ["policy_kwargs.activation_fn", "'softmax'", "tanh"]),
        ({"activation_fn": "torch.os.system"}, ["activation_fn", "relu", "leaky_relu"]),
        ({"activation_fn": nn.Tanh}, ["activation_fn", "one of"]),  # objects are not data
        ({"net_arch": "[8, 8]"}, ["policy_kwargs.net_arch", "'[8, 8]'", "list"]),
        ({"net_arch": [8, 0]}, ["policy_kwargs.net_arch", "positive integers"]),
        ({"net_arch": {"pi": [8], "critic": [8]}}, ["net_arch.critic", "['pi', 'vf', 'qf']"]),
        ({"features_extractor_class": "x"}, ["policy_kwargs.features_extractor_class", "unknown"]),
        ({"ortho_init": "yes"}, ["policy_kwargs.ortho_init", "true or false"]),
        ({"log_std_init": "low"}, ["policy_kwargs.log_std_init", "'low'", "finite number"]),
        ({"n_critics": 0}, ["policy_kwargs.n_critics", "positive integer"]),
        ({"optimizer_kwargs": {"eps": "os.system"}}, ["optimizer_kwargs.eps", "finite number"]),
        ({"optimizer_kwargs": "dict(eps=1e-5)"}, ["policy_kwargs.optimizer_kwargs", "mapping"]),
        (["net_arch"], ["policy_kwargs: got ['net_arch']", "allowed: a mapping"]),
    ],
)
def test_bad_policy_kwargs_are_rejected_naming_key_value_and_allowed(
    policy_kwargs: Any, expected: list[str]
) -> None:
    with pytest.raises(ConfigError) as info:
        validate_policy_kwargs(policy_kwargs)
    message = str(info.value)
    for part in expected:
        assert part in message, message
    entry = {**load_hyperparams("sac", ENV), "policy_kwargs": policy_kwargs}
    with pytest.raises(ValueError, match="policy_kwargs"):
        resolve_settings("sac", entry)


def test_plain_policy_kwargs_pass_as_data() -> None:
    given = {
        "net_arch": {"pi": [64, 64], "qf": [64]},
        "activation_fn": "LeakyReLU",
        "log_std_init": "-2",  # a numeric string (YAML may leave 1e-5 as one)
        "use_expln": True,
        "n_critics": 2,
        "optimizer_kwargs": {"eps": "1e-5", "betas": [0.9, 0.999], "amsgrad": False},
    }
    out = validate_policy_kwargs(given)
    assert out == {
        **given,
        "activation_fn": "leaky_relu",
        "log_std_init": -2.0,
        "optimizer_kwargs": {"eps": 1e-5, "betas": [0.9, 0.999], "amsgrad": False},
    }
    assert validate_policy_kwargs(None) == {}
    yaml.safe_dump(out)  # plain data: the run's config.yaml can hold it


def test_asymmetric_policy_fixes_its_features_extractors_in_one_place() -> None:
    from agents.rl.asymmetric import AsymmetricActorCriticPolicy
    from agents.rl.lane_share import ACTOR_KEY, PRIVILEGED_KEY

    with pytest.raises(ConfigError, match="features_extractor_kwargs: fixed by Asymmetric"):
        validate_policy_kwargs({"features_extractor_kwargs": {}}, ASYMMETRIC)
    box = gym.spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
    space = gym.spaces.Dict({ACTOR_KEY: box, PRIVILEGED_KEY: box})
    with pytest.raises(ConfigError, match="features_extractor_kwargs: fixed by Asymmetric"):
        AsymmetricActorCriticPolicy(space, box, lambda _: 3e-4, features_extractor_kwargs={})


def test_normalize_strings_are_read_as_yaml_not_evaluated(tmp_path: Path) -> None:
    assert parse_normalize("{'norm_obs': True, 'norm_reward': False}") == {
        "norm_obs": True,
        "norm_reward": False,
    }
    assert parse_normalize("{norm_obs: true}") == {"norm_obs": True}
    target = tmp_path / "pwned"
    with pytest.raises(ValueError, match="normalize"):
        parse_normalize(f"__import__('os').system('touch {target}')")
    assert not target.exists()


def test_shipped_agent_configs_write_policy_kwargs_as_mappings() -> None:
    for path in sorted((ROOT / "configs" / "agents").glob("*.yaml")):
        for env_id, entry in yaml.safe_load(path.read_text()).items():
            value = entry.get("policy_kwargs")
            assert value is None or isinstance(value, dict), f"{path.name}[{env_id}]"


def test_no_config_text_is_evaluated_anywhere_in_the_source() -> None:
    found = []
    for folder in ("agents", "quadslam_env", "estimators", "tools", "examples"):
        for path in sorted((ROOT / folder).rglob("*.py")):
            for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
                if not isinstance(node, ast.Call):
                    continue
                func = node.func
                name = func.id if isinstance(func, ast.Name) else None
                attr = func.attr if isinstance(func, ast.Attribute) else None
                if name in ("eval", "exec", "literal_eval") or attr == "literal_eval":
                    found.append(f"{path.relative_to(ROOT)}:{node.lineno}")
    assert not found, found
