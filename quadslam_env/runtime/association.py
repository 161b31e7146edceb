"""The core's side of data association: which scans the estimator gets, and how its map and
its pairing of returns are scored (docs/design.md §4, §5).

``lidar.association`` picks one of two components (:func:`association_for`), which
:class:`~quadslam_env.core.SimCore` calls the same way at every step:

- :class:`KnownAssociation`: labeled scans (:class:`~quadslam_env.sim.scans.LabeledScans`); an
  estimator's map entry j is landmark j, so the map is scored by id and nothing is kept.
- :class:`UnknownAssociation`: unlabeled returns (:class:`~quadslam_env.sim.scans.UnlabeledScans`);
  the estimator names landmarks itself, so after each update the simulator names the map's
  entries by their true landmarks (:func:`~quadslam_env.metrics.match_landmarks`), counts how
  the estimator labeled the returns (:func:`~quadslam_env.metrics.association_counts`),
  scores the map over the matched entries and reports the association terms.
"""

from __future__ import annotations

import dataclasses
from typing import Any, Protocol, cast

import numpy as np

from quadslam_env.estimation.protocol import AssociatesUnlabeled, BatchEstimator
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.metrics.association import ASSOCIATION_KEYS, association_counts, match_landmarks
from quadslam_env.metrics.step import METRIC_KEYS, metric_columns
from quadslam_env.sim.lidar import LidarBatch
from quadslam_env.sim.scans import LabeledScans, Scans, UnlabeledScans
from quadslam_env.types import EUL, POS, FloatArray

_N_MAPPED = METRIC_KEYS.index("est_n_mapped")


class Association(Protocol):
    """What the core asks of either association component."""

    def scan(
        self,
        lidar: LidarBatch,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        lanes: np.ndarray,
    ) -> Scans:
        """The scans of ``lanes`` (k,) from their true poses, of the kind the estimator takes.

        Args:
            lidar: The lanes' LiDAR.
            pos: (B, 3) true positions in N, m.
            dcm: (B, 3, 3) true ``C_NB``.
            landmarks: (B, Lmax, 3) true landmark positions in N, m.
            n_landmarks: (B,) int landmarks present per lane.
            lanes: (k,) int lanes that scan now.
        """

    def update(
        self,
        est: BatchEstimate,
        estimator: BatchEstimator,
        scans: Scans | None,
        changed: np.ndarray,
        state: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
    ) -> None:
        """Take note of the estimator's belief ``est`` after a step or a reset.

        Args:
            est: The estimator's belief now.
            estimator: The estimator that produced it (its labelling of ``scans``' returns).
            scans: The scans the estimator took this step (measured now, or arrived late:
                ``EstimatorCopies.applied``; ``None``: none, or a reset).
            changed: (B,) bool lanes whose map changed other than by ``scans``: reset, or
                rebuilt from a filter copy (``EstimatorCopies.refreshed``,
                :mod:`quadslam_env.runtime.period_log`).
            state: (B, 12) true states.
            landmarks: (B, Lmax, 3) true landmark positions in N, m.
            n_landmarks: (B,) int landmarks present per lane.
        """

    def metric_columns(
        self,
        state: FloatArray,
        est: BatchEstimate,
        landmarks: FloatArray,
        bias: FloatArray,
        values: FloatArray,
        wind: FloatArray | None = None,
    ) -> tuple[tuple[str, int], ...]:
        """:func:`~quadslam_env.metrics.metric_columns` with the map scored as this
        association names it (arguments, the true wind included, and return as there)."""

    def info(self) -> dict[str, Any]:
        """The association terms of the last :meth:`update` (each (B,)), for ``info``."""


class KnownAssociation:
    """Known association (:class:`Association`): labeled scans, the map scored by id."""

    def scan(
        self,
        lidar: LidarBatch,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        lanes: np.ndarray,
    ) -> LabeledScans:
        visible, meas = lidar.scan(pos, dcm, landmarks, n_landmarks, lanes)
        return LabeledScans(lanes, visible, meas)

    def update(
        self,
        est: BatchEstimate,
        estimator: BatchEstimator,
        scans: Scans | None,
        changed: np.ndarray,
        state: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
    ) -> None:
        """Nothing to note: the returns carry their landmark ids."""

    def metric_columns(
        self,
        state: FloatArray,
        est: BatchEstimate,
        landmarks: FloatArray,
        bias: FloatArray,
        values: FloatArray,
        wind: FloatArray | None = None,
    ) -> tuple[tuple[str, int], ...]:
        return metric_columns(state, est, landmarks, bias, values, wind)

    def info(self) -> dict[str, Any]:
        return {}


class UnknownAssociation:
    """Unknown association (:class:`Association`): unlabeled returns, the estimator's map
    entries named by their true landmarks, the association outcomes counted.

    Args:
        num_lanes: B.
    """

    def __init__(self, num_lanes: int) -> None:
        b = self.num_lanes = int(num_lanes)
        self._match = np.full((b, 0), -1, dtype=np.int64)  # true id of each estimator label
        self._matched = np.zeros((b, 0), dtype=bool)
        self._match_truth = np.zeros((b, 0, 3))  # the true position each label is named by
        self._spurious = np.zeros(b)
        self._counts = dict.fromkeys(ASSOCIATION_KEYS, np.zeros(b))

    def scan(
        self,
        lidar: LidarBatch,
        pos: FloatArray,
        dcm: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
        lanes: np.ndarray,
    ) -> UnlabeledScans:
        return UnlabeledScans(lanes, lidar.returns(pos, dcm, landmarks, n_landmarks, lanes))

    def update(
        self,
        est: BatchEstimate,
        estimator: BatchEstimator,
        scans: Scans | None,
        changed: np.ndarray,
        state: FloatArray,
        landmarks: FloatArray,
        n_landmarks: np.ndarray,
    ) -> None:
        """Name the map's entries by their true landmarks in the lanes that scanned or
        ``changed`` (a lane's map changes only then, and naming a lane at other times would
        make it depend on the other lanes), then count the outcomes of ``scans``."""
        rematch = changed.copy()
        if scans is not None:
            rematch[scans.lanes] = True
        if rematch.any() or self._match.shape != est.landmark_mapped.shape:
            match = match_landmarks(
                est.landmark_means, est.landmark_mapped, np.hstack((est.position, est.euler)),
                landmarks, n_landmarks, np.hstack((state[:, POS], state[:, EUL])),
            )  # fmt: skip
            if self._match.shape == match.shape:
                match = np.where(rematch[:, None], match, self._match)
            self._match = match
            self._matched = match >= 0
            self._match_truth = np.take_along_axis(
                landmarks, np.maximum(match, 0)[..., None], axis=1
            )
            self._spurious = (est.landmark_mapped & ~self._matched).sum(axis=1).astype(float)
        if scans is None:
            self._counts = dict.fromkeys(ASSOCIATION_KEYS, np.zeros(self.num_lanes))
            return
        returns = cast(UnlabeledScans, scans).returns  # made by :meth:`scan`
        # the scenario check let only an estimator that AssociatesUnlabeled through
        labels = cast(AssociatesUnlabeled, estimator).last_association
        self._counts = association_counts(returns.truth, labels, returns.count, self._match)

    def metric_columns(
        self,
        state: FloatArray,
        est: BatchEstimate,
        landmarks: FloatArray,
        bias: FloatArray,
        values: FloatArray,
        wind: FloatArray | None = None,
    ) -> tuple[tuple[str, int], ...]:
        """The map RMSE over the entries matched to a true landmark (each against it); the
        mapped count over every entry."""
        matched = dataclasses.replace(est, landmark_mapped=self._matched)
        keys = metric_columns(state, matched, self._match_truth, bias, values, wind)
        values[_N_MAPPED] = est.landmark_mapped.sum(axis=1)
        return keys

    def info(self) -> dict[str, Any]:
        counts = self._counts
        out: dict[str, Any] = {"spurious_landmarks": self._spurious.copy(), **counts}
        with np.errstate(invalid="ignore", divide="ignore"):
            out["assoc_wrong_rate"] = counts["assoc_n_wrong"] / counts["assoc_n_associated"]
            out["assoc_missed_rate"] = counts["assoc_n_missed"] / counts["assoc_n_true"]
        return out


def association_for(association: str, num_lanes: int) -> Association:
    """The component for ``lidar.association`` (``"known"`` or ``"unknown"``) of B lanes."""
    return UnknownAssociation(num_lanes) if association == "unknown" else KnownAssociation()
