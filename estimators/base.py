"""Estimator interface, the ``Estimate`` snapshot and the name → class registry.

See docs/design.md §5.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from quadslam_env.measurements import Control, ImuSample, LidarScan
from quadslam_env.types import FloatArray


@dataclass(frozen=True)
class Estimate:
    """Frozen snapshot of an estimator's belief.

    Attributes:
        position: (3,) ρ̂ in N, m.
        vel_body: (3,) v̂ in B, m/s.
        vel_inertial: (3,) ``C_NB(Λ̂) v̂`` in N, m/s.
        euler: (3,) Λ̂ = (φ̂, θ̂, ψ̂) in rad.
        rates: (3,) ω̂ in B, rad/s (for EKF-SLAM: the bias-corrected gyro).
        pose_cov: (9, 9) covariance of (ρ, v, Λ), or ``None`` when the estimator has none
            (the oracle).
        landmark_ids: (n,) int ids of mapped landmarks.
        landmark_means: (n, 3) estimated landmark positions in N, m.
        landmark_covs: (n, 3, 3) landmark covariances in m².
        accel_bias: (3,) estimated total accelerometer bias in m/s², or ``None``.
        gyro_bias: (3,) estimated total gyro bias in rad/s, or ``None``.
        diagnostics: Scalars such as ``nis``, ``nis_dof``, ``n_rejected``, ``ess``.
    """

    position: FloatArray
    vel_body: FloatArray
    vel_inertial: FloatArray
    euler: FloatArray
    rates: FloatArray
    pose_cov: FloatArray | None
    landmark_ids: np.ndarray
    landmark_means: FloatArray
    landmark_covs: FloatArray
    accel_bias: FloatArray | None = None
    gyro_bias: FloatArray | None = None
    diagnostics: dict[str, float] = field(default_factory=dict)


@runtime_checkable
class Estimator(Protocol):
    """What the env needs from an estimator. Estimators never receive the true state."""

    def reset(
        self,
        mean0: FloatArray,
        cov0: FloatArray,
        rng: np.random.Generator,
        known_landmarks: tuple[np.ndarray, FloatArray] | None = None,
    ) -> None:
        """Start from a 12-state mean ``(ρ, v_B, Λ, ω)`` and its (12, 12) covariance.

        ``known_landmarks`` is ``(ids (L,), positions (L, 3))`` for known-map modes; ``rng`` is
        the only source of randomness the estimator may use.
        """

    def predict(self, imu: ImuSample, control: Control, dt: float) -> None:
        """Propagate over ``dt`` seconds with one IMU sample and the applied control."""

    def update(self, scan: LidarScan) -> None:
        """Correct with one LiDAR scan (an empty scan is allowed)."""

    def estimate(self) -> Estimate:
        """Return a frozen snapshot of the current belief."""


_REGISTRY: dict[str, Callable[..., Estimator]] = {}
# Modules imported on first use, so `import estimators` stays cheap and a broken optional
# estimator cannot break the others.
_MODULES: dict[str, str] = {
    "oracle": "estimators.oracle",
    "ekf_slam": "estimators.ekf_slam",
    "fastslam": "estimators.fastslam",
    "fastslam_kinematic": "estimators.fastslam",
    "isam2": "estimators.isam2",  # needs the optional extra quadslam[gtsam]
}

ENTRY_POINT_GROUP = "quadslam.estimators"
"""Entry-point group through which another distribution provides estimators.

A package declares, in its ``pyproject.toml``::

    [project.entry-points."quadslam.estimators"]
    mine = "my_package.filters:MyFilter"

and ``estimator.name: mine`` then builds ``MyFilter(vehicle=..., **estimator.params)``. The
object is imported only when an env first builds that estimator.
"""


@functools.cache
def _entry_points() -> dict[str, importlib.metadata.EntryPoint]:
    """Installed ``quadslam.estimators`` entry points by name (read once per process)."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=ENTRY_POINT_GROUP)}


def register(name: str) -> Callable[[Callable[..., Estimator]], Callable[..., Estimator]]:
    """Class decorator that makes an estimator constructible by ``make(name, **cfg)``.

    The class (or any factory) is called as ``cls(vehicle=VehicleParams, **estimator.params)``
    and must return an object that implements :class:`Estimator`. A name registered here is
    accepted by the scenario's ``estimator.name`` from then on.

    Raises:
        ValueError: ``name`` is not a non-empty string.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"estimators.register: got {name!r}; allowed: a non-empty string")

    def deco(cls: Callable[..., Estimator]) -> Callable[..., Estimator]:
        _REGISTRY[name] = cls
        return cls

    return deco


def available() -> list[str]:
    """Names accepted by :func:`make` and by the scenario's ``estimator.name``.

    The built-in estimators, those registered with :func:`register` in this process, and those
    of installed ``quadslam.estimators`` entry points (listed without importing them).
    """
    return sorted(set(_REGISTRY) | set(_MODULES) | set(_entry_points()))


def _load(name: str) -> None:
    """Import the module or entry point that registers ``name`` (if not registered yet)."""
    if name in _REGISTRY:
        return
    if name in _MODULES:
        importlib.import_module(_MODULES[name])
        return
    entry = _entry_points().get(name)
    if entry is None:
        return
    try:
        obj = entry.load()
    except Exception as exc:  # any import error of a third-party plug-in
        raise ValueError(
            f"estimator.name: {name!r} (entry point {entry.value!r} of group "
            f"{ENTRY_POINT_GROUP!r}) cannot be loaded: {type(exc).__name__}: {exc}"
        ) from exc
    if not callable(obj):
        raise ValueError(
            f"estimator.name: {name!r} (entry point {entry.value!r}) is a "
            f"{type(obj).__name__}; allowed: an estimator class or factory"
        )
    # The module may have registered itself under this name with @register; keep that.
    _REGISTRY.setdefault(name, obj)


def associates_unlabeled(name: str) -> bool:
    """Whether the estimator ``name`` accepts unlabeled scans (``lidar.association: unknown``).

    Its class says so with ``associates_unlabeled = True``; it then takes a
    :class:`~quadslam_env.measurements.LidarScan` with ``ids=None`` and sets
    ``last_association`` (k,), the landmark id each return was paired with (-1: none).
    Estimators that use the truth (the oracle) need no association and accept them too.

    Raises:
        ValueError: A plug-in that cannot be loaded.
    """
    _load(name)
    cls = _REGISTRY.get(name)
    return bool(getattr(cls, "associates_unlabeled", False) or getattr(cls, "uses_truth", False))


def make(name: str, **cfg: Any) -> Estimator:
    """Build an estimator by name.

    Args:
        name: Registered name (see :func:`available`).
        **cfg: Keyword settings for that estimator; unknown keys raise ``ValueError``.

    Raises:
        ValueError: Unknown name, a plug-in that cannot be loaded, or invalid settings.
    """
    _load(name)
    if name not in _REGISTRY:
        raise ValueError(f"estimator.name: got {name!r}; allowed: one of {available()}")
    return _REGISTRY[name](**cfg)


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
