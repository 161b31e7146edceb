"""A learned result over its training seeds: the median, the interquartile mean (IQM) with a
95% bootstrap confidence interval, and on how many seeds a claim holds.

The definitions are those of Agarwal et al., "Deep reinforcement learning at the edge of the
statistical precipice" (NeurIPS 2021), as their library ``rliable`` computes them (not a
dependency here): ``rliable.metrics.aggregate_iqm`` is
``scipy.stats.trim_mean(scores, proportiontocut=0.25, axis=None)`` on the runs × tasks score
matrix, and ``rliable.library.get_interval_estimates`` a percentile bootstrap (95%) that
resamples the runs of each task on their own (the stratified bootstrap). A row of a study is
one task, so here:

- **IQM**: the 25% trimmed mean of the training seeds' scores, ``int(0.25 n)`` scores cut from
  each end (scipy's rounding down, rliable's rule): 8 seeds give the mean of the middle 4, 5
  seeds of the middle 3, 2 or 3 seeds the plain mean;
- **CI**: the percentile bootstrap resampling the training seeds with replacement
  (``scipy.stats.bootstrap`` with ``method="percentile"`` on ``scipy.stats.trim_mean(..., 0.25)``,
  :data:`N_RESAMPLES` resamples, seeded: the same seed gives the same interval).

A seed's score is already an aggregate, as a run's is in rliable: its median over the held-out
episodes. Given per-episode scores (training seeds × evaluation episodes), :func:`seed_stats`
takes each seed's median over its episodes and computes the IQM and its CI over the seeds, not
over the pooled seed × episode scores: the episodes of one seed fly one policy, so pooling them
would count each episode as a training run of its own and the interval would describe the
spread of the evaluation episodes, not what another training seed would give.

A claim about a learned row (its score at most a factor times a baseline's, say) is reported as
the number of training seeds on which it holds (:func:`holds_on`, :func:`claim_at_most`).
"""

from __future__ import annotations

import inspect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

TRIM = 0.25
"""The share of the scores cut from each end for the IQM (rliable's ``proportiontocut``)."""
CONFIDENCE = 0.95
N_RESAMPLES = 10_000
"""Bootstrap resamples (rliable's default is 50,000; the percentile endpoints move by far
less between the two than between two sets of training seeds)."""
SEED = 0
"""The bootstrap's seed when none is given: a study's output is the same on every run."""


def iqm(scores: ArrayLike) -> float:
    """The interquartile mean of ``scores`` (all entries pooled; the module docstring)."""
    from scipy.stats import trim_mean

    return float(trim_mean(np.asarray(scores, dtype=float), TRIM, axis=None))


@dataclass(frozen=True)
class SeedStats:
    """A learned row's score over its training seeds.

    Attributes:
        median: The median of the seeds' scores.
        iqm: Their interquartile mean.
        ci_low: Lower end of the bootstrap confidence interval of the IQM.
        ci_high: Its upper end.
        n_seeds: The number of training seeds.
        per_seed: Each seed's score (its median over the episodes when these were given).
        n_episodes: Evaluation episodes per seed (``None``: per-seed scores were given).
        confidence: The interval's confidence level.
        n_resamples: The bootstrap resamples.
    """

    median: float
    iqm: float
    ci_low: float
    ci_high: float
    n_seeds: int
    per_seed: tuple[float, ...]
    n_episodes: int | None = None
    confidence: float = CONFIDENCE
    n_resamples: int = N_RESAMPLES

    def as_dict(self) -> dict[str, Any]:
        """The JSON form (:func:`summary`'s keys, ``undefined`` null)."""
        return {
            "median": self.median,
            "iqm": self.iqm,
            "iqm_ci": [self.ci_low, self.ci_high],
            "confidence": self.confidence,
            "n_seeds": self.n_seeds,
            "per_seed": list(self.per_seed),
            "undefined": None,
        }


def seed_stats(
    scores: ArrayLike,
    rng: int | np.random.Generator | None = None,
    confidence: float = CONFIDENCE,
    n_resamples: int = N_RESAMPLES,
) -> SeedStats:
    """Median, IQM and the bootstrap CI of the IQM over training seeds.

    Args:
        scores: ``(seeds,)`` one score per training seed, or ``(seeds, episodes)`` per-episode
            scores, each seed then scored by its median over its episodes.
        rng: The bootstrap's generator or seed (default :data:`SEED`).
        confidence: The interval's confidence level, in (0, 1).
        n_resamples: Bootstrap resamples, 1 or more.

    Returns:
        The statistics; the same ``scores`` and seed give the same interval.

    Raises:
        ValueError: ``scores`` of another shape, of fewer than 2 seeds (a bootstrap over one
            seed has no spread), empty or not finite, or ``confidence`` or ``n_resamples``
            out of range; the message names the argument and the value.
    """
    from scipy.stats import bootstrap, trim_mean

    per_seed, n_episodes = _per_seed(scores)
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence: got {confidence!r}; allowed: a level in (0, 1)")
    if isinstance(n_resamples, bool) or not isinstance(n_resamples, int) or n_resamples < 1:
        raise ValueError(f"n_resamples: got {n_resamples!r}; allowed: an integer >= 1")
    generator = np.random.default_rng(SEED if rng is None else rng)
    # scipy >= 1.15 names the generator `rng`; older releases `random_state`.
    seeded = "rng" if "rng" in inspect.signature(bootstrap).parameters else "random_state"
    result = bootstrap(
        (per_seed,),
        lambda sample, axis: trim_mean(sample, TRIM, axis=axis),
        n_resamples=n_resamples,
        vectorized=True,
        confidence_level=confidence,
        method="percentile",
        **{seeded: generator},
    )
    return SeedStats(
        median=float(np.median(per_seed)),
        iqm=iqm(per_seed),
        ci_low=float(result.confidence_interval.low),
        ci_high=float(result.confidence_interval.high),
        n_seeds=int(per_seed.size),
        per_seed=tuple(float(v) for v in per_seed),
        n_episodes=n_episodes,
        confidence=confidence,
        n_resamples=n_resamples,
    )


def _per_seed(scores: ArrayLike) -> tuple[np.ndarray, int | None]:
    """``(per-seed scores, episodes per seed or None)`` of :func:`seed_stats`'s ``scores``,
    checked."""
    try:
        arr = np.asarray(scores, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(
            f"scores: got {_shown(scores)}; allowed: numbers, (seeds,) or (seeds, episodes)"
        ) from exc
    if arr.ndim not in (1, 2) or 0 in arr.shape:
        raise ValueError(
            f"scores: got shape {arr.shape}; allowed: (seeds,) or (seeds, episodes), none empty"
        )
    bad = np.argwhere(~np.isfinite(arr))
    if bad.size:
        where = ", ".join(
            f"{name} {i}" for name, i in zip(("seed", "episode"), bad[0], strict=False)
        )
        raise ValueError(
            f"scores: got {arr[tuple(bad[0])]} at {where} of {_shown(scores)}; "
            "allowed: finite numbers"
        )
    if arr.shape[0] < 2:
        raise ValueError(
            f"scores: got {arr.shape[0]} training seed ({_shown(scores)}); allowed: 2 or more "
            "(a bootstrap over one seed has no spread)"
        )
    if arr.ndim == 2:
        return np.median(arr, axis=1), int(arr.shape[1])
    return arr, None


def _shown(value: Any) -> str:
    """``value`` for an error message, at most 80 characters."""
    text = repr(value.tolist() if isinstance(value, np.ndarray) else value)
    return text if len(text) <= 80 else f"{text[:77]}..."


def summary(per_seed: Sequence[float | None], rng: int | None = None) -> dict[str, Any]:
    """:meth:`SeedStats.as_dict` of a study row's per-seed scores, or, where they allow no
    statistics (fewer than 2 seeds, a seed without a value), the same keys with ``None``
    (the median kept for a single seed) and ``undefined`` saying why."""
    values = [math.nan if v is None else float(v) for v in per_seed]
    missing = [i for i, v in enumerate(values) if not math.isfinite(v)]
    reason = None
    if missing:
        reason = f"no value on the training seed(s) at positions {missing} of {len(values)}"
    elif len(values) < 2:
        reason = f"{len(values)} training seed; the IQM and its CI need 2 or more"
    if reason is None:
        return seed_stats(values, rng).as_dict()
    return {
        "median": float(np.median(values)) if values and not missing else None,
        "iqm": None,
        "iqm_ci": None,
        "confidence": CONFIDENCE,
        "n_seeds": len(values),
        "per_seed": [v if math.isfinite(v) else None for v in values],
        "undefined": reason,
    }


@dataclass(frozen=True)
class Holds:
    """On ``k`` of ``n`` training seeds a claim holds."""

    k: int
    n: int

    def __str__(self) -> str:
        return f"{self.k}/{self.n} seeds"


def holds_on(per_seed: Sequence[bool]) -> Holds:
    """On how many training seeds a claim holds, from its truth on each seed.

    Raises:
        ValueError: ``per_seed`` empty or with an entry that is not a bool.
    """
    flags = list(per_seed)
    if not flags:
        raise ValueError("per_seed: got no training seed; allowed: one bool per seed")
    bad = next((f for f in flags if not isinstance(f, bool | np.bool_)), None)
    if bad is not None:
        raise ValueError(f"per_seed: got {bad!r} in {_shown(flags)}; allowed: bools")
    return Holds(sum(bool(f) for f in flags), len(flags))


def claim_at_most(
    text: str, per_seed: Sequence[float | None], baseline: float | None, factor: float = 1.0
) -> dict[str, Any]:
    """The claim "a seed's score is at most ``factor`` × ``baseline``" on each training seed.

    A seed without a score (``None``, NaN) does not count as holding; without a baseline value
    the claim is undefined (``per_seed`` and ``holds`` ``None``).

    Args:
        text: The claim in words, for the report.
        per_seed: Each training seed's score (lower is better).
        baseline: The baseline's score on the same episodes.
        factor: The claim's factor (0.9: at least 10% better than the baseline).

    Returns:
        ``{"claim", "baseline", "factor", "per_seed", "holds_on", "n_seeds", "holds"}``.
    """
    out: dict[str, Any] = {"claim": text, "baseline": baseline, "factor": factor}
    if baseline is None or not math.isfinite(baseline):
        undefined = {"per_seed": None, "holds_on": None, "n_seeds": len(per_seed), "holds": None}
        return out | {"baseline": None} | undefined
    bound = factor * baseline
    flags = [v is not None and math.isfinite(v) and v <= bound for v in per_seed]
    held = holds_on(flags)
    return out | {"per_seed": flags, "holds_on": held.k, "n_seeds": held.n, "holds": str(held)}


def ci_cell(stats: dict[str, Any], fmt: str = "{:.3f}") -> str:
    """``IQM [low, high]`` of a :func:`summary` for a text table (``–`` when undefined)."""
    if stats.get("iqm") is None:
        return "–"
    low, high = stats["iqm_ci"]
    return f"{fmt.format(stats['iqm'])} [{fmt.format(low)}, {fmt.format(high)}]"
