"""Weighted particle moments for the FastSLAM estimate, as numba kernels over the N particles.

The state mean uses the weighted circular mean for the Euler angles and the pose covariance
wrapped angle deviations; the map is the mixture of the particles' landmark EKFs. Each kernel
is one or two passes over the particles into preallocated outputs.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_from_trig, wrap_pi
from quadslam_env.models.jit import kernel
from quadslam_env.types import POSE_DIM, FloatArray


@kernel
def weighted_mean(a: FloatArray, w: FloatArray, out: FloatArray) -> None:
    """``out = Σ_i w_i a_i`` for rows of ``a`` (N, m) and weights ``w`` (N,) into ``out`` (m,)."""
    for j in range(a.shape[1]):
        out[j] = 0.0
    for i in range(a.shape[0]):
        wi = w[i]
        for j in range(a.shape[1]):
            out[j] += wi * a[i, j]


@kernel
def state_moments(
    x: FloatArray, w: FloatArray, mean: FloatArray, cov: FloatArray, vel_inertial: FloatArray
) -> None:
    """Weighted mean of states (N, 12), covariance of the pose ``(ρ, v_B, Λ)``, ``C_NB v̄``.

    The Euler angles' mean is the circular mean ``atan2(Σ w sin Λ, Σ w cos Λ)``; the
    covariance ``Σ_i w_i d_i d_iᵀ`` uses deviations ``d_i = x_i − x̄`` with the angle
    deviations wrapped to (-π, π].

    Args:
        x: (N, 12) states ``(ρ m, v_B m/s, Λ rad, ω rad/s)``. w: (N,) normalised weights.
        mean: (12,) receives the mean. cov: (9, 9) receives the pose covariance.
        vel_inertial: (3,) receives ``C_NB(Λ̄) v̄`` in m/s (N frame).
    """
    weighted_mean(x, w, mean)
    s0 = s1 = s2 = c0 = c1 = c2 = 0.0
    for i in range(x.shape[0]):
        wi = w[i]
        s0 += wi * math.sin(x[i, 6])
        c0 += wi * math.cos(x[i, 6])
        s1 += wi * math.sin(x[i, 7])
        c1 += wi * math.cos(x[i, 7])
        s2 += wi * math.sin(x[i, 8])
        c2 += wi * math.cos(x[i, 8])
    mean[6], mean[7], mean[8] = math.atan2(s0, c0), math.atan2(s1, c1), math.atan2(s2, c2)
    for a in range(POSE_DIM):
        for b in range(POSE_DIM):
            cov[a, b] = 0.0
    dev = np.empty(POSE_DIM)
    for i in range(x.shape[0]):
        for a in range(6):
            dev[a] = x[i, a] - mean[a]
        for a in range(6, POSE_DIM):
            dev[a] = wrap_pi(x[i, a] - mean[a])
        for a in range(POSE_DIM):
            da = dev[a] * w[i]
            for b in range(a, POSE_DIM):
                cov[a, b] += da * dev[b]
    for a in range(POSE_DIM):
        for b in range(a):
            cov[a, b] = cov[b, a]
    phi, theta, psi = mean[6], mean[7], mean[8]
    C = dcm_from_trig(
        math.cos(phi), math.sin(phi), math.cos(theta), math.sin(theta), math.cos(psi), math.sin(psi)
    )
    for r in range(3):
        vel_inertial[r] = C[3 * r] * mean[3] + C[3 * r + 1] * mean[4] + C[3 * r + 2] * mean[5]


@kernel
def landmark_mixture(
    mu: FloatArray,
    sigma: FloatArray,
    w: FloatArray,
    order: np.ndarray,
    mean: FloatArray,
    cov: FloatArray,
) -> None:
    """Mean and covariance of each landmark's Gaussian mixture over the particles.

    ``μ̄ = Σ_i w_i μ^i``, ``Σ̄ = Σ_i w_i Σ^i + Σ_i w_i (μ^i − μ̄)(μ^i − μ̄)ᵀ``.

    Args:
        mu: (N, L, 3) landmark means in m. sigma: (N, L, 3, 3) covariances in m² (both
            C-contiguous). w: (N,) normalised weights.
        order: (L,) int, output row k holds landmark slot ``order[k]``.
        mean: (L, 3) receives μ̄. cov: (L, 3, 3) receives Σ̄.
    """
    n, n_lm = mu.shape[0], mu.shape[1]
    mu_rows, sigma_rows = mu.reshape(n, 3 * n_lm), sigma.reshape(n, 9 * n_lm)
    m_sum, s_sum = np.zeros(3 * n_lm), np.zeros(9 * n_lm)
    for i in range(n):  # flat rows: the inner loops vectorise
        wi = w[i]
        for t in range(3 * n_lm):
            m_sum[t] += wi * mu_rows[i, t]
        for t in range(9 * n_lm):
            s_sum[t] += wi * sigma_rows[i, t]
    spread = np.zeros(9 * n_lm)
    e = np.empty(3 * n_lm)
    for i in range(n):
        sq = math.sqrt(w[i])
        for t in range(3 * n_lm):
            e[t] = (mu_rows[i, t] - m_sum[t]) * sq
        for k in range(n_lm):
            for a in range(3):
                for b in range(3):
                    spread[9 * k + 3 * a + b] += e[3 * k + a] * e[3 * k + b]
    for k in range(n_lm):
        s = order[k]
        for a in range(3):
            mean[k, a] = m_sum[3 * s + a]
            for b in range(3):
                cov[k, a, b] = s_sum[9 * s + 3 * a + b] + spread[9 * s + 3 * a + b]
