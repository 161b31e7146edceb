"""Estimators (layer 3): they see sensor data and applied controls only, never the truth.

``estimators.make(name, **cfg)`` builds one by name; ``estimators.metrics`` is the only module
that sees truth and estimate together.
"""

from estimators.base import Estimate, Estimator, available, make, register

__all__ = ["Estimate", "Estimator", "available", "make", "register"]
