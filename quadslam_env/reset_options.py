"""Validation of the ``options`` of ``reset``: a given initial state and landmark map
(shared by the scalar and the vector env)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.config import ConfigError
from quadslam_env.types import STATE_DIM, FloatArray

RESET_OPTIONS = ("initial_state", "landmarks")


def parse_reset_options(options: dict[str, Any] | None) -> dict[str, FloatArray]:
    """Validate ``reset`` options: ``initial_state`` (12,), ``landmarks`` (L, 3).

    Raises:
        ConfigError: Not a dict, an unknown key, or a value of the wrong shape or range.
    """
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ConfigError(
            f"reset options: got {options!r}; allowed: a dict with keys {list(RESET_OPTIONS)}"
        )
    out: dict[str, FloatArray] = {}
    for key, value in options.items():
        if key not in RESET_OPTIONS:
            raise ConfigError(f"reset options.{key}: unknown key; allowed: {list(RESET_OPTIONS)}")
        arr = _as_float_array(value)
        if key == "initial_state":
            if arr is None or arr.shape != (STATE_DIM,) or not np.all(np.isfinite(arr)):
                raise ConfigError(
                    f"reset options.initial_state: got {value!r}; allowed: 12 "
                    "finite numbers (ρ [m], v_B [m/s], Λ [rad], ω [rad/s])"
                )
            if abs(arr[7]) >= math.radians(89.0):
                raise ConfigError(
                    f"reset options.initial_state[7] (pitch): got {arr[7]}; allowed: |θ| < 89°"
                )
        if key == "landmarks" and (
            arr is None
            or arr.ndim != 2
            or arr.shape[1] != 3
            or arr.shape[0] == 0
            or not np.all(np.isfinite(arr))
        ):
            raise ConfigError(
                f"reset options.landmarks: got {value!r}; allowed: a non-empty "
                "(L, 3) list of finite NED positions in m"
            )
        out[key] = arr  # type: ignore[assignment]
    return out


def _as_float_array(value: Any) -> FloatArray | None:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
