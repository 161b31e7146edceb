"""Progressive correction of a scan whose likelihood is far narrower than the particle cloud.

After landmarks have been out of view, the particle cloud has spread by the dead-reckoning drift
(metres) while one scan pins the pose to centimetres. Weighting with the full likelihood then
leaves the few particles nearest the posterior, often none of them near it: after resampling
the whole set is copies of the least bad particle, with a spread of centimetres and an error of
metres, and the filter never recovers (measured on ``fastslam_out_of_view_600s`` and on the
600 s helix, docs/filter-consistency.md). This is the textbook failure of importance sampling from a
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

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

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
from estimators.fastslam.state import ParticleState
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


@dataclass(frozen=True)
class Tempering:
    """What progressive correction needs of the filter besides its state: its tempering
    settings, its resampling step and its generator.

    Attributes:
        inflation: λ ≥ 1, ``likelihood_inflation`` (the LiDAR weight is ``p(z|x)^{1/λ}``).
        progressive_ess: Stages run when one scan would leave fewer effective particles
            than this share of N (0: never).
        resample_threshold: The filter's resampling threshold, a share of N.
        resample: The filter's resampling step: particle i becomes a copy of ``idx[i]`` in
            every per-particle array of the filter, and the weights become equal.
        rng: The filter's random generator (the jitter of each stage).
    """

    inflation: float
    progressive_ess: float
    resample_threshold: float
    resample: Callable[[np.ndarray], None]
    rng: np.random.Generator


class ScanLikelihood(NamedTuple):
    """What a labeled scan gave every particle (:func:`scan_update`).

    Attributes:
        loglik: (N,) each particle's ``Σ_j log N(ν_j; 0, S_j)`` over the observed landmarks,
            at the particles' final poses (untempered).
        nis: (N,) each particle's ``Σ_j ν_jᵀ S_j⁻¹ ν_j``.
        remaining: The share of the tempered log-likelihood still to apply to the weights,
            in (0, 1] (1 if no stage ran).
        stages: Tempered stages run (each one resampled the particles).
    """

    loglik: FloatArray
    nis: FloatArray
    remaining: float
    stages: int


def scan_update(
    state: ParticleState,
    slots: np.ndarray,
    meas: FloatArray,
    R: FloatArray,
    tempering: Tempering,
) -> ScanLikelihood:
    """The landmark EKF update of a labeled scan, after progressive correction if it is needed.

    Updates the observed landmark EKFs of every particle in ``state.mu`` and ``state.sigma``
    (:func:`.landmarks.landmark_ekf_particles`) and returns each particle's log-likelihood and
    NIS; the weights are the caller's to update with them. With ``progressive_ess > 0`` the
    update is first computed on copies of the observed landmarks; if the scan keeps enough
    effective particles those copies are the result (no second pass), otherwise
    :func:`progressive_correction` runs and the update is made at the moved particles.

    Args:
        state: The filter's particles. slots: (k,) observed slots. meas: (k, 3) measurements.
        R: (3, 3) measurement noise. tempering: The filter's tempering settings and steps.
    """
    n = state.n_particles
    loglik, nis = np.empty(n), np.empty(n)
    remaining, stages = 1.0, 0
    if tempering.progressive_ess > 0.0:
        mu, sigma = state.mu[:, slots], state.sigma[:, slots]  # fancy indexing: copies
        landmark_ekf_particles(state.x, mu, sigma, np.arange(slots.shape[0]), meas, R, loglik, nis)
        ll = loglik / tempering.inflation
        if ess_after(state.logw, ll, 1.0) >= tempering.progressive_ess * n:
            state.mu[:, slots], state.sigma[:, slots] = mu, sigma
            return ScanLikelihood(loglik, nis, remaining, stages)
        remaining, stages = progressive_correction(state, slots, meas, R, tempering, ll)
    landmark_ekf_particles(state.x, state.mu, state.sigma, slots, meas, R, loglik, nis)
    return ScanLikelihood(loglik, nis, remaining, stages)


def progressive_correction(
    state: ParticleState,
    slots: np.ndarray,
    meas: FloatArray,
    R: FloatArray,
    tempering: Tempering,
    first: FloatArray | None = None,
) -> tuple[float, int]:
    """Apply a degenerate scan's likelihood in stages, moving the particles in between.

    Each stage updates ``state``'s weights, resamples through ``tempering.resample`` and
    jitters the particles' pose states in ``state.x`` in place.

    Args:
        state: The filter's particles. slots: (k,) observed landmark slots.
        meas: (k, 3) measurements. R: (3, 3) measurement noise.
        tempering: The filter's settings (λ tempers the LiDAR weight) and resampling step.
        first: (N,) the tempered log-likelihood at the current particles, if already computed.

    Returns:
        ``(remaining, stages)``: the share of the (tempered) log-likelihood still to apply, in
        (0, 1] (1 if no stage ran), and the number of stages run.
    """
    n = state.n_particles
    loglik, nis = np.empty(n), np.empty(n)
    target = max(tempering.resample_threshold, tempering.progressive_ess) * n
    remaining = 1.0
    h = regularisation_bandwidth(n, POSE_DIM)
    stages = 0
    for stage in range(MAX_STAGES):
        if stage == 0 and first is not None:
            ll = first
        else:
            scan_loglik(state.x, state.mu, state.sigma, slots, meas, R, loglik, nis)
            ll = loglik / tempering.inflation
        if stage == 0 and ess_after(state.logw, ll, 1.0) >= tempering.progressive_ess * n:
            return 1.0, 0
        alpha = stage_exponent(state.logw, ll, remaining, target)
        if alpha >= remaining:
            break
        state.set_logw(
            normalise_log_weights(state.logw + alpha * np.where(np.isfinite(ll), ll, -np.inf))
        )
        remaining -= alpha
        w = state.w.copy()
        cov = pose_covariance(state.x, w)
        tempering.resample(systematic_resample(w, tempering.rng))
        state.x[:, 0:POSE_DIM] += regularisation_jitter(cov, h, n, tempering.rng)
        wrap_euler_rows(state.x)
        stages += 1
    return remaining, stages
