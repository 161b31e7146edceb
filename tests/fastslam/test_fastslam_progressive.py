"""Tests of the progressive correction of the FastSLAM filters (fastslam/progressive.py)."""

from __future__ import annotations

import math

import numpy as np

from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.landmarks import landmark_ekf_update
from estimators.fastslam.progressive import Tempering, ess_after, scan_update, stage_exponent
from estimators.fastslam.state import ParticleState
from quadslam_env.estimation.measurements import LidarScan
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.models.lidar import lidar_measure
from quadslam_env.models.params import vehicle_preset
from quadslam_env.types import EUL

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


def test_scan_update_returns_the_likelihoods_and_leaves_the_weights_to_the_filter() -> None:
    """Without stages: every particle's landmark EKFs are updated as by the batched textbook
    update, its log-likelihood and NIS are returned, and the weights are not touched."""
    est = _wide_cloud(0.0, seed=1)
    s = est.state
    s.set_logw(np.log(np.random.default_rng(2).dirichlet(np.ones(est.n_particles))))
    logw, x, mu0, sigma0 = s.logw.copy(), s.x.copy(), s.mu.copy(), s.sigma.copy()
    z = lidar_measure(np.array([0.3, -0.2, 0.1]), np.eye(3), POLES)
    R = np.diag(SIGMA**2)
    resampled: list[np.ndarray] = []
    tempering = Tempering(1.0, 0.0, 0.5, resampled.append, np.random.default_rng(0))
    result = scan_update(s, np.arange(4), z, R, tempering)
    dcm = dcm_from_euler_batch(x[:, EUL])[:, None]
    ref_mu, ref_sigma, ref_ll, ref_nis = landmark_ekf_update(
        mu0, sigma0, x[:, None, 0:3], dcm, z[None], R
    )
    np.testing.assert_allclose(result.loglik, ref_ll.sum(axis=1), rtol=1e-12)
    np.testing.assert_allclose(result.nis, ref_nis.sum(axis=1), rtol=1e-12)
    np.testing.assert_allclose(s.mu, ref_mu, rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(s.sigma, ref_sigma, rtol=1e-12, atol=1e-18)
    assert (result.remaining, result.stages, resampled) == (1.0, 0, [])
    np.testing.assert_array_equal(s.logw, logw)  # the filter applies the likelihood
    np.testing.assert_array_equal(s.x, x)


def test_each_stage_resamples_through_the_filter_and_is_counted() -> None:
    est = _wide_cloud(0.1, seed=3)
    calls: list[np.ndarray] = []

    def resample(idx: np.ndarray) -> None:
        calls.append(idx)
        est._resample(idx)

    z = lidar_measure(np.array([0.3, -0.2, 0.1]), np.eye(3), POLES)
    tempering = Tempering(1.0, 0.1, 0.5, resample, np.random.default_rng(0))
    result = scan_update(est.state, np.arange(4), z, np.diag(SIGMA**2), tempering)
    assert result.stages > 0 and len(calls) == result.stages
    assert 0.0 < result.remaining <= 1.0
    assert est.n_resamples == result.stages


def test_set_logw_keeps_the_weights_and_the_ess_in_step() -> None:
    state = ParticleState.empty(5)
    assert math.isclose(state.ess, 5.0, rel_tol=1e-14) and np.allclose(state.w, 0.2, rtol=1e-15)
    w = np.array([0.1, 0.2, 0.3, 0.15, 0.25])
    state.set_logw(np.log(w))
    np.testing.assert_allclose(state.w, w, rtol=1e-15)
    assert math.isclose(state.ess, 1.0 / float(np.sum(w * w)), rel_tol=1e-14)
