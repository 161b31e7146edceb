"""EKF-SLAM's integrity monitor as the filter holds it: the settings it is given and the
arrays its update kernel takes (:mod:`estimators.ekf.fde`; docs/integrity.md)."""

from __future__ import annotations

import numpy as np

from estimators.ekf.state import EkfState
from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.types import FloatArray

Thresholds = tuple[FloatArray, FloatArray, FloatArray]
"""The tests' thresholds as the update kernel takes them: (landmark, scan, sequential)."""

_OFF = np.zeros(3)
"""The monitor arguments of the update kernel when there is no monitor."""
_NO_THRESHOLDS = np.full(1, np.inf)
_NO_SEQUENTIAL = np.full((1, 1), np.inf)


class IntegrityMonitor:
    """:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity` for
    :class:`~estimators.ekf.filter.EkfSlamBatch` (a mixin): the scan tests, exclusion and
    solution separations of :mod:`estimators.ekf.fde` on every later update."""

    monitors_integrity = True
    state: EkfState
    _monitor: MonitorSettings | None = None
    _thresholds_for = -1
    _monitor_thresholds: Thresholds = (_NO_THRESHOLDS, _NO_THRESHOLDS, _NO_SEQUENTIAL)

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Monitor every later scan with ``settings`` (``None``: no monitor, the default); the
        lanes' sequential windows start empty."""
        self._monitor = settings
        self._thresholds_for = -1
        window = 0 if settings is None else settings.sequential_window or 0
        self.state.set_window(window)

    def monitor_arguments(self, capacity: int) -> tuple[FloatArray, Thresholds]:
        """``(monitor (3,), thresholds)`` of the update kernel for scans of up to ``capacity``
        landmarks: the mode (0 off, 1 detect, 2 exclude), the most exclusions and the
        readmission delay, and the tests' thresholds (landmark, scan, sequential; tabulated
        once per capacity)."""
        cfg = self._monitor
        if cfg is None:
            return _OFF, (_NO_THRESHOLDS, _NO_THRESHOLDS, _NO_SEQUENTIAL)
        if self._thresholds_for != capacity:
            self._monitor_thresholds = (
                cfg.landmark_thresholds(capacity),
                cfg.scan_thresholds(capacity),
                cfg.sequential_thresholds(capacity),
            )
            self._thresholds_for = capacity
        mode = 2.0 if cfg.exclude else 1.0
        args = np.array([mode, float(cfg.max_exclusions), cfg.readmit_s])
        return args, self._monitor_thresholds
