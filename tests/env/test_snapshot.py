"""The one snapshot type (quadslam_env/estimation/snapshot.py): a one-lane snapshot lays one
vehicle's map out by id, and the lane loop's stacking copies lane 0 of each into the batch."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadslam_env.estimation.snapshot import (
    BatchEstimate,
    LaneMap,
    empty_batch,
    id_width,
    stack_lanes,
)


def _lane(seed: int, ids: list[int], diagnostics: dict[str, float], cov: bool = True):
    """A one-lane snapshot with random values, and the (n, 3), (n, 3, 3) map it was given."""
    rng = np.random.default_rng(seed)
    means = rng.normal(size=(len(ids), 3))
    covs = rng.normal(size=(len(ids), 3, 3))
    snap = BatchEstimate.one_lane(
        position=rng.normal(size=3),
        vel_body=rng.normal(size=3),
        vel_inertial=rng.normal(size=3),
        euler=rng.normal(size=3),
        rates=rng.normal(size=3),
        pose_cov=rng.normal(size=(9, 9)) if cov else None,
        landmark_ids=np.array(ids, dtype=np.int64),
        landmark_means=means,
        landmark_covs=covs,
        gyro_bias=rng.normal(size=3),
        diagnostics=diagnostics,
    )
    return snap, means, covs


def test_one_lane_lays_the_map_out_by_id_and_keeps_the_vectors() -> None:
    position = np.array([1.0, 2.0, 3.0])
    snap, means, covs = _lane(0, [5, 0, 2], {"nis": 4.0})
    assert snap.position.shape == (1, 3) and snap.pose_cov.shape == (1, 9, 9)
    np.testing.assert_array_equal(snap.landmark_mapped[0], [1, 0, 1, 0, 0, 1])
    np.testing.assert_array_equal(snap.landmark_ids(), [0, 2, 5])
    ids, m, c = snap.mapped_landmarks()
    order = [1, 2, 0]  # ids 0, 2, 5 were given at rows 1, 2, 0
    np.testing.assert_array_equal(ids, [0, 2, 5])
    np.testing.assert_array_equal(m, means[order])
    np.testing.assert_array_equal(c, covs[order])
    assert snap.accel_bias is None and snap.gyro_bias.shape == (1, 3)
    assert snap.diagnostics == {"nis": np.array([4.0])}
    wrapped = BatchEstimate.one_lane(
        position, position, position, position, position, None, np.zeros(0), np.zeros((0, 3)),
        np.zeros((0, 3, 3)),
    )  # fmt: skip
    assert np.shares_memory(wrapped.position, position)  # a view with a leading axis, no copy
    assert wrapped.position.shape == (1, 3)
    assert wrapped.landmark_means.shape == (1, 0, 3) and wrapped.pose_cov is None


def test_stack_lanes_copies_lane_zero_of_each_snapshot() -> None:
    snaps = [
        _lane(1, [3, 1], {"nis": 2.0, "ess": 10.0})[0],
        _lane(2, [], {"nis": 5.0})[0],
        _lane(3, [0, 4, 6], {"ess": 7.0})[0],
    ]
    assert id_width(snaps) == 7
    out = empty_batch(3, 9)
    out.landmark_means[:] = 1e9  # stale rows of unmapped ids may stay: only the mask counts
    out.landmark_mapped[:] = True
    stack_lanes(out, snaps)
    for lane, s in enumerate(snaps):
        for name in ("position", "vel_body", "vel_inertial", "euler", "rates", "pose_cov"):
            np.testing.assert_array_equal(getattr(out, name)[lane], getattr(s, name)[0], name)
        np.testing.assert_array_equal(out.gyro_bias[lane], s.gyro_bias[0])
        ids, means, _ = s.mapped_landmarks()
        np.testing.assert_array_equal(out.landmark_ids(lane), ids)
        np.testing.assert_array_equal(out.landmark_means[lane, ids], means)
    assert out.accel_bias is None and out.landmark_covs is None
    np.testing.assert_array_equal(out.diagnostics["nis"][:2], [2.0, 5.0])
    np.testing.assert_array_equal(out.diagnostics["ess"][[0, 2]], [10.0, 7.0])
    assert math.isnan(out.diagnostics["nis"][2]) and math.isnan(out.diagnostics["ess"][1])
    with pytest.raises(ValueError, match="no landmark covariances"):
        out.mapped_landmarks(0)


def test_stack_lanes_drops_the_covariance_when_the_first_lane_has_none() -> None:
    snaps = [_lane(4, [0], {}, cov=False)[0], _lane(5, [1], {})[0]]
    out = empty_batch(2, id_width(snaps))
    stack_lanes(out, snaps)
    assert out.pose_cov is None
    np.testing.assert_array_equal(out.landmark_mapped, [[1, 0], [0, 1]])


@pytest.mark.parametrize("ids", [[0, 1, 2], [1, 4], []], ids=["in-order", "scattered", "none"])
def test_shared_lane_map_is_a_read_only_copy_in_the_layout_by_id(ids: list[int]) -> None:
    """A shared map (one per keyframe, several steps' snapshots) holds copies, row ``i`` of
    landmark id ``i``, and refuses writes; a snapshot on it equals :meth:`one_lane`'s."""
    rng = np.random.default_rng(5)
    means, covs = rng.normal(size=(len(ids), 3)), rng.normal(size=(len(ids), 3, 3))
    lane_map = LaneMap.of(np.array(ids, dtype=np.int64), means, covs, shared=True)
    width = max(ids, default=-1) + 1
    assert lane_map.means.shape == (1, width, 3) and lane_map.covs is not None
    assert np.flatnonzero(lane_map.mapped[0]).tolist() == ids
    for row, i in enumerate(ids):
        np.testing.assert_array_equal(lane_map.means[0, i], means[row])
        np.testing.assert_array_equal(lane_map.covs[0, i], covs[row])
    for a in (lane_map.means, lane_map.mapped, lane_map.covs):
        assert not a.flags.writeable
    means[:] = 7.0  # the caller's arrays are not the map's
    assert not np.any(lane_map.means == 7.0)
    state = {"position": np.ones(3), "vel_body": np.zeros(3), "vel_inertial": np.zeros(3),
             "euler": np.zeros(3), "rates": np.zeros(3), "pose_cov": np.eye(9)}  # fmt: skip
    on_map = BatchEstimate.on_map(lane_map, **state, diagnostics={"diverged": 0.0})
    one = BatchEstimate.one_lane(
        **state,
        landmark_ids=np.array(ids, dtype=np.int64),
        landmark_means=lane_map.means[0, ids],
        landmark_covs=lane_map.covs[0, ids],
        diagnostics={"diverged": 0.0},
    )
    for name in ("position", "pose_cov", "landmark_means", "landmark_mapped", "landmark_covs"):
        np.testing.assert_array_equal(getattr(on_map, name), getattr(one, name))
    assert on_map.diagnostics == one.diagnostics
