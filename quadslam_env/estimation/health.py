"""The health check of a belief: non-finite values, a covariance that is not one
(asymmetric, not positive semi-definite), a trace beyond a bound (docs/design.md §7)."""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

HEALTH_PROBLEMS = (
    "",
    "estimator reported divergence",
    "non-finite position",
    "non-finite vel_body",
    "non-finite euler",
    "non-finite rates",
    "non-finite landmark means",
    "non-finite pose covariance",
    "asymmetric pose covariance",
    "pose covariance not positive semi-definite (negative variance)",
    "pose covariance not positive semi-definite (correlation beyond ±1)",
    "pose covariance trace above episode.max_cov_trace",
)
"""What :func:`health_codes` codes mean (0: healthy)."""

PSD_TOLERANCE = 1e-6
"""Round-off allowed by the positive-semi-definiteness checks, relative to the largest pose
variance: a variance below ``-tol·scale`` or a 2×2 minor ``P_ij² − P_ii P_jj`` above
``tol·P_ii P_jj + (tol·scale)²`` is not round-off."""


_NO_COV = np.zeros((1, 1, 1))


@kernel
def _covariance_code(P: FloatArray, tol: float, max_trace: float) -> int:
    """Codes 7–11 (0: healthy) of one pose covariance (n, n), in one pass over its entries.

    The first failed check in :data:`HEALTH_PROBLEMS` order wins: non-finite, asymmetric,
    negative variance, correlation beyond ±1 (a 2×2 minor beyond round-off), trace too large.
    """
    n = P.shape[0]
    scale = 1e-12
    trace = 0.0
    for i in range(n):
        scale = max(scale, abs(P[i, i]))
        trace += P[i, i]
    nonfinite = asymmetric = negative = correlated = False
    for i in range(n):
        pii = P[i, i]
        nonfinite = nonfinite or not math.isfinite(pii)
        negative = negative or pii < -tol * scale
        for j in range(i):
            pij, pji = P[i, j], P[j, i]
            nonfinite = nonfinite or not (math.isfinite(pij) and math.isfinite(pji))
            asymmetric = asymmetric or abs(pij - pji) > 1e-6 * scale
            prod = max(pii, 0.0) * max(P[j, j], 0.0)
            correlated = correlated or pij * pij - prod > tol * prod + (tol * scale) ** 2
    if nonfinite:
        return 7
    if asymmetric:
        return 8
    if negative:
        return 9
    if correlated:
        return 10
    return 11 if trace > max_trace else 0


@kernel
def _health_codes(
    diverged: FloatArray,
    position: FloatArray,
    vel_body: FloatArray,
    euler: FloatArray,
    rates: FloatArray,
    lm_means: FloatArray,
    lm_mapped: np.ndarray,
    cov: FloatArray,
    has_cov: bool,
    max_trace: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (B,) with the first failed check's index into :data:`HEALTH_PROBLEMS`."""
    tol = PSD_TOLERANCE
    for b in range(out.shape[0]):
        code = 1 if diverged[b] > 0.0 else 0
        for i in range(3):  # codes 2-5: position, vel_body, euler, rates (first failure wins)
            if code == 0 and not math.isfinite(position[b, i]):
                code = 2
        for i in range(3):
            if code == 0 and not math.isfinite(vel_body[b, i]):
                code = 3
        for i in range(3):
            if code == 0 and not math.isfinite(euler[b, i]):
                code = 4
        for i in range(3):
            if code == 0 and not math.isfinite(rates[b, i]):
                code = 5
        for j in range(lm_mapped.shape[1]):
            for i in range(3):
                if code == 0 and lm_mapped[b, j] and not math.isfinite(lm_means[b, j, i]):
                    code = 6
        if code == 0 and has_cov:
            code = _covariance_code(cov[b], tol, max_trace)
        out[b] = code


def health_codes(est: BatchEstimate, max_cov_trace: float = math.inf) -> np.ndarray:
    """What is wrong with each lane's belief, as (B,) indices into :data:`HEALTH_PROBLEMS`.

    Checks (docs/design.md §7), first failure wins: the estimator's own ``diverged`` flag, a finite
    mean (pose, rates and mapped landmarks), a finite and symmetric pose covariance with no
    negative variance and no correlation beyond ±1 (beyond :data:`PSD_TOLERANCE` round-off),
    and a pose-covariance trace (over ρ m², v m²/s², Λ rad²) at most ``max_cov_trace``. The
    full positive-semi-definiteness test is the Cholesky factorisation that the NEES needs
    anyway (:func:`quadslam_env.metrics.cholesky_nees` returns inf on failure), so it is not
    repeated. Every estimator is checked the same way (the oracle has no covariance).

    Args:
        est: The belief of B lanes.
        max_cov_trace: Largest healthy trace of the 9×9 pose covariance (``inf``: no limit).
    """
    b = est.position.shape[0]
    out = np.zeros(b, dtype=np.int64)
    diverged = est.diagnostics.get("diverged")
    cov = est.pose_cov
    _health_codes(
        np.zeros(b) if diverged is None else np.asarray(diverged, dtype=float),
        est.position,
        est.vel_body,
        est.euler,
        est.rates,
        est.landmark_means,
        est.landmark_mapped,
        _NO_COV if cov is None else cov,
        cov is not None,
        float(max_cov_trace),
        out,
    )
    return out


def health_problem(
    est: BatchEstimate, lane: int = 0, max_cov_trace: float = math.inf
) -> str | None:
    """What is wrong with lane ``lane`` of ``est`` (see :func:`health_codes`); ``None`` if
    healthy."""
    code = int(health_codes(est, max_cov_trace)[lane])
    return HEALTH_PROBLEMS[code] or None


def position_std(est: BatchEstimate) -> FloatArray:
    """The estimator's own position uncertainty √trace(P_ρ) (B,) in m: 0 without a covariance
    (the oracle) and where the trace is not finite (such a lane ends as diverged on this step,
    see :func:`health_codes`)."""
    cov = est.pose_cov
    if cov is None:
        return np.zeros(est.position.shape[0])
    trace = cov[:, 0, 0] + cov[:, 1, 1] + cov[:, 2, 2]
    return np.where(np.isfinite(trace), np.sqrt(np.maximum(trace, 0.0)), 0.0)
