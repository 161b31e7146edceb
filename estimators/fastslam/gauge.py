"""The SLAM gauge of the FastSLAM filters: the initial position and yaw, kept out of the particles.

Without a known map every measurement of the FastSLAM filters is relative: the IMU (specific
force and rates in B, gravity along n3), the dynamics and the LiDAR (landmark relative to the
vehicle, the map unknown) are all unchanged if the whole solution — vehicle path and map — is
translated by ``δρ`` and rotated about n3 by ``δψ`` around a point ``ρ_a``. These four directions
are the *gauge* of SLAM: no measurement informs them, so their posterior is their prior, the
initial covariance ``G = P0[g, g]`` with ``g = (ρ_x, ρ_y, ρ_z, ψ)``, for the whole flight.

Left in the particles, that prior spread is lost: each resampling keeps a random subset of the
particles, selection on the observable states (velocity, roll/pitch, the path relative to the
map) makes one initial particle the ancestor of all within seconds, and the particle covariance
then holds none of the initial position and yaw uncertainty while the error keeps it (Bailey,
Nieto and Nebot, *Consistency of the FastSLAM algorithm*, ICRA 2006, §IV: FastSLAM cannot
keep the uncertainty of past poses; seed 004 §3 on sample impoverishment). The estimate is then
over-confident exactly in those directions.

So, with ``anchor_gauge`` (the default, unknown map only), the particles are drawn from the prior
*conditioned* on the gauge at its mean, ``N(x̄0, P0 − P0[:, g] G⁺ P0[g, :])``, and the gauge is
carried analytically: a solution shifted by ``γ = (δρ, δψ) ~ N(0, G)`` is equally likely, so the
reported pose and map covariances add the first-order effect ``J G Jᵀ`` of the shift,

* vehicle position: ``∂ρ/∂γ = [I₃, n₃ × (ρ̄ − ρ_a)]``, yaw: ``∂ψ/∂γ = [0, 0, 0, 1]`` (a rotation
  about n₃ premultiplies ``C_NB = C₃(ψ) C₂(θ) C₁(φ)`` by ``C₃(δψ)``, seed 001 eq. 1, so it adds
  ``δψ`` to ψ and leaves φ, θ and the body-frame velocity unchanged);
* landmark j: ``∂l_j/∂γ = [I₃, n₃ × (μ̄_j − ρ_a)]``;

with the rotation centre ``ρ_a`` the initial position mean. The particle part is the uncertainty
of the solution *given* the gauge, which the weights and the landmark EKFs do estimate. The split
is exact for a prior in which the gauge is uncorrelated with the other states (every shipped
scenario's P0 is diagonal); for a correlated prior the particles start from the conditional and
the gauge–state correlation is dropped (the observable states then converge from there).
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.jit import kernel
from quadslam_env.types import POS, POSE_DIM, FloatArray

GAUGE_INDEX = np.array([0, 1, 2, 8])
"""State indices of the gauge ``(ρ_x, ρ_y, ρ_z, ψ)`` in the 12-state ``(ρ, v_B, Λ, ω)``."""


def gauge_split(cov0: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Split the initial covariance into the gauge prior and the conditional particle prior.

    Args:
        cov0: (12, 12) initial covariance ``P0`` (symmetric PSD).

    Returns:
        ``(G, P_c)``: ``G = P0[g, g]`` (4, 4), the gauge prior (m², m·rad, rad²), and
        ``P_c = P0 − P0[:, g] G⁺ P0[g, :]`` (12, 12), the covariance of the other states given
        the gauge, which is zero in the gauge rows and columns.
    """
    P = 0.5 * (cov0 + cov0.T)
    g = GAUGE_INDEX
    G = P[np.ix_(g, g)].copy()
    cross = P[:, g]
    Pc = P - cross @ np.linalg.pinv(G) @ cross.T
    Pc = 0.5 * (Pc + Pc.T)
    Pc[g, :] = 0.0
    Pc[:, g] = 0.0
    return G, Pc


def rotation_lever(points: FloatArray, anchor: FloatArray) -> FloatArray:
    """``n₃ × (p − ρ_a)`` for points (..., 3): the velocity of a point under a unit yaw rate.

    Args:
        points: (..., 3) positions in N, m. anchor: (3,) rotation centre ``ρ_a`` in N, m.

    Returns:
        (..., 3) ``(−(p_y − a_y), p_x − a_x, 0)`` in m/rad.
    """
    d = np.asarray(points, dtype=float) - anchor
    out = np.zeros(d.shape)
    out[..., 0] = -d[..., 1]
    out[..., 1] = d[..., 0]
    return out


@kernel
def _add_shift_cov(point: FloatArray, anchor: FloatArray, G: FloatArray, out: FloatArray) -> None:
    """``out[0:3, 0:3] += J G Jᵀ`` for ``J = [I₃, n₃ × (p − ρ_a)]`` (3, 4) of one point p, and,
    when ``out`` is the (9, 9) pose covariance, the yaw row/column ``∂ψ/∂γ = [0, 0, 0, 1]``."""
    lever = (-(point[1] - anchor[1]), point[0] - anchor[0], 0.0)
    pose = out.shape[0] > 3
    n = 4 if pose else 3  # rows of J: ρ (or l) x, y, z, then ψ (pose only, row 8 of out)
    J = np.zeros((4, 4))
    for i in range(3):
        J[i, i] = 1.0
        J[i, 3] = lever[i]
    J[3, 3] = 1.0
    rows = (0, 1, 2, 8)
    for a in range(n):
        for b in range(n):
            v = 0.0
            for k in range(4):
                for m in range(4):
                    v += J[a, k] * G[k, m] * J[b, m]
            out[rows[a], rows[b]] += v


def pose_gauge_cov(position: FloatArray, anchor: FloatArray, G: FloatArray) -> FloatArray:
    """The gauge's share ``J G Jᵀ`` (9, 9) of the pose ``(ρ, v_B, Λ)`` covariance.

    Args:
        position: (3,) position mean ρ̄ in N, m. anchor: (3,) ``ρ_a``, m.
        G: (4, 4) gauge covariance of ``(δρ, δψ)``.

    Returns:
        (9, 9) covariance to add to the particle pose covariance (m², m²/s², rad² blocks).
    """
    out = np.zeros((POSE_DIM, POSE_DIM))
    _add_shift_cov(np.asarray(position, dtype=float), anchor, G, out)
    return out


def landmark_gauge_cov(means: FloatArray, anchor: FloatArray, G: FloatArray) -> FloatArray:
    """The gauge's share ``J_j G J_jᵀ`` (L, 3, 3) of each landmark's covariance.

    Args:
        means: (L, 3) landmark means in N, m. anchor: (3,) ``ρ_a``, m.
        G: (4, 4) gauge covariance of ``(δρ, δψ)``.

    Returns:
        (L, 3, 3) covariances in m² to add to the landmark covariances.
    """
    means = np.asarray(means, dtype=float).reshape(-1, 3)
    out = np.zeros((means.shape[0], 3, 3))
    _add_landmark_shift_covs(means, anchor, G, out)
    return out


@kernel
def _add_landmark_shift_covs(
    means: FloatArray, anchor: FloatArray, G: FloatArray, covs: FloatArray
) -> None:
    for j in range(means.shape[0]):
        _add_shift_cov(means[j], anchor, G, covs[j])


def add_gauge_cov(
    gauge: tuple[FloatArray, FloatArray],
    position: FloatArray,
    pose_cov: FloatArray,
    lm_means: FloatArray,
    lm_covs: FloatArray,
) -> None:
    """Add the gauge's share to a pose covariance and landmark covariances, in place.

    Args:
        gauge: ``(G (4, 4), anchor ρ_a (3,))``. position: (3,) position mean ρ̄ in N, m.
        pose_cov: (9, 9) pose covariance. lm_means: (L, 3) landmark means, m.
        lm_covs: (L, 3, 3) landmark covariances, m².
    """
    G, anchor = gauge
    _add_shift_cov(position, anchor, G, pose_cov)
    if lm_means.shape[0]:
        _add_landmark_shift_covs(lm_means, anchor, G, lm_covs)


def move_anchor(G: FloatArray, old: FloatArray, new: FloatArray) -> FloatArray:
    """The gauge covariance about rotation centre ``old`` re-expressed about ``new`` (4, 4).

    A shift ``(δρ, δψ)`` about ``old`` moves a point p by ``δρ + δψ n₃ × (p − old)``
    ``= [δρ + δψ n₃ × (new − old)] + δψ n₃ × (p − new)``: the same shift about ``new`` with
    ``δρ' = δρ + δψ n₃ × (new − old)``, ``δψ' = δψ``.

    Args:
        G: (4, 4) covariance of ``(δρ, δψ)`` about ``old``. old, new: (3,) centres in N, m.

    Returns:
        (4, 4) covariance of ``(δρ', δψ')``.
    """
    M = np.eye(4)
    M[0:3, 3] = rotation_lever(new, old)
    return M @ G @ M.T


def pin_gauge(
    x: FloatArray, w: FloatArray, G: FloatArray, anchor: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Move the particles' spread in position and yaw into the gauge, when the map is born.

    Until the first landmark is mapped, the particles' position and yaw spread grows by dead
    reckoning (an unknown initial velocity, process noise). The first landmarks are mapped
    from each particle's own pose, so from then on that spread is a shift of each particle's
    whole solution that no later measurement can see, exactly like the initial prior. Pinning
    every particle's position and yaw to the weighted mean *before* the map is initialised
    changes no particle's future likelihood (the measurements are invariant under the shift,
    :mod:`.gauge`), and the removed spread, the weighted covariance of ``(ρ_i, ψ_i)``, is added
    to the gauge about the new rotation centre ``ρ̄``.

    Args:
        x: (N, 12) particles; position and yaw set to their weighted means in place.
        w: (N,) normalised weights. G: (4, 4) gauge covariance about ``anchor`` (3,).

    Returns:
        ``(G', ρ̄)``: the gauge covariance (4, 4) about the new centre ``ρ̄`` (3,).
    """
    pos = x[:, POS]
    mean = w @ pos
    psi = math.atan2(float(w @ np.sin(x[:, 8])), float(w @ np.cos(x[:, 8])))
    dev = np.empty((x.shape[0], 4))
    dev[:, 0:3] = pos - mean
    dev[:, 3] = (x[:, 8] - psi + math.pi) % (2.0 * math.pi) - math.pi
    spread = (dev * w[:, None]).T @ dev
    x[:, POS] = mean
    x[:, 8] = psi
    return move_anchor(G, anchor, mean) + spread, mean
