"""The estimator's belief as the env reads it: one snapshot type, :class:`BatchEstimate`, for
B lanes; an estimator of one vehicle returns it with B = 1.

See docs/design.md §5 and §9. Landmark identities inside the core are the indices ``0 … L-1``
of the lane's landmark array, so a snapshot's landmark outputs are arrays indexed by id, padded
to a capacity ``Lmax`` with a mask.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from quadslam_env.types import POSE_DIM, FloatArray


@dataclass(frozen=True)
class LaneMap:
    """One lane's landmarks in a snapshot's layout: arrays by id with a leading lane axis.

    Attributes:
        means: (1, W, 3) positions by id in N, m (rows of unmapped ids zero), W = max id + 1.
        mapped: (1, W) bool, which ids are mapped.
        covs: (1, W, 3, 3) covariances by id in m², or ``None`` (left out).
    """

    means: FloatArray
    mapped: np.ndarray
    covs: FloatArray | None

    @classmethod
    def of(
        cls,
        ids: np.ndarray,
        means: FloatArray,
        covs: FloatArray | None,
        shared: bool = False,
    ) -> LaneMap:
        """The landmarks in the snapshot's layout.

        Args:
            ids: (n,) distinct non-negative int ids.
            means: (n, 3) their positions in N, m.
            covs: (n, 3, 3) their covariances in m², or ``None`` to leave them out.
            shared: Make the arrays copies and read-only, so that one map can serve the
                snapshots of several steps (otherwise they may be views of the inputs).
        """
        ids_list = np.asarray(ids).tolist()
        n = len(ids_list)
        if ids_list == list(range(n)):  # ids 0 … n-1 in order (the usual case): no scatter
            out_means = np.asarray(means, dtype=float).reshape(1, n, 3)
            out_covs = None if covs is None else np.asarray(covs, dtype=float).reshape(1, n, 3, 3)
            mapped = np.empty((1, n), dtype=bool)
            mapped.fill(True)  # half the cost of np.ones on a few ids
        else:
            # max of a list: a tenth of ndarray.max()'s cost on the few ids a snapshot holds
            width = max(ids_list) + 1
            out_means = np.zeros((1, width, 3))
            out_covs = None
            mapped = np.zeros((1, width), dtype=bool)
            out_means[0, ids_list] = means
            if covs is not None:
                out_covs = np.zeros((1, width, 3, 3))
                out_covs[0, ids_list] = covs
            mapped[0, ids_list] = True
        if shared:
            out_means, mapped = np.array(out_means), np.array(mapped)
            out_covs = None if out_covs is None else np.array(out_covs)
            for a in (out_means, mapped, out_covs):
                if a is not None:
                    a.setflags(write=False)
        return cls(out_means, mapped, out_covs)


@dataclass
class BatchEstimate:
    """The belief of B lanes (B = 1 from an estimator of one vehicle).

    A batch estimator's :meth:`~quadslam_env.estimation.protocol.BatchEstimator.estimate`
    returns views into its buffers (read, don't keep); a one-lane snapshot
    (:meth:`~quadslam_env.estimation.protocol.Estimator.estimate`,
    :meth:`~quadslam_env.estimation.protocol.BatchEstimator.lane_estimate`) holds copies.

    Attributes:
        position: (B, 3) ρ̂ in N, m.
        vel_body: (B, 3) v̂ in B, m/s.
        vel_inertial: (B, 3) ``C_NB(Λ̂) v̂`` in N, m/s.
        euler: (B, 3) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
        rates: (B, 3) ω̂ in B, rad/s (for EKF-SLAM: the bias-corrected gyro).
        pose_cov: (B, 9, 9) covariance of (ρ, v_B, Λ), or ``None`` (the oracle).
        landmark_means: (B, Lmax, 3) estimated landmark positions by id in N, m (rows of
            unmapped ids are undefined).
        landmark_mapped: (B, Lmax) bool, which ids the lane has mapped (or knows).
        landmark_covs: (B, Lmax, 3, 3) landmark covariances by id in m² (rows of unmapped ids
            are undefined), or ``None`` where the snapshot leaves them out (the env's
            per-step snapshot of every lane; a one-lane snapshot has them).
        accel_bias: (B, 3) estimated accelerometer bias in m/s², or ``None``.
        gyro_bias: (B, 3) estimated gyro bias in rad/s, or ``None``.
        diagnostics: name → (B,) float array (``nis``, ``nis_dof``, ``n_rejected``, ``ess``,
            ``diverged``, …; NaN where a lane has no value).
        wind: (B, 2) estimated horizontal wind (w_N, w_E) in N, m/s, or ``None`` (an estimator
            without wind states).
    """

    position: FloatArray
    vel_body: FloatArray
    vel_inertial: FloatArray
    euler: FloatArray
    rates: FloatArray
    pose_cov: FloatArray | None
    landmark_means: FloatArray
    landmark_mapped: np.ndarray
    landmark_covs: FloatArray | None = None
    accel_bias: FloatArray | None = None
    gyro_bias: FloatArray | None = None
    diagnostics: dict[str, FloatArray] = field(default_factory=dict)
    wind: FloatArray | None = None

    @classmethod
    def one_lane(
        cls,
        position: FloatArray,
        vel_body: FloatArray,
        vel_inertial: FloatArray,
        euler: FloatArray,
        rates: FloatArray,
        pose_cov: FloatArray | None,
        landmark_ids: np.ndarray,
        landmark_means: FloatArray,
        landmark_covs: FloatArray | None,
        accel_bias: FloatArray | None = None,
        gyro_bias: FloatArray | None = None,
        diagnostics: Mapping[str, float] | None = None,
        wind: FloatArray | None = None,
    ) -> BatchEstimate:
        """The snapshot (B = 1) of one vehicle's belief, its map given by id.

        Like a frozen record, it keeps the arrays it is given (as views with a leading axis of
        1) instead of copying them: pass arrays that nothing writes to afterwards (fresh
        results, or copies of the estimator's buffers). A lane loop builds one per lane and
        step, where every small array costs about a microsecond.

        Args:
            position: (3,) ρ̂ in N, m.
            vel_body: (3,) v̂ in B, m/s.
            vel_inertial: (3,) ``C_NB(Λ̂) v̂`` in N, m/s.
            euler: (3,) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
            rates: (3,) ω̂ in B, rad/s.
            pose_cov: (9, 9) or ``None``.
            landmark_ids: (n,) distinct non-negative int ids of the mapped landmarks.
            landmark_means: (n, 3) their positions in N, m.
            landmark_covs: (n, 3, 3) their covariances in m², or ``None`` to leave them out
                (:class:`~quadslam_env.estimation.protocol.EstimatesState`).
            accel_bias: (3,) estimated accelerometer bias in m/s², or ``None``.
            gyro_bias: (3,) estimated gyro bias in rad/s, or ``None``.
            diagnostics: name → float.
            wind: (2,) estimated horizontal wind (w_N, w_E) in m/s, or ``None``.

        Returns:
            A :class:`BatchEstimate` of width ``Lmax = max(landmark_ids) + 1`` (0 without
            landmarks).
        """
        return cls.on_map(
            LaneMap.of(landmark_ids, landmark_means, landmark_covs),
            position,
            vel_body,
            vel_inertial,
            euler,
            rates,
            pose_cov,
            accel_bias,
            gyro_bias,
            diagnostics,
            wind,
        )

    @classmethod
    def on_map(
        cls,
        lane_map: LaneMap,
        position: FloatArray,
        vel_body: FloatArray,
        vel_inertial: FloatArray,
        euler: FloatArray,
        rates: FloatArray,
        pose_cov: FloatArray | None,
        accel_bias: FloatArray | None = None,
        gyro_bias: FloatArray | None = None,
        diagnostics: Mapping[str, float] | None = None,
        wind: FloatArray | None = None,
    ) -> BatchEstimate:
        """:meth:`one_lane` with the map already in the snapshot's layout (an estimator whose
        map changes less often than its state keeps one :class:`LaneMap` between steps).

        Args:
            lane_map: The lane's landmarks (its arrays become the snapshot's, not copied).
            position: (3,) ρ̂ in N, m.
            vel_body: (3,) v̂ in B, m/s.
            vel_inertial: (3,) ``C_NB(Λ̂) v̂`` in N, m/s.
            euler: (3,) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
            rates: (3,) ω̂ in B, rad/s.
            pose_cov: (9, 9) or ``None``.
            accel_bias: (3,) estimated accelerometer bias in m/s², or ``None``.
            gyro_bias: (3,) estimated gyro bias in rad/s, or ``None``.
            diagnostics: name → float.
            wind: (2,) estimated horizontal wind (w_N, w_E) in m/s, or ``None``.

        Returns:
            A :class:`BatchEstimate` of the map's width.
        """
        diag = diagnostics or {}
        values = np.array(list(diag.values()), dtype=float).reshape(-1, 1)  # one array

        return cls(
            position=_lane_axis(position),
            vel_body=_lane_axis(vel_body),
            vel_inertial=_lane_axis(vel_inertial),
            euler=_lane_axis(euler),
            rates=_lane_axis(rates),
            pose_cov=None if pose_cov is None else _lane_axis(pose_cov),
            landmark_means=lane_map.means,
            landmark_mapped=lane_map.mapped,
            landmark_covs=lane_map.covs,
            accel_bias=None if accel_bias is None else _lane_axis(accel_bias),
            gyro_bias=None if gyro_bias is None else _lane_axis(gyro_bias),
            diagnostics=dict(zip(diag, values, strict=True)),
            wind=None if wind is None else _lane_axis(wind),
        )

    def landmark_ids(self, lane: int = 0) -> np.ndarray:
        """(n,) int ascending ids of the landmarks lane ``lane`` has mapped (or knows)."""
        return np.flatnonzero(self.landmark_mapped[lane])

    def mapped_landmarks(self, lane: int = 0) -> tuple[np.ndarray, FloatArray, FloatArray]:
        """Lane ``lane``'s mapped landmarks by ascending id (copies).

        Returns:
            ``(ids (n,) int, means (n, 3) m, covs (n, 3, 3) m²)``.

        Raises:
            ValueError: The snapshot has no landmark covariances (a batch's per-step
                snapshot; a one-lane snapshot has them).
        """
        if self.landmark_covs is None:
            raise ValueError(
                "this snapshot has no landmark covariances: take a one-lane snapshot "
                "(lane_estimate) for them"
            )
        ids = self.landmark_ids(lane)
        return ids, self.landmark_means[lane, ids], self.landmark_covs[lane, ids]


def _lane_axis(a: FloatArray) -> FloatArray:
    """``a`` with a leading axis of 1: a view of a float array, else a new float array."""
    if type(a) is np.ndarray and a.dtype == np.float64:
        return a[None]  # half the cost of np.asarray(a, dtype=float)[None]
    return np.asarray(a, dtype=float)[None]


def empty_batch(num_lanes: int, capacity: int) -> BatchEstimate:
    """Zero snapshot of ``num_lanes`` lanes with landmark arrays of width ``capacity``."""
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


def id_width(snaps: Sequence[BatchEstimate]) -> int:
    """Landmark-array width that holds every landmark of the snapshots."""
    return max(s.landmark_mapped.shape[1] for s in snaps)


def stack_lanes(out: BatchEstimate, snaps: Sequence[BatchEstimate]) -> None:
    """Write the one-lane snapshots ``snaps`` (lane 0 of each, in lane order) into ``out``.

    ``out`` must be at least :func:`id_width` wide. The landmark covariances are left out
    (``out.landmark_covs`` is ``None``). Optional parts (covariance, biases, wind,
    diagnostics) follow the snapshots: ``pose_cov``, the biases and the wind become ``None``
    when the first lane has none; a diagnostic missing in a lane is NaN there.
    """
    b = len(snaps)
    if snaps[0].pose_cov is None:
        out.pose_cov = None
    elif out.pose_cov is None:
        out.pose_cov = np.zeros((b, POSE_DIM, POSE_DIM))
    out.landmark_covs = None
    # Reused between calls (the batch is a view: read, don't keep); zeroed like new arrays.
    for name, width in (("accel_bias", 3), ("gyro_bias", 3), ("wind", 2)):
        if getattr(snaps[0], name) is None:
            setattr(out, name, None)
        elif getattr(out, name) is None:
            setattr(out, name, np.zeros((b, width)))
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
    # A (1, …) row assigned to a lane's (…) slot drops its leading axis (numpy broadcasting),
    # at half the cost of indexing it first.
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
        if out.wind is not None and s.wind is not None:
            out.wind[lane] = s.wind
        width = s.landmark_mapped.shape[1]
        if width:
            out.landmark_means[lane, :width] = s.landmark_means
            out.landmark_mapped[lane, :width] = s.landmark_mapped
        diagnostics = out.diagnostics
        for k, v in s.diagnostics.items():
            diagnostics[k][lane] = v[0]
