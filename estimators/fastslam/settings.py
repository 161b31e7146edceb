"""Parameter validation shared by the FastSLAM filters (errors name ``estimator.params.<key>``)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from estimators.association import chi2_threshold
from estimators.tentative import check_confirm_rule
from quadslam_env.types import MEAS_DIM, STATE_DIM, FloatArray

OWNER = "estimator.params"
FLOAT = (float, int)
VECTOR = (float, int, list, tuple, np.ndarray)

SIGMA_FLOOR = 1e-9
"""Smallest sensor standard deviation used in R (keeps S invertible for noise-free sensors)."""


def scan_noise(sigma: FloatArray) -> FloatArray:
    """The LiDAR noise covariance R (3, 3) of a scan's σ (3,) (rad, rad, m), floored."""
    sig = np.maximum(np.asarray(sigma, dtype=float).reshape(3), SIGMA_FLOOR)
    return np.diag(sig * sig)


def fail(key: str, value: Any, allowed: str) -> ValueError:
    """The ``ValueError`` for setting ``key`` = ``value``, naming what is allowed."""
    return ValueError(f"{OWNER}.{key}: invalid value {value!r}; allowed: {allowed}")


def positive(key: str, value: Any, strict: bool = True) -> float:
    """``value`` as a finite float > 0 (``strict``) or >= 0; else :func:`fail`."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (strict and v == 0.0):
        raise fail(key, value, "a finite number > 0" if strict else "a finite number >= 0")
    return v


def fraction(key: str, value: Any) -> float:
    """``value`` as a float in [0, 1]; else :func:`fail`."""
    v = float(value)
    if not 0.0 <= v <= 1.0:
        raise fail(key, value, "a number in [0, 1]")
    return v


def parse_process_noise(key: str, value: Any) -> FloatArray:
    """Expand a scalar, 4 group values (ρ, v, Λ, ω) or 12 values to a (12,) density."""
    allowed = "a number, 4 values (ρ, v, Λ, ω groups) or 12 values, all finite and >= 0"
    try:
        arr = np.asarray(value, dtype=float).ravel()
    except (TypeError, ValueError):
        raise fail(key, value, allowed) from None
    if arr.size == 1:
        arr = np.full(STATE_DIM, arr[0])
    elif arr.size == 4:
        arr = np.repeat(arr, 3)
    elif arr.size != STATE_DIM:
        raise fail(key, value, allowed)
    if not np.all(np.isfinite(arr)) or np.any(arr < 0.0):
        raise fail(key, value, allowed)
    return arr


@dataclass(frozen=True)
class AssociationSettings:
    """Per-particle data association settings (``lidar.association: unknown``).

    Attributes:
        gate_probability: p of the individual χ²₃ gate on ``νᵀ S⁻¹ ν``, in (0, 1] (1: no gate).
        new_landmark_likelihood: p0 > 0, the likelihood density (per rad²·m of measurement
            space) of a return under the new-landmark/clutter hypothesis.
        confirm_hits: M of the M-of-N rule for tentative landmarks.
        confirm_window: N of the M-of-N rule.
    """

    gate_probability: float = 0.99
    new_landmark_likelihood: float = 1e-3
    confirm_hits: int = 3
    confirm_window: int = 5

    @classmethod
    def from_params(cls, params: dict[str, Any]) -> AssociationSettings:
        """Read and validate the four keys from ``params`` (the others are ignored).

        Raises:
            ValueError: Naming the key, the value and what is allowed.
        """
        prob = params.get("gate_probability", cls.gate_probability)
        if not 0.0 < float(prob) <= 1.0:
            raise fail("gate_probability", prob, "a number p with 0 < p <= 1")
        p0 = positive(
            "new_landmark_likelihood",
            params.get("new_landmark_likelihood", cls.new_landmark_likelihood),
        )
        hits, window = check_confirm_rule(
            params.get("confirm_hits", cls.confirm_hits),
            params.get("confirm_window", cls.confirm_window),
            OWNER,
        )
        return cls(float(prob), p0, hits, window)

    @property
    def gate(self) -> float:
        """The χ²₃ quantile of :attr:`gate_probability` (inf when it is 1)."""
        return chi2_threshold(MEAS_DIM, self.gate_probability)
