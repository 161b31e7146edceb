"""The iSAM2 estimator's output: its snapshot every control step, with or without the landmark
covariances, and its handling of a failure (docs/isam2.md, "The estimate every control step").

Between keyframes the estimate is the last keyframe's smoothed state predicted with the current
preintegration; its covariance is the keyframe's joint marginal propagated through the IMU
factor linearised from the keyframe to the prediction
(:class:`~estimators.isam2.transition.ImuTransition`). The landmarks' marginals change at
keyframes only and cost a Bayes-tree query over every landmark: they are recovered when a
snapshot first asks for them, while the smoother is still at that keyframe.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from estimators.isam2.fde import LandmarkKeys
from estimators.isam2.graph import keyframe_marginals
from estimators.isam2.settings import Isam2Settings
from estimators.isam2.snapshot import flagged, landmark_map, neutral, snapshot
from estimators.isam2.team import VEHICLE_STRIDE
from estimators.isam2.transition import ImuTransition
from quadslam_env.estimation.snapshot import BatchEstimate, LaneMap
from quadslam_env.types import POSE_DIM, FloatArray


class Isam2Output:
    """Mixin of :class:`~estimators.isam2.estimator.Isam2Slam`: its snapshots. Reads the
    keyframe state the smoother leaves behind; writes the snapshot caches, the landmark
    covariances it recovers on request and, on a failure, the divergence flag."""

    settings: Isam2Settings
    last_error: str
    _g: Any
    _isam: Any
    _smoother: Any
    _k: int
    _kf_pose: Any
    _kf_vel: FloatArray
    _kf_bias: Any
    _kf_cov: FloatArray
    _kf_dcm: FloatArray
    _kf_biases: tuple[FloatArray, FloatArray]
    _transition: ImuTransition | None
    _transition_current: bool
    _pim: Any
    _rates: FloatArray
    _known: dict[int, FloatArray] | None
    _lm_means: dict[int, FloatArray]
    _lm_covs: dict[int, FloatArray] | None
    _lm_map: LaneMap | None
    _diverged: bool
    _vehicle: int
    _landmark_keys: LandmarkKeys
    _monitor_diagnostics: Callable[[], dict[str, float]]  # estimators.isam2.fde
    _cache: BatchEstimate | None
    _state_cache: BatchEstimate | None
    _last: BatchEstimate | None

    def _key(self, char: str, index: int) -> int:
        """GTSAM's key of variable ``char`` (``x``, ``v``, ``b``: keyframe ``index``'s pose,
        velocity, biases; ``l``: landmark id ``index``), a vehicle's states shifted by its
        index in a team (:data:`~estimators.isam2.team.VEHICLE_STRIDE`; landmarks are shared)."""
        if char != "l":
            index += self._vehicle * VEHICLE_STRIDE
        else:  # a landmark the integrity monitor retired has a successor (estimators.isam2.fde)
            index = self._landmark_keys.index(index)
        return int(self._g.symbol(char, index))

    def estimate(self) -> BatchEstimate:
        """Snapshot of the belief (B = 1, copies).

        Returns:
            :class:`BatchEstimate` of one lane with the keyframe's smoothed state predicted to
            now with the current preintegration, ``pose_cov`` (9, 9) over (ρ, v_B, Λ),
            ``rates`` = last gyro minus the gyro-bias estimate, the landmarks by id with their
            covariances (known map: the map, zero covariance), the biases when estimated and
            the diagnostics ``diverged``, ``n_keyframes``, ``n_mapped``. The landmark
            covariances are recovered from the Bayes tree at the first call after a keyframe.
        """
        if self._cache is None:
            self._cache = self._take(with_covs=True)
        return self._cache

    def state_estimate(self) -> BatchEstimate:
        """:meth:`estimate` without the landmark covariances (``landmark_covs`` None).

        The env's per-step snapshot leaves them out
        (:class:`~quadslam_env.estimation.EstimatesState`), and recovering them costs more
        than the rest of a keyframe's marginals (one Bayes-tree query over every landmark).
        """
        if self._cache is not None:  # the full snapshot of this step serves as well
            return self._cache
        if self._state_cache is None:
            self._state_cache = self._take(with_covs=False)
        return self._state_cache

    def _take(self, with_covs: bool) -> BatchEstimate:
        """A new snapshot; on a failure the last finite one, flagged as diverged."""
        if self._smoother is None:  # before the first reset
            return neutral(self._diagnostics(0))
        try:
            est = self._build_estimate(with_covs)
        except Exception as exc:  # a failed prediction or covariance: keep the last one
            self._diverge(exc)
            est = flagged(self._last if self._last is not None else neutral(self._diagnostics(0)))
            if with_covs and est.landmark_covs is None:  # the last one left them out
                est.landmark_covs = np.zeros((*est.landmark_means.shape, 3))
        if not self._diverged:
            self._last = est
        return est

    def _diverge(self, exc: BaseException) -> None:
        self._diverged = True
        self.last_error = f"{type(exc).__name__}: {exc}"

    def _link(self) -> ImuTransition:
        """The IMU factor's linearisation at the current keyframe (moved there on first use)."""
        if self._transition is None:
            self._transition = ImuTransition(self._g, self._kf_pose, self._kf_vel, self._kf_bias)
        elif not self._transition_current:
            self._transition.rebase(self._kf_pose, self._kf_vel, self._kf_bias)
        self._transition_current = True
        return self._transition

    def _predicted(self) -> tuple[Any, FloatArray, FloatArray, FloatArray]:
        """``(pose, v_N (3,), C_NB (3, 3), Σ (9, 9) over (δθ, δt, δv_N))`` now: the keyframe
        state predicted with the current preintegration, ``Σ = F Σ_i Fᵀ + Q``
        (:meth:`~estimators.isam2.transition.ImuTransition.propagate`)."""
        pim = self._pim
        if pim is None or pim.deltaTij() <= 0.0:
            cov = np.ascontiguousarray(self._kf_cov[:POSE_DIM, :POSE_DIM])
            return self._kf_pose, self._kf_vel, self._kf_dcm, cov
        return self._link().propagate(pim, self._kf_cov)

    def _landmark_covs(self) -> dict[int, FloatArray]:
        """Each mapped landmark's marginal (3, 3) in m² at the current keyframe: recovered from
        the Bayes tree on first use (the smoother has not moved since the keyframe), then kept."""
        if self._lm_covs is None:
            ids = sorted(self._lm_means)
            keys = [self._key("l", i) for i in ids]
            blocks = keyframe_marginals(self._isam, [], keys)[1] if ids else []
            self._lm_covs = dict(zip(ids, blocks, strict=True))
        return self._lm_covs

    def _build_estimate(self, with_covs: bool) -> BatchEstimate:
        pose, vel_n, dcm, cov_t = self._predicted()
        lane_map = self._lm_map  # the map changes at keyframes only (known map: no covs)
        if lane_map is None or (with_covs and lane_map.covs is None):
            covs = self._landmark_covs() if with_covs else None
            lane_map = self._lm_map = landmark_map(self._known or self._lm_means, covs)
        biases = self._kf_biases if self.settings.estimate_imu_bias else None
        return snapshot(
            pose.translation(),
            dcm,
            vel_n,
            cov_t,
            self._rates,
            lane_map,
            biases,
            self._diagnostics(int(np.count_nonzero(lane_map.mapped))),
        )

    def _diagnostics(self, n_mapped: int) -> dict[str, float]:
        return {
            "diverged": float(self._diverged),
            "n_keyframes": float(self._k),
            "n_mapped": float(n_mapped),
            **self._monitor_diagnostics(),
        }
