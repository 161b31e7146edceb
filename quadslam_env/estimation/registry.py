"""The one estimator registry: name → class (or factory), built-ins and plug-ins alike.

See docs/design.md §5. The env finds every estimator here by name and never imports one: the
built-ins are imported on first use through the module paths of ``_MODULES``, plug-ins through
their ``quadslam.estimators`` entry points, and :func:`register` adds one in this process. A
registered class is either batched (it implements
:class:`~quadslam_env.estimation.protocol.BatchEstimator`) or written for one vehicle (an
:class:`~quadslam_env.estimation.protocol.Estimator`), which :func:`make` runs through the one
adapter, :class:`~quadslam_env.estimation.lane_loop.LaneLoop`.
"""

from __future__ import annotations

import functools
import importlib
import importlib.metadata
from collections.abc import Callable
from typing import Any

from quadslam_env.estimation.lane_loop import LaneLoop
from quadslam_env.estimation.memory import LANE_OBJECT_BYTES, LANES, MemoryTerm, Workload
from quadslam_env.estimation.protocol import BatchEstimator, UsesTruth
from quadslam_env.schema import ConfigError

Factory = Callable[..., Any]
"""A class or factory called as ``factory(vehicle=VehicleParams, **estimator.params)`` (plus
``num_lanes=`` and ``landmark_capacity=`` when it is batched)."""

_REGISTRY: dict[str, Factory] = {}
# Modules imported on first use, so the registry stays cheap to import, a broken optional
# estimator cannot break the others, and nothing below the env imports an estimator.
_MODULES: dict[str, str] = {
    "oracle": "estimators.oracle",
    "ekf_slam": "estimators.ekf",
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


def register(name: str) -> Callable[[Factory], Factory]:
    """Class decorator that makes an estimator constructible by ``make(name, …)``.

    The class is batched when it has ``reset_lanes`` (a
    :class:`~quadslam_env.estimation.protocol.BatchEstimator`), else it is one vehicle's
    :class:`~quadslam_env.estimation.protocol.Estimator`. A name registered here is accepted by
    the scenario's ``estimator.name`` from then on.

    Raises:
        ValueError: ``name`` is not a non-empty string.
    """
    if not isinstance(name, str) or not name:
        raise ValueError(f"estimators.register: got {name!r}; allowed: a non-empty string")

    def deco(cls: Factory) -> Factory:
        _REGISTRY[name] = cls
        return cls

    return deco


def available() -> list[str]:
    """Names accepted by :func:`make` and by the scenario's ``estimator.name``.

    The built-in estimators, those registered with :func:`register` in this process, and those
    of installed ``quadslam.estimators`` entry points (listed without importing them).
    """
    return sorted(set(_REGISTRY) | set(_MODULES) | set(_entry_points()))


def _load(name: str) -> Factory:
    """The class registered as ``name``, importing its module or entry point on first use.

    Raises:
        ValueError: Unknown name, or a plug-in that cannot be loaded or is not callable.
    """
    if name not in _REGISTRY and name in _MODULES:
        importlib.import_module(_MODULES[name])
    entry = _entry_points().get(name)
    if name not in _REGISTRY and entry is not None:
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
    if name not in _REGISTRY:
        raise ValueError(f"estimator.name: got {name!r}; allowed: one of {available()}")
    return _REGISTRY[name]


def is_batched(factory: Factory) -> bool:
    """Whether a registered class is batched (has ``reset_lanes``) rather than one vehicle's."""
    return callable(getattr(factory, "reset_lanes", None))


def associates_unlabeled(name: str) -> bool:
    """Whether the estimator ``name`` accepts unlabeled scans (``lidar.association: unknown``).

    Its class says so with ``associates_unlabeled = True``: a batched one then implements
    ``update_unlabeled`` (see :class:`~quadslam_env.estimation.protocol.BatchEstimator`), one
    vehicle's takes a :class:`~quadslam_env.estimation.measurements.LidarScan` with ``ids=None`` and
    sets ``last_association`` (k,), the landmark id each return was paired with (-1: none).
    Estimators that use the truth (the oracle) need no association and accept them too.

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    cls = _load(name)
    return bool(getattr(cls, "associates_unlabeled", False) or getattr(cls, "uses_truth", False))


def copyable(name: str) -> bool:
    """Whether the env may deep-copy the estimator ``name`` (:func:`copy.deepcopy`).

    An IMU slower than the control (:mod:`quadslam_env.runtime.imu_replay`) and a delayed LiDAR
    (:mod:`quadslam_env.runtime.scan_delay`) run a copy of the env's estimator beside it. Every
    estimator is copyable unless its class says ``copyable = False`` (one that holds native
    state with no copy, such as a factor-graph library's smoother); the scenario check reads the
    flag before any estimator is built.

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "copyable", True))


def monitors_integrity(name: str) -> bool:
    """Whether the estimator ``name`` has an integrity monitor: its class says
    ``monitors_integrity = True`` (:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity`;
    the scenario's ``integrity.monitor`` is refused otherwise).

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "monitors_integrity", False))


def fuses_landmarks(name: str) -> bool:
    """Whether the estimator ``name`` fuses another vehicle's landmark estimates: its class
    says ``fuses_landmarks = True`` (:class:`~quadslam_env.estimation.protocol.FusesLandmarks`;
    the team env's ``team.fusion`` ``ci`` and ``naive`` are refused otherwise).

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "fuses_landmarks", False))


def fuses_ranges(name: str) -> bool:
    """Whether the estimator ``name`` fuses a range to another vehicle: its class says
    ``fuses_ranges = True`` (:class:`~quadslam_env.estimation.protocol.FusesRanges`; the team
    env's ``team.range_fusion: ci`` is refused otherwise).

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "fuses_ranges", False))


def joins_team(name: str) -> bool:
    """Whether the estimator ``name``'s vehicles can be one estimator of the team: its class
    says ``joins_team = True`` (:class:`~quadslam_env.estimation.protocol.JoinsTeam`; the team
    env's ``team.fusion: centralised`` is refused otherwise).

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "joins_team", False))


def takes_late_scans(name: str) -> bool:
    """Whether the estimator ``name`` takes a delayed LiDAR's scans at their own time without
    being copied: its class says ``takes_late_scans = True``
    (:class:`~quadslam_env.estimation.protocol.TakesLateScans`;
    :mod:`quadslam_env.runtime.scan_delay` then hands it each scan when it arrives, with its
    measurement time). A copyable estimator without the flag is run from copies instead.

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "takes_late_scans", False))


def models_drag(name: str) -> bool:
    """Whether the estimator ``name``'s process model has the vehicle's drag, so that a known
    wind changes it (``wind.inform_estimator``): its class says ``models_drag = True`` and
    takes the wind through ``set_wind`` (:class:`~quadslam_env.estimation.protocol.TakesWind`,
    or :class:`~quadslam_env.estimation.protocol.ModelsDrag` for one vehicle's). IMU-driven
    models (EKF-SLAM, iSAM2, the kinematic FastSLAM) take the sensed specific force, drag
    included, and have no drag term to tell.

    Raises:
        ValueError: Unknown name or a plug-in that cannot be loaded.
    """
    return bool(getattr(_load(name), "models_drag", False))


def estimates_wind(name: str, params: dict[str, Any]) -> bool:
    """Whether the estimator ``name`` with the settings ``params`` reports the horizontal wind
    (:attr:`~quadslam_env.estimation.snapshot.BatchEstimate.wind` not ``None``), asked of its
    class before any estimator is built: ``cls.estimates_wind(params)`` (a class method; the
    built-in with it is EKF-SLAM, with ``wind: estimate``). A class without the method reports
    none (the oracle, whose truth the env feeds has no wind, and FastSLAM, which is told it).

    Raises:
        ValueError: Unknown name, a plug-in that cannot be loaded, or invalid ``params``.
    """
    query = getattr(_load(name), "estimates_wind", None)
    return bool(query(dict(params))) if callable(query) else False


def memory_terms(name: str, load: Workload, params: dict[str, Any]) -> list[MemoryTerm]:
    """The buffers the estimator ``name`` will hold for ``load``, asked of its class before
    any estimator is built: ``cls.memory_terms(load, params)`` (a class method; ``params``
    are ``estimator.params``, validated by it as its constructor would). The class may raise
    its own :class:`~quadslam_env.estimation.memory.MemoryLimitError` (a filter's one big
    buffer above its share); one without the method is counted as nothing beyond, for a
    one-vehicle class, the :class:`LaneLoop`'s objects per lane.

    Raises:
        ValueError: Unknown name, a plug-in that cannot be loaded, invalid ``params`` or the
            class's own refusal.
    """
    cls = _load(name)
    sizing = getattr(cls, "memory_terms", None)
    terms = [] if sizing is None else list(sizing(load, dict(params)))
    if not is_batched(cls):
        b = load.num_lanes
        what = f"one {name} object per lane ({LANE_OBJECT_BYTES // 1024} KiB each)"
        terms.append(MemoryTerm(b * LANE_OBJECT_BYTES, LANES, f"{b} lane(s)", what))
    return terms


def estimator_flag(name: str, flag: Callable[[str], bool]) -> bool:
    """``flag(name)`` for a scenario check, with ``flag`` one of the class flags above
    (:func:`associates_unlabeled`, :func:`copyable`, :func:`models_drag`,
    :func:`monitors_integrity`, :func:`takes_late_scans`, :func:`fuses_landmarks`,
    :func:`fuses_ranges`, :func:`joins_team`).

    Raises:
        ConfigError: Unknown name or a plug-in that cannot be loaded (the registry's message).
    """
    try:
        return flag(name)
    except ValueError as exc:
        raise ConfigError(str(exc)) from exc


def make(name: str, num_lanes: int = 1, landmark_capacity: int = 0, **cfg: Any) -> BatchEstimator:
    """Build the estimator ``name`` for ``num_lanes`` lanes.

    Args:
        name: Registered name (see :func:`available`).
        num_lanes: Number of lanes B ≥ 1.
        landmark_capacity: Lmax, an upper bound on the landmark ids the lanes will see (the
            estimator may grow beyond it when a reset brings a larger map).
        **cfg: Keyword settings of the estimator (``vehicle=`` and ``estimator.params``);
            unknown keys raise ``ValueError``.

    Returns:
        The batched estimator, or B instances of one vehicle's estimator in a
        :class:`~quadslam_env.estimation.lane_loop.LaneLoop` (whose memory check runs after
        the first instance is built, before the others).

    Raises:
        ValueError: Unknown name, a plug-in that cannot be loaded, invalid settings, or an
            estimator that says ``uses_truth = True`` but is not a batched one that
            :class:`~quadslam_env.estimation.protocol.UsesTruth` (the env feeds the truth
            only through ``set_truth`` of a batch).
    """
    cls = _load(name)
    if not is_batched(cls):
        if getattr(cls, "uses_truth", False):
            raise ValueError(_TRUTH_ERROR.format(name=name, kind="written for one vehicle"))
        return LaneLoop.build(lambda: cls(**cfg), num_lanes, landmark_capacity)
    est: BatchEstimator = cls(num_lanes=num_lanes, landmark_capacity=landmark_capacity, **cfg)
    if est.uses_truth and not isinstance(est, UsesTruth):
        raise ValueError(_TRUTH_ERROR.format(name=name, kind="without set_truth"))
    return est


_TRUTH_ERROR = (
    "estimator.name: got {name!r}, which says uses_truth = True but is {kind}; allowed: a "
    "batched estimator (reset_lanes) with set_truth(states, landmarks, counts), like the oracle"
)
