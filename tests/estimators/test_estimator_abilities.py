"""The optional estimator abilities (``quadslam_env.estimation.protocol``, docs/design.md §5):
which registered estimator has which, written out by hand from the estimators' documentation,
against what ``isinstance`` finds on the objects ``make`` builds."""

from __future__ import annotations

import copy
import importlib.util
from typing import Any

import numpy as np
import pytest

from quadslam_env.config.scenario import load_scenario
from quadslam_env.estimation import registry
from quadslam_env.estimation.lane_loop import LaneLoop, ParticleLaneLoop
from quadslam_env.estimation.protocol import (
    AssociatesUnlabeled,
    ChecksMemory,
    FusesLandmarks,
    FusesRanges,
    HasFullState,
    HasParticles,
    JoinsTeam,
    LabelsReturns,
    ModelsDrag,
    MonitorsIntegrity,
    ReportsLandmarkCovariances,
    ReservesLandmarks,
    ShowsParticles,
    TakesLateScans,
    TakesVehicle,
    TakesWind,
    UsesTruth,
    UsesVehicle,
)
from quadslam_env.models.params import vehicle_preset
from quadslam_env.schema import ConfigError

BUILT_IN = {"ekf_slam", "fastslam", "fastslam_kinematic", "isam2", "oracle"}
LOOPED = {"fastslam", "fastslam_kinematic", "isam2"}

# Abilities of the batch the env talks to. Every built-in takes unlabeled scans
# (docs/estimators.md); only EKF-SLAM sizes its map ahead and has one Gaussian over the whole
# state; only the oracle takes the truth; only the FastSLAM filters have particles to show.
BATCH: dict[type, set[str]] = {
    ReservesLandmarks: {"ekf_slam"},
    AssociatesUnlabeled: BUILT_IN,
    UsesTruth: {"oracle"},
    ShowsParticles: {"fastslam", "fastslam_kinematic"},
    HasFullState: {"ekf_slam"},
    # EKF-SLAM has the integrity monitor, and the LaneLoop passes one on to its lanes (iSAM2's
    # take it, FastSLAM's refuse it: the scenario reads the class flag, MONITORS_INTEGRITY).
    MonitorsIntegrity: {"ekf_slam"} | LOOPED,
    # Only EKF-SLAM fuses another vehicle's landmarks into its joint Gaussian (docs/team.md).
    FusesLandmarks: {"ekf_slam"},
    # and a range to another vehicle, beaconed by its broadcast position (docs/team.md).
    FusesRanges: {"ekf_slam"},
    # and gives every lane's landmark covariances at once (the team's map terms).
    ReportsLandmarkCovariances: {"ekf_slam"},
    # The LaneLoop passes a vehicle or a wind on to the lanes that use it (below).
    TakesVehicle: {"fastslam", "fastslam_kinematic", "isam2"},
    TakesWind: {"fastslam", "fastslam_kinematic", "isam2"},
    # The LaneLoop says whether its lanes take late scans (their class flag, TAKES_LATE_SCANS).
    TakesLateScans: {"fastslam", "fastslam_kinematic", "isam2"},
}
# Abilities of the one-vehicle estimators the LaneLoop runs (FastSLAM and iSAM2).
ONE_VEHICLE: dict[type, set[str]] = {
    ChecksMemory: {"fastslam", "fastslam_kinematic"},
    LabelsReturns: {"fastslam", "fastslam_kinematic", "isam2"},
    HasParticles: {"fastslam", "fastslam_kinematic"},
    # Only the dynamics-based FastSLAM's model has the vehicle (mass, inertia, drag) in it; the
    # others are driven by the IMU (docs/physics.md "Domain randomisation", "Wind").
    UsesVehicle: {"fastslam"},
    ModelsDrag: {"fastslam"},
    # Only the smoother's vehicles can share one graph (the team's centralised fusion).
    JoinsTeam: {"isam2"},
}
# The class flag read before any estimator is built: every built-in may be deep-copied (for a
# slow IMU or a delayed LiDAR) except iSAM2, whose GTSAM smoother has no copy (docs/isam2.md).
COPYABLE = BUILT_IN - {"isam2"}
MODELS_DRAG = {"fastslam"}
# Only the smoother puts a delayed scan on a keyframe of its own time (docs/isam2.md).
TAKES_LATE_SCANS = {"isam2"}
MONITORS_INTEGRITY = {"ekf_slam", "isam2"}
FUSES_LANDMARKS = {"ekf_slam"}
FUSES_RANGES = {"ekf_slam"}
JOINS_TEAM = {"isam2"}


def _built() -> dict[str, Any]:
    """Every built-in of the registry, built for two lanes (iSAM2 only with GTSAM)."""
    names = set(registry.available())
    assert names >= BUILT_IN, BUILT_IN - names
    vehicle = vehicle_preset("rauniyar2023")
    out = {}
    for name in sorted(names & BUILT_IN):
        if name == "isam2" and importlib.util.find_spec("gtsam") is None:
            continue
        out[name] = registry.make(name, num_lanes=2, landmark_capacity=4, vehicle=vehicle)
    return out


@pytest.fixture(scope="module")
def built() -> dict[str, Any]:
    return _built()


@pytest.mark.parametrize("ability", list(BATCH), ids=lambda p: p.__name__)
def test_batch_abilities_are_the_documented_ones(built: dict[str, Any], ability: type) -> None:
    found = {name for name, est in built.items() if isinstance(est, ability)}
    assert found == BATCH[ability] & set(built)


@pytest.mark.parametrize("ability", list(ONE_VEHICLE), ids=lambda p: p.__name__)
def test_one_vehicle_abilities_are_the_documented_ones(
    built: dict[str, Any], ability: type
) -> None:
    looped = {name: est for name, est in built.items() if isinstance(est, LaneLoop)}
    assert set(looped) == LOOPED & set(built)
    found = {name for name, est in looped.items() if all(isinstance(x, ability) for x in est.lanes)}
    assert found == ONE_VEHICLE[ability] & set(built)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_copyable_flag_is_the_documented_one(name: str) -> None:
    assert registry.copyable(name) == (name in COPYABLE)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_models_drag_flag_is_the_documented_one(name: str) -> None:
    assert registry.models_drag(name) == (name in MODELS_DRAG)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_takes_late_scans_flag_is_the_documented_one(name: str) -> None:
    assert registry.takes_late_scans(name) == (name in TAKES_LATE_SCANS)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_monitors_integrity_flag_is_the_documented_one(name: str) -> None:
    assert registry.monitors_integrity(name) == (name in MONITORS_INTEGRITY)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_fuses_landmarks_flag_is_the_documented_one(name: str) -> None:
    assert registry.fuses_landmarks(name) == (name in FUSES_LANDMARKS)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_fuses_ranges_flag_is_the_documented_one(name: str) -> None:
    assert registry.fuses_ranges(name) == (name in FUSES_RANGES)


@pytest.mark.parametrize("name", sorted(BUILT_IN))
def test_joins_team_flag_is_the_documented_one(name: str) -> None:
    assert registry.joins_team(name) == (name in JOINS_TEAM)


def test_the_loop_says_its_lanes_flag(built: dict[str, Any]) -> None:
    for name, est in built.items():
        if isinstance(est, TakesLateScans):
            assert est.takes_late_scans == (name in TAKES_LATE_SCANS)


def test_copyable_estimators_copy_and_the_others_refuse(built: dict[str, Any]) -> None:
    """What the flag promises, on the built objects: a deep copy (what the slow-IMU and
    delayed-LiDAR runs take) succeeds and is a separate object with the same belief."""
    for name, est in built.items():
        if name not in COPYABLE:
            with pytest.raises(TypeError, match="cannot be copied"):
                copy.deepcopy(est)
            continue
        twin = copy.deepcopy(est)
        assert twin is not est
        np.testing.assert_array_equal(twin.estimate().position, est.estimate().position)


def test_particle_loop_shows_each_lanes_particles(built: dict[str, Any]) -> None:
    """Known map (no position gauge): each lane's cloud is its own draw from N(ρ0, I)."""
    est = built["fastslam_kinematic"]
    assert isinstance(est, ParticleLaneLoop)
    mean0 = np.zeros((2, 12))
    mean0[1, 0:3] = (5.0, -3.0, -2.0)
    known = [(np.arange(2), np.zeros((2, 3)))] * 2
    rngs = [np.random.default_rng(s) for s in (1, 2)]
    est.reset_lanes(np.arange(2), mean0, np.tile(np.eye(12), (2, 1, 1)), rngs, known)
    for lane in range(2):
        cloud = est.lane_particles(lane)
        n = cloud.shape[0]
        assert cloud.shape == (500, 3)  # FastSLAM's default n_particles
        # Sample mean and std of N draws: standard errors 1/√N and about 1/√(2N).
        np.testing.assert_allclose(cloud.mean(axis=0), mean0[lane, 0:3], atol=5.0 / np.sqrt(n))
        np.testing.assert_allclose(cloud.std(axis=0), 1.0, atol=5.0 / np.sqrt(2 * n))


class _Truthful:
    """A one-vehicle estimator that asks for the truth, which only a batch can receive."""

    uses_truth = True

    def __init__(self, vehicle: Any = None) -> None:
        self.vehicle = vehicle


class _TruthfulBatch:
    """A batch that says it uses the truth but has no ``set_truth`` to receive it."""

    uses_truth = True

    def __init__(self, num_lanes: int, landmark_capacity: int, vehicle: Any = None) -> None:
        self.num_lanes = num_lanes

    def reset_lanes(self, *args: Any) -> None:
        """Nothing to reset."""


@pytest.mark.parametrize(
    ("cls", "kind"), [(_Truthful, "written for one vehicle"), (_TruthfulBatch, "without set_truth")]
)
def test_make_rejects_truth_it_cannot_deliver(
    monkeypatch: pytest.MonkeyPatch, cls: type, kind: str
) -> None:
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    registry.register("truthful")(cls)
    with pytest.raises(ValueError, match=f"'truthful', which says uses_truth = True but is {kind}"):
        registry.make("truthful")


class _Uncopyable:
    """A one-vehicle plug-in that holds state it cannot copy, and says so."""

    copyable = False

    def __init__(self, vehicle: Any = None) -> None:
        self.vehicle = vehicle


@pytest.mark.parametrize(
    ("over", "got"),
    [
        ({"imu": {"rate_hz": 10.0}}, "imu.rate_hz: got 10.0 < episode.control_hz = 100.0"),
        ({"lidar": {"delay_steps": 2}}, "lidar.delay_steps: got 2"),
    ],
)
def test_a_plugin_that_cannot_be_copied_is_refused_like_isam2(
    monkeypatch: pytest.MonkeyPatch, over: dict[str, Any], got: str
) -> None:
    """The slow IMU and the delayed LiDAR ask the registry's one question (``copyable``) of a
    plug-in as of a built-in, before any estimator is built (iSAM2 takes a delayed LiDAR's
    scans itself: tests/isam2/test_isam2_latency.py)."""
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    registry.register("uncopyable")(_Uncopyable)
    refused = ("uncopyable", "isam2") if "imu" in over else ("uncopyable",)
    for name in refused:
        with pytest.raises(ConfigError) as err:
            load_scenario("paper_ekf_figure8", {**over, "estimator": {"name": name}})
        assert str(err.value).startswith(
            f"{got} with estimator.name = {name!r}, which cannot be copied ("
        )
        assert "allowed: " in str(err.value) and "copyable = False" in str(err.value)
    # The same class without the flag is copyable by default, and the scenario loads.
    registry.register("uncopyable")(type("Copyable", (), {"__init__": _Uncopyable.__init__}))
    scenario = load_scenario("paper_ekf_figure8", {**over, "estimator": {"name": "uncopyable"}})
    assert scenario.estimator.name == "uncopyable"


class _LateUncopyable(_Uncopyable):
    """A plug-in that cannot be copied but takes late scans itself."""

    takes_late_scans = True


@pytest.mark.parametrize(
    ("over", "accepted"),
    [({"lidar": {"delay_steps": 2}}, True), ({"imu": {"rate_hz": 10.0}}, False)],
)
def test_an_uncopyable_plugin_that_takes_late_scans_goes_with_a_delayed_lidar_only(
    monkeypatch: pytest.MonkeyPatch, over: dict[str, Any], accepted: bool
) -> None:
    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    registry.register("late")(_LateUncopyable)
    if accepted:
        scenario = load_scenario("paper_ekf_figure8", {**over, "estimator": {"name": "late"}})
        assert scenario.lidar.delay_steps == 2
        return
    with pytest.raises(ConfigError, match=r"^imu\.rate_hz: got 10\.0 .*'late', which cannot"):
        load_scenario("paper_ekf_figure8", {**over, "estimator": {"name": "late"}})
