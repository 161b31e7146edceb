"""Validation of the arguments of ``reset``: the seed, a given initial state and landmark map
(shared by the scalar and the vector env) and the vector env's ``reset_mask``."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from quadslam_env.config.randomize import parse_pins
from quadslam_env.schema import ConfigError
from quadslam_env.types import EUL, POS, RATE, STATE_DIM, VEL, FloatArray

RESET_OPTIONS = ("initial_state", "landmarks", "randomized")
POSITION_MAX_M = 1e6
"""Largest |coordinate| of a given start position or landmark, m (as ``episode.initial_position``
and ``trajectory.center``)."""
SPEED_MAX_MPS = 1e3
"""Largest |component| of a given start velocity, m/s (as ``episode.initial_velocity``)."""
RATE_MAX_RAD_S = 100.0
"""Largest |component| of a given start body rate, rad/s (16 turns per second, beyond every
gyro preset's full scale of 2000 deg/s = 35 rad/s)."""
_STATE_BOUNDS = (
    (POS, "position ρ", POSITION_MAX_M, "m"),
    (VEL, "velocity v_B", SPEED_MAX_MPS, "m/s"),
    (EUL, "attitude Λ", math.pi, "rad"),
    (RATE, "rate ω", RATE_MAX_RAD_S, "rad/s"),
)
"""``(entries, name, largest magnitude, unit)`` of the ``initial_state`` option; the pitch is
bounded tighter (|θ| < 89°)."""
RESET_MASK = "reset_mask"
_SEED_ALLOWED = "None or an integer >= 0"


def parse_seed(seed: Any, key: str = "seed", allowed: str = _SEED_ALLOWED) -> int | None:
    """Validate one seed as ``gymnasium.Env.reset`` takes it, NumPy integers included.

    Args:
        seed: ``None`` or an integer ≥ 0 (``int`` or ``np.integer``; not ``bool``).
        key: The name in the error message, e.g. ``seed[2]`` for an entry of a list.
        allowed: What the error message says is allowed.

    Returns:
        The seed as a Python ``int`` (what ``gymnasium.utils.seeding`` accepts), or ``None``.

    Raises:
        ConfigError: Not an integer (a float, a string, a bool), or negative.
    """
    if seed is None:
        return None
    # bool is an int subclass, but True is a mistake, not seed 1.
    if isinstance(seed, bool | np.bool_) or not isinstance(seed, int | np.integer) or seed < 0:
        raise ConfigError(f"{key}: got {seed!r}; allowed: {allowed}")
    return int(seed)


def parse_lane_seeds(seed: Any, num_lanes: int) -> list[int | None]:
    """The seed of each of ``num_lanes`` lanes, as Gymnasium's vector envs take them.

    Args:
        seed: ``None`` (no lane reseeded), an integer s (lane i gets s + i) or a list, tuple or
            1-D array of ``num_lanes`` entries, each ``None`` or an integer ≥ 0.
        num_lanes: B.

    Returns:
        (B,) list of ``int`` or ``None``.

    Raises:
        ConfigError: A seed that :func:`parse_seed` rejects, or a sequence of the wrong length.
    """
    each = f"a list of {num_lanes} seeds, one per lane, each {_SEED_ALLOWED}"
    if isinstance(seed, list | tuple) or (isinstance(seed, np.ndarray) and seed.ndim == 1):
        if len(seed) != num_lanes:
            raise ConfigError(f"seed: got {seed!r} (a list of {len(seed)}); allowed: {each}")
        entry = f"{_SEED_ALLOWED} (one seed per lane)"
        return [parse_seed(s, f"seed[{i}]", entry) for i, s in enumerate(seed)]
    first = parse_seed(seed, "seed", f"None, an integer >= 0 (lane i gets seed + i) or {each}")
    return [None if first is None else first + i for i in range(num_lanes)]


def split_reset_mask(
    options: dict[str, Any] | None, num_lanes: int
) -> tuple[np.ndarray | None, dict[str, Any] | None]:
    """Take the vector env's ``reset_mask`` out of ``options`` (the caller's dict is not changed).

    Args:
        options: The ``options`` of a vector env's ``reset``.
        num_lanes: B.

    Returns:
        ``(mask (B,) bool or None, the other options or None)``.

    Raises:
        ConfigError: A mask that is not a (B,) bool array with at least one ``True`` (as
            Gymnasium's vector envs require).
    """
    if not isinstance(options, dict) or RESET_MASK not in options:
        return None, options
    value = options[RESET_MASK]
    try:
        mask = np.asarray(value) if isinstance(value, list | tuple | np.ndarray) else None
    except ValueError:  # a ragged list
        mask = None
    if mask is None or mask.dtype != np.bool_ or mask.shape != (num_lanes,) or not mask.any():
        raise ConfigError(
            f"reset options.{RESET_MASK}: got {value!r}; allowed: a ({num_lanes},) bool array "
            "with at least one True (the lanes to reset)"
        )
    rest = {key: v for key, v in options.items() if key != RESET_MASK}
    return mask.copy(), rest or None


def parse_reset_options(options: dict[str, Any] | None) -> dict[str, Any]:
    """Validate ``reset`` options: ``initial_state`` (12,), ``landmarks`` (L, 3), ``randomized``
    (a mapping of domain-randomisation scales to pin, :func:`parse_pins`).

    Raises:
        ConfigError: Not a dict, an unknown key, or a value of the wrong shape or range.
    """
    if options is None:
        return {}
    if not isinstance(options, dict):
        raise ConfigError(
            f"reset options: got {options!r}; allowed: a dict with keys {list(RESET_OPTIONS)}"
        )
    out: dict[str, Any] = {}
    for key, value in options.items():
        if key not in RESET_OPTIONS:
            raise ConfigError(f"reset options.{key}: unknown key; allowed: {list(RESET_OPTIONS)}")
        if key == "randomized":
            out[key] = parse_pins(value)
            continue
        arr = _as_float_array(value)
        if key == "initial_state":
            if arr is None or arr.shape != (STATE_DIM,) or not np.all(np.isfinite(arr)):
                raise ConfigError(
                    f"reset options.initial_state: got {value!r}; allowed: 12 "
                    "finite numbers (ρ [m], v_B [m/s], Λ [rad], ω [rad/s])"
                )
            _check_state(arr)
        if key == "landmarks" and (
            arr is None
            or arr.ndim != 2
            or arr.shape[1] != 3
            or arr.shape[0] == 0
            or not np.all(np.abs(arr) <= POSITION_MAX_M)  # also False at NaN
        ):
            raise ConfigError(
                f"reset options.landmarks: got {value!r}; allowed: a non-empty "
                f"(L, 3) list of NED positions in m, each coordinate in ±{POSITION_MAX_M:g}"
            )
        out[key] = arr
    return out


def _check_state(state: FloatArray) -> None:
    """Each entry of a finite (12,) ``initial_state`` within its bound (:data:`_STATE_BOUNDS`).

    Raises:
        ConfigError: Naming the first entry out of range, its value and what is allowed.
    """
    for entries, name, bound, unit in _STATE_BOUNDS:
        for i in range(STATE_DIM)[entries]:
            if abs(state[i]) > bound:
                raise ConfigError(
                    f"reset options.initial_state[{i}] ({name}): got {float(state[i])}; allowed: a "
                    f"number in ±{bound:g} {unit}"
                )
    if abs(state[7]) >= math.radians(89.0):
        raise ConfigError(
            f"reset options.initial_state[7] (pitch): got {float(state[7])}; allowed: |θ| < 89°"
        )


def _as_float_array(value: Any) -> FloatArray | None:
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return None
