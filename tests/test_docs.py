"""The documentation covers every setting, parameter, command and info key, and builds strictly."""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import fields
from pathlib import Path

import gymnasium as gym
import pytest

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from agents.lab.cli import reference
from agents.lab.cli.main import build_parser
from quadslam_env.config.scenario import SECTIONS

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"


def test_every_scenario_setting_is_in_the_generated_tables() -> None:
    text = reference.scenario_settings_markdown()
    for name, section in SECTIONS.items():
        assert f"### `{name}`" in text
        for fld in fields(section):  # type: ignore[arg-type]
            assert f"| `{name}.{fld.name}` |" in text, f"{name}.{fld.name}"
            assert fld.metadata["doc"], f"{name}.{fld.name} has no description"
    assert "<!-- generated: scenario-settings -->" in (DOCS / "scenarios.md").read_text()


def test_every_estimator_parameter_is_documented() -> None:
    text = reference.estimator_params_markdown()
    for name, keys in reference.estimator_param_keys().items():
        block = text.split(f"### `{name}`", 1)[1].split("### ", 1)[0]
        for key in keys:
            assert f"| `estimator.params.{key}` |" in block, f"{name}: estimator.params.{key}"
    assert "<!-- generated: estimator-params -->" in (DOCS / "scenarios.md").read_text()


def test_every_cli_command_is_in_the_generated_help() -> None:
    text = reference.cli_markdown()
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for command in sub.choices:  # type: ignore[union-attr]
        assert f"### `quadslam {command}`" in text
    assert "--version" in text
    assert "<!-- generated: cli -->" in (DOCS / "agents.md").read_text()


def _info_keys(env_id: str, **kwargs: object) -> set[str]:
    env = gym.make(env_id, episode={"duration_s": 0.3, "report_step_time": True}, **kwargs)
    policy = DFLQRPolicy.from_env(env)
    obs, info = env.reset(seed=0)
    keys, done = set(info), False
    while not done:
        obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
        keys |= set(info)
        done = terminated or truncated
    return keys


def test_every_info_key_is_documented_with_a_unit() -> None:
    keys = _info_keys("QuadSLAM-EKF-v0", scenario="ekf_figure8_biased_imu")
    keys |= _info_keys("QuadSLAM-EKF-v0", scenario="ekf_figure8_wind_states")
    keys |= _info_keys("QuadSLAM-FastSLAM-v0", estimator={"params": {"n_particles": 20}})
    keys |= _info_keys("QuadSLAM-Oracle-v0")
    assert {"est_ess", "est_gyro_bias_rel_err", "episode_anees_pose", "est_step_time_ms"} <= keys
    assert {"est_wind_err_mps", "episode_est_wind_rmse_mps"} <= keys
    page = (DOCS / "env.md").read_text()
    rows = [line for line in page.splitlines() if line.startswith("| `")]
    for key in keys:
        row = next((r for r in rows if f"`{key}`" in r.split("|")[1]), None)
        assert row is not None, f"info key {key!r} is not in docs/env.md"
        assert row.rstrip(" |").rsplit("|", 1)[1].strip(), f"{key}: no unit column"


def test_mkdocs_build_strict(tmp_path: Path) -> None:
    pytest.importorskip("mkdocs")
    pytest.importorskip("mkdocstrings")
    env = {**os.environ, "PYTHONPATH": str(ROOT), "NO_MKDOCS_2_WARNING": "1"}
    done = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-q", "-d", str(tmp_path / "site")],
        cwd=ROOT,
        env=env,
        capture_output=True,
        text=True,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    scenarios = (tmp_path / "site" / "scenarios" / "index.html").read_text()
    assert "episode.duration_s" in scenarios and "generated:" not in scenarios


def test_performance_page_shows_the_bench_json_as_measured() -> None:
    """The generated tables carry each series' median from the JSON, the fastest B in bold,
    and the page asks for them (its figures cannot drift from the measured ones)."""
    import json

    from agents.lab.bench.report import bench_markdown, figure

    page = (DOCS / "performance.md").read_text()
    assert "<!-- generated: bench-latest -->" in page
    assert "<!-- generated: bench-physics -->" in page
    doc = json.loads((DOCS / "results" / "bench_latest.json").read_text())
    text = bench_markdown(DOCS / "results" / "bench_latest.json")
    vector = [e for e in doc["results"] if e["group"] == "vector"]
    assert vector
    for name in {e["name"] for e in vector}:
        row = next(r for r in text.splitlines() if r.startswith(f"| `{name.split('/')[1]}` |"))
        series = [e for e in vector if e["name"] == name]
        fastest = max(series, key=lambda e: e["median"])
        assert f"**{figure(fastest['median'])}**" in row  # the best B, in bold
        for e in series:
            assert figure(e["median"]) in row
    physics = json.loads((DOCS / "results" / "bench_physics.json").read_text())
    ratio = next(e for e in physics["results"] if e["name"] == "full_over_nominal")
    assert f"| `full_over_nominal` | {figure(ratio['median'])} (" in (
        bench_markdown(DOCS / "results" / "bench_physics.json")
    )


def test_figures_round_to_four_significant_digits() -> None:
    from agents.lab.bench.report import figure

    assert figure(80780.4) == "80,780"
    assert figure(236346.0) == "236,300"
    assert figure(819.84) == "819.8"
    assert figure(0.905512) == "0.9055"
    assert figure(0.0) == "0"
