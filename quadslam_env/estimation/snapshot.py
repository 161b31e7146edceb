"""The estimator's belief as the env reads it: one lane (:class:`Estimate`) or B lanes
(:class:`BatchEstimate`), and the conversion of the first into the second.

See docs/design.md §5 and §9. Landmark identities inside the core are the indices ``0 … L-1``
of the lane's landmark array, so a batch's landmark outputs are arrays indexed by id, padded to
a capacity ``Lmax`` with a mask.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from quadslam_env.types import POSE_DIM, FloatArray


@dataclass(frozen=True)
class Estimate:
    """Frozen snapshot of an estimator's belief.

    Attributes:
        position: (3,) ρ̂ in N, m.
        vel_body: (3,) v̂ in B, m/s.
        vel_inertial: (3,) ``C_NB(Λ̂) v̂`` in N, m/s.
        euler: (3,) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
        rates: (3,) ω̂ in B, rad/s (for EKF-SLAM: the bias-corrected gyro).
        pose_cov: (9, 9) covariance of (ρ, v, Λ), or ``None`` when the estimator has none
            (the oracle).
        landmark_ids: (n,) int ids of mapped landmarks.
        landmark_means: (n, 3) estimated landmark positions in N, m.
        landmark_covs: (n, 3, 3) landmark covariances in m².
        accel_bias: (3,) estimated total accelerometer bias in m/s², or ``None``.
        gyro_bias: (3,) estimated total gyro bias in rad/s, or ``None``.
        diagnostics: Scalars such as ``nis``, ``nis_dof``, ``n_rejected``, ``ess``.
    """

    position: FloatArray
    vel_body: FloatArray
    vel_inertial: FloatArray
    euler: FloatArray
    rates: FloatArray
    pose_cov: FloatArray | None
    landmark_ids: np.ndarray
    landmark_means: FloatArray
    landmark_covs: FloatArray
    accel_bias: FloatArray | None = None
    gyro_bias: FloatArray | None = None
    diagnostics: dict[str, float] = field(default_factory=dict)


@dataclass
class BatchEstimate:
    """The belief of B lanes (views into the estimator's buffers: read, don't keep).

    Attributes:
        position: (B, 3) ρ̂ in N, m.
        vel_body: (B, 3) v̂ in B, m/s.
        vel_inertial: (B, 3) ``C_NB(Λ̂) v̂`` in N, m/s.
        euler: (B, 3) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
        rates: (B, 3) ω̂ in B, rad/s.
        pose_cov: (B, 9, 9) covariance of (ρ, v_B, Λ), or ``None`` (the oracle).
        landmark_means: (B, Lmax, 3) estimated landmark positions by id, m (rows of unmapped
            ids are undefined).
        landmark_mapped: (B, Lmax) bool, which ids the lane has mapped (or knows).
        accel_bias: (B, 3) estimated accelerometer bias in m/s², or ``None``.
        gyro_bias: (B, 3) estimated gyro bias in rad/s, or ``None``.
        diagnostics: name → (B,) float array (``nis``, ``ess``, ``diverged``, …; NaN where a
            lane has no value).
    """

    position: FloatArray
    vel_body: FloatArray
    vel_inertial: FloatArray
    euler: FloatArray
    rates: FloatArray
    pose_cov: FloatArray | None
    landmark_means: FloatArray
    landmark_mapped: np.ndarray
    accel_bias: FloatArray | None = None
    gyro_bias: FloatArray | None = None
    diagnostics: dict[str, FloatArray] = field(default_factory=dict)


def id_width(snaps: Sequence[Estimate]) -> int:
    """Landmark-array width that holds every id of the snapshots (largest id + 1)."""
    # max of a list: a tenth of ndarray.max()'s cost on the few ids a snapshot holds
    return max((max(s.landmark_ids.tolist()) + 1 for s in snaps if s.landmark_ids.size), default=0)


def empty_batch(num_lanes: int, capacity: int) -> BatchEstimate:
    b = num_lanes
    return BatchEstimate(
        position=np.zeros((b, 3)),
        vel_body=np.zeros((b, 3)),
        vel_inertial=np.zeros((b, 3)),
        euler=np.zeros((b, 3)),
        rates=np.zeros((b, 3)),
        pose_cov=np.zeros((b, POSE_DIM, POSE_DIM)),
        landmark_means=np.zeros((b, capacity, 3)),
        landmark_mapped=np.zeros((b, capacity), dtype=bool),
    )


def fill_batch(out: BatchEstimate, snaps: Sequence[Estimate]) -> None:
    """Write the scalar snapshots ``snaps`` (one per lane, in lane order) into ``out``.

    Optional parts (covariance, biases, diagnostics) follow the snapshots: ``pose_cov`` and
    the biases become ``None`` when the first lane has none; a diagnostic missing in a lane is
    NaN there.
    """
    b = len(snaps)
    if snaps[0].pose_cov is None:
        out.pose_cov = None
    elif out.pose_cov is None:
        out.pose_cov = np.zeros((b, POSE_DIM, POSE_DIM))
    # Reused between calls (the batch is a view: read, don't keep); zeroed like new arrays.
    for name in ("accel_bias", "gyro_bias"):
        if getattr(snaps[0], name) is None:
            setattr(out, name, None)
        elif getattr(out, name) is None:
            setattr(out, name, np.zeros((b, 3)))
        else:
            getattr(out, name)[:] = 0.0
    keys = list(snaps[0].diagnostics)
    if b > 1:
        keys = sorted({k for s in snaps for k in s.diagnostics})
    if list(out.diagnostics) != keys:
        out.diagnostics = {k: np.full(b, np.nan) for k in keys}
    elif b > 1:
        for column in out.diagnostics.values():
            column[:] = np.nan
    out.landmark_mapped[:] = False
    for lane, s in enumerate(snaps):
        out.position[lane] = s.position
        out.vel_body[lane] = s.vel_body
        out.vel_inertial[lane] = s.vel_inertial
        out.euler[lane] = s.euler
        out.rates[lane] = s.rates
        if out.pose_cov is not None and s.pose_cov is not None:
            out.pose_cov[lane] = s.pose_cov
        if out.accel_bias is not None and s.accel_bias is not None:
            out.accel_bias[lane] = s.accel_bias
        if out.gyro_bias is not None and s.gyro_bias is not None:
            out.gyro_bias[lane] = s.gyro_bias
        if s.landmark_ids.size:
            out.landmark_means[lane, s.landmark_ids] = s.landmark_means
            out.landmark_mapped[lane, s.landmark_ids] = True
        diagnostics = out.diagnostics
        for k, v in s.diagnostics.items():
            diagnostics[k][lane] = v


def batch_from_estimates(snaps: Sequence[Estimate]) -> BatchEstimate:
    """A fresh :class:`BatchEstimate` holding the scalar snapshots ``snaps``."""
    out = empty_batch(len(snaps), id_width(snaps))
    fill_batch(out, snaps)
    return out
