"""Tests of the progressive correction of the FastSLAM filters (fastslam/progressive.py)."""

from __future__ import annotations

import math

import numpy as np

from estimators.fastslam import DynamicFastSLAM
from estimators.fastslam.progressive import ess_after, stage_exponent
from quadslam_env.measurements import LidarScan
from quadslam_env.models import lidar_measure, vehicle_preset

SIGMA = np.array([math.radians(0.1), math.radians(0.1), 0.03])
POLES = np.array([[2.0, 2.0, -1.0], [-2.0, 2.0, -1.0], [-2.0, -2.0, -1.0], [2.0, -2.0, -1.0]])


def test_stage_exponent_is_the_largest_keeping_the_ess() -> None:
    rng = np.random.default_rng(0)
    logw = np.full(400, -math.log(400))
    loglik = -0.5 * (rng.normal(size=400) * 30.0) ** 2
    alpha = stage_exponent(logw, loglik, 1.0, 200.0)
    assert 0.0 < alpha < 1.0
    assert ess_after(logw, loglik, alpha) >= 200.0
    grid = np.linspace(alpha * 1.001, 1.0, 200)  # brute force: nothing larger keeps the ESS
    assert all(ess_after(logw, loglik, a) < 200.0 for a in grid)
    assert stage_exponent(logw, 0.001 * loglik / np.abs(loglik).max(), 1.0, 200.0) == 1.0


def _wide_cloud(progressive_ess: float, seed: int) -> DynamicFastSLAM:
    """A known map and a prior 0.5 m wide per axis: one scan pins the pose to centimetres."""
    est = DynamicFastSLAM(
        vehicle_preset("sadeghzadeh2021"),
        n_particles=500,
        progressive_ess=progressive_ess,
        likelihood_inflation=1.0,
    )
    cov0 = np.diag([0.25] * 3 + [1e-4] * 3 + [1e-8] * 3 + [1e-8] * 3)
    est.reset(
        np.zeros(12), cov0, np.random.default_rng(seed), known_landmarks=(np.arange(4), POLES)
    )
    return est


def test_a_scan_far_narrower_than_the_cloud_is_absorbed_in_stages() -> None:
    truth = np.array([0.3, -0.2, 0.1])
    z = lidar_measure(truth, np.eye(3), POLES)
    scan = LidarScan(0.0, np.arange(4), z, SIGMA)
    err_plain, err_prog, ess_plain = [], [], []
    for seed in range(5):
        plain, prog = _wide_cloud(0.0, seed), _wide_cloud(0.1, seed)
        plain.resample_threshold = 0.0  # keep the weights to read their ESS
        plain.update(scan)
        prog.update(scan)
        ess_plain.append(plain.estimate().diagnostics["ess"][0])
        err_plain.append(np.linalg.norm(plain.estimate().position[0] - truth))
        err_prog.append(np.linalg.norm(prog.estimate().position[0] - truth))
        assert prog.n_progressive_stages > 0
    # Without stages the weights fall on one or two particles, none of them at the truth ...
    assert np.median(ess_plain) < 3.0
    assert np.median(err_plain) > 0.05
    # ... with them the cloud is moved onto the scan (a noise-free scan: posterior σ of mm).
    assert np.median(err_prog) < 0.5 * np.median(err_plain)
    assert np.median(err_prog) < 0.05
