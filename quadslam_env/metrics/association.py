"""Data-association metrics of unlabeled scans (``lidar.association: unknown``): which mapped
landmark is which true one, and per-scan counts of right, wrong and missed pairings.

See docs/design.md §5. Everything works on B lanes at once (a leading batch axis).
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.models.frames import dcm_from_trig
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

MATCH_RADIUS_M = 0.5
"""A mapped landmark with no true landmark this close (in the vehicle frame) is spurious."""

ASSOCIATION_KEYS = (
    "assoc_n_returns",
    "assoc_n_associated",
    "assoc_n_wrong",
    "assoc_n_true",
    "assoc_n_missed",
)
"""Per-scan association counts (unknown association; 0 in lanes that did not scan)."""


@kernel
def _match_lanes(
    means: FloatArray,
    mapped: np.ndarray,
    est_pose: FloatArray,
    true_landmarks: FloatArray,
    n_true: np.ndarray,
    true_pose: FloatArray,
    radius: float,
    out: np.ndarray,
) -> None:
    """Fill ``out`` (B, Le) (see :func:`match_landmarks`); poses are (B, 6) (ρ, Λ)."""
    d_est = np.empty(3)
    d_true = np.empty((true_landmarks.shape[1], 3))
    for b in range(mapped.shape[0]):
        ce = dcm_from_trig(
            math.cos(est_pose[b, 3]), math.sin(est_pose[b, 3]), math.cos(est_pose[b, 4]),
            math.sin(est_pose[b, 4]), math.cos(est_pose[b, 5]), math.sin(est_pose[b, 5]),
        )  # fmt: skip
        ct = dcm_from_trig(
            math.cos(true_pose[b, 3]), math.sin(true_pose[b, 3]), math.cos(true_pose[b, 4]),
            math.sin(true_pose[b, 4]), math.cos(true_pose[b, 5]), math.sin(true_pose[b, 5]),
        )  # fmt: skip
        for j in range(n_true[b]):  # C_NBᵀ (l − ρ): the true map about the true pose
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    acc += ct[3 * c + r] * (true_landmarks[b, j, c] - true_pose[b, c])
                d_true[j, r] = acc
        for i in range(mapped.shape[1]):
            out[b, i] = -1
            if not mapped[b, i]:
                continue
            for r in range(3):
                acc = 0.0
                for c in range(3):
                    acc += ce[3 * c + r] * (means[b, i, c] - est_pose[b, c])
                d_est[r] = acc
            best = radius * radius
            for j in range(n_true[b]):
                d2 = 0.0
                for r in range(3):
                    d2 += (d_est[r] - d_true[j, r]) ** 2
                if d2 <= best:
                    best = d2
                    out[b, i] = j


def match_landmarks(
    means: FloatArray,
    mapped: np.ndarray,
    est_pose: FloatArray,
    true_landmarks: FloatArray,
    n_true: np.ndarray,
    true_pose: FloatArray,
) -> np.ndarray:
    """Name each mapped landmark by its nearest true landmark within :data:`MATCH_RADIUS_M`.

    With unknown association an estimator names landmarks itself; this matching (the truth
    the simulator alone knows) is what the map RMSE and the association metrics use. It is
    done in the vehicle frame, as the sensor sees the map: ``C_NB(Λ̂)ᵀ (l̂ − ρ̂)`` against
    ``C_NB(Λ)ᵀ (l − ρ)``, so a SLAM map that drifts together with its vehicle (an unobservable
    offset) still matches.

    Args:
        means: (B, Le, 3) estimated landmark positions by estimator label (N, m).
        mapped: (B, Le) bool, labels in the map.
        est_pose: (B, 6) estimated (ρ̂ m, Λ̂ rad).
        true_landmarks: (B, L, 3) true positions by id (N, m); lane b uses the first
            ``n_true[b]`` rows.
        n_true: (B,) int.
        true_pose: (B, 6) true (ρ m, Λ rad).

    Returns:
        (B, Le) int: the true id of each label, -1 for unmapped labels and spurious entries.
    """
    out = np.empty(mapped.shape, dtype=np.int64)
    _match_lanes(
        np.ascontiguousarray(means, dtype=float),
        np.ascontiguousarray(mapped, dtype=bool),
        np.ascontiguousarray(est_pose, dtype=float),
        np.ascontiguousarray(true_landmarks, dtype=float),
        np.ascontiguousarray(n_true, dtype=np.int64),
        np.ascontiguousarray(true_pose, dtype=float),
        MATCH_RADIUS_M,
        out,
    )
    return out


def association_counts(
    truth: np.ndarray, labels: np.ndarray, count: np.ndarray, match: np.ndarray
) -> dict[str, FloatArray]:
    """Association counts of one scan of B lanes (:data:`ASSOCIATION_KEYS`, each (B,)).

    A return is *associated* when the estimator paired it with a map entry (label ≥ 0); it is
    *wrong* when that entry is not matched to the return's true landmark (a false return
    paired with anything is wrong); a *true* return (from a landmark) left unpaired is
    *missed*.

    Args:
        truth: (B, R) true landmark id of each return, -1 for a false return.
        labels: (B, ≥ R) the estimator's label of each return, -1 for none.
        count: (B,) returns per lane (0: the lane did not scan).
        match: (B, Le) true id of each label (:func:`match_landmarks`).
    """
    width = truth.shape[1]
    present = np.arange(width) < count[:, None]
    labels = np.pad(labels[:, :width], ((0, 0), (0, max(0, width - labels.shape[1]))),
                    constant_values=-1)  # fmt: skip
    associated = present & (labels >= 0)
    padded = np.pad(match, ((0, 0), (0, 1)), constant_values=-1)  # column -1: no entry
    named = np.take_along_axis(padded, np.where(labels < match.shape[1], labels, -1), axis=1)
    true_ret = present & (truth >= 0)
    return {
        "assoc_n_returns": count.astype(float),
        "assoc_n_associated": associated.sum(axis=1).astype(float),
        "assoc_n_wrong": (associated & ((truth < 0) | (named != truth))).sum(axis=1).astype(float),
        "assoc_n_true": true_ret.sum(axis=1).astype(float),
        "assoc_n_missed": (true_ret & ~associated).sum(axis=1).astype(float),
    }
