"""Particle weights and resampling (seed 004 §3, Table 3-2).

The weight arithmetic is numba kernels over the N particles (:func:`normalise_into`,
:func:`apply_log_likelihood`): log-sum-exp normalisation, the weights themselves and the
effective sample size in one pass, written into preallocated arrays.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray


@kernel
def ess_of(weights: FloatArray) -> float:
    """``N_eff = 1 / Σ w_i²`` for normalised weights (N,) (seed 004 Table 3-2, line 3)."""
    total = 0.0
    for i in range(weights.shape[0]):
        total += weights[i] * weights[i]
    return 1.0 / total


@kernel
def normalise_into(logw: FloatArray, out: FloatArray, weights: FloatArray) -> float:
    """Log-sum-exp normalisation ``out = logw − log Σ exp(logw)``; ``weights = exp(out)``.

    Args:
        logw: (N,) unnormalised log-weights; ``-inf`` allowed, at least one finite.
        out: (N,) receives the normalised log-weights (may be ``logw`` itself).
        weights: (N,) receives ``exp(out)``.

    Returns:
        The effective sample size ``1 / Σ w_i²`` of the normalised weights.
    """
    n = logw.shape[0]
    top = -np.inf
    for i in range(n):
        top = max(top, logw[i])
    total = 0.0
    for i in range(n):
        total += math.exp(logw[i] - top)
    shift = top + math.log(total)
    for i in range(n):
        out[i] = logw[i] - shift
        weights[i] = math.exp(out[i])
    return ess_of(weights)


@kernel
def apply_log_likelihood(
    logw: FloatArray, loglik: FloatArray, scale: float, scratch: FloatArray, weights: FloatArray
) -> float:
    """``log w ← log w + log p(z | particle) / scale``, normalised (eq. 28), in place.

    NaN and ``+inf`` sums count as impossible (``-inf``). If no particle keeps a finite
    log-weight, nothing is written.

    Args:
        logw: (N,) normalised log-weights, updated in place.
        loglik: (N,) log-likelihoods; ``scale`` divides them (tempering λ, 1 for none).
        scratch: (N,) work array.
        weights: (N,) receives ``exp(log w)``.

    Returns:
        The effective sample size of the new weights, or ``-1.0`` if every sum was
        non-finite (the filter diverged; ``logw`` and ``weights`` are unchanged).
    """
    finite = False
    for i in range(logw.shape[0]):
        v = logw[i] + loglik[i] / scale
        if math.isnan(v) or v == np.inf:
            v = -np.inf
        finite = finite or math.isfinite(v)
        scratch[i] = v
    if not finite:
        return -1.0
    return normalise_into(scratch, logw, weights)


def normalise_log_weights(logw: FloatArray) -> FloatArray:
    """Normalise log-weights with log-sum-exp so that ``Σ exp(logw) = 1``.

    Args:
        logw: (N,) unnormalised log-weights; ``-inf`` allowed, at least one finite.

    Returns:
        (N,) normalised log-weights.
    """
    src = np.ascontiguousarray(logw, dtype=float)
    out = np.empty(src.shape)
    normalise_into(src, out, np.empty(src.shape))
    return out


def effective_sample_size(weights: FloatArray) -> float:
    """``N_eff = 1 / Σ w_i²`` for normalised weights (N,) (seed 004 Table 3-2, line 3)."""
    return float(ess_of(np.ascontiguousarray(weights, dtype=float)))


def systematic_resample(weights: FloatArray, rng: np.random.Generator) -> np.ndarray:
    """Systematic resampling: one uniform draw, N evenly spaced pointers.

    Particle i is copied either ``⌊N w_i⌋`` or ``⌈N w_i⌉`` times.

    Args:
        weights: (N,) normalised weights.
        rng: Random generator.

    Returns:
        (N,) int indices of the selected particles, ascending.
    """
    w = np.asarray(weights, dtype=float)
    n = w.shape[0]
    cdf = np.cumsum(w)
    cdf /= cdf[-1]
    cdf[-1] = 1.0
    pointers = (rng.random() + np.arange(n)) / n
    idx = np.searchsorted(cdf, pointers, side="right")
    return np.minimum(idx, n - 1)
