"""The integrity monitor of EKF-SLAM (estimators/ekf/fde.py) and the protection levels
(quadslam_env/estimation/integrity.py), against brute force on a linear-Gaussian update."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.stats import chi2, norm

from estimators.ekf.fde import (
    FDE_DETECTED,
    FDE_EXCLUDED,
    FDE_PASS,
    FDE_UNRESOLVED,
    landmark_tests,
    monitor_scan,
    separation_variances,
    subset_inverse,
)
from estimators.ekf.filter import EkfSlamBatch
from quadslam_env.estimation.integrity import LevelFactors, MonitorSettings, protection_levels


def _linear_update(rng: np.random.Generator, n: int = 12, k: int = 4):
    """A random prior P (n, n), a measurement model H (3k, n) with noise R, and S, U."""
    A = rng.standard_normal((n, n))
    P = A @ A.T / n + 0.1 * np.eye(n)
    H = rng.standard_normal((3 * k, n))
    R = np.diag(rng.uniform(0.05, 0.2, 3 * k))
    S = H @ P @ H.T + R
    return P, H, R, S, H @ P


def _posterior(P, H, S, rows):
    """Posterior covariance and gain of the Kalman update with the measurement rows ``rows``."""
    Hs, Ss = H[rows], S[np.ix_(rows, rows)]
    K = P @ Hs.T @ np.linalg.inv(Ss)
    return P - K @ Hs @ P, K


def test_separation_equals_subset_solutions_brute_force():
    """D_i = P_(i) − P and t_i = q − q_(i) (the drop of the NIS), for every landmark i."""
    rng = np.random.default_rng(3)
    k = 4
    P, H, _, S, U = _linear_update(rng, k=k)
    nu = rng.standard_normal(3 * k)
    keep = np.ones(k, dtype=bool)
    idx = np.empty(3 * k, dtype=np.int64)
    Sigma = np.empty((3 * k, 3 * k))
    m = subset_inverse(S, keep, idx, Sigma)
    assert m == 3 * k
    np.testing.assert_allclose(Sigma, np.linalg.inv(S), rtol=1e-10, atol=1e-12)
    t = np.empty(k)
    q = landmark_tests(Sigma, m, nu, idx, t)
    all_rows = np.arange(3 * k)
    assert q == pytest.approx(nu @ np.linalg.solve(S, nu), rel=1e-10)
    P0, K0 = _posterior(P, H, S, all_rows)
    worst = np.zeros(3)
    for i in range(k):
        rows = np.delete(all_rows, np.arange(3 * i, 3 * i + 3))
        Pi, Ki = _posterior(P, H, S, rows)
        q_i = nu[rows] @ np.linalg.solve(S[np.ix_(rows, rows)], nu[rows])
        assert t[i] == pytest.approx(q - q_i, rel=1e-9)
        D = Pi - P0
        delta = K0 @ nu - Ki @ nu[rows]
        # Δ_iᵀ D_i⁺ Δ_i = t_i: the landmark test is the χ² of the solution separation
        assert delta @ np.linalg.pinv(D, rcond=1e-10) @ delta == pytest.approx(t[i], rel=1e-6)
        worst = np.maximum(worst, np.diag(D)[:3])
    sep = np.empty(3)
    separation_variances(Sigma, m, U, idx, sep)
    np.testing.assert_allclose(sep, worst, rtol=1e-9)


def _thresholds(p_fa: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    cfg = MonitorSettings(p_fa=p_fa, exclude=True, max_exclusions=1, readmit_s=1.0)
    return cfg.landmark_thresholds(k), cfg.scan_thresholds(k)


def _monitor(S, U, nu, lm, scan, exclude: bool) -> tuple[int, np.ndarray, np.ndarray]:
    """``monitor_scan`` on every landmark: ``(status, keep, sep)``."""
    keep, sep = np.ones(nu.shape[0] // 3, dtype=bool), np.empty(4)
    return monitor_scan(S, U, nu, lm, scan, exclude, 1, keep, sep), keep, sep


def test_thresholds_are_the_chi2_quantiles():
    lm, scan = _thresholds(0.01, 5)
    assert math.isinf(lm[0]) and math.isinf(scan[0])
    np.testing.assert_allclose(lm[1:], chi2.isf(0.01 / (2 * np.arange(1, 6)), 3), rtol=1e-10)
    np.testing.assert_allclose(scan[1:], chi2.isf(0.005, np.arange(1, 16)), rtol=1e-10)


def test_false_alarm_rate_is_within_the_budget():
    """Fault-free innovations ν ~ N(0, S): the tests alarm on at most p_fa of the scans (the
    Bonferroni split) and on more than half of it (the scan and landmark tests overlap)."""
    rng = np.random.default_rng(11)
    k, p_fa, runs = 5, 0.02, 20_000
    _, _, _, S, U = _linear_update(rng, k=k)
    lm, scan = _thresholds(p_fa, k)
    L = np.linalg.cholesky(S)
    alarms = 0
    for _ in range(runs):
        nu = L @ rng.standard_normal(3 * k)
        alarms += _monitor(S, U, nu, lm, scan, False)[0] != FDE_PASS
    rate = alarms / runs
    half_width = 3.0 * math.sqrt(p_fa * (1 - p_fa) / runs)
    assert 0.5 * p_fa <= rate <= p_fa + half_width


def test_a_faulty_landmark_is_excluded_and_all_faulty_is_unresolved():
    rng = np.random.default_rng(5)
    k = 5
    _, _, _, S, U = _linear_update(rng, k=k)
    lm, scan = _thresholds(1e-3, k)
    L = np.linalg.cholesky(S)
    nu = L @ rng.standard_normal(3 * k)
    status, keep, sep = _monitor(S, U, nu, lm, scan, True)
    assert status == FDE_PASS and keep.all() and sep[3] == k
    faulty = nu.copy()
    faulty[6:9] += 30.0 * np.sqrt(np.diag(S)[6:9])  # landmark 2
    status, keep, _ = _monitor(S, U, faulty, lm, scan, False)
    assert status == FDE_DETECTED and keep.all()
    status, keep, sep = _monitor(S, U, faulty, lm, scan, True)
    assert status == FDE_EXCLUDED
    assert keep.tolist() == [True, True, False, True, True] and sep[3] == k - 1
    everywhere = nu + 30.0 * np.sqrt(np.diag(S)) * rng.choice([-1.0, 1.0], 3 * k)
    status, keep, sep = _monitor(S, U, everywhere, lm, scan, True)
    assert status == FDE_UNRESOLVED and not keep.any() and (sep == 0.0).all()


def test_protection_levels_analytic():
    """k = 0: PL = K σ per axis with K = Φ⁻¹(1 − p/8) (N, E) and Φ⁻¹(1 − p/4) (D), HPL their
    root-sum-square; with separations the worst hypothesis' √(T D) + K √(σ² + D)."""
    var = np.array([[0.04, 0.09, 0.01], [0.04, 0.09, 0.01]])
    sep = np.array([[0.0, 0.0, 0.0], [0.01, 0.02, 0.005]])
    hyp = np.array([0.0, 4.0])
    p_fa, p_hmi = 1e-3, 1e-4
    pose_cov = np.stack([np.diag(v) for v in var])
    hpl, vpl = protection_levels(pose_cov, sep.T, hyp, LevelFactors(p_fa, p_hmi))
    k_h, k_v = norm.isf(p_hmi / 8), norm.isf(p_hmi / 4)
    assert hpl[0] == pytest.approx(k_h * math.hypot(0.2, 0.3), rel=1e-12)
    assert vpl[0] == pytest.approx(k_v * 0.1, rel=1e-12)
    T = chi2.isf(p_fa / 8, 3)
    k_h, k_v = norm.isf(p_hmi / 40), norm.isf(p_hmi / 20)
    pl = [
        math.sqrt(T * d) + kk * math.sqrt(v + d)
        for v, d, kk in zip(var[1], sep[1], (k_h, k_h, k_v), strict=True)
    ]
    assert hpl[1] == pytest.approx(math.hypot(pl[0], pl[1]), rel=1e-12)
    assert vpl[1] == pytest.approx(pl[2], rel=1e-12)


def test_monitor_off_leaves_the_filter_unchanged_and_excluded_landmarks_are_dropped():
    """Without a monitor the update is the gated one; with one, a landmark whose range jumps
    is left out of the update, dropped from the map and not re-registered until readmitted."""
    sigma = np.full(3, 0.01)
    lanes = np.zeros(1, dtype=np.int64)
    meas = np.array([[[0.1, 0.1, 5.0], [0.2, 0.0, 4.0], [-0.2, 0.05, 6.0], [0.0, -0.1, 3.0]]])
    visible = np.ones((1, 4), dtype=bool)
    jumped = meas.copy()
    jumped[0, 2, 2] += 0.5
    runs = {}
    for monitor in (None, MonitorSettings(1e-3, True, 1, 0.25)):
        ekf = EkfSlamBatch(1, 4)
        ekf.set_monitor(monitor)
        ekf.reset_lanes(lanes, np.zeros((1, 12)), 0.01 * np.eye(12)[None], [None])
        ekf.update(np.zeros(1), lanes, visible, meas, sigma)
        ekf.update(np.full(1, 0.1), lanes, visible, jumped, sigma)
        diag = {key: float(v[0]) for key, v in ekf.estimate().diagnostics.items()}
        runs[monitor is None] = ekf.state.mapped.copy(), diag
        if monitor is not None:
            ekf.update(np.full(1, 0.2), lanes, visible, meas, sigma)  # still left out
            assert not ekf.state.mapped[0, 2]
            ekf.update(np.full(1, 0.4), lanes, visible, meas, sigma)  # readmitted: registered
            assert ekf.state.mapped[0, 2]
    mapped, diag = runs[True]
    assert mapped.all() and diag["fde_tests"] == 0 and diag["n_rejected"] == 1
    mapped, diag = runs[False]
    assert mapped[0].tolist() == [True, True, False, True]
    assert diag["fde_alarms"] == 1 and diag["fde_exclusions"] == 1
