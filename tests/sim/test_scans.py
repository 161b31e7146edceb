"""Typed scans (quadslam_env/sim/scans.py): what the log keeps of a step's scans comes back
intact."""

from __future__ import annotations

import numpy as np
import pytest

from quadslam_env.config.hardware import LidarConfig
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.runtime.association import association_for
from quadslam_env.sim.lidar import LidarBatch
from quadslam_env.sim.scans import UnlabeledScans

B, LMAX = 5, 30


def _scene(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    pts = rng.uniform(-20.0, 20.0, (B, LMAX, 3))
    pos = rng.normal(size=(B, 3))
    dcm = dcm_from_euler_batch(rng.normal(size=(B, 3)) * 0.4)
    return pos, dcm, pts, rng.integers(LMAX // 2, LMAX + 1, B)


@pytest.mark.parametrize("association", ["known", "unknown"])
def test_one_lane_copies_stack_back_to_the_scans_after_the_lidar_scans_again(
    association: str,
) -> None:
    """Each scanning lane's copy (``lane``) stacked with the others (``stack``) gives back the
    lane's returns, in order, and the lanes that did not scan stay empty, although the LiDAR
    has since written its next scan into the buffers the step's scans refer to."""
    extra = {"clutter_rate": 2.0, "detection_prob": 0.8} if association == "unknown" else {}
    cfg = LidarConfig.from_dict({"azimuth_fov_deg": 120.0, "association": association, **extra})
    lidar = LidarBatch(cfg, B)
    lidar.reset(np.arange(B), [np.random.default_rng(30 + i) for i in range(B)])
    assoc = association_for(association, B)
    rng = np.random.default_rng(4)
    assoc.scan(lidar, *_scene(rng), np.arange(B))  # the buffers as wide as later scans need
    lanes = np.array([0, 2, 3])
    scans = assoc.scan(lidar, *_scene(rng), lanes)
    n_returns = scans.n_returns.copy()
    kept = [scans.meas[lane][scans.returned[lane]].copy() for lane in range(B)]
    np.testing.assert_array_equal(scans.returned.sum(axis=1), n_returns)
    assert n_returns[lanes].sum() > 0 and not n_returns[[1, 4]].any()
    rows = {lane: scans.lane(lane) for lane in lanes.tolist()}
    truth = scans.returns.truth.copy() if isinstance(scans, UnlabeledScans) else None
    assoc.scan(lidar, *_scene(rng), np.arange(B))
    if truth is not None:  # the LiDAR wrote its next returns into the same buffers
        assert not np.array_equal(scans.meas[lanes[0]][scans.returned[lanes[0]]], kept[lanes[0]])
    stacked = rows[0].stack(rows, B)
    np.testing.assert_array_equal(stacked.lanes, lanes)
    np.testing.assert_array_equal(stacked.n_returns, n_returns)
    for lane in range(B):
        np.testing.assert_array_equal(stacked.meas[lane][stacked.returned[lane]], kept[lane])
    if truth is not None:  # the true ids travel with their returns
        assert isinstance(stacked, UnlabeledScans)
        for lane in lanes.tolist():
            k = n_returns[lane]
            np.testing.assert_array_equal(stacked.returns.truth[lane, :k], truth[lane, :k])
