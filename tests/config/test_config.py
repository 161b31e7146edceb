"""Scenario configuration: loading, merging, presets and validation errors.

See docs/design.md §4 and §7.
"""

from __future__ import annotations

import contextlib
import math
import os
import threading
from pathlib import Path

import gymnasium as gym
import pytest
import yaml

import quadslam_env  # noqa: F401  (registers the env ids)
from quadslam_env.config.files import available_scenarios, load_yaml
from quadslam_env.config.hardware import ImuConfig, LidarConfig, VehicleConfig
from quadslam_env.config.scenario import load_scenario
from quadslam_env.schema import ConfigError

SCENARIO_DIR = Path(__file__).resolve().parents[2] / "configs" / "scenarios"
SCENARIO_FILES = sorted(SCENARIO_DIR.glob("*.yaml"))
MICRO_G = 1e-6 * 9.81


def test_scenario_files_exist():
    assert SCENARIO_FILES, f"no scenarios in {SCENARIO_DIR}"
    assert sorted(p.stem for p in SCENARIO_FILES) == available_scenarios()


@pytest.mark.parametrize("path", SCENARIO_FILES, ids=lambda p: p.stem)
def test_every_shipped_scenario_loads_and_keeps_its_values(path):
    by_name = load_scenario(path.stem)
    by_path = load_scenario(path)
    assert by_name == by_path
    raw = yaml.safe_load(path.read_text()) or {}
    # Every explicit value in the file ends up in the typed config.
    for section, values in raw.items():
        if section == "name" or not isinstance(values, dict):
            continue
        sec = getattr(by_name, section)
        for key, value in values.items():
            got = getattr(sec, key)
            if isinstance(value, list):
                got = [list(v) if isinstance(v, tuple) else v for v in got]
            assert got == value, f"{section}.{key}: {got!r} != {value!r}"
    assert by_name.max_steps == math.ceil(
        by_name.episode.duration_s * by_name.episode.control_hz - 1e-9
    )


def test_default_scenario_is_paper_figure8():
    cfg = load_scenario()
    assert cfg.trajectory.kind == "figure8"
    assert cfg.estimator.name == "ekf_slam"
    assert cfg.lidar_every == 10  # 100 Hz control, 10 Hz LiDAR


# ----------------------------------------------------------------------------- errors
BAD = [
    # (overrides, fragments that must appear in the message)
    ({"sensors": {"x": 1}}, ["sensors", "unknown section"]),
    ({"imu": {"bogus_key": 1.0}}, ["imu.bogus_key", "unknown"]),
    ({"imu": {"accel_noise_density": "abc"}}, ["imu.accel_noise_density", "'abc'"]),
    ({"episode": {"duration_s": True}}, ["episode.duration_s", "True"]),
    ({"episode": {"duration_s": float("nan")}}, ["episode.duration_s", "nan"]),
    ({"episode": {"control_hz": [100]}}, ["episode.control_hz", "[100]"]),
    ({"landmarks": {"count": 2.5}}, ["landmarks.count", "2.5"]),
    ({"imu": {"gyro_noise_density": -0.1}}, ["imu.gyro_noise_density", "-0.1"]),
    ({"lidar": {"sigma_range_m": -0.01}}, ["lidar.sigma_range_m", "-0.01"]),
    ({"lidar": {"azimuth_fov_deg": 190.0}}, ["lidar.azimuth_fov_deg", "190"]),
    ({"lidar": {"elevation_fov_deg": 0.0}}, ["lidar.elevation_fov_deg", "0.0"]),
    ({"lidar": {"rate_hz": 30.0}}, ["lidar.rate_hz", "30", "episode.control_hz"]),
    ({"lidar": {"rate_hz": 200.0}}, ["lidar.rate_hz", "200"]),
    ({"landmarks": {"layout": "explicit", "positions": []}}, ["landmarks.positions", "[]"]),
    ({"landmarks": {"layout": "explicit", "positions": [[1, 2]]}}, ["landmarks.positions"]),
    ({"lidar": {"range_min_m": 5.0, "range_max_m": 5.0}}, ["lidar.range_max_m", "5.0"]),
    ({"lidar": {"range_min_m": 10.0, "range_max_m": 3.0}}, ["lidar.range_max_m", "3.0"]),
    ({"trajectory": {"kind": "spiral"}}, ["trajectory.kind", "spiral", "figure8"]),
    ({"trajectory": {"center": [0.0, 0.0]}}, ["trajectory.center", "[0.0, 0.0]"]),
    ({"vehicle": {"preset": "dji"}}, ["vehicle.preset", "dji"]),
    ({"vehicle": {"max_thrust_n": 1.0}}, ["vehicle.max_thrust_n", "1.0"]),
    ({"estimator": {"name": "ukf"}}, ["estimator.name", "ukf"]),
    ({"imu": {"preset": "nope"}}, ["imu.preset", "nope"]),
    ({"episode": {"max_tilt_deg": 95.0}}, ["episode.max_tilt_deg", "95"]),
    ({"episode": {"initial_euler_deg": [0.0, 89.5, 0.0]}}, ["initial_euler_deg", "89.5"]),
    ({"imu": "loud"}, ["imu", "'loud'"]),
]


@pytest.mark.parametrize(("overrides", "fragments"), BAD, ids=[str(b[1][0]) for b in BAD])
def test_invalid_values_raise_config_error_naming_key_and_value(overrides, fragments):
    with pytest.raises(ConfigError) as info:
        load_scenario("paper_ekf_figure8", overrides)
    assert isinstance(info.value, ValueError)
    msg = str(info.value)
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    assert "allowed" in msg  # says what is allowed


def test_gym_make_rejects_bad_override():
    with pytest.raises(ConfigError, match=r"imu\.bogus"):
        gym.make("QuadSLAM-Oracle-v0", imu={"bogus": 1})
    with pytest.raises(ValueError, match=r"lidar\.azimuth_fov_deg"):
        gym.make("QuadSLAM-Oracle-v0", lidar={"azimuth_fov_deg": 181.0})


def test_missing_scenario_name():
    with pytest.raises(ConfigError, match="no_such_scenario_xyz") as info:
        load_scenario("no_such_scenario_xyz")
    assert "paper_ekf_figure8" in str(info.value)  # lists what is available


def test_missing_scenario_path(tmp_path):
    path = tmp_path / "absent.yaml"
    with pytest.raises(ConfigError, match=r"absent\.yaml"):
        load_scenario(path)


def test_malformed_yaml_names_the_file(tmp_path):
    path = tmp_path / "broken.yaml"
    path.write_text("episode:\n  duration_s: [1.0\n  control_hz: 100\n")
    with pytest.raises(ConfigError) as info:
        load_scenario(path)
    assert str(path) in str(info.value)
    assert "YAML" in str(info.value)


def test_yaml_that_is_not_a_mapping(tmp_path):
    path = tmp_path / "list.yaml"
    path.write_text("- 1\n- 2\n")
    with pytest.raises(ConfigError, match=r"list\.yaml"):
        load_scenario(path)


def test_yaml_file_with_bad_value_names_the_key(tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text("lidar:\n  range_max_m: -3\n")
    with pytest.raises(ConfigError, match=r"lidar\.range_max_m.*-3"):
        load_scenario(path)


def test_scenario_from_path(tmp_path):
    path = tmp_path / "mine.yaml"
    path.write_text("trajectory:\n  kind: circle\n  radius_m: 3.0\nepisode:\n  duration_s: 4.0\n")
    cfg = load_scenario(path)
    assert cfg.name == "mine"
    assert cfg.trajectory.kind == "circle" and cfg.trajectory.radius_m == 3.0
    assert cfg.episode.duration_s == 4.0
    assert cfg.max_steps == 400


# ----------------------------------------------------------------------------- merging
def test_override_one_key_keeps_the_others():
    base = load_scenario("paper_ekf_figure8")
    cfg = load_scenario("paper_ekf_figure8", {"episode": {"duration_s": 5.0}})
    assert cfg.episode.duration_s == 5.0
    assert cfg.max_steps == 500
    raw = yaml.safe_load((SCENARIO_DIR / "paper_ekf_figure8.yaml").read_text())
    assert cfg.episode.control_hz == raw["episode"]["control_hz"]
    assert list(cfg.episode.initial_position) == raw["episode"]["initial_position"]
    for section in ("vehicle", "imu", "lidar", "landmarks", "trajectory", "estimator"):
        assert getattr(cfg, section) == getattr(base, section)


def test_nested_params_override_merges():
    cfg = load_scenario("paper_ekf_figure8", {"estimator": {"params": {"extra": 1}}})
    raw = yaml.safe_load((SCENARIO_DIR / "paper_ekf_figure8.yaml").read_text())
    assert cfg.estimator.params == {**raw["estimator"]["params"], "extra": 1}


def test_estimator_swap_drops_foreign_params():
    cfg = load_scenario("paper_ekf_figure8", estimator_name="oracle")
    assert cfg.estimator.name == "oracle"
    assert cfg.estimator.params == {}
    same = load_scenario("paper_ekf_figure8", estimator_name="ekf_slam")
    assert same.estimator.params == load_scenario("paper_ekf_figure8").estimator.params


def test_config_is_frozen():
    cfg = load_scenario("hover")
    with pytest.raises(AttributeError):
        cfg.episode.duration_s = 3.0  # type: ignore[misc]


def test_to_dict_round_trips():
    cfg = load_scenario("paper_fastslam_helix", {"episode": {"duration_s": 3.0}})
    again = load_scenario(cfg.to_dict())
    assert again == cfg


# ----------------------------------------------------------------------------- presets
def test_imu_presets_fill_values_from_the_papers():
    r = ImuConfig.from_dict({"preset": "rauniyar2023"})
    assert r.accel_noise_density == pytest.approx(300 * MICRO_G)  # 300 µg/√Hz
    assert r.gyro_noise_density == pytest.approx(math.radians(0.01))  # 0.01 °/s/√Hz
    assert r.accel_bias == (0.0, 0.0, 0.0) and r.gyro_bias == (0.0, 0.0, 0.0)
    s = ImuConfig.from_dict({"preset": "sadeghzadeh2021"})
    assert s.accel_bias == pytest.approx((0.005,) * 3)
    assert s.gyro_bias == pytest.approx((0.005,) * 3)


def test_lidar_presets_fill_values_from_the_papers():
    r = LidarConfig.from_dict({"preset": "rauniyar2023"})
    assert (r.azimuth_fov_deg, r.elevation_fov_deg) == (45.0, 30.0)
    assert (r.range_min_m, r.range_max_m, r.rate_hz) == (0.0, 100.0, 10.0)
    assert (r.sigma_azimuth_deg, r.sigma_elevation_deg, r.sigma_range_m) == (0.33, 0.30, 0.1)
    v = LidarConfig.from_dict({"preset": "vlp16"})
    assert v.azimuth_fov_deg == 180.0 and v.elevation_fov_deg == 15.0
    assert v.range_max_m == 100.0 and v.sigma_range_m == pytest.approx(0.03)


def test_explicit_keys_win_over_presets():
    lidar = LidarConfig.from_dict({"preset": "rauniyar2023", "azimuth_fov_deg": 60.0})
    assert lidar.azimuth_fov_deg == 60.0
    assert lidar.elevation_fov_deg == 30.0  # still from the preset
    imu = ImuConfig.from_dict({"preset": "sadeghzadeh2021", "gyro_bias": [0.0, 0.0, 0.001]})
    assert imu.gyro_bias == (0.0, 0.0, 0.001)
    assert imu.accel_bias == pytest.approx((0.005,) * 3)
    cfg = load_scenario("paper_fastslam_helix_small_bias")
    assert cfg.imu.accel_bias == pytest.approx((0.0005,) * 3)  # file overrides its preset


def test_vehicle_presets_and_overrides():
    r = VehicleConfig.from_dict({"preset": "rauniyar2023"}).params()
    assert r.mass == 1.56
    assert [r.inertia[i, i] for i in range(3)] == [0.1147, 0.0576, 0.1712]
    assert r.max_thrust > r.mass * 9.81
    s = VehicleConfig.from_dict({"preset": "sadeghzadeh2021"}).params()
    assert s.mass == 1.477
    assert [s.inertia[i, i] for i in range(3)] == [0.01152, 0.01152, 0.0218]
    o = VehicleConfig.from_dict({"preset": "sadeghzadeh2021", "mass_kg": 2.0}).params()
    assert o.mass == 2.0
    assert [o.inertia[i, i] for i in range(3)] == [0.01152, 0.01152, 0.0218]


def test_exponent_floats_without_a_dot_are_numbers(tmp_path: Path) -> None:
    """PyYAML (YAML 1.1) reads ``1e-4`` as a string; configs and overrides must not."""
    from agents.io.overrides import parse_overrides
    from agents.rl.hyperparams import parse_hyperparam_overrides

    assert parse_overrides(["estimator.params.x=1e-4"]) == {"estimator": {"params": {"x": 1e-4}}}
    assert parse_hyperparam_overrides(["learning_rate=3E-4"]) == {"learning_rate": 3e-4}
    path = tmp_path / "s.yaml"
    path.write_text("estimator:\n  initial_cov_diag: [1e-3, -2e+1, 5, 0.5, 1.0e-2, 1_0e0]\n")
    assert load_yaml(path)["estimator"]["initial_cov_diag"] == [1e-3, -20.0, 5, 0.5, 1e-2, 10.0]


def test_switching_the_estimator_by_override_starts_from_its_own_defaults() -> None:
    # The scenario's EKF settings belong to the EKF: an override that names another estimator
    # drops them; one that keeps the estimator merges into them.
    swapped = load_scenario("ekf_figure8_biased_imu", {"estimator": {"name": "oracle"}})
    assert swapped.estimator.name == "oracle" and swapped.estimator.params == {}
    fastslam = load_scenario(
        "ekf_figure8_biased_imu",
        {"estimator": {"name": "fastslam", "params": {"n_particles": 30}}},
    )
    assert fastslam.estimator.params == {"n_particles": 30}
    kept = load_scenario(
        "ekf_figure8_biased_imu", {"estimator": {"params": {"estimate_imu_bias": False}}}
    )
    assert kept.estimator.params["process_noise"] == [0.0] * 9
    assert kept.estimator.params["estimate_imu_bias"] is False


# ----------------------------------------------------------------------------- bounded reading


def _fifo_with(path: Path, data: bytes) -> threading.Thread:
    """A FIFO at ``path`` fed ``data`` by a thread (as ``<(cat scenario.yaml)`` is)."""
    os.mkfifo(path)

    def feed() -> None:
        with contextlib.suppress(BrokenPipeError), open(path, "wb") as fh:
            fh.write(data)

    thread = threading.Thread(target=feed, daemon=True)
    thread.start()
    return thread


def test_a_scenario_from_a_pipe_is_read(tmp_path: Path) -> None:
    thread = _fifo_with(tmp_path / "scenario.yaml", b"episode: {duration_s: 3.0}\n")
    assert load_scenario(tmp_path / "scenario.yaml").episode.duration_s == 3.0
    thread.join(10)


def test_a_pipe_is_read_up_to_the_cap_only(tmp_path: Path) -> None:
    from quadslam_env.config.files import MAX_CONFIG_BYTES

    thread = _fifo_with(tmp_path / "endless.yaml", b"#" * (3 * MAX_CONFIG_BYTES))
    with pytest.raises(ConfigError, match=r"endless\.yaml'.*more than 1 MiB; allowed: at most"):
        load_yaml(tmp_path / "endless.yaml")
    thread.join(10)  # the writer saw the reader go (a broken pipe), not a full read


def test_a_file_at_the_cap_is_read_and_one_byte_more_is_not(tmp_path: Path) -> None:
    from quadslam_env.config.files import MAX_CONFIG_BYTES

    path = tmp_path / "padded.yaml"
    head = b"episode: {duration_s: 2.0}\n"
    path.write_bytes(head + b"#" * (MAX_CONFIG_BYTES - len(head)))
    assert load_yaml(path) == {"episode": {"duration_s": 2.0}}
    path.write_bytes(path.read_bytes() + b"#")
    with pytest.raises(ConfigError, match=r"1 MiB; allowed: at most 1 MiB"):
        load_yaml(path)


YAML_BOMBS = {
    "billion_laughs": (
        "".join(
            f"{k}: &{k} [{', '.join([f'*{p}'] * 9 if p else ['lol'] * 9)}]\n"
            for p, k in zip(["", *"abcdefgh"], "abcdefghi", strict=True)
        ),
        "more than 100,000 values once its aliases are expanded",
    ),
    "quadratic_blowup": (
        "a: &a [" + ", ".join(["x"] * 2000) + "]\nb: [" + ", ".join(["*a"] * 2000) + "]\n",
        "more than 100,000 values",
    ),
    "recursive_alias": ("a: &a [1, *a]\n", "an alias refers to its own anchor"),
    "deep_nesting": ("a: " + "[" * 150 + "]" * 150 + "\n", "nested more than 100 levels"),
    "deeper_than_the_parser": ("a: " + "[" * 5000 + "]" * 5000 + "\n", "nested too deeply"),
}


@pytest.mark.parametrize("name", sorted(YAML_BOMBS))
def test_yaml_bombs_are_one_line_config_errors(tmp_path: Path, name: str) -> None:
    text, expected = YAML_BOMBS[name]
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as info:
        load_yaml(path)
    message = str(info.value)
    assert expected in message and str(path) in message
    assert "\n" not in message and len(message) < 500


def test_ordinary_aliases_and_merges_still_load(tmp_path: Path) -> None:
    path = tmp_path / "aliases.yaml"
    path.write_text(
        "imu: &imu {preset: ideal}\n"
        "lidar: &lidar {sigma_range_m: 0.05}\n"
        "episode:\n  <<: {duration_s: 2.0}\n  control_hz: 100\n"
    )
    data = load_yaml(path)
    assert data["imu"] == {"preset": "ideal"} and data["episode"]["duration_s"] == 2.0
    assert load_scenario(path).lidar.sigma_range_m == 0.05
