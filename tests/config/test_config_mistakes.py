"""Ordinary mistakes in configuration files and settings that cannot fit: each ends in a
one-line error naming the key, the file or the size (status 2 from the CLI) before any work."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import pytest
from conftest import RUN, cli

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.files import available_scenarios
from quadslam_env.config.scenario import load_scenario
from quadslam_env.schema import ConfigError

# ---------------------------------------------------------------------- configuration files


@pytest.mark.parametrize("value", [5, 3.5, ["paper_ekf_figure8"], True, ""])
def test_scenario_of_the_wrong_type_names_the_key(value: Any) -> None:
    with pytest.raises(ConfigError, match=r"^scenario: got"):
        gym.make("QuadSLAM-v0", scenario=value)


def test_estimator_name_of_the_wrong_type_names_the_key() -> None:
    with pytest.raises(ConfigError, match=r"^estimator_name: got 3"):
        gym.make("QuadSLAM-v0", estimator_name=3)


SCENARIO_FILES: dict[str, tuple[bytes, str]] = {
    "latin1": ("episode:\n  duration_s: 5 # \xb5s\n".encode("latin-1"), "not UTF-8"),
    "empty": (b"", "empty"),
    "comments_only": (b"# nothing here\n", "empty"),
    "dup_section": (b"episode:\n  duration_s: 5\nepisode:\n  control_hz: 50\n", "'episode'"),
    "dup_key": (b"imu:\n  preset: ideal\n  preset: rauniyar2023\n", "'preset'"),
    "dup_flow": (b"episode: {duration_s: 5, duration_s: 6}\n", "'duration_s'"),
}


@pytest.mark.parametrize("name", sorted(SCENARIO_FILES))
def test_bad_scenario_files_name_the_file(
    capsys: pytest.CaptureFixture[str], tmp_path: Path, no_work: None, name: str
) -> None:
    content, expected = SCENARIO_FILES[name]
    path = tmp_path / f"{name}.yaml"
    path.write_bytes(content)
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert str(path) in str(info.value) and expected in str(info.value)
    code, _, line = cli(capsys, [*RUN, "--no-plots", "--scenario", str(path)])
    assert code == 2 and str(path) in line and expected in line


def test_explicit_empty_mapping_still_means_defaults(tmp_path: Path) -> None:
    path = tmp_path / "defaults.yaml"
    path.write_text("{}\n")
    assert load_scenario(path).episode.duration_s == 50.0


def test_duplicate_key_in_an_agent_yaml_names_key_and_file(tmp_path: Path) -> None:
    from agents.rl.hyperparams import load_hyperparams

    path = tmp_path / "ppo.yaml"
    path.write_text("QuadSLAM-EKF-v0:\n  n_steps: 64\n  n_steps: 128\n")
    with pytest.raises(ValueError, match=r"ppo\.yaml.*duplicate key 'n_steps' at line 3"):
        load_hyperparams("ppo", "QuadSLAM-EKF-v0", path)


@pytest.mark.parametrize(
    ("sets", "expected"),
    [
        (["episode.duration_s=1", "episode.duration_s=2"], "--set episode.duration_s: given"),
        (
            ["estimator.params={gate_probability: 0.9, gate_probability: 0.5}"],
            "duplicate key 'gate_probability'",
        ),
    ],
)
def test_duplicate_set_keys(
    capsys: pytest.CaptureFixture[str], no_work: None, sets: list[str], expected: str
) -> None:
    argv = [*RUN, "--no-plots"]
    for item in sets:
        argv += ["--set", item]
    code, _, line = cli(capsys, argv)
    assert code == 2 and expected in line


@pytest.mark.parametrize(
    ("scenario", "overrides", "key"),
    [
        ("paper_fastslam_helix", {"landmarks": {"count": 2000}}, "landmarks.count"),
        ("paper_fastslam_helix", {"landmarks": {"range_m": [1, 2]}}, "landmarks.range_m"),
        ("paper_ekf_figure8", {"landmarks": {"pole_spacing_m": 3.0}}, "landmarks.pole_spacing_m"),
        (
            "paper_ekf_figure8",
            {"landmarks": {"positions": [[1.0, 2.0, -3.0]]}},
            "landmarks.positions",
        ),
        ("paper_ekf_figure8", {"trajectory": {"radius_m": 3.0}}, "trajectory.radius_m"),
        ("hover", {"trajectory": {"period_s": 10.0}}, "trajectory.period_s"),
        ("paper_ekf_figure8", {"action": {"max_rate_dps": [90, 90, 45]}}, "action.max_rate_dps"),
    ],
)
def test_settings_the_layout_ignores_are_errors(
    scenario: str, overrides: dict[str, Any], key: str
) -> None:
    with pytest.raises(ConfigError, match=rf"^{key}: got .* ignores; allowed"):
        load_scenario(scenario, overrides)


def test_every_shipped_scenario_round_trips_through_its_resolved_form() -> None:
    for name in available_scenarios():
        scenario = load_scenario(name)
        assert load_scenario(scenario.to_dict()) == scenario


def test_layout_check_from_the_cli_comes_before_flying(
    capsys: pytest.CaptureFixture[str], no_work: None
) -> None:
    argv = [*RUN, "--scenario", "paper_fastslam_helix", "--set", "landmarks.count=2000"]
    code, _, line = cli(capsys, argv)
    assert code == 2
    assert "landmarks.count: got 2000" in line and "'poles4'" in line


# --------------------------------------------------------------------- memory of the EKF map


def test_ekf_map_that_cannot_fit_is_rejected_with_its_size() -> None:
    with pytest.raises(ValueError, match=r"landmarks: a map of 100000 landmarks") as info:
        gym.make("QuadSLAM-EKF-v0", landmarks={"count": 100000})
    message = str(info.value)
    assert "670.6 GiB" in message and "8 × 1 × 300009²" in message
    assert "allowed: at most" in message


def test_ekf_memory_limit_counts_the_lanes(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(2 * 8 * 8 * 129**2))
    gym.make_vec("QuadSLAM-EKF-v0", num_envs=8, vectorization_mode="vector_entry_point")
    with pytest.raises(ValueError, match=r"on 9 lane\(s\).*at most 37 landmarks per lane"):
        gym.make_vec("QuadSLAM-EKF-v0", num_envs=9, vectorization_mode="vector_entry_point")


def test_ekf_map_growing_beyond_memory_is_rejected_at_reset(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """A reset option with more landmarks than the scenario's grows the map: the growth is
    checked at that reset, like the first allocation, before any step."""
    env = gym.make("QuadSLAM-EKF-v0", landmarks={"count": 10})
    env.reset(seed=0, options={"landmarks": [[5.0 + 0.01 * i, 0.0, -2.0] for i in range(30)]})
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", "1000000")
    points = [[5.0 + 0.01 * i, 0.0, -2.0] for i in range(200)]  # in front of the vehicle
    with pytest.raises(ValueError, match=r"a map of \d+ landmarks with EKF-SLAM"):
        env.reset(seed=0, options={"landmarks": points})
    monkeypatch.delenv("QUADSLAM_MEMORY_LIMIT_BYTES")
    env.step(env.action_space.sample() * 0.0)  # the failed reset changed nothing
    assert env.unwrapped.core.n_landmarks[0] == 30


def test_fastslam_map_that_cannot_fit_is_rejected_with_its_size(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """FastSLAM's particles and landmark filters (N particles × (512 B + L landmarks × 96 B)
    per lane) are checked when the env is built, for every lane of a vector env."""
    monkeypatch.setenv("QUADSLAM_MEMORY_LIMIT_BYTES", str(2 * 4 * 500 * (512 + 96 * 40)))
    kwargs = {"estimator": {"params": {"n_particles": 500}},
              "landmarks": {"layout": "rauniyar2023", "count": 40}}  # fmt: skip
    gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=4, vectorization_mode="vector_entry_point",
                 **kwargs)  # fmt: skip
    with pytest.raises(ValueError, match=r"500 particles .* on 5 lane\(s\) \(num_envs\)") as info:
        gym.make_vec("QuadSLAM-FastSLAM-v0", num_envs=5, vectorization_mode="vector_entry_point",
                     **kwargs)  # fmt: skip
    message = str(info.value)
    assert "5 × 500 × (512 + 96 × 40)" in message and "a map of 40 landmarks" in message
    # Half the limit, 8,704,000 B, for 5 × 500 particles: 3481 B each, 512 B for the state.
    assert "at most 30 landmarks" in message and "at most 400 particles" in message
    assert "at most 4 lanes" in message
