"""Learned results over training seeds: the IQM, its bootstrap CI and "holds on k of n seeds"
against hand-computed values and rliable's definition."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from scipy.stats import trim_mean

from agents.evaluation.seed_stats import (
    claim_at_most,
    holds_on,
    iqm,
    seed_stats,
    summary,
)


def test_iqm_of_eight_values_is_the_mean_of_the_middle_four() -> None:
    x = [10.0, 1.0, 7.0, 3.0, 100.0, 5.0, -50.0, 4.0]  # sorted: -50 1 | 3 4 5 7 | 10 100
    assert iqm(x) == pytest.approx((3 + 4 + 5 + 7) / 4)
    assert iqm(x) == pytest.approx(trim_mean(x, 0.25))


@pytest.mark.parametrize(
    ("x", "want"),
    [
        ([100.0, 1.0, 2.0, 3.0, 4.0], (2 + 3 + 4) / 3),  # int(1.25) = 1 cut from each end
        ([1.0, 2.0, 3.0, 4.0, 5.0, 600.0], (2 + 3 + 4 + 5) / 4),  # int(1.5) = 1
        ([0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 700.0], (1 + 2 + 3 + 4 + 5) / 5),  # int(1.75) = 1
        ([1.0, 2.0, 30.0], 11.0),  # int(0.75) = 0: the plain mean
        ([1.0, 3.0], 2.0),
    ],
)
def test_iqm_for_n_not_divisible_by_4_is_rliables(x: list[float], want: float) -> None:
    """rliable's ``metrics.aggregate_iqm(scores)`` is, in full,
    ``scipy.stats.trim_mean(scores, proportiontocut=0.25, axis=None)``: ``int(0.25 n)`` scores
    cut from each end of the flattened runs × tasks matrix."""
    assert iqm(x) == pytest.approx(want)
    assert iqm(x) == trim_mean(np.array(x)[:, None], proportiontocut=0.25, axis=None)


def test_iqm_of_a_runs_by_tasks_matrix_pools_every_score() -> None:
    scores = np.arange(12.0).reshape(4, 3) ** 2
    assert iqm(scores) == pytest.approx(np.mean(np.sort(scores.ravel())[3:9]))


def test_two_seeds_give_their_mean_and_the_interval_between_them() -> None:
    """Resampling two seeds gives (a, a), (a, b), (b, a), (b, b) with equal chances: the mean is
    a with probability 1/4 and b with 1/4, so the 2.5% and 97.5% percentiles are a and b."""
    stats = seed_stats([0.3, 0.1])
    assert [stats.median, stats.iqm] == pytest.approx([0.2, 0.2])
    assert [stats.ci_low, stats.ci_high] == pytest.approx([0.1, 0.3])
    assert stats.n_seeds == 2 and stats.per_seed == (0.3, 0.1) and stats.n_episodes is None
    same = seed_stats([0.2, 0.2, 0.2])
    assert [same.ci_low, same.iqm, same.ci_high] == pytest.approx([0.2] * 3)


def test_the_ci_covers_the_true_iqm_of_a_normal_sample() -> None:
    """200 samples of 20 from N(3, 2²), whose IQM is its mean 3 (a symmetric distribution): the
    95% interval holds 3 in 90–99% of them (the percentile bootstrap runs a little short of its
    nominal level on small samples)."""
    rng = np.random.default_rng(0)
    hits = 0
    for _ in range(200):
        stats = seed_stats(rng.normal(3.0, 2.0, 20), rng, n_resamples=2000)
        hits += stats.ci_low <= 3.0 <= stats.ci_high
    assert 0.90 <= hits / 200 <= 0.99


def test_the_same_seed_gives_the_same_interval() -> None:
    x = np.random.default_rng(1).normal(0.1, 0.02, 12)
    first, again = seed_stats(x, 7), seed_stats(x, np.random.default_rng(7))
    assert first == again == seed_stats(x, 7)
    assert seed_stats(x) == seed_stats(x, 0)  # the default seed
    other = seed_stats(x, 8)  # another seed: other resamples (the test can fail)
    assert (other.iqm, other.median) == (first.iqm, first.median)
    assert (other.ci_low, other.ci_high) != (first.ci_low, first.ci_high)


def test_per_episode_scores_are_scored_per_seed_by_their_median() -> None:
    episodes = [[0.1, 0.5, 0.2], [0.4, 0.3, 0.9], [0.6, 0.7, 0.8]]
    stats = seed_stats(episodes, 3)
    assert stats.per_seed == (0.2, 0.4, 0.7) and stats.n_episodes == 3
    by_seed = seed_stats([0.2, 0.4, 0.7], 3)
    assert (stats.iqm, stats.ci_low, stats.ci_high) == (by_seed.iqm, by_seed.ci_low,
                                                        by_seed.ci_high)  # fmt: skip


@pytest.mark.parametrize(
    ("scores", "match"),
    [
        ([0.1], r"^scores: got 1 training seed \(\[0.1\]\); allowed: 2 or more"),
        ([[0.1, 0.2]], r"^scores: got 1 training seed"),
        ([0.1, math.nan, 0.2], r"^scores: got nan at seed 1 of \[0.1, nan, 0.2\]; allowed: finite"),
        ([0.1, math.inf], r"^scores: got inf at seed 1"),
        ([[0.1, 0.2], [0.3, math.nan]], r"^scores: got nan at seed 1, episode 1 of"),
        ([], r"^scores: got shape \(0,\)"),
        ([[[0.1]], [[0.2]]], r"^scores: got shape \(2, 1, 1\)"),
        (["a", "b"], r"^scores: got \['a', 'b'\]; allowed: numbers"),
    ],
)
def test_bad_scores_are_a_clear_error(scores: object, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        seed_stats(scores)  # type: ignore[arg-type]


def test_bad_bootstrap_settings_are_a_clear_error() -> None:
    with pytest.raises(ValueError, match=r"^confidence: got 1.0; allowed"):
        seed_stats([0.1, 0.2], confidence=1.0)
    with pytest.raises(ValueError, match=r"^n_resamples: got 0; allowed"):
        seed_stats([0.1, 0.2], n_resamples=0)


def test_holds_on_counts_the_seeds() -> None:
    flags: list[Any] = [True, False, True, np.bool_(True), False]
    held = holds_on(flags)
    assert (held.k, held.n, str(held)) == (3, 5, "3/5 seeds")
    with pytest.raises(ValueError, match=r"^per_seed: got no training seed"):
        holds_on([])
    with pytest.raises(ValueError, match=r"^per_seed: got 1 in \[True, 1\]; allowed: bools"):
        holds_on([True, 1])  # type: ignore[list-item]


def test_a_claim_holds_where_a_seed_is_at_most_the_factor_times_the_baseline() -> None:
    got = claim_at_most("<= 0.9 x dflqr", [0.08, 0.09, 0.095, None, 0.05], 0.1, 0.9)
    assert got["per_seed"] == [True, True, False, False, True]  # 0.09 <= 0.09; None: not shown
    assert (got["holds_on"], got["n_seeds"], got["holds"]) == (3, 5, "3/5 seeds")
    assert got["claim"] == "<= 0.9 x dflqr" and got["baseline"] == 0.1 and got["factor"] == 0.9
    undefined = claim_at_most("<= 1 x lookat", [0.1, 0.2], None)
    assert undefined["per_seed"] is None and undefined["holds"] is None
    assert undefined["n_seeds"] == 2 and undefined["baseline"] is None


def test_summary_is_the_statistics_or_says_why_there_are_none() -> None:
    values = [0.12, 0.1, 0.11, 0.14, 0.09]
    got = summary(values)
    stats = seed_stats(values)
    assert got == {
        "median": stats.median,
        "iqm": stats.iqm,
        "iqm_ci": [stats.ci_low, stats.ci_high],
        "confidence": 0.95,
        "n_seeds": 5,
        "per_seed": values,
        "undefined": None,
    }
    assert got["iqm"] == pytest.approx((0.1 + 0.11 + 0.12) / 3)
    one = summary([0.1])
    assert one["iqm"] is None and one["iqm_ci"] is None and "need 2 or more" in one["undefined"]
    assert one["median"] == 0.1 and one["n_seeds"] == 1
    gap = summary([0.1, None, math.nan])
    assert gap["per_seed"] == [0.1, None, None] and "[1, 2] of 3" in gap["undefined"]
    assert gap["median"] is None and summary([None])["median"] is None
    assert set(gap) == set(got)
