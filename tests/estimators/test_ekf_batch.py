"""Tests of the batched EKF-SLAM (estimators/ekf): lanes are independent filters.

Every lane of an :class:`EkfSlamBatch` must behave like the one lane of an
:class:`EkfSlamBatch` with B = 1 fed the same inputs, whatever the other lanes do (different
maps, scan timings, known-map mode, inactive steps, resets). The one-lane filter itself is
tested against independent facts in tests/estimators/test_ekf_slam.py.
"""

from __future__ import annotations

import copy
import math
import pickle

import numpy as np
import pytest
from conftest import lane_predict, lane_reset, lane_update

from estimators.ekf.filter import EkfSlamBatch
from quadslam_env.estimation.measurements import Control, ImuSample, LidarScan
from quadslam_env.estimation.registry import make
from quadslam_env.models.frames import dcm_from_euler, wrap_angle
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.strapdown import process_derivative
from quadslam_env.types import GRAVITY

SIG_LIDAR = np.array([np.deg2rad(0.33), np.deg2rad(0.30), 0.1])
SIG_ACC, SIG_GYR = 0.03, 0.002
DT = 0.01
NO_CONTROL = Control(0.0, np.zeros(3))
N_LANDMARKS = (12, 20, 8, 15)  # lane 2 localises against its known map
LMAX = max(N_LANDMARKS)
KNOWN_LANE = 2


def _lane_run(lane: int, steps: int) -> tuple[np.ndarray, np.ndarray, list]:
    """A coordinated turn of lane ``lane``: its map (L, 3), initial mean (12,) and per step
    ``(accel (3,), gyro (3,), scan ids (k,) or None, scan meas (k, 3))``."""
    rng = np.random.default_rng(100 + lane)
    n_lm = N_LANDMARKS[lane]
    az = rng.uniform(-1.2, 1.2, n_lm) + 0.3 * lane  # around the initial heading
    el = rng.uniform(-0.45, 0.45, n_lm)
    rng_m = rng.uniform(8.0, 20.0, n_lm)
    lms = np.stack(
        [rng_m * np.cos(el) * np.cos(az), rng_m * np.cos(el) * np.sin(az), rng_m * np.sin(el)], 1
    )
    speed, yaw_rate = 1.0 + 0.5 * lane, 0.2 + 0.1 * lane
    roll = math.atan(yaw_rate * speed / GRAVITY)
    s = np.array([0.0, 0.0, -2.0, speed, 0.0, 0.0, roll, 0.0, 0.3 * lane])
    mean0 = np.r_[s, 0.0, 0.0, 0.0]
    inputs = []
    for i in range(steps):
        az_true = -(GRAVITY * math.cos(roll) + math.sin(roll) * yaw_rate * speed)
        gyro_true = np.array([0.0, math.sin(roll) * yaw_rate, math.cos(roll) * yaw_rate])
        gyro_true[0] += 0.05 * math.sin(0.5 * i * DT + lane)
        s = s + DT * process_derivative(s, az_true, gyro_true)
        accel = np.array([0.0, 0.0, az_true]) + SIG_ACC * rng.normal(size=3)
        gyro = gyro_true + SIG_GYR * rng.normal(size=3)
        ids = meas = None
        if (i + 3 * lane) % (5 if lane == 3 else 10) == 0:  # lanes scan at different steps
            m = lidar_measure(s[:3], dcm_from_euler(s[6:9]), lms)
            ids = np.flatnonzero((np.abs(m[:, 0]) <= np.pi / 4) & (np.abs(m[:, 1]) <= np.pi / 6))
            meas = m[ids] + SIG_LIDAR * rng.normal(size=(ids.size, 3))
            meas[:, :2] = wrap_angle(meas[:, :2])
        inputs.append((accel, gyro, ids, meas))
    return lms, mean0, inputs


def _cov0() -> np.ndarray:
    return np.diag([1e-3] * 3 + [1e-3] * 3 + [1e-4] * 3 + [0.0] * 3)


def _known(lane: int, lms: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    return (np.arange(lms.shape[0]), lms) if lane == KNOWN_LANE else None


def _one_lane(**params) -> EkfSlamBatch:
    """The batch filter with one lane (room for 32 landmark ids before it grows)."""
    return EkfSlamBatch(1, 32, **params)


def _make_pair(steps: int, **params):
    """A batch of 4 lanes and 4 one-lane filters, reset identically, plus the lanes' inputs."""
    runs = [_lane_run(lane, steps) for lane in range(4)]
    batch = EkfSlamBatch(4, LMAX, **params)
    batch.reset_lanes(
        np.arange(4),
        np.stack([r[1] for r in runs]),
        np.stack([_cov0()] * 4),
        [np.random.default_rng(lane) for lane in range(4)],
        [_known(lane, runs[lane][0]) for lane in range(4)],
    )
    scalars = []
    for lane, (lms, mean0, _) in enumerate(runs):
        f = _one_lane(**params)
        lane_reset(f, mean0, _cov0(), np.random.default_rng(lane), _known(lane, lms))
        scalars.append(f)
    return batch, scalars, runs


def _step(batch, scalars, runs, i: int, active: np.ndarray) -> None:
    """Feed step i to the active lanes of the batch and to the matching one-lane filters."""
    accel = np.stack([r[2][i][0] for r in runs])
    gyro = np.stack([r[2][i][1] for r in runs])
    t = np.full(4, i * DT)
    batch.predict(t, accel, gyro, SIG_ACC, SIG_GYR, np.zeros(4), np.zeros((4, 3)), DT, active)
    visible = np.zeros((4, LMAX), dtype=bool)
    meas = np.full((4, LMAX, 3), np.nan)  # entries that are not visible are never read
    scanning = []
    for lane in np.flatnonzero(active).tolist():
        accel_l, gyro_l, ids, z = runs[lane][2][i]
        lane_predict(
            scalars[lane], ImuSample(i * DT, accel_l, gyro_l, SIG_ACC, SIG_GYR), NO_CONTROL, DT
        )
        if ids is not None:
            scanning.append(lane)
            visible[lane, ids] = True
            meas[lane, ids] = z
            lane_update(scalars[lane], LidarScan(i * DT, ids, z, SIG_LIDAR))
    if scanning:
        batch.update(t, np.array(scanning), visible, meas, SIG_LIDAR)


def _assert_lane_equals_scalar(batch: EkfSlamBatch, lane: int, scalar: EkfSlamBatch) -> None:
    xb, Pb, ids_b = batch.full_state(lane)
    xs, Ps, ids_s = scalar.full_state()
    np.testing.assert_array_equal(ids_b, ids_s)
    np.testing.assert_allclose(xb, xs, rtol=1e-12, atol=1e-12 * np.abs(xs).max())
    np.testing.assert_allclose(Pb, Ps, rtol=1e-12, atol=1e-12 * np.abs(Ps).max())
    eb, es = batch.lane_estimate(lane), scalar.lane_estimate(0)
    assert eb.diagnostics.keys() == es.diagnostics.keys()
    for key, value in es.diagnostics.items():
        assert eb.diagnostics[key][0] == pytest.approx(value[0], rel=1e-12, nan_ok=True), key
    np.testing.assert_array_equal(eb.landmark_ids(), es.landmark_ids())
    np.testing.assert_allclose(eb.rates, es.rates, rtol=1e-12, atol=1e-15)


@pytest.mark.parametrize("bias", [False, True])
def test_each_lane_equals_a_scalar_filter(bias):
    """Different maps, scan timings, a known-map lane and an inactive period."""
    steps = 160
    batch, scalars, runs = _make_pair(steps, estimate_imu_bias=bias)
    for i in range(steps):
        active = np.ones(4, dtype=bool)
        if 40 <= i < 70:
            active[3] = False  # lane 3 pauses (e.g. its episode ended and awaits a reset)
        _step(batch, scalars, runs, i, active)
    est = batch.estimate()
    assert est.diagnostics["n_updates"].min() >= 5
    assert est.diagnostics["n_mapped"][KNOWN_LANE] == 0
    assert est.diagnostics["n_mapped"][[0, 1, 3]].min() >= 3
    assert np.all(est.diagnostics["diverged"] == 0.0)
    for lane in range(4):
        _assert_lane_equals_scalar(batch, lane, scalars[lane])
    assert batch.known_map.tolist() == [False, False, True, False]


def test_inactive_and_non_scanning_lanes_are_untouched():
    batch, scalars, runs = _make_pair(60)
    for i in range(30):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    before = [batch.full_state(lane) for lane in range(4)]
    rates = batch.estimate().rates.copy()
    active = np.array([True, False, True, False])
    accel = np.tile([0.0, 0.0, -GRAVITY], (4, 1))
    gyro = np.full((4, 3), 0.1)
    batch.predict(
        np.zeros(4), accel, gyro, SIG_ACC, SIG_GYR, np.zeros(4), np.zeros((4, 3)), DT, active
    )
    # Lanes 1 and 3 have visible returns in the arrays but are not listed as scanning.
    visible = np.ones((4, LMAX), dtype=bool)
    meas = np.tile([0.1, 0.05, 10.0], (4, LMAX, 1))
    batch.update(np.zeros(4), np.array([0]), visible, meas, SIG_LIDAR)
    for lane in (1, 3):
        after = batch.full_state(lane)
        for a, b in zip(before[lane], after, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_array_equal(batch.estimate().rates[lane], rates[lane])
    x2, P2, _ = batch.full_state(2)  # predicted only
    assert x2.shape == before[2][0].shape and not np.array_equal(P2, before[2][1])
    assert batch.state_dim[0] > before[0][0].size  # lane 0 registered new landmarks


def test_reset_of_one_lane_leaves_the_others_alone():
    steps = 100
    batch, scalars, runs = _make_pair(steps)
    for i in range(50):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    others = [batch.full_state(lane) for lane in (0, 2, 3)]
    mean0 = runs[1][1]
    batch.reset_lanes(np.array([1]), mean0[None], _cov0()[None], [np.random.default_rng(9)])
    scalars[1] = _one_lane()
    lane_reset(scalars[1], mean0, _cov0(), np.random.default_rng(9))
    for lane, before in zip((0, 2, 3), others, strict=True):
        for a, b in zip(before, batch.full_state(lane), strict=True):
            np.testing.assert_array_equal(a, b)
    est = batch.estimate()
    assert est.diagnostics["n_mapped"][1] == 0 and math.isnan(est.diagnostics["nis"][1])
    assert not est.landmark_mapped[1].any()
    for i in range(50, steps):  # the reset lane restarts while the others carry on
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    for lane in range(4):
        _assert_lane_equals_scalar(batch, lane, scalars[lane])


def test_batch_estimate_matches_lane_estimates():
    batch, scalars, runs = _make_pair(80, estimate_imu_bias=True)
    for i in range(80):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    est = batch.estimate()
    for lane in range(4):
        snap = batch.lane_estimate(lane)
        np.testing.assert_array_equal(est.position[lane], snap.position[0])
        np.testing.assert_array_equal(est.euler[lane], snap.euler[0])
        np.testing.assert_allclose(est.vel_inertial[lane], snap.vel_inertial[0], rtol=1e-14)
        np.testing.assert_array_equal(est.pose_cov[lane], snap.pose_cov[0])
        np.testing.assert_array_equal(est.gyro_bias[lane], snap.gyro_bias[0])
        np.testing.assert_array_equal(est.accel_bias[lane], snap.accel_bias[0])
        ids, means, _ = snap.mapped_landmarks()
        np.testing.assert_array_equal(np.flatnonzero(est.landmark_mapped[lane]), ids)
        np.testing.assert_array_equal(est.landmark_means[lane, ids], means)
        for key, value in snap.diagnostics.items():
            assert est.diagnostics[key][lane] == pytest.approx(value[0], nan_ok=True)
    np.testing.assert_array_equal(est.landmark_mapped[KNOWN_LANE, : N_LANDMARKS[KNOWN_LANE]], True)
    np.testing.assert_array_equal(
        est.landmark_means[KNOWN_LANE, : N_LANDMARKS[KNOWN_LANE]], runs[KNOWN_LANE][0]
    )


def test_capacity_grows_for_larger_ids_and_keeps_every_lane():
    batch, scalars, runs = _make_pair(40)
    for i in range(40):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    before = [batch.full_state(lane) for lane in range(4)]
    big = np.random.default_rng(5).normal(scale=10.0, size=(50, 3))
    batch.reset_lanes(
        np.array([2]), runs[2][1][None], _cov0()[None], [None], [(np.arange(50), big)]
    )
    assert batch.landmark_capacity >= 50
    for lane in (0, 1, 3):
        for a, b in zip(before[lane], batch.full_state(lane), strict=True):
            np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(batch.estimate().landmark_means[2, :50], big)
    visible = np.zeros((4, 70), dtype=bool)  # a scan wider than the capacity
    visible[0, 65] = True
    meas = np.zeros((4, 70, 3))
    meas[0, 65] = [0.2, 0.1, 12.0]
    batch.update(np.zeros(4), np.array([0]), visible, meas, SIG_LIDAR)
    assert batch.landmark_capacity >= 70 and batch.estimate().landmark_mapped[0, 65]
    x0, _, ids0 = batch.full_state(0)
    assert ids0[-1] == 65 and x0.size == before[0][0].size + 3


def test_make_batch_builds_the_native_filter_and_validates():
    est = make("ekf_slam", 3, 10, gate_probability=0.95)
    assert isinstance(est, EkfSlamBatch) and est.num_lanes == 3 and not est.uses_truth
    assert est.gate_threshold == pytest.approx(7.815, abs=1e-3)
    with pytest.raises(ValueError, match="process_noise"):
        make("ekf_slam", 2, 10, process_noise=[0.1] * 8)
    with pytest.raises(ValueError, match="bogus"):
        EkfSlamBatch(2, 10, bogus=1)
    with pytest.raises(ValueError, match="dt"):
        est.predict(
            np.zeros(3),
            np.zeros((3, 3)),
            np.zeros((3, 3)),
            0.1,
            0.1,
            np.zeros(3),
            np.zeros((3, 3)),
            0.0,
            np.ones(3, dtype=bool),
        )


def test_bad_inputs_raise_and_change_nothing():
    batch, scalars, runs = _make_pair(20)
    for i in range(20):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    before = [batch.full_state(lane) for lane in range(4)]
    visible = np.zeros((4, LMAX), dtype=bool)
    visible[[0, 3], 1] = True
    meas = np.ones((4, LMAX, 3))
    meas[3, 1, 2] = np.inf
    with pytest.raises(ValueError, match="lane 3"):
        batch.update(np.zeros(4), np.array([0, 3]), visible, meas, SIG_LIDAR)
    mean0 = np.zeros((2, 12))
    mean0[1, 4] = np.nan
    with pytest.raises(ValueError, match="mean0"):
        batch.reset_lanes(np.array([0, 1]), mean0, np.stack([_cov0()] * 2), [None, None])
    with pytest.raises(ValueError, match=">= 0"):
        batch.reset_lanes(
            np.array([0]),
            np.zeros((1, 12)),
            _cov0()[None],
            [None],
            [(np.array([-1]), np.ones((1, 3)))],
        )
    for lane in range(4):
        for a, b in zip(before[lane], batch.full_state(lane), strict=True):
            np.testing.assert_array_equal(a, b)


def test_sparse_ids_give_the_filter_of_dense_ids_seen_in_the_same_order():
    """Landmark ids index the map arrays, but map slots follow registration order (ascending
    within a scan): sparse ids give the same filter as dense ids registered in that order."""
    rng = np.random.default_rng(3)
    lms = rng.normal(scale=8.0, size=(4, 3)) + np.array([12.0, 0.0, 0.0])
    sparse, dense = _one_lane(), _one_lane()
    for f in (sparse, dense):
        lane_reset(f, np.zeros(12), _cov0(), rng)
    meas = lidar_measure(np.zeros(3), np.eye(3), lms)
    lane_update(sparse, LidarScan(0.0, np.array([7, 42]), meas[[0, 1]], SIG_LIDAR))
    lane_update(dense, LidarScan(0.0, np.array([0, 1]), meas[[0, 1]], SIG_LIDAR))
    lane_update(sparse, LidarScan(0.0, np.array([3, 7, 42, 60]), meas[[2, 0, 1, 3]], SIG_LIDAR))
    lane_update(dense, LidarScan(0.0, np.array([0, 1, 2, 3]), meas[[0, 1, 2, 3]], SIG_LIDAR))
    xs, Ps, ids = sparse.full_state()
    xd, Pd, _ = dense.full_state()
    np.testing.assert_array_equal(ids, [7, 42, 3, 60])
    np.testing.assert_allclose(xs, xd, rtol=1e-12)
    np.testing.assert_allclose(Ps, Pd, rtol=1e-10, atol=1e-15)
    np.testing.assert_array_equal(sparse.lane_estimate(0).landmark_ids(), [3, 7, 42, 60])


def test_copies_are_independent_and_estimate_views_follow_their_own_buffers():
    batch, scalars, runs = _make_pair(30)
    for i in range(30):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    batch.estimate()  # caches views
    for twin in (copy.deepcopy(batch), pickle.loads(pickle.dumps(batch))):
        accel = np.tile([0.0, 0.0, -GRAVITY], (4, 1))
        twin.predict(
            np.zeros(4),
            accel,
            np.ones((4, 3)),
            SIG_ACC,
            SIG_GYR,
            np.zeros(4),
            np.zeros((4, 3)),
            DT,
            np.ones(4, dtype=bool),
        )
        np.testing.assert_array_equal(twin.estimate().rates, 1.0)
        np.testing.assert_array_equal(twin.estimate().euler[1], twin.full_state(1)[0][6:9])
        assert not np.array_equal(batch.estimate().rates, 1.0)


def test_known_map_batches_carry_no_landmark_states_until_a_slam_lane_returns():
    """All lanes on known maps: x and P shrink to the vehicle states; a SLAM reset restores
    the landmark slots without touching the known-map lanes, which still equal scalars."""
    steps = 60
    runs = [_lane_run(lane, steps) for lane in range(4)]
    maps = [(np.arange(r[0].shape[0]), r[0]) for r in runs]
    batch = EkfSlamBatch(4, LMAX)
    mean0 = np.stack([r[1] for r in runs])
    rngs = [np.random.default_rng(lane) for lane in range(4)]
    batch.reset_lanes(np.arange(4), mean0, np.stack([_cov0()] * 4), rngs, maps)
    assert batch.state_capacity == batch.nv
    scalars = []
    for lane in range(4):
        f = _one_lane()
        lane_reset(f, runs[lane][1], _cov0(), rngs[lane], maps[lane])
        scalars.append(f)
    for i in range(30):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    before = [batch.full_state(lane) for lane in range(3)]
    batch.reset_lanes(np.array([3]), mean0[3:], _cov0()[None], [np.random.default_rng(3)])
    scalars[3] = _one_lane()
    lane_reset(scalars[3], runs[3][1], _cov0(), np.random.default_rng(3))
    assert batch.state_capacity == batch.nv + 3 * batch.landmark_capacity
    for lane in range(3):
        for a, b in zip(before[lane], batch.full_state(lane), strict=True):
            np.testing.assert_array_equal(a, b)
    for i in range(30, steps):
        _step(batch, scalars, runs, i, np.ones(4, dtype=bool))
    assert batch.estimate().diagnostics["n_mapped"][3] >= 3  # the SLAM lane maps again
    for lane in range(4):
        _assert_lane_equals_scalar(batch, lane, scalars[lane])
