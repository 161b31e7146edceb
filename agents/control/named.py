"""The baseline controllers by name: what ``--policy NAME`` and ``wrapper.base: NAME`` build.

Each entry builds its controller from a (possibly wrapped) scalar or vector env, flying on
whatever the env's estimator reports (the observation), with SB3's ``predict`` signature. The
builders import their module when called, so the CLI reads the names without loading numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def _dflqr(env: Any) -> Any:
    from agents.control.dflqr import DFLQRPolicy

    return DFLQRPolicy.from_env(env)


def _lqi(env: Any) -> Any:
    from agents.control.lqi import LQIPolicy

    return LQIPolicy.from_env(env)


def _se3(env: Any) -> Any:
    from agents.control.se3 import SE3Policy

    return SE3Policy.from_env(env)


CONTROLLERS: dict[str, Callable[[Any], Any]] = {"dflqr": _dflqr, "lqi": _lqi, "se3": _se3}
"""Name → builder from an env: ``dflqr`` (seed 001 §2.2, the paper's gains), ``lqi`` (DF-LQR
with integral action in the Riccati design, :mod:`agents.control.lqi`) and ``se3`` (geometric
tracking on SE(3) with integral action, :mod:`agents.control.se3`)."""


def build_controller(name: str, env: Any, key: str = "--policy") -> Any:
    """The controller ``name`` (one of :data:`CONTROLLERS`) for ``env``.

    Args:
        name: Controller name.
        env: The env it flies (its vehicle, control period and action layout).
        key: The setting that named it, for the error.

    Raises:
        ValueError: ``name`` is not in :data:`CONTROLLERS` (naming ``key``).
    """
    if name not in CONTROLLERS:
        raise ValueError(f"{key}: got {name!r}; allowed: one of {sorted(CONTROLLERS)}")
    return CONTROLLERS[name](env)
