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
    sequential_tests,
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


def _no_windows(k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The sequential arguments of ``monitor_scan`` without a sequential test."""
    return np.arange(k), np.zeros((k, 0)), np.zeros(k, dtype=np.int64), np.full((k + 1, 1), np.inf)


def _monitor(S, U, nu, lm, scan, exclude: bool) -> tuple[int, np.ndarray, np.ndarray]:
    """``monitor_scan`` on every landmark: ``(status, keep, sep)``."""
    k = nu.shape[0] // 3
    keep, sep = np.ones(k, dtype=bool), np.empty(4)
    status = monitor_scan(S, U, nu, lm, scan, exclude, 1, keep, sep, *_no_windows(k))
    return status, keep, sep


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


def _sequential(p_fa: float, k: int, window: int) -> MonitorSettings:
    return MonitorSettings(p_fa, True, 1, 1.0, sequential_window=window)


def test_sequential_thresholds_are_the_chi2_quantiles_and_the_budget_is_split():
    """The sequential test of n statistics: χ²_3n(1 − p_fa/(2k)); beside it the one-scan tests
    have half the budget; without it the thresholds are those of the full budget."""
    p_fa, k, window = 0.01, 5, 4
    cfg = _sequential(p_fa, k, window)
    seq = cfg.sequential_thresholds(k)
    assert seq.shape == (k + 1, window + 1)
    assert np.isinf(seq[0]).all() and np.isinf(seq[:, 0]).all()
    for n in range(1, window + 1):
        want = chi2.ppf(1.0 - p_fa / (2.0 * np.arange(1, k + 1)), 3 * n)
        np.testing.assert_allclose(seq[1:, n], want, rtol=1e-9)
    assert cfg.snapshot_p_fa == p_fa / 2
    lm, scan = cfg.landmark_thresholds(k), cfg.scan_thresholds(k)
    np.testing.assert_allclose(lm[1:], chi2.ppf(1.0 - p_fa / (4.0 * np.arange(1, k + 1)), 3))
    np.testing.assert_allclose(scan[1:], chi2.ppf(1.0 - p_fa / 4.0, np.arange(1, 3 * k + 1)))
    off = MonitorSettings(p_fa, True, 1, 1.0)
    assert off.snapshot_p_fa == p_fa and off.sequential_thresholds(k).shape == (k + 1, 1)
    np.testing.assert_array_equal(off.landmark_thresholds(k), _thresholds(p_fa, k)[0])


def test_window_sum_is_the_hand_computed_sum_of_the_last_statistics():
    """Each tested landmark's statistic enters its id's ring of W; the excess is the sum of its
    last min(c, W) statistics over χ²_3n of the landmarks tested; untested ids keep theirs."""
    window, lmax = 3, 4
    thr = _sequential(0.01, 3, window).sequential_thresholds(3)
    stats, count = np.zeros((lmax, window)), np.zeros(lmax, dtype=np.int64)
    ids = np.array([3, 0, 2])
    history: dict[int, list[float]] = {3: [], 0: [], 2: []}
    rng = np.random.default_rng(2)
    for scan in range(6):
        keep = np.array([True, scan % 2 == 0, True])  # id 0 tested every other scan
        t = rng.uniform(0.0, 10.0, 3)
        excess = np.empty(3)
        sequential_tests(t, keep, ids, stats, count, thr, excess)
        kept = int(keep.sum())
        for i, a in zip(np.flatnonzero(keep), range(kept), strict=True):
            history[int(ids[i])].append(float(t[a]))
        for i, j in enumerate(ids.tolist()):
            last = history[j][-window:]
            assert count[j] == len(history[j])
            if keep[i]:
                assert excess[i] == pytest.approx(sum(last) / thr[kept, len(last)], rel=1e-12)
            else:
                assert excess[i] == 0.0
    assert count[1] == 0 and (stats[1] == 0.0).all()


def test_a_sequential_alarm_excludes_the_landmark_the_one_scan_tests_miss():
    """S = I (t_i = |ν_i|²): a landmark whose every t_i is below the one-scan thresholds is
    excluded at the first scan where its window sum crosses χ²_3n, and not before."""
    k, window, p_fa = 2, 4, 1e-3
    cfg = _sequential(p_fa, k, window)
    lm, scan, seq = cfg.landmark_thresholds(k), cfg.scan_thresholds(k), cfg.sequential_thresholds(k)
    S, U = np.eye(3 * k), np.zeros((3 * k, 9))
    value = 0.7 * lm[k]  # t of landmark 1 on every scan; landmark 0 has ν = 0
    nu = np.zeros(3 * k)
    nu[3] = math.sqrt(value)
    sums = np.cumsum(np.full(window, value))
    first = next(n for n in range(1, window + 1) if sums[n - 1] > seq[k, n])  # by hand
    assert first > 1 and value < scan[3 * k]
    stats, count = np.zeros((k, window)), np.zeros(k, dtype=np.int64)
    for n in range(1, first + 1):
        keep, sep = np.ones(k, dtype=bool), np.empty(4)
        status = monitor_scan(S, U, nu, lm, scan, True, 1, keep, sep, np.arange(k), stats, count,
                              seq)  # fmt: skip
        assert stats[1, n - 1] == pytest.approx(value, rel=1e-12) and count[1] == n
        if n < first:
            assert status == FDE_PASS and keep.all()
    assert status == FDE_EXCLUDED and keep.tolist() == [True, False] and sep[3] == 1
    status = monitor_scan(S, U, nu, lm, scan, True, 1, np.ones(k, dtype=bool), sep,
                          *_no_windows(k))  # fmt: skip
    assert status == FDE_PASS  # the one-scan tests alone do not see it


def test_sequential_false_alarm_rate_is_within_its_budget():
    """Fault-free innovations ν ~ N(0, S), independent from scan to scan (a consistent linear
    filter): the sequential tests alone alarm on their half of p_fa, the three tests together
    on at most p_fa. The windows overlap, so alarms come in runs of up to W scans: the bound is
    3 standard deviations of a W-dependent Bernoulli mean, √((2W − 1) p (1 − p) / N)."""
    rng = np.random.default_rng(17)
    k, p_fa, window, runs = 5, 0.02, 3, 40_000
    _, _, _, S, U = _linear_update(rng, k=k)
    cfg = _sequential(p_fa, k, window)
    lm, scan, seq = cfg.landmark_thresholds(k), cfg.scan_thresholds(k), cfg.sequential_thresholds(k)
    off = np.full_like(lm, np.inf), np.full_like(scan, np.inf)
    L = np.linalg.cholesky(S)
    ids, sep = np.arange(k), np.empty(4)
    windows = [(np.zeros((k, window)), np.zeros(k, dtype=np.int64)) for _ in range(2)]
    alarms = np.zeros(2)
    for _ in range(runs):
        nu = L @ rng.standard_normal(3 * k)
        for row, (thr_lm, thr_scan) in enumerate((off, (lm, scan))):
            keep = np.ones(k, dtype=bool)
            status = monitor_scan(S, U, nu, thr_lm, thr_scan, False, 1, keep, sep, ids,
                                  *windows[row], seq)  # fmt: skip
            alarms[row] += status != FDE_PASS
    sequential, total = alarms / runs
    budget = p_fa / 2
    bound = 3.0 * math.sqrt((2 * window - 1) * budget * (1 - budget) / runs)
    assert 0.5 * budget <= sequential <= budget + bound
    assert sequential <= total <= p_fa + 3.0 * math.sqrt((2 * window - 1) * p_fa / runs)


def test_sequential_windows_restart_when_left_out_and_at_reset():
    sigma = np.full(3, 0.01)
    lanes = np.zeros(1, dtype=np.int64)
    meas = np.array([[[0.1, 0.1, 5.0], [0.2, 0.0, 4.0], [-0.2, 0.05, 6.0], [0.0, -0.1, 3.0]]])
    visible = np.ones((1, 4), dtype=bool)
    jumped = meas.copy()
    jumped[0, 2, 2] += 0.5
    ekf = EkfSlamBatch(1, 4)
    ekf.set_monitor(_sequential(1e-3, 4, 3))
    ekf.reset_lanes(lanes, np.zeros((1, 12)), 0.01 * np.eye(12)[None], [None])
    ekf.update(np.zeros(1), lanes, visible, meas, sigma)  # registers the landmarks
    ekf.update(np.full(1, 0.1), lanes, visible, meas, sigma)
    assert ekf.state.seq_stats.shape == (1, 4, 3) and ekf.state.seq_count[0].tolist() == [1] * 4
    ekf.update(np.full(1, 0.2), lanes, visible, jumped, sigma)
    assert ekf.state.seq_count[0].tolist() == [2, 2, 0, 2]  # landmark 2 left out
    ekf.reset_lanes(lanes, np.zeros((1, 12)), 0.01 * np.eye(12)[None], [None])
    assert not ekf.state.seq_count.any() and not ekf.state.seq_stats.any()
