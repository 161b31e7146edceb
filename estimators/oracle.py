"""Oracle estimator: reports the true state (docs/design.md §5), for ablations.

It is the one estimator the simulation feeds with the truth (through ``set_truth``); it has no
covariance, so NEES is reported as NaN by the metrics. :class:`OracleBatch` serves B lanes (one
lane for the scalar env).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from estimators.memory import MemoryTerm, Workload, oracle_terms
from quadslam_env.estimation.protocol import KnownMaps
from quadslam_env.estimation.registry import register
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.models.frames import dcm_from_euler_batch
from quadslam_env.schema import Section
from quadslam_env.types import EUL, POS, RATE, VEL, FloatArray


@dataclass(frozen=True)
class OracleSettings(Section):
    """The oracle has no settings: any ``estimator.params`` key is rejected."""

    SECTION: ClassVar[str] = "estimator.params"


@register("oracle")
class OracleBatch:
    """The true vehicle states and maps of B lanes.

    Args:
        num_lanes: B.
        landmark_capacity: Initial width Lmax of the map arrays (grows as needed).
        vehicle: Nominal vehicle parameters (unused; accepted like every estimator).
    """

    uses_truth = True

    @classmethod
    def memory_terms(cls, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
        """The snapshot of ``load``'s lanes (:func:`estimators.memory.oracle_terms`).

        Raises:
            ConfigError: Any ``estimator.params`` key (the oracle has none).
        """
        OracleSettings.from_dict(params)
        return oracle_terms(load)

    def __init__(
        self, num_lanes: int, landmark_capacity: int, vehicle: Any = None, **params: Any
    ) -> None:
        OracleSettings.from_dict(params)
        self.num_lanes = num_lanes
        b = num_lanes
        # Separate arrays, not views of one state array: views would not survive pickling.
        self._out = BatchEstimate(
            position=np.zeros((b, 3)),
            vel_body=np.zeros((b, 3)),
            vel_inertial=np.zeros((b, 3)),
            euler=np.zeros((b, 3)),
            rates=np.zeros((b, 3)),
            pose_cov=None,
            landmark_means=np.zeros((b, landmark_capacity, 3)),
            landmark_mapped=np.zeros((b, landmark_capacity), dtype=bool),
        )

    def reset_lanes(
        self,
        lanes: np.ndarray,
        mean0: FloatArray,
        cov0: FloatArray,
        rngs: Sequence[np.random.Generator],
        known_landmarks: KnownMaps = None,
    ) -> None:
        """Start; the state is overwritten by :meth:`set_truth` before every use."""
        self._write_state(np.asarray(lanes), np.asarray(mean0, dtype=float))
        self._out.landmark_mapped[lanes] = False

    def _write_state(self, lanes: np.ndarray | slice, states: FloatArray) -> None:
        out = self._out
        out.position[lanes] = states[:, POS]
        out.vel_body[lanes] = states[:, VEL]
        out.euler[lanes] = states[:, EUL]
        out.rates[lanes] = states[:, RATE]
        dcm = dcm_from_euler_batch(states[:, EUL])
        out.vel_inertial[lanes] = np.einsum("bij,bj->bi", dcm, states[:, VEL])

    def set_truth(self, states: FloatArray, landmarks: FloatArray, counts: np.ndarray) -> None:
        """Receive the true states (B, 12) and maps (B, L, 3) with ``counts`` (B,) landmarks."""
        self._write_state(slice(None), states)
        out = self._out
        width = landmarks.shape[1]
        if width > out.landmark_means.shape[1]:
            out.landmark_means = np.zeros((self.num_lanes, width, 3))
            out.landmark_mapped = np.zeros((self.num_lanes, width), dtype=bool)
        out.landmark_means[:, :width] = landmarks
        out.landmark_mapped[:] = np.arange(out.landmark_mapped.shape[1]) < counts[:, None]

    def predict(self, *args: Any, **kwargs: Any) -> None:
        """Nothing to do: the truth arrives through :meth:`set_truth`."""

    def update(self, *args: Any, **kwargs: Any) -> None:
        """Nothing to do: the truth arrives through :meth:`set_truth`."""

    update_unlabeled = update

    @property
    def last_association(self) -> np.ndarray:
        """(B, 0): the oracle pairs no return (its map is the truth, labeled by id)."""
        return np.zeros((self.num_lanes, 0), dtype=np.int64)

    def estimate(self) -> BatchEstimate:
        """The truth of every lane, with no covariance."""
        return self._out

    def lane_estimate(self, lane: int) -> BatchEstimate:
        """The truth of one lane as a one-lane snapshot (B = 1, copies)."""
        out = self._out
        ids = np.flatnonzero(out.landmark_mapped[lane])
        return BatchEstimate.one_lane(
            position=out.position[lane].copy(),
            vel_body=out.vel_body[lane].copy(),
            vel_inertial=out.vel_inertial[lane].copy(),
            euler=out.euler[lane].copy(),
            rates=out.rates[lane].copy(),
            pose_cov=None,
            landmark_ids=ids,
            landmark_means=out.landmark_means[lane, ids],
            landmark_covs=np.zeros((ids.size, 3, 3)),
        )
