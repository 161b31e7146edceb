"""The ``integrity`` section: the estimator's integrity monitor, its budgets and the alert
limits (docs/integrity.md), re-exported by :mod:`quadslam_env.config`.

``monitor: off`` (the default) runs nothing and adds no ``info`` terms. ``detect`` runs the
estimator's scan tests and reports protection levels and alerts; ``exclude`` also leaves out the
landmarks found faulty (:mod:`estimators.ekf.fde`, :mod:`estimators.isam2.fde`). Only an
estimator whose class says ``monitors_integrity = True`` has a monitor (EKF-SLAM, iSAM2).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.schema import ConfigError, Section
from quadslam_env.schema import spec as _spec

MONITOR_MODES = ("off", "detect", "exclude")
"""The values of ``integrity.monitor``."""

_ON = MONITOR_MODES[1:]


@dataclass(frozen=True)
class IntegrityConfig(Section):
    """The integrity monitor (off by default): fault detection and exclusion on each scan,
    protection levels against alert limits."""

    SECTION: ClassVar[str] = "integrity"
    ONLY_FOR: ClassVar[dict[str, tuple[str, tuple[str, ...]]]] = {
        **dict.fromkeys(
            (
                "p_fa",
                "p_hmi",
                "alert_limit_m",
                "vertical_alert_limit_m",
                "alert_weight",
                "terminate_on_alert",
            ),
            ("monitor", _ON),
        ),
        **dict.fromkeys(("max_exclusions", "readmit_s"), ("monitor", ("exclude",))),
        "sequential_window": ("monitor", _ON),
    }
    monitor: str = _spec(
        "off",
        kind="str",
        choices=MONITOR_MODES,
        doc="off: no monitor; detect: test each scan, report protection levels and alerts; "
        "exclude: also leave out the landmarks found faulty",
    )
    p_fa: float = _spec(
        1e-3,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="false-alarm budget of one scan's tests (the scan's NIS and each landmark's), in "
        "(0, 1)",
    )
    p_hmi: float = _spec(
        1e-3,
        lo=0.0,
        lo_open=True,
        hi=1.0,
        doc="integrity risk per step the protection levels are computed for, in (0, 1)",
    )
    alert_limit_m: float = _spec(
        1.0,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        doc="horizontal alert limit, m: an alert when the horizontal protection level exceeds it",
    )
    vertical_alert_limit_m: float | None = _spec(
        None,
        lo=0.0,
        lo_open=True,
        hi=1e4,
        optional=True,
        doc="vertical alert limit, m; null = alert_limit_m",
    )
    max_exclusions: int = _spec(
        1,
        kind="int",
        lo=0,
        hi=10,
        doc="most landmarks left out of one scan (an alarm that persists after them: the scan "
        "is not used)",
    )
    readmit_s: float = _spec(
        5.0,
        lo=0.0,
        hi=1e6,
        doc="a landmark left out is dropped from the map and may be registered anew from a "
        "sighting this long after, s",
    )
    sequential_window: int | None = _spec(
        None,
        kind="int",
        lo=1,
        hi=100,
        optional=True,
        doc="W: also test the sum of each landmark's statistics over its last W sightings "
        "(a sequential test, with half of p_fa); null = no sequential test",
    )

    alert_weight: float = _spec(
        0.0,
        lo=0.0,
        hi=1e6,
        doc="reward term −alert_weight on every step with an integrity alert (reward_alert; "
        "0: none)",
    )
    terminate_on_alert: bool = _spec(
        False,
        kind="bool",
        doc="end the episode (integrity_alert) on an alert after episode.settle_s",
    )

    def validate(self) -> None:
        """The budgets are probabilities strictly inside (0, 1)."""
        for key in ("p_fa", "p_hmi"):
            value = getattr(self, key)
            if not value < 1.0:
                raise ConfigError(f"integrity.{key}: got {value!r}; allowed: a number in (0, 1)")

    @property
    def enabled(self) -> bool:
        """Whether a monitor runs."""
        return self.monitor != "off"

    @property
    def vertical_limit_m(self) -> float:
        """The vertical alert limit, m."""
        limit = self.vertical_alert_limit_m
        return self.alert_limit_m if limit is None else limit

    def monitor_settings(self) -> MonitorSettings | None:
        """What the estimator is told (``None`` with the monitor off)."""
        if not self.enabled:
            return None
        return MonitorSettings(
            p_fa=self.p_fa,
            exclude=self.monitor == "exclude",
            max_exclusions=self.max_exclusions,
            readmit_s=self.readmit_s,
            sequential_window=self.sequential_window,
        )

    def check_scenario(self, scenario: Any) -> None:
        """Of the :class:`~quadslam_env.config.ScenarioConfig` ``scenario`` (typed ``Any``:
        this module sits below it), refuse the protection levels in the observation without a
        monitor, and a monitor with an estimator that has none, with unknown association (the
        monitor's readmission follows landmark ids, which unlabeled scans do not carry), or
        with a second run of the estimator from copies (a slower IMU, a delayed LiDAR), whose
        output the monitor's counts would not follow.

        Raises:
            ConfigError: Names ``observation.protection_levels`` or ``integrity.monitor``, the
                estimator, the association or the setting.
        """
        if scenario.observation.protection_levels and not self.enabled:
            raise ConfigError(
                "observation.protection_levels: got true with integrity.monitor = 'off'; "
                "allowed: false, or integrity.monitor 'detect' or 'exclude'"
            )
        name, association = scenario.estimator.name, scenario.lidar.association
        second_run = scenario.second_run
        if not self.enabled:
            return
        if second_run is not None:
            raise ConfigError(
                f"integrity.monitor: got {self.monitor!r} with {second_run} set (the estimator "
                f"runs from copies); allowed: 'off', or {second_run} at its default"
            )
        from quadslam_env.estimation.registry import estimator_flag, monitors_integrity

        if not estimator_flag(name, monitors_integrity):
            raise ConfigError(
                f"integrity.monitor: got {self.monitor!r} with estimator.name = {name!r}, which "
                "has no integrity monitor; allowed: 'off', or an estimator with one (ekf_slam, "
                "isam2, or a plug-in with monitors_integrity = True)"
            )
        if association != "known":
            raise ConfigError(
                f"integrity.monitor: got {self.monitor!r} with lidar.association = "
                f"{association!r}; allowed: 'off', or lidar.association 'known'"
            )
