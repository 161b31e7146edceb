"""The baseline controllers by name: what ``--policy NAME`` and ``wrapper.base: NAME`` build.

Each entry builds its controller from a (possibly wrapped) scalar or vector env, flying on
whatever the env's estimator reports (the observation), with SB3's ``predict`` signature. The
builders import their module when called, so the CLI reads the names without loading numpy.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any


def _dflqr(env: Any, **options: Any) -> Any:
    from agents.control.dflqr import DFLQRPolicy

    return DFLQRPolicy.from_env(env, **options)


def _lqi(env: Any, **options: Any) -> Any:
    from agents.control.lqi import LQIPolicy

    return LQIPolicy.from_env(env, **options)


def _se3(env: Any, **options: Any) -> Any:
    from agents.control.se3 import SE3Policy

    return SE3Policy.from_env(env, **options)


CONTROLLERS: dict[str, Callable[..., Any]] = {"dflqr": _dflqr, "lqi": _lqi, "se3": _se3}
"""Name → builder from an env: ``dflqr`` (seed 001 §2.2, the paper's gains), ``lqi`` (DF-LQR
with integral action in the Riccati design, :mod:`agents.control.lqi`) and ``se3`` (geometric
tracking on SE(3) with integral action, :mod:`agents.control.se3`)."""

FEEDFORWARD = ("lqi", "se3")
"""The controllers that take ``drag_feedforward`` (:mod:`agents.control.drag`)."""

ADAPTATION = ("lqi", "se3")
"""The controllers that take ``thrust_adaptation`` (:mod:`agents.control.adaptation`)."""

OPTIONS = {
    "drag_feedforward": (FEEDFORWARD, "the drag feed-forward"),
    "thrust_adaptation": (ADAPTATION, "the thrust adaptation"),
}
"""Each option of :func:`build_controller`: the controllers that take it and its name in errors."""


def controller_options(name: str, key: str = "--policy", **given: Any) -> dict[str, Any]:
    """The options of :data:`OPTIONS` in ``given`` that are not ``False``, checked against
    the controller ``name`` (its name is not checked: a name that is no controller takes
    none).

    Args:
        name: What ``key`` names: a controller, or another policy (a trained model).
        key: The setting that named it, for the error.
        **given: Option → value (``drag_feedforward=True``).

    Raises:
        ValueError: An option not in :data:`OPTIONS`, or one on a policy without it (naming
            the option and ``key``).
    """
    options = {option: value for option, value in given.items() if value is not False}
    for option, value in options.items():
        if option not in OPTIONS:
            raise ValueError(f"{option}: unknown controller option; allowed: {list(OPTIONS)}")
        names, what = OPTIONS[option]
        if name not in names:
            raise ValueError(
                f"{option}: got {value!r} with {key} {name}; allowed: false, or a controller "
                f"with {what} ({', '.join(names)})"
            )
    return options


def build_controller(
    name: str,
    env: Any,
    key: str = "--policy",
    *,
    drag_feedforward: bool = False,
    thrust_adaptation: bool = False,
) -> Any:
    """The controller ``name`` (one of :data:`CONTROLLERS`) for ``env``.

    Args:
        name: Controller name.
        env: The env it flies (its vehicle, control period, action and observation layout).
        key: The setting that named it, for the error.
        drag_feedforward: Turn on the drag feed-forward (:data:`FEEDFORWARD` controllers only;
            the env must observe the estimated air velocity, ``observation.air_velocity``).
        thrust_adaptation: Turn on the thrust adaptation (:data:`ADAPTATION` controllers only).

    Raises:
        ValueError: ``name`` is not in :data:`CONTROLLERS` (naming ``key``), or an option on
            a controller without it (:func:`controller_options`).
        ConfigError: An option not a bool, or ``drag_feedforward`` on an env without the air
            velocity.
    """
    if name not in CONTROLLERS:
        raise ValueError(f"{key}: got {name!r}; allowed: one of {sorted(CONTROLLERS)}")
    options = controller_options(
        name, key, drag_feedforward=drag_feedforward, thrust_adaptation=thrust_adaptation
    )
    return CONTROLLERS[name](env, **options)
