"""Plug-in estimators: ``estimators.register`` and the ``quadslam.estimators`` entry points."""

from __future__ import annotations

import importlib.util
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import gymnasium as gym
import numpy as np
import pytest
from conftest import fly_dflqr

import estimators
import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation import registry as base
from quadslam_env.schema import ConfigError

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"


@pytest.fixture
def clean_registry(monkeypatch: pytest.MonkeyPatch) -> None:
    """Restore the name registry and forget cached entry points after the test."""
    monkeypatch.setattr(base, "_REGISTRY", dict(base._REGISTRY))
    base._entry_points.cache_clear()
    yield
    base._entry_points.cache_clear()


def _load_example(name: str = "complementary_filter") -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"example_{name}", EXAMPLES / f"{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _fly(env: gym.Env, steps: int) -> list[dict]:
    infos, _ = fly_dflqr(env, 3, steps)
    assert len(infos) == steps, infos[-1].get("termination_reason")  # no early end
    return infos


def test_unknown_estimator_names_key_value_and_allowed_names() -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario("paper_ekf_figure8", {"estimator": {"name": "ukf", "params": {}}})
    message = str(err.value)
    assert message.startswith("estimator.name: got 'ukf'; allowed: one of [")
    for name in ("ekf_slam", "fastslam", "fastslam_kinematic", "oracle"):
        assert f"'{name}'" in message


@pytest.mark.usefixtures("clean_registry")
def test_registered_complementary_filter_flies_through_gymnasium_make() -> None:
    with pytest.raises(ConfigError, match=r"estimator\.name: got 'complementary'"):
        load_scenario("paper_ekf_figure8_known", estimator_name="complementary")
    _load_example()
    assert "complementary" in estimators.available()
    env = gym.make(
        "QuadSLAM-v0", scenario="paper_ekf_figure8_known", estimator_name="complementary"
    )
    infos = _fly(env, 500)  # 5 s: the climb to the figure-8 and the first 50 scans
    errors = np.array([info["est_pos_err_m"] for info in infos])
    # LiDAR fixes of the known map keep the dead-reckoned position within a few centimetres.
    assert errors.max() < 0.2 and np.sqrt(np.mean(errors**2)) < 0.1
    # Without a covariance there is no NEES: the key is absent rather than NaN.
    assert "est_nees_pose" not in infos[-1]
    assert infos[-1]["est_n_visible"] > 0


@pytest.mark.usefixtures("clean_registry")
def test_plugin_runs_in_the_vector_env_as_lanes() -> None:
    _load_example()
    kwargs = {"scenario": "paper_ekf_figure8_known", "estimator_name": "complementary"}
    vec = gym.make_vec("QuadSLAM-v0", num_envs=2, vectorization_mode="vector_entry_point", **kwargs)
    policy = DFLQRPolicy.from_env(vec)
    obs, _ = vec.reset(seed=3)
    for _ in range(100):
        obs, _, terminated, truncated, info = vec.step(policy.predict(obs)[0])
        assert not (terminated.any() or truncated.any())
    assert np.all(info["est_pos_err_m"] < 0.2)
    # Lane 0 of the vector env is the scalar env with the same seed.
    env = gym.make("QuadSLAM-v0", **kwargs)
    scalar = _fly(env, 100)
    assert info["est_pos_err_m"][0] == pytest.approx(scalar[-1]["est_pos_err_m"], rel=1e-9)


def _fake_distribution(root: Path, entry_points: str) -> None:
    """A minimal installed distribution (``.dist-info``) with ``entry_points.txt``."""
    info = root / "quadslam_plugin_demo-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: quadslam-plugin-demo\nVersion: 0.1\n"
    )
    (info / "entry_points.txt").write_text(f"[quadslam.estimators]\n{entry_points}\n")


@pytest.mark.usefixtures("clean_registry")
def test_entry_point_estimator_is_listed_lazily_and_flies(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    module = "qs_demo_filter"
    (tmp_path / f"{module}.py").write_text(
        (EXAMPLES / "complementary_filter.py").read_text()
        + "\n\nclass Stiffer(ComplementaryFilter):\n"
        + "    def __init__(self, vehicle=None):\n"
        + "        super().__init__(vehicle, position_gain=0.3)\n"
    )
    _fake_distribution(tmp_path, f"cf_entry = {module}:Stiffer")
    monkeypatch.syspath_prepend(str(tmp_path))
    base._entry_points.cache_clear()
    assert "cf_entry" in estimators.available()
    assert module not in sys.modules  # listed, not imported
    cfg = load_scenario("paper_ekf_figure8_known", estimator_name="cf_entry")
    assert cfg.estimator.name == "cf_entry" and module not in sys.modules
    env = gym.make("QuadSLAM-v0", scenario="paper_ekf_figure8_known", estimator_name="cf_entry")
    infos = _fly(env, 200)
    assert module in sys.modules
    assert type(env.unwrapped.estimator.lanes[0]).__name__ == "Stiffer"
    assert infos[-1]["est_pos_err_m"] < 0.2
    monkeypatch.delitem(sys.modules, module)


@pytest.mark.usefixtures("clean_registry")
def test_broken_entry_point_error_names_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _fake_distribution(tmp_path, "broken = no_such_module_here:Filter")
    monkeypatch.syspath_prepend(str(tmp_path))
    base._entry_points.cache_clear()
    with pytest.raises(ValueError) as err:
        gym.make("QuadSLAM-v0", estimator_name="broken")
    message = str(err.value)
    assert "'broken'" in message and "no_such_module_here:Filter" in message
    assert "quadslam.estimators" in message


def test_register_rejects_a_bad_name() -> None:
    with pytest.raises(ValueError, match=r"estimators\.register: got ''"):
        estimators.register("")


# docs/design.md §5: both filters associate unlabeled returns and can be copied; only
# FastSLAM's process model has the drag (EKF-SLAM is driven by the sensed specific force).
FLAGS = {
    "associates_unlabeled": {"ekf_slam": True, "fastslam": True},
    "copyable": {"ekf_slam": True, "fastslam": True},
    "models_drag": {"ekf_slam": False, "fastslam": True},
}


@pytest.mark.parametrize("flag", [base.associates_unlabeled, base.copyable, base.models_drag])
def test_estimator_flag_reads_the_flag_and_turns_an_unknown_name_into_a_config_error(
    flag: Callable[[str], bool],
) -> None:
    for name, expected in FLAGS[flag.__name__].items():
        assert base.estimator_flag(name, flag) is expected
    with pytest.raises(ConfigError, match=r"^estimator\.name: got 'no_such_filter'; allowed: "):
        base.estimator_flag("no_such_filter", flag)
