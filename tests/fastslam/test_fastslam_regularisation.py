"""Tests of the regularised resampling of the FastSLAM filters against independent facts."""

from __future__ import annotations

import math

import numpy as np

from estimators.fastslam.dynamic import DynamicFastSLAM
from estimators.fastslam.resampling import regularisation_bandwidth, regularisation_jitter
from quadslam_env.models.params import vehicle_preset


def test_bandwidth_in_one_dimension_is_silvermans_rule() -> None:
    # Silverman (1986), eq. 3.28: h = (4/3)^{1/5} σ N^{-1/5} ≈ 1.06 σ N^{-1/5} for d = 1.
    for n in (10, 500, 10_000):
        assert math.isclose(regularisation_bandwidth(n, 1), 1.0592 * n ** (-0.2), rel_tol=1e-4)
    # It shrinks with N and, for fixed N, grows with d towards 1.
    assert regularisation_bandwidth(1000, 12) < regularisation_bandwidth(100, 12)
    assert regularisation_bandwidth(500, 1) < regularisation_bandwidth(500, 12) < 1.0


def test_jitter_covariance_is_h_squared_times_the_particle_covariance() -> None:
    rng = np.random.default_rng(0)
    A = rng.normal(size=(4, 4))
    cov = A @ A.T
    cov[3, :] = cov[:, 3] = 0.0  # a singular covariance is allowed: no jitter there
    jitter = regularisation_jitter(cov, 0.4, 200_000, np.random.default_rng(1))
    np.testing.assert_allclose(np.cov(jitter.T), 0.16 * cov, atol=0.01 * np.abs(cov).max())
    assert np.all(jitter[:, 3] == 0.0)


def _filter(n: int) -> DynamicFastSLAM:
    est = DynamicFastSLAM(
        vehicle_preset("sadeghzadeh2021"), n_particles=n, regularisation=1.0, anchor_gauge=False
    )
    est.reset(np.zeros(12), np.diag([1e-2] * 3 + [1e-4] * 9), np.random.default_rng(3))
    return est


def test_filter_regularisation_moves_the_copies_of_one_particle_by_the_shrunk_kernel() -> None:
    n = 4000
    est = _filter(n)
    before = np.cov(est.state.x.T, bias=True)
    mean, centre = est.state.x.mean(axis=0), est.state.x[7].copy()
    est._resample(np.full(n, 7))  # every particle a copy of particle 7
    h = regularisation_bandwidth(n, 9)
    a = math.sqrt(1.0 - h * h)
    after = np.cov(est.state.x.T, bias=True)
    np.testing.assert_allclose(np.diag(after)[0:9], h**2 * np.diag(before)[0:9], rtol=0.1)
    assert np.all(np.ptp(est.state.x[:, 9:12], axis=0) == 0.0)  # ω is copied, not moved
    sem = h * np.sqrt(np.diag(before)[0:9] / n)  # Liu–West: centred on x̄ + a (x_7 − x̄)
    assert np.all(
        np.abs(est.state.x.mean(axis=0)[0:9] - (mean + a * (centre - mean))[0:9]) < 5 * sem
    )
    assert np.all(est.lineage == 7)


def test_filter_regularisation_keeps_the_cloud_covariance() -> None:
    # Uniform weights and every particle kept once: a² Σ + h² Σ = Σ, not (1 + h²) Σ.
    n = 4000
    est = _filter(n)
    before = np.cov(est.state.x[:, 0:9].T, bias=True)
    for _ in range(5):
        est._resample(np.arange(n))
    after = np.cov(est.state.x[:, 0:9].T, bias=True)
    np.testing.assert_allclose(np.diag(after), np.diag(before), rtol=0.15)
    h = regularisation_bandwidth(n, 9)
    assert np.all(np.diag(after) < (1.0 + h * h) ** 2 * np.diag(before))
