"""Estimators (docs/design.md §1, §5): they see sensor data and applied controls only, never
the truth.

``estimators.make(name, num_lanes=B, **settings)`` builds one by name through the registry of
the estimator boundary (:mod:`quadslam_env.estimation`), which these names are taken from;
``@estimators.register(name)`` adds your own.
"""

from quadslam_env.estimation import (
    BatchEstimate,
    BatchEstimator,
    Estimator,
    available,
    make,
    register,
)

__all__ = [
    "BatchEstimate",
    "BatchEstimator",
    "Estimator",
    "available",
    "make",
    "register",
]
