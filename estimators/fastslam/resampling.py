"""Particle weights and resampling (seed 004 §3, Table 3-2).

The weight arithmetic is numba kernels over the N particles (:func:`normalise_into`,
:func:`apply_log_likelihood`): log-sum-exp normalisation, the weights themselves and the
effective sample size in one pass, written into preallocated arrays.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.models.linalg import psd_sqrt
from quadslam_env.types import EUL, POSE_DIM, FloatArray


@kernel
def ess_of(weights: FloatArray) -> float:
    """``N_eff = 1 / Σ w_i²`` for normalised weights (N,) (seed 004 Table 3-2, line 3).

    Capped at N: for equal weights the rounded sum can fall an ulp below 1/N.
    """
    total = 0.0
    for i in range(weights.shape[0]):
        total += weights[i] * weights[i]
    return min(1.0 / total, float(weights.shape[0]))


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


def regularisation_bandwidth(n: int, dim: int) -> float:
    """Optimal bandwidth of the Gaussian kernel of a regularised particle filter.

    ``h_opt = A N^{−1/(d+4)}`` with ``A = (4 / (d + 2))^{1/(d+4)}`` (Musso, Oudjane and Le Gland,
    *Improving regularised particle filters*, in Doucet, de Freitas and Gordon (eds.), Sequential
    Monte Carlo Methods in Practice, 2001, §12.2.2): the kernel width that minimises the mean
    integrated squared error of the kernel density estimate for a Gaussian density.

    Args:
        n: Number of particles N ≥ 1. dim: State dimension d ≥ 1.

    Returns:
        ``h_opt`` (dimensionless, a factor on the particle covariance's square root).
    """
    return (4.0 / (dim + 2.0)) ** (1.0 / (dim + 4.0)) * n ** (-1.0 / (dim + 4.0))


def regularisation_jitter(
    cov: FloatArray, h: float, n: int, rng: np.random.Generator
) -> FloatArray:
    """Draws of the post-resampling kernel of a regularised particle filter.

    After resampling, each particle is moved by ``h D ε``, ``ε ~ N(0, I)``, with ``D Dᵀ`` the
    weighted particle covariance before resampling (Musso et al. 2001, Algorithm 12.2): the new
    particles are a sample of the Gaussian kernel density estimate of the posterior instead of
    copies of the old ones.

    Args:
        cov: (d, d) weighted particle covariance (symmetric PSD; singular allowed).
        h: Bandwidth (:func:`regularisation_bandwidth` times a user factor).
        n: Number of draws. rng: Random generator.

    Returns:
        (n, d) jitter with covariance ``h² cov``.
    """
    d = cov.shape[0]
    return h * (rng.standard_normal((n, d)) @ psd_sqrt(cov).T)


def pose_moments(x: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Weighted mean, deviations and covariance of the pose ``(ρ, v_B, Λ)`` of particles.

    Args:
        x: (N, ≥9) particle states. w: (N,) normalised weights.

    Returns:
        ``(mean (9,), dev (N, 9), cov (9, 9))``: the Euler angles' mean is circular and their
        deviations are wrapped to (-π, π].
    """
    pose = x[:, :POSE_DIM]
    mean = w @ pose
    mean[EUL] = np.arctan2(w @ np.sin(pose[:, EUL]), w @ np.cos(pose[:, EUL]))
    dev = pose - mean
    dev[:, EUL] = (dev[:, EUL] + np.pi) % (2.0 * np.pi) - np.pi
    return mean, dev, (dev * w[:, None]).T @ dev


def regularise_pose(
    x: FloatArray, idx: np.ndarray, w: FloatArray, h: float, rng: np.random.Generator
) -> FloatArray:
    """The resampled particles ``x[idx]`` with their pose moved by a shrunk Gaussian kernel.

    Each selected particle's pose becomes ``x̄ + a (x_i − x̄) + h D ε`` with ``D Dᵀ`` the weighted
    pose covariance before resampling, ``ε ~ N(0, I)`` and ``a = √(1 − h²)``: the kernel of the
    regularised particle filter (Musso et al. 2001) with the shrinkage of Liu and West
    (*Combined parameter and state estimation in simulation-based filtering*, 2001, §3.3), which
    keeps the cloud's mean and covariance (``a² Σ + h² Σ = Σ``) instead of inflating it by
    ``1 + h²`` at every resampling. The other states (ω) are copied unchanged: the dynamic
    filter identifies the gyro bias from ω against the dynamics, which a kernel on ω would blur.

    Args:
        x: (N, 12) particles before resampling. idx: (N,) selected indices. w: (N,) their
            normalised weights. h: Bandwidth in [0, 1]. rng: Random generator.

    Returns:
        (N, 12) the new particles (a fresh array; angles wrapped).
    """
    if not 0.0 <= h <= 1.0:
        raise ValueError(f"regularise_pose: bandwidth h must be in [0, 1], got {h!r}")
    mean, dev, cov = pose_moments(x, w)
    out = x[idx]
    a = math.sqrt(1.0 - h * h)
    out[:, :POSE_DIM] = mean + a * dev[idx] + regularisation_jitter(cov, h, idx.shape[0], rng)
    out[:, EUL] = (out[:, EUL] + np.pi) % (2.0 * np.pi) - np.pi
    return out
