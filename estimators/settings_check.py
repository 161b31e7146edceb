"""The check of an estimator's keyword settings: unknown keys and wrong types name the key."""

from __future__ import annotations

from typing import Any

import numpy as np


def check_kwargs(
    owner: str, given: dict[str, Any], allowed: dict[str, type | tuple[type, ...]]
) -> None:
    """Reject unknown or wrongly typed estimator settings with a message naming the key.

    Args:
        owner: Prefix for the message, e.g. ``"estimator.params"``.
        given: The settings passed in.
        allowed: Map from key to accepted type(s).

    Raises:
        ValueError: On an unknown key or a value of the wrong type.
    """
    for key, value in given.items():
        if key not in allowed:
            raise ValueError(f"{owner}.{key}: unknown key; allowed: {sorted(allowed)}")
        accepted = allowed[key]
        want: tuple[type, ...] = accepted if isinstance(accepted, tuple) else (accepted,)
        # NumPy scalars are as good as Python numbers (e.g. a particle count from np.arange).
        if isinstance(value, np.integer) and int in want:
            value = int(value)
        elif isinstance(value, np.floating) and float in want:
            value = float(value)
        # bool is an int subclass: accept it only where bool is asked for.
        wrong_bool = isinstance(value, bool) and bool not in want
        if wrong_bool or not isinstance(value, want):
            names = " or ".join(t.__name__ for t in want)
            raise ValueError(f"{owner}.{key}: expected {names}, got {value!r}")
