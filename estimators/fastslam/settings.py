"""Parameter validation shared by the FastSLAM filters (errors name ``estimator.params.<key>``)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.types import STATE_DIM, FloatArray

OWNER = "estimator.params"
FLOAT = (float, int)
VECTOR = (float, int, list, tuple, np.ndarray)

SIGMA_FLOOR = 1e-9
"""Smallest sensor standard deviation used in R (keeps S invertible for noise-free sensors)."""


def fail(key: str, value: Any, allowed: str) -> ValueError:
    """The ``ValueError`` for setting ``key`` = ``value``, naming what is allowed."""
    return ValueError(f"{OWNER}.{key}: invalid value {value!r}; allowed: {allowed}")


def positive(key: str, value: Any, strict: bool = True) -> float:
    """``value`` as a finite float > 0 (``strict``) or >= 0; else :func:`fail`."""
    v = float(value)
    if not math.isfinite(v) or v < 0.0 or (strict and v == 0.0):
        raise fail(key, value, "a finite number > 0" if strict else "a finite number >= 0")
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
