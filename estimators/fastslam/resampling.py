"""Particle weights and resampling (seed 004 §3, Table 3-2)."""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.types import FloatArray


def normalise_log_weights(logw: FloatArray) -> FloatArray:
    """Normalise log-weights with log-sum-exp so that ``Σ exp(logw) = 1``.

    Args:
        logw: (N,) unnormalised log-weights; ``-inf`` allowed, at least one finite.

    Returns:
        (N,) normalised log-weights.
    """
    top = np.max(logw)
    return logw - (top + math.log(float(np.sum(np.exp(logw - top)))))


def effective_sample_size(weights: FloatArray) -> float:
    """``N_eff = 1 / Σ w_i²`` for normalised weights (N,) (seed 004 Table 3-2, line 3)."""
    w = np.asarray(weights, dtype=float)
    return float(1.0 / np.dot(w, w))


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
