"""Accuracy and consistency metrics: the only package that sees truth and estimate together.

:mod:`.step` compares one step's estimate with the truth, :mod:`.association` scores the data
association of unlabeled scans, :mod:`.episode` sums both over an episode and its phases.
"""

from quadslam_env.metrics.association import (
    ASSOCIATION_KEYS,
    MATCH_RADIUS_M,
    association_counts,
    match_landmarks,
)
from quadslam_env.metrics.episode import (
    PHASES,
    SETTLE_TOL_S,
    EpisodeMetrics,
    input_columns,
    phase_key,
)
from quadslam_env.metrics.step import (
    METRIC_KEYS,
    NEES_POSE_BOUNDS_95,
    WIND_METRIC_KEYS,
    anees_bounds,
    cholesky_nees,
    metric_columns,
    step_metrics,
    wind_columns,
)

__all__ = [
    "ASSOCIATION_KEYS",
    "MATCH_RADIUS_M",
    "METRIC_KEYS",
    "NEES_POSE_BOUNDS_95",
    "PHASES",
    "SETTLE_TOL_S",
    "WIND_METRIC_KEYS",
    "EpisodeMetrics",
    "anees_bounds",
    "association_counts",
    "cholesky_nees",
    "input_columns",
    "match_landmarks",
    "metric_columns",
    "phase_key",
    "step_metrics",
    "wind_columns",
]
