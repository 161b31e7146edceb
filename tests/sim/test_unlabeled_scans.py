"""Unknown data association: unlabeled returns, misses and clutter; config, metrics, EKF."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import AHEAD
from scipy.stats import binomtest, kstest, poisson
from test_sensors import NOISE_FREE_LIDAR, POSE_EULER, POSE_POS, _scan, c3c2c1, lidar_point

import estimators
from quadslam_env.config.hardware import LidarConfig
from quadslam_env.config.scenario import load_scenario
from quadslam_env.metrics.association import association_counts, match_landmarks
from quadslam_env.schema import ConfigError
from quadslam_env.sim.lidar import Lidar

NOISY = {**NOISE_FREE_LIDAR, "sigma_azimuth_deg": 0.3, "sigma_elevation_deg": 0.3,
         "sigma_range_m": 0.1}  # fmt: skip
P_FAIL = 1e-6


def _points(n: int = 6) -> list[np.ndarray]:
    dcm = c3c2c1(*POSE_EULER)
    return [lidar_point(POSE_POS, dcm, -40.0 + 15.0 * i, 5.0, 5.0 + 3 * i) for i in range(n)]


def test_unlabeled_scan_is_a_shuffle_of_the_labeled_scan_with_the_same_noise() -> None:
    """With detection 1 and no clutter the unlabeled scan draws the same noise first: its
    returns are the labeled returns in another order, and ``last_truth`` names them."""
    pts = _points()
    known = _scan(NOISY, pts, seed=3)
    unknown = _scan({**NOISY, "association": "unknown"}, pts, seed=3)
    assert unknown.ids is None and not unknown.labeled
    lidar = Lidar(LidarConfig.from_dict({**NOISY, "association": "unknown"}))
    lidar.reset(np.random.default_rng(3))
    scan = lidar.scan(0.5, POSE_POS, c3c2c1(*POSE_EULER), np.arange(len(pts)), np.array(pts))
    np.testing.assert_array_equal(scan.meas, unknown.meas)
    order = np.argsort(lidar.last_truth)
    np.testing.assert_array_equal(lidar.last_truth[order], known.ids)
    np.testing.assert_array_equal(scan.meas[order], known.meas)
    assert not np.array_equal(lidar.last_truth, known.ids)  # shuffled (6! orders)


@pytest.mark.parametrize("association", ["known", "unknown"])
def test_detection_probability_is_the_share_of_landmarks_returned(association: str) -> None:
    cfg = LidarConfig.from_dict({**NOISY, "detection_prob": 0.7, "association": association})
    lidar = Lidar(cfg)
    lidar.reset(np.random.default_rng(0))
    pts = np.array(_points())
    returned = 0
    scans = 400
    for k in range(scans):
        scan = lidar.scan(0.1 * k, POSE_POS, c3c2c1(*POSE_EULER), np.arange(6), pts)
        returned += scan.count
    assert binomtest(returned, 6 * scans, 0.7).pvalue > P_FAIL


def test_clutter_is_poisson_and_uniform_over_the_fov_volume() -> None:
    rate = 4.0
    cfg = LidarConfig.from_dict({**NOISE_FREE_LIDAR, "association": "unknown",
                                 "clutter_rate": rate})  # fmt: skip
    lidar = Lidar(cfg)
    lidar.reset(np.random.default_rng(1))
    counts, rows = [], []
    for k in range(1500):  # no landmark: every return is clutter
        scan = lidar.scan(
            0.1 * k, POSE_POS, c3c2c1(*POSE_EULER), np.zeros(0, int), np.zeros((0, 3))
        )
        assert (lidar.last_truth == -1).all()
        counts.append(scan.count)
        rows.append(scan.meas)
    counts_arr = np.array(counts)
    # The total of n Poisson(rate) counts is Poisson(n·rate).
    total = counts_arr.sum()
    assert poisson.cdf(total, rate * counts_arr.size) > P_FAIL / 2
    assert poisson.sf(total - 1, rate * counts_arr.size) > P_FAIL / 2
    meas = np.concatenate(rows)
    az, el, rng_m = meas[:, 0], meas[:, 1], meas[:, 2]
    a_max, e_max = math.radians(45.0), math.radians(30.0)
    assert (np.abs(az) <= a_max).all() and (np.abs(el) <= e_max).all()
    assert ((rng_m >= 2.0) & (rng_m <= 50.0)).all()
    # Uniform in volume: α, sin β and δ³ are uniform on their intervals.
    assert kstest((az + a_max) / (2 * a_max), "uniform").pvalue > P_FAIL
    assert kstest((np.sin(el) / math.sin(e_max) + 1) / 2, "uniform").pvalue > P_FAIL
    assert kstest((rng_m**3 - 8.0) / (50.0**3 - 8.0), "uniform").pvalue > P_FAIL


@pytest.mark.parametrize(
    ("overrides", "fragment"),
    [
        ({"lidar": {"detection_prob": 1.5}}, "lidar.detection_prob"),
        ({"lidar": {"detection_prob": -0.1}}, "lidar.detection_prob"),
        ({"lidar": {"clutter_rate": -1.0}}, "lidar.clutter_rate"),
        ({"lidar": {"clutter_rate": 2.0}}, "lidar.clutter_rate: got 2.0; allowed: 0 with"),
        ({"lidar": {"association": "maybe"}}, "lidar.association"),
        (
            {"lidar": {"association": "unknown"}, "estimator": {"params": {"association": "x"}}},
            "estimator.params.association: got 'x'; allowed: one of ['nn', 'jcbb']",
        ),
        (
            {"lidar": {"association": "unknown"}, "estimator": {"params": {"confirm_hits": 0}}},
            "estimator.params.confirm_hits",
        ),
        (
            {
                "lidar": {"association": "unknown"},
                "estimator": {"params": {"confirm_hits": 4, "confirm_window": 3}},
            },
            "estimator.params.confirm_window: got 3",
        ),
    ],
)
def test_bad_association_settings_name_the_key(overrides: dict, fragment: str) -> None:
    import gymnasium as gym

    import quadslam_env  # noqa: F401

    with pytest.raises((ConfigError, ValueError), match=None) as err:
        env = gym.make("QuadSLAM-EKF-v0", **overrides)
        env.close()
    assert fragment in str(err.value)


def test_unknown_association_needs_an_estimator_that_associates() -> None:
    @estimators.register("test_labels_only")
    class LabelsOnly:  # a plug-in without associates_unlabeled
        def __init__(self, vehicle=None, **params):
            pass

    with pytest.raises(ConfigError, match="cannot associate unlabeled returns"):
        load_scenario(
            "paper_ekf_figure8",
            {"lidar": {"association": "unknown"}, "estimator": {"name": "test_labels_only"}},
        )


def test_landmark_matching_and_association_counts_on_a_hand_case() -> None:
    true_lm = np.array([[[0.0, 0, 0], [5.0, 0, 0], [10.0, 0, 0]]])
    # Labels: 0 ≈ landmark 1, 1 ≈ landmark 0, 2 spurious (1 m from everything), 3 unmapped.
    means = np.array([[[5.1, 0, 0], [0.0, 0.2, 0], [2.5, 1.0, 0], [10.0, 0, 0]]])
    mapped = np.array([[True, True, True, False]])
    pose = np.zeros((1, 6))
    match = match_landmarks(means, mapped, pose, true_lm, np.array([3]), pose)
    assert match.tolist() == [[1, 0, -1, -1]]
    only_first = match_landmarks(means, mapped, pose, true_lm, np.array([1]), pose)
    assert only_first.tolist() == [[-1, 0, -1, -1]]
    # In the vehicle frame: a map that drifted with its vehicle (3 m and 40° of yaw) matches
    # the same way; the same drifted map about the true pose does not.
    yaw = np.radians(40.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    drifted = means @ rot.T + np.array([3.0, -1.0, 0.5])
    est_pose = np.array([[3.0, -1.0, 0.5, 0.0, 0.0, yaw]])
    again = match_landmarks(drifted, mapped, est_pose, true_lm, np.array([3]), pose)
    assert again.tolist() == match.tolist()
    assert match_landmarks(drifted, mapped, pose, true_lm, np.array([3]), pose).max() == -1
    # Returns: from landmark 1 → label 0 (right); from 0 → label 0 (wrong); clutter → label 2
    # (wrong); from 2 → none (missed); clutter → none; row 5 beyond the count.
    truth = np.array([[1, 0, -1, 2, -1, 0]])
    labels = np.array([[0, 0, 2, -1, -1, 1, -1]])
    counts = association_counts(truth, labels, np.array([5]), match)
    assert {k: float(v[0]) for k, v in counts.items()} == {
        "assoc_n_returns": 5.0,
        "assoc_n_associated": 3.0,
        "assoc_n_wrong": 2.0,
        "assoc_n_true": 3.0,
        "assoc_n_missed": 1.0,
    }


def _hover_run(overrides: dict, steps: int = 150) -> tuple[np.ndarray, list[dict]]:
    import gymnasium as gym

    import quadslam_env  # noqa: F401

    layout = {"layout": "explicit", "positions": AHEAD}
    env = gym.make("QuadSLAM-EKF-v0", landmarks=layout, **overrides)
    env.reset(seed=11)
    hover = env.unwrapped.hover_action
    positions, infos = [], []
    for _ in range(steps):
        _, _, term, trunc, info = env.step(hover)
        positions.append(env.unwrapped.core.est.position[0].copy())
        infos.append(info)
        assert not (term or trunc)
    env.close()
    return np.array(positions), infos


@pytest.mark.parametrize("method", ["nn", "jcbb"])
def test_ekf_with_unlabeled_returns_equals_the_labeled_filter_when_association_is_easy(
    method: str,
) -> None:
    """A static vehicle among well-separated landmarks, every landmark returned, no clutter,
    a landmark mapped at first sight (M = N = 1) and a gate wide enough to pass every true
    pairing: association is then exactly the truth, so the filter fed the shuffled,
    unlabeled scans must match the filter fed the labeled scans, up to the rounding of another
    landmark order, and name every return by the landmark the labeled filter gave it."""
    from conftest import lane_predict, lane_reset, lane_update

    from estimators.ekf.filter import EkfSlamBatch
    from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
    from quadslam_env.models.frames import dcm_from_euler, wrap_angle
    from quadslam_env.models.lidar import lidar_measure
    from quadslam_env.types import GRAVITY

    rng = np.random.default_rng(4)
    wide = {"gate_probability": 1.0 - 1e-12}  # the new-landmark gate takes the same
    labeled = EkfSlamBatch(1, 0, **wide)
    unlabeled = EkfSlamBatch(1, 0, **wide, association=method, confirm_hits=1, confirm_window=1)
    lms = np.array(AHEAD, dtype=float)
    sigma = np.array([np.deg2rad(0.33), np.deg2rad(0.30), 0.1])
    mean0 = np.zeros(12)
    cov0 = np.diag([1e-3] * 3 + [1e-2] * 3 + [1e-4] * 3 + [1e-6] * 3)
    for f in (labeled, unlabeled):
        lane_reset(f, mean0, cov0, np.random.default_rng(0))
    imu = ImuSample(0.0, np.array([0.0, 0.0, -GRAVITY]), np.zeros(3), 0.03, 1e-3)
    for k in range(30):
        for _ in range(10):
            for f in (labeled, unlabeled):
                lane_predict(f, imu, Control(0.0, np.zeros(3)), 0.01)
        meas = lidar_measure(np.zeros(3), dcm_from_euler(np.zeros(3)), lms)
        meas = meas + sigma * rng.standard_normal(meas.shape)
        meas[:, :2] = wrap_angle(meas[:, :2])
        order = rng.permutation(len(lms))
        lane_update(labeled, LidarScan(0.1 * k, np.arange(len(lms)), meas, sigma))
        names = lane_update(unlabeled, LidarScan(0.1 * k, None, meas[order], sigma))
        a, b = labeled.lane_estimate(0), unlabeled.lane_estimate(0)
        np.testing.assert_allclose(b.position, a.position, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.pose_cov, a.pose_cov, rtol=0, atol=1e-12)
        # The unlabeled filter's names: the landmark the return came from, in its own labels.
        assert names is not None and (names >= 0).all()
        np.testing.assert_allclose(
            b.landmark_means[0, names], a.landmark_means[0, order], rtol=0, atol=1e-9
        )


def test_ekf_keeps_clutter_out_of_the_map() -> None:
    """Clutter 5 per scan, detection 0.9: after 1.5 s of hover no false return has been
    confirmed (the M-of-N rule) and the returns that were paired are right."""
    _, infos = _hover_run({"lidar": {"association": "unknown", "clutter_rate": 5.0,
                                     "detection_prob": 0.9}})  # fmt: skip
    last = infos[-1]
    assert last["spurious_landmarks"] == 0
    assert last["est_n_mapped"] == len(AHEAD)
    assert sum(i["assoc_n_wrong"] for i in infos) == 0
    assert sum(i["assoc_n_returns"] - i["assoc_n_true"] for i in infos) > 20  # clutter came
