"""Faults of the simulated world (the ``faults`` section, :mod:`quadslam_env.sim.faults`): each
kind against its analytic effect on the truth or the scans, the same seed without the fault,
the lanes of a vector env against the scalar env, and every bad setting.

Flights that compare two runs hold the hover action, so the true vehicle and every sensor's
random stream are the same whatever the estimator makes of the fault.
"""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from conftest import assert_lanes_equal_scalar_env

import quadslam_env  # noqa: F401  (registers the ids)
from quadslam_env.config.scenario import load_scenario
from quadslam_env.models.flatness import state_on_reference
from quadslam_env.models.frames import dcm_from_euler
from quadslam_env.schema import ConfigError
from quadslam_env.sim.scans import LabeledScans, UnlabeledScans
from quadslam_env.types import DEG

EKF = "QuadSLAM-EKF-v0"
SHORT = {"duration_s": 1.5}


def _hover(env: gym.Env, seed: int, steps: int) -> list[tuple[dict[str, Any], Any, np.ndarray]]:
    """Hold the hover action ``steps`` steps from ``reset(seed=seed)``: each step's info, a
    copy of its scan (``core.last_scan``: unlabeled returns live in a buffer the LiDAR reuses)
    and the IMU's true total bias (B = 1: row 0)."""
    core = env.unwrapped.core
    _, info = env.reset(seed=seed)
    out = [(info, None, core.imu.total_bias[0].copy())]
    hover = core.action_map.hover_action.copy()
    for _ in range(steps):
        _, _, terminated, truncated, info = env.step(hover)
        assert not (terminated or truncated)
        scan = core.last_scan
        out.append((info, None if scan is None else scan.lane(0), core.imu.total_bias[0].copy()))
    return out


# ------------------------------------------------------------------ off: nothing changes
def test_without_a_fault_the_rollout_is_the_one_without_the_section() -> None:
    """``kind: none`` (the default) and a section left out fly the same episode bit for bit,
    with no fault term in ``info``."""
    runs = []
    for faults in (None, {"kind": "none"}):
        kwargs: dict[str, Any] = {"episode": SHORT}
        if faults is not None:
            kwargs["faults"] = faults
        env = gym.make(EKF, **kwargs)
        runs.append(_hover(env, 3, 60))
        env.close()
    for (info_a, scan_a, bias_a), (info_b, scan_b, bias_b) in zip(*runs, strict=True):
        assert info_a.keys() == info_b.keys()
        assert not any(key.startswith(("fault_", "episode_fault")) for key in info_a)
        for key in info_a:
            np.testing.assert_array_equal(info_a[key], info_b[key])
        np.testing.assert_array_equal(bias_a, bias_b)
        if scan_a is not None:
            np.testing.assert_array_equal(scan_a.meas, scan_b.meas)


@pytest.mark.parametrize("scenario", ["paper_ekf_figure8", "ekf_figure8_wind"])
def test_a_fault_that_changes_nothing_leaves_every_stream_as_it_was(scenario: str) -> None:
    """An IMU bias step of 0 draws its onset from its own generator and changes nothing else:
    the observations of two episodes (the second from the same env generator) equal those
    without the fault, bit for bit, in still air and in Dryden gusts (whose generator is
    spawned from the same world child first)."""
    faults = {"kind": "imu_bias_step", "magnitude": 0.0, "onset_s": 0.1, "onset_max_s": 0.3}
    obs: list[list[np.ndarray]] = []
    for kwargs in ({}, {"faults": faults}):
        env = gym.make(EKF, scenario=scenario, episode={"duration_s": 0.4}, **kwargs)
        hover = env.unwrapped.core.action_map.hover_action.copy()
        seen = []
        for seed in (5, None):
            seen.append(env.reset(seed=seed)[0])
            for _ in range(20):
                seen.append(env.step(hover)[0])
        obs.append(seen)
        env.close()
    for a, b in zip(*obs, strict=True):
        np.testing.assert_array_equal(a, b)


# ------------------------------------------------------------------ landmark_moves
def test_a_moving_landmark_is_at_start_plus_speed_times_time() -> None:
    """The true landmark moves at the set speed and heading from the onset for the duration
    and then stays; the other landmarks stay; the map RMSE compares with the current truth."""
    speed, heading, onset, duration = 0.8, 30.0, 0.4, 0.5
    faults = {"kind": "landmark_moves", "landmark": 3, "magnitude": speed, "onset_s": onset,
              "duration_s": duration, "direction_deg": heading}  # fmt: skip
    env = gym.make(EKF, episode=SHORT, faults=faults)
    core = env.unwrapped.core
    env.reset(seed=1)
    start = core.landmarks[0].copy()
    way = np.array([math.cos(heading * DEG), math.sin(heading * DEG), 0.0])
    hover = core.action_map.hover_action.copy()
    for _ in range(120):
        info = env.step(hover)[4]
        t = info["t"]
        moved = speed * min(max(t - onset, 0.0), duration)
        np.testing.assert_allclose(core.landmarks[0, 3], start[3] + moved * way, rtol=0, atol=1e-12)
        np.testing.assert_array_equal(np.delete(core.landmarks[0], 3, axis=0),
                                      np.delete(start, 3, axis=0))  # fmt: skip
        active = onset <= t + 1e-9 < onset + duration
        assert info["fault_active"] == float(active)
        assert info["fault_kind"] == ("landmark_moves" if active else "")
        assert info.get("fault_landmark") == (3.0 if active else None)
        scan = core.last_scan  # labeled: slot 3 is landmark 3
        seen = active and scan is not None and 0 in scan.lanes and bool(scan.returned[0, 3])
        assert info["fault_in_view"] == float(seen)
        est = core.est
        mapped = est.landmark_mapped[0]
        if mapped.any():
            err = est.landmark_means[0, mapped] - core.landmarks[0, mapped]
            rmse = math.sqrt(float((err**2).sum(axis=1).mean()))
            assert info["est_map_rmse_m"] == pytest.approx(rmse, rel=1e-12)
    env.close()


def test_the_drawn_moving_landmark_is_one_the_reference_sees() -> None:
    """With ``landmark`` null the landmark is drawn per episode among those in the LiDAR's
    view from the reference pose at some scan while the fault is active."""
    onset, duration = 1.0, 2.0
    faults = {"kind": "landmark_moves", "onset_s": onset, "duration_s": duration}
    env = gym.make(EKF, episode={"duration_s": 4.0}, faults=faults)
    core = env.unwrapped.core
    cfg, lidar = core.scenario, core.scenario.lidar
    drawn = set()
    for seed in range(6):
        env.reset(seed=seed)
        landmark = int(core.faults.target[0])
        drawn.add(landmark)
        point = core.landmarks[0, landmark]
        seen = False
        for k in range(1, cfg.max_steps // cfg.lidar_every + 1):
            t = k * cfg.lidar_every / cfg.episode.control_hz
            if not onset <= t < onset + duration:
                continue
            ref = core.trajectory(t)
            x = state_on_reference(ref.pos, ref.vel, ref.acc, ref.yaw, ref.yaw_rate,
                                   core.vehicle_params.mass)  # fmt: skip
            c = dcm_from_euler(x[6:9]).T @ (point - x[:3])
            az, el = math.atan2(c[1], c[0]), math.atan2(c[2], math.hypot(c[0], c[1]))
            az_max, el_max = lidar.azimuth_fov_deg * DEG, lidar.elevation_fov_deg * DEG
            seen |= abs(az) <= az_max and abs(el) <= el_max
        assert seen, f"seed {seed}: landmark {landmark} is not in view of the reference"
    assert len(drawn) > 1  # drawn per episode
    env.close()


# ------------------------------------------------------------------ range_bias
@pytest.mark.parametrize("association", ["known", "unknown"])
@pytest.mark.parametrize("fraction", [1.0, 0.5])
def test_a_range_bias_adds_exactly_the_bias_to_the_affected_returns(
    association: str, fraction: float
) -> None:
    """Against the same seed without the fault: the affected returns' ranges are the
    unbiased ones plus the bias while active, everything else is equal; with fraction 1 every
    return (false ones too), else round(fraction · L) landmarks drawn per episode."""
    bias, onset, duration = 0.25, 0.3, 0.5
    lidar = {"association": association}
    if association == "unknown":
        lidar |= {"clutter_rate": 2.0, "detection_prob": 0.9}
    faults = {"kind": "range_bias", "magnitude": bias, "fraction": fraction, "onset_s": onset,
              "duration_s": duration}  # fmt: skip
    runs, cores = [], []
    for extra in ({}, {"faults": faults}):
        env = gym.make(EKF, episode=SHORT, lidar=lidar, **extra)
        runs.append(_hover(env, 2, 120))
        cores.append(env.unwrapped.core)
    affected = cores[1].faults.affected[0]
    if fraction == 1.0:
        assert affected is None
    else:
        assert affected is not None and affected.shape == (20,)  # half of the 40 landmarks
    biased_steps = 0
    for (_, plain, _), (info, faulty, _) in zip(*runs, strict=True):
        if plain is None:
            assert faulty is None
            continue
        assert type(plain) is type(faulty) is (LabeledScans if association == "known"
                                               else UnlabeledScans)  # fmt: skip
        np.testing.assert_array_equal(plain.returned, faulty.returned)
        np.testing.assert_array_equal(plain.meas[..., :2], faulty.meas[..., :2])
        rows = plain.returned[0]
        hit = rows if affected is None else rows & np.isin(plain.true_ids[0], affected)
        active = onset <= info["t"] + 1e-9 < onset + duration
        expected = plain.meas[0, :, 2] + bias if active else plain.meas[0, :, 2]
        np.testing.assert_array_equal(faulty.meas[0, hit, 2], expected[hit])
        np.testing.assert_array_equal(faulty.meas[0, ~hit, 2], plain.meas[0, ~hit, 2])
        biased_steps += bool(active and hit.any())
    assert biased_steps >= 4


# ------------------------------------------------------------------ imu_bias_step
@pytest.mark.parametrize(("sensor", "axis", "step"), [("gyro", 1, 0.02), ("accel", 2, -0.3)])
def test_an_imu_bias_step_is_in_the_total_bias_exactly_while_active(
    sensor: str, axis: int, step: float
) -> None:
    """The true total bias (the metrics' truth) is the one without the fault plus the step on
    the steps with onset <= t < onset + duration, and the same bit for bit elsewhere."""
    onset, duration = 0.35, 0.4
    faults = {"kind": "imu_bias_step", "sensor": sensor, "axis": axis, "magnitude": step,
              "onset_s": onset, "duration_s": duration}  # fmt: skip
    runs = []
    for extra in ({}, {"faults": faults}):
        env = gym.make(EKF, scenario="ekf_figure8_biased_imu", episode=SHORT, **extra)
        runs.append(_hover(env, 4, 100))
        env.close()
    column = (0 if sensor == "accel" else 3) + axis
    stepped = 0
    for (_, _, plain), (info, _, faulty) in zip(*runs, strict=True):
        active = onset <= info["t"] + 1e-9 < onset + duration
        assert info["fault_active"] == float(active)
        if active:
            expected = plain.copy()
            expected[column] += step
            np.testing.assert_allclose(faulty, expected, rtol=0, atol=1e-15)
            np.testing.assert_array_equal(np.delete(faulty, column), np.delete(plain, column))
            stepped += 1
        else:
            np.testing.assert_array_equal(faulty, plain)
    assert stepped == round(duration * 100)


# ------------------------------------------------------------------ phantom_landmark
def test_the_phantom_returns_at_its_body_frame_offset() -> None:
    """Noise-free: from the onset the labeled scans carry id L (after the lane's L
    landmarks) at the azimuth, elevation and range of ``offset_m``; before it, nothing."""
    offset, onset = (5.0, 1.0, -0.5), 0.3
    lidar = {"sigma_azimuth_deg": 0.0, "sigma_elevation_deg": 0.0, "sigma_range_m": 0.0}
    faults = {"kind": "phantom_landmark", "offset_m": list(offset), "onset_s": onset}
    env = gym.make("QuadSLAM-Oracle-v0", episode=SHORT, lidar=lidar, faults=faults)
    x, y, z = offset
    expected = [math.atan2(y, x), math.atan2(z, math.hypot(x, y)), math.sqrt(x * x + y * y + z * z)]
    scans = 0
    for info, scan, _ in _hover(env, 0, 100)[1:]:
        active = info["t"] + 1e-9 >= onset
        assert info.get("fault_landmark") == (40.0 if active else None)
        if scan is None:
            continue
        assert bool(scan.returned[0, 40]) is active
        if active:
            np.testing.assert_allclose(scan.meas[0, 40], expected, rtol=0, atol=1e-12)
            scans += 1
    assert scans >= 5
    env.close()


def test_the_phantom_is_mapped_but_not_scored() -> None:
    """EKF-SLAM maps the phantom as landmark L; the mapped count and the map RMSE leave it
    out (they are scored over the true landmarks only)."""
    faults = {"kind": "phantom_landmark", "onset_s": 0.2}
    env = gym.make(EKF, episode=SHORT, faults=faults)
    core = env.unwrapped.core
    steps = _hover(env, 6, 100)
    info = steps[-1][0]
    mapped = core.est.landmark_mapped[0]
    assert mapped.shape[0] >= 41 and mapped[40]  # the estimator took it for a landmark
    assert info["est_n_mapped"] == mapped[:40].sum()
    err = core.est.landmark_means[0, :40][mapped[:40]] - core.landmarks[0][mapped[:40]]
    assert info["est_map_rmse_m"] == pytest.approx(math.sqrt((err**2).sum(axis=1).mean()))
    env.close()


def test_with_unknown_association_the_phantom_is_a_false_return() -> None:
    """Unlabeled: the phantom's return (found by its noise-free measurement) has the true
    id -1, as a false return; the landmarks' returns keep their ids."""
    lidar = {"association": "unknown", "sigma_azimuth_deg": 0.0, "sigma_elevation_deg": 0.0,
             "sigma_range_m": 0.0}  # fmt: skip
    env = gym.make("QuadSLAM-Oracle-v0", episode=SHORT, lidar=lidar,
                   faults={"kind": "phantom_landmark"})  # fmt: skip
    found = 0
    for _, scan, _ in _hover(env, 0, 50)[1:]:
        if scan is None:
            continue
        n = int(scan.n_returns[0])
        at = np.flatnonzero(np.all(np.abs(scan.meas[0, :n] - [0.0, 0.0, 4.0]) < 1e-12, axis=1))
        assert at.shape == (1,)
        assert scan.true_ids[0, at[0]] == -1
        assert (np.delete(scan.true_ids[0, :n], at) >= 0).all()  # no clutter configured
        found += 1
    assert found >= 4
    env.close()


# ------------------------------------------------------------------ lanes and info
LANE_FAULTS = [
    {"kind": "landmark_moves", "onset_s": 0.1, "onset_max_s": 0.5},
    {"kind": "phantom_landmark", "onset_s": 0.1, "onset_max_s": 0.5, "duration_s": 0.6},
    {"kind": "range_bias", "onset_s": 0.1, "onset_max_s": 0.5, "fraction": 0.3},
    {"kind": "imu_bias_step", "onset_s": 0.1, "onset_max_s": 0.5, "sensor": "gyro", "axis": 0,
     "magnitude": 0.05},
]  # fmt: skip


@pytest.mark.parametrize("faults", LANE_FAULTS, ids=lambda f: f["kind"])
def test_lanes_equal_the_scalar_env_with_a_fault(faults: dict) -> None:
    """Lane i of a vector env seeded s + i flies the scalar env seeded s + i, bit for bit,
    with every fault on (its draws from each lane's own generator)."""
    kwargs = {"episode": {"duration_s": 1.2}, "faults": faults}
    assert_lanes_equal_scalar_env(EKF, kwargs, "dflqr", [3, 4], 100)


def test_the_vector_env_reports_the_fault_kind_as_text() -> None:
    """``fault_kind`` is an object array of strings with a mask of the lanes where a fault is
    active, like ``termination_reason``; the episode ends with its onset."""
    faults = {"kind": "range_bias", "onset_s": 0.1, "onset_max_s": 0.5}
    vec = gym.make_vec(EKF, num_envs=3, vectorization_mode="vector_entry_point",
                       episode={"duration_s": 0.6}, faults=faults)  # fmt: skip
    vec.reset(seed=0)
    hover = np.tile(vec.unwrapped.core.action_map.hover_action, (3, 1))
    onsets = vec.unwrapped.core.faults.onset.copy()
    assert ((onsets >= 0.1) & (onsets <= 0.5)).all() and len(set(onsets.tolist())) == 3
    saw_text = False
    for _ in range(60):
        _, _, term, trunc, info = vec.step(hover)
        active = info.get("fault_active", np.zeros(3)) == 1.0
        if "fault_kind" in info:
            assert info["fault_kind"].dtype == object
            np.testing.assert_array_equal(info["_fault_kind"], active)
            assert list(info["fault_kind"]) == ["range_bias" if a else "" for a in active]
            saw_text = True
    assert saw_text and (term | trunc).all()
    np.testing.assert_array_equal(info["episode_fault_onset_s"], onsets)
    vec.close()


# ------------------------------------------------------------------ bad input
BAD = [
    ({"kind": "explodes"}, "faults.kind"),
    ({"kind": "range_bias", "onset_s": -1.0}, "faults.onset_s"),
    ({"kind": "range_bias", "duration_s": -1.0}, "faults.duration_s"),
    ({"kind": "range_bias", "duration_s": 0.0}, "faults.duration_s"),
    ({"kind": "range_bias", "onset_s": 2.0, "onset_max_s": 1.0}, "faults.onset_max_s"),
    ({"kind": "range_bias", "onset_s": 50.0}, "faults.onset_s"),  # at the episode's end
    ({"kind": "range_bias", "onset_s": 1.0, "onset_max_s": 60.0}, "faults.onset_max_s"),
    ({"kind": "landmark_moves", "landmark": 40}, "faults.landmark"),  # of 40 landmarks
    ({"kind": "landmark_moves", "landmark": -1}, "faults.landmark"),
    ({"kind": "landmark_moves", "magnitude": -0.5}, "faults.magnitude"),
    ({"kind": "range_bias", "fraction": 0.0}, "faults.fraction"),
    ({"kind": "range_bias", "fraction": 1.5}, "faults.fraction"),
    ({"kind": "imu_bias_step", "axis": 3}, "faults.axis"),
    ({"kind": "imu_bias_step", "sensor": "compass"}, "faults.sensor"),
    ({"kind": "phantom_landmark", "offset_m": [-4.0, 0.0, 0.0]}, "faults.offset_m"),  # behind
    ({"kind": "phantom_landmark", "offset_m": [0.0, 0.0, 0.0]}, "faults.offset_m"),
    ({"kind": "range_bias", "magnitude": 1e3}, "faults.magnitude"),
    # a setting the kind ignores
    ({"onset_s": 1.0}, "faults.onset_s"),
    ({"kind": "imu_bias_step", "fraction": 0.5}, "faults.fraction"),
    ({"kind": "range_bias", "sensor": "gyro"}, "faults.sensor"),
    ({"kind": "landmark_moves", "offset_m": [3.0, 0.0, 0.0]}, "faults.offset_m"),
    ({"kind": "phantom_landmark", "magnitude": 2.0}, "faults.magnitude"),
    ({"kind": "range_bias", "landmark": 2}, "faults.landmark"),
    ({"kind": "imu_bias_step", "direction_deg": 90.0}, "faults.direction_deg"),
    ({"kind": "range_bias", "surprise": 1}, "faults.surprise"),
]


@pytest.mark.parametrize(("faults", "key"), BAD, ids=[f"{k}-{i}" for i, (_, k) in enumerate(BAD)])
def test_every_bad_fault_setting_names_its_key(faults: dict, key: str) -> None:
    with pytest.raises(ConfigError) as err:
        load_scenario(None, {"faults": faults})
    message = str(err.value)
    assert message.startswith(key) and "allowed" in message and "\n" not in message


def test_a_moving_landmark_beyond_a_reset_map_fails_at_reset() -> None:
    """Against the lane's actual map: a reset option of 3 landmarks has no landmark 5."""
    env = gym.make(EKF, episode=SHORT, faults={"kind": "landmark_moves", "landmark": 5})
    points = np.array([[10.0, 0.0, -2.0], [0.0, 10.0, -2.0], [10.0, 10.0, -2.0]])
    with pytest.raises(ConfigError, match=r"^faults\.landmark: got 5 with a map of 3"):
        env.reset(seed=0, options={"landmarks": points})
    env.close()
