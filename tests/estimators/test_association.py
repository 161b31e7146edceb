"""Data association: the χ² gate, nearest neighbour and JCBB against exhaustive enumeration."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
from scipy.stats import chi2

from estimators.association import (
    chi2_threshold,
    individual_nis,
    jcbb,
    joint_thresholds,
    nearest_neighbour,
    solve3_nis,
)

PROB = 0.99


def _case(rng: np.random.Generator, m: int, r: int, spread: float) -> tuple[np.ndarray, ...]:
    """A random scan: M predictions with a correlated joint covariance, R returns (some from
    the landmarks, some clutter), innovations and individual NIS."""
    A = rng.standard_normal((3 * m, 3 * m)) * 0.3
    shared = rng.standard_normal((3 * m, 3)) * 0.5  # a common (pose-like) error
    S = A @ A.T + shared @ shared.T + 0.2 * np.eye(3 * m)
    h = rng.uniform(-spread, spread, (m, 3))
    truth = rng.choice(m, size=min(r, m), replace=False)
    err = np.linalg.cholesky(S) @ rng.standard_normal(3 * m)
    z = np.empty((r, 3))
    for i in range(r):
        if i < truth.size and rng.random() < 0.8:
            j = truth[i]
            z[i] = h[j] + err[3 * j : 3 * j + 3]
        else:
            z[i] = rng.uniform(-spread, spread, 3)
    nu = z[:, None, :] - h[None, :, :]
    d2 = np.empty((r, m))
    individual_nis(nu, S, d2)
    return nu, S, d2


def _joint_nis(nu: np.ndarray, S: np.ndarray, pairs: list[tuple[int, int]]) -> float:
    idx = np.concatenate([np.arange(3 * j, 3 * j + 3) for _, j in pairs])
    v = np.concatenate([nu[i, j] for i, j in pairs])
    return float(v @ np.linalg.solve(S[np.ix_(idx, idx)], v))


def _exhaustive(nu: np.ndarray, S: np.ndarray, d2: np.ndarray, gate: float) -> tuple[int, float]:
    """Largest jointly compatible hypothesis by enumeration: (pairings, smallest joint NIS)."""
    r, m = d2.shape
    options = [[-1] + [j for j in range(m) if d2[i, j] <= gate] for i in range(r)]
    best = (0, 0.0)
    for hyp in itertools.product(*options):
        pairs = [(i, j) for i, j in enumerate(hyp) if j >= 0]
        if len({j for _, j in pairs}) < len(pairs) or not pairs:
            continue
        nis = _joint_nis(nu, S, pairs)
        if nis > chi2.ppf(PROB, 3 * len(pairs)):
            continue
        if len(pairs) > best[0] or (len(pairs) == best[0] and nis < best[1]):
            best = (len(pairs), nis)
    return best


def test_thresholds_are_chi2_quantiles() -> None:
    assert chi2_threshold(3, 0.99) == pytest.approx(11.3449, abs=1e-4)
    t = joint_thresholds(4, 0.95)
    assert t[0] == 0.0
    assert t[1:] == pytest.approx([chi2.ppf(0.95, 3 * k) for k in range(1, 5)])
    assert chi2_threshold(6, 1.0) == math.inf


def test_individual_nis_is_the_mahalanobis_distance() -> None:
    rng = np.random.default_rng(0)
    A = rng.standard_normal((6, 6))
    S = A @ A.T + np.eye(6)
    nu = rng.standard_normal(3)
    assert solve3_nis(S, 3, nu) == pytest.approx(nu @ np.linalg.solve(S[3:, 3:], nu))
    assert solve3_nis(-np.eye(3), 0, nu) == math.inf  # not positive definite


@pytest.mark.parametrize("seed", range(60))
def test_jcbb_finds_the_largest_jointly_compatible_hypothesis(seed: int) -> None:
    rng = np.random.default_rng(seed)
    m, r = int(rng.integers(1, 6)), int(rng.integers(1, 6))
    nu, S, d2 = _case(rng, m, r, spread=float(rng.choice([1.0, 3.0])))
    gate = chi2_threshold(3, PROB)
    out = np.empty(r, dtype=np.int64)
    nis = jcbb(nu, S, d2, gate, joint_thresholds(r, PROB), out)
    best_k, best_nis = _exhaustive(nu, S, d2, gate)
    pairs = [(i, int(j)) for i, j in enumerate(out) if j >= 0]
    assert len(pairs) == best_k
    assert len({j for _, j in pairs}) == len(pairs)
    if pairs:
        assert all(d2[i, j] <= gate for i, j in pairs)
        assert nis == pytest.approx(_joint_nis(nu, S, pairs), rel=1e-9)
        assert nis == pytest.approx(best_nis, rel=1e-9)


def test_jcbb_rejects_a_pairing_that_is_only_individually_compatible() -> None:
    """Two close landmarks with strongly correlated predictions (a shared pose error): the
    returns swapped are each individually compatible, but not jointly; JCBB must pair them
    the right way round, nearest neighbour need not."""
    s_pose = np.full((6, 6), 0.0)
    for a in range(2):
        for b in range(2):
            s_pose[3 * a : 3 * a + 3, 3 * b : 3 * b + 3] = np.eye(3)  # fully shared error
    S = s_pose + 0.01 * np.eye(6)
    h = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    shift = np.array([0.6, 0.0, 0.0])  # the common error: both returns moved right
    z = h + shift
    nu = z[:, None, :] - h[None, :, :]
    d2 = np.empty((2, 2))
    individual_nis(nu, S, d2)
    gate = chi2_threshold(3, PROB)
    assert d2[0, 1] <= gate and d2[0, 0] <= gate  # return 0 gates with both landmarks
    nn = np.empty(2, dtype=np.int64)
    nearest_neighbour(d2, gate, nn)
    assert nn[0] == 1  # nearest neighbour takes the wrong (closer) landmark
    out = np.empty(2, dtype=np.int64)
    jcbb(nu, S, d2, gate, joint_thresholds(2, PROB), out)
    assert out.tolist() == [0, 1]


@pytest.mark.parametrize("seed", range(20))
def test_nearest_neighbour_is_the_greedy_assignment(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    _, _, d2 = _case(rng, int(rng.integers(1, 7)), int(rng.integers(1, 7)), spread=2.0)
    gate = chi2_threshold(3, PROB)
    out = np.empty(d2.shape[0], dtype=np.int64)
    nearest_neighbour(d2, gate, out)
    # Enumerated: pairs in increasing distance, each return and landmark at most once.
    want = np.full(d2.shape[0], -1)
    for flat in np.argsort(d2, axis=None, kind="stable"):
        i, j = np.unravel_index(flat, d2.shape)
        if d2[i, j] <= gate and want[i] < 0 and j not in want:
            want[i] = j
    assert out.tolist() == want.tolist()
