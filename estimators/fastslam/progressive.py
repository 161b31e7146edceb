"""Progressive correction of a scan whose likelihood is far narrower than the particle cloud.

After landmarks have been out of view, the particle cloud has spread by the dead-reckoning drift
(metres) while one scan pins the pose to centimetres. Weighting with the full likelihood then
leaves the few particles nearest the posterior, often none of them near it: after resampling
the whole set is copies of the least bad particle, with a spread of centimetres and an error of
metres, and the filter never recovers (measured on ``fastslam_out_of_view_600s`` and on the
600 s helix, docs/reproducing.md). This is the textbook failure of importance sampling from a
prior much wider than the likelihood.

The remedy is progressive correction (Musso, Oudjane and Le Gland, *Improving regularised
particle filters*, in Sequential Monte Carlo Methods in Practice, 2001, §12.4; Oudjane and
Musso, *Progressive correction for regularized particle filters*, FUSION 2000): the likelihood
``p(z|x)`` is applied as ``p(z|x)^{α_1} ⋯ p(z|x)^{α_K}``, ``Σ α_k = 1``. Each exponent is the
largest that keeps the effective sample size at the target; after each stage the particles are
resampled and moved by the regularised-PF kernel (:func:`.resampling.regularisation_jitter`,
bandwidth ``h_opt`` for the 9 pose states ``(ρ, v_B, Λ)``, covariance the weighted cloud's), so
the cloud contracts towards the posterior in steps it can represent. The landmark EKFs are
updated once, after the last stage, at the particles' final poses (the exponents only split the
weighting). ω and the bias means are not moved (their identification rests on the dynamics).

The stages run only when the full scan would leave fewer than ``progressive_ess``·N effective
particles; otherwise the scan is processed as without them.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from estimators.fastslam.landmarks import landmark_ekf_particles
from estimators.fastslam.process import wrap_euler_rows
from estimators.fastslam.resampling import (
    normalise_into,
    normalise_log_weights,
    regularisation_bandwidth,
    regularisation_jitter,
    systematic_resample,
)
from quadslam_env.models.frames import wrap_angle
from quadslam_env.types import EUL, POSE_DIM, FloatArray

MAX_STAGES = 30
"""Tempered stages per scan at most; the rest of the likelihood is then applied at once."""


def scan_loglik(
    x: FloatArray, mu: FloatArray, sigma: FloatArray, slots: np.ndarray, meas: FloatArray,
    R: FloatArray, loglik: FloatArray, nis: FloatArray,
) -> None:  # fmt: skip
    """Each particle's LiDAR log-likelihood of a scan without changing its landmark EKFs.

    Args:
        x: (N, 12) particle states. mu: (N, L, 3), sigma: (N, L, 3, 3) landmark EKFs (read only).
        slots: (k,) observed slots. meas: (k, 3) their measurements. R: (3, 3) noise.
        loglik: (N,) receives ``Σ_j log N(ν_j; 0, S_j)``. nis: (N,) receives ``Σ_j ν_jᵀS_j⁻¹ν_j``.
    """
    k = slots.shape[0]
    landmark_ekf_particles(
        x, mu[:, slots].copy(), sigma[:, slots].copy(), np.arange(k), meas, R, loglik, nis
    )


def ess_after(logw: FloatArray, loglik: FloatArray, alpha: float) -> float:
    """The effective sample size of the weights ``∝ exp(log w + α·loglik)`` (N,)."""
    v = logw + alpha * loglik
    v = np.where(np.isfinite(v), v, -np.inf)
    out, w = np.empty(v.shape), np.empty(v.shape)
    if not np.any(np.isfinite(v)):
        return 0.0
    return float(normalise_into(v, out, w))


def stage_exponent(logw: FloatArray, loglik: FloatArray, remaining: float, target: float) -> float:
    """The largest ``α ∈ (0, remaining]`` with ``ESS(log w + α·loglik) ≥ target`` (bisection).

    The ESS falls monotonically in α for a fixed log-likelihood in practice; 40 bisection steps
    resolve α to ``remaining·2⁻⁴⁰``.

    Args:
        logw: (N,) normalised log-weights. loglik: (N,) tempered log-likelihoods.
        remaining: The share of the likelihood not yet applied, in (0, 1].
        target: ESS target in particles.

    Returns:
        α (``remaining`` if the whole rest keeps the ESS at the target).
    """
    if ess_after(logw, loglik, remaining) >= target:
        return remaining
    lo, hi = 0.0, remaining
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if ess_after(logw, loglik, mid) >= target:
            lo = mid
        else:
            hi = mid
    return max(lo, remaining * 2.0**-40)


def pose_covariance(x: FloatArray, w: FloatArray) -> FloatArray:
    """The weighted covariance (9, 9) of the pose states ``(ρ, v_B, Λ)`` of particles (N, 12).

    Args:
        x: (N, 12) particles. w: (N,) normalised weights.

    Returns:
        ``Σ_i w_i d_i d_iᵀ`` with ``d_i`` the deviation from the weighted mean (angles wrapped).
    """
    dev = x[:, 0:POSE_DIM] - w @ x[:, 0:POSE_DIM]
    dev[:, EUL] = wrap_angle(dev[:, EUL])
    return (dev * w[:, None]).T @ dev


def scan_update(filt: Any, slots: np.ndarray, meas: FloatArray, R: FloatArray) -> float:
    """The landmark EKF update of a labeled scan, after progressive correction if it is needed.

    Fills ``filt._loglik`` and ``filt._nis_sum`` (N,) and updates the observed landmark EKFs of
    every particle (:func:`.landmarks.landmark_ekf_particles`). With ``progressive_ess > 0`` the
    update is first computed on copies of the observed landmarks; if the scan keeps enough
    effective particles those copies are the result (no second pass), otherwise
    :func:`progressive_correction` runs and the update is made at the moved particles.

    Args:
        filt: The filter. slots: (k,) observed slots. meas: (k, 3) measurements. R: (3, 3).

    Returns:
        The share of the tempered log-likelihood still to apply to the weights, in (0, 1].
    """
    loglik, nis = filt._loglik, filt._nis_sum
    if filt.progressive_ess > 0.0:
        mu, sigma = filt.mu[:, slots], filt.sigma[:, slots]  # fancy indexing: copies
        landmark_ekf_particles(filt.x, mu, sigma, np.arange(slots.shape[0]), meas, R, loglik, nis)
        ll = loglik / filt.likelihood_inflation
        if ess_after(filt.logw, ll, 1.0) >= filt.progressive_ess * filt.n_particles:
            filt.mu[:, slots], filt.sigma[:, slots] = mu, sigma
            return 1.0
        remaining = progressive_correction(filt, slots, meas, R, filt.likelihood_inflation, ll)
    else:
        remaining = 1.0
    landmark_ekf_particles(filt.x, filt.mu, filt.sigma, slots, meas, R, loglik, nis)
    return remaining


def progressive_correction(
    filt: Any,
    slots: np.ndarray,
    meas: FloatArray,
    R: FloatArray,
    scale: float,
    first: FloatArray | None = None,
) -> float:
    """Apply a degenerate scan's likelihood in stages, moving the particles in between.

    ``filt`` is a :class:`~estimators.fastslam.particles.FastSLAMBase`; its particles, weights
    and per-particle arrays are resampled and its pose states jittered in place.

    Args:
        filt: The filter. slots: (k,) observed landmark slots. meas: (k, 3) measurements.
        R: (3, 3) measurement noise. scale: Tempering λ of the LiDAR weight.
        first: (N,) the tempered log-likelihood at the current particles, if already computed.

    Returns:
        The share of the (tempered) log-likelihood still to apply, in (0, 1]; 1 if no stage ran.
    """
    n = filt.n_particles
    loglik, nis = np.empty(n), np.empty(n)
    target = max(filt.resample_threshold, filt.progressive_ess) * n
    remaining = 1.0
    h = regularisation_bandwidth(n, POSE_DIM)
    for stage in range(MAX_STAGES):
        if stage == 0 and first is not None:
            ll = first
        else:
            scan_loglik(filt.x, filt.mu, filt.sigma, slots, meas, R, loglik, nis)
            ll = loglik / scale
        if stage == 0 and ess_after(filt.logw, ll, 1.0) >= filt.progressive_ess * n:
            return 1.0
        alpha = stage_exponent(filt.logw, ll, remaining, target)
        if alpha >= remaining:
            break
        filt.logw = normalise_log_weights(
            filt.logw + alpha * np.where(np.isfinite(ll), ll, -np.inf)
        )
        remaining -= alpha
        w = filt.weights
        cov = pose_covariance(filt.x, w)
        filt._resample(systematic_resample(w, filt._rng))
        filt.x[:, 0:POSE_DIM] += regularisation_jitter(cov, h, n, filt._rng)
        wrap_euler_rows(filt.x)
        filt.n_progressive_stages += 1
    return remaining
