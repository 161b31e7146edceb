"""EKF-SLAM's integrity monitor as the filter holds it: the settings it is given and the
arrays its update kernel takes (:mod:`estimators.ekf.fde`; docs/integrity.md)."""

from __future__ import annotations

import numpy as np

from quadslam_env.estimation.integrity import MonitorSettings
from quadslam_env.types import FloatArray

_OFF = np.zeros(3)
"""The monitor arguments of the update kernel when there is no monitor."""
_NO_THRESHOLDS = np.full(1, np.inf)


class IntegrityMonitor:
    """:class:`~quadslam_env.estimation.protocol.MonitorsIntegrity` for
    :class:`~estimators.ekf.filter.EkfSlamBatch` (a mixin): the scan tests, exclusion and
    solution separations of :mod:`estimators.ekf.fde` on every later update."""

    monitors_integrity = True
    _monitor: MonitorSettings | None = None
    _thresholds_for = -1
    _lm_thr = _NO_THRESHOLDS
    _scan_thr = _NO_THRESHOLDS

    def set_monitor(self, settings: MonitorSettings | None) -> None:
        """Monitor every later scan with ``settings`` (``None``: no monitor, the default)."""
        self._monitor = settings
        self._thresholds_for = -1

    def monitor_arguments(self, capacity: int) -> tuple[FloatArray, FloatArray, FloatArray]:
        """``(monitor (3,), lm_thr, scan_thr)`` of the update kernel for scans of up to
        ``capacity`` landmarks: the mode (0 off, 1 detect, 2 exclude), the most exclusions
        and the readmission delay, and the tests' thresholds (tabulated once per capacity)."""
        cfg = self._monitor
        if cfg is None:
            return _OFF, _NO_THRESHOLDS, _NO_THRESHOLDS
        if self._thresholds_for != capacity:
            self._lm_thr = cfg.landmark_thresholds(capacity)
            self._scan_thr = cfg.scan_thresholds(capacity)
            self._thresholds_for = capacity
        mode = 2.0 if cfg.exclude else 1.0
        args = np.array([mode, float(cfg.max_exclusions), cfg.readmit_s])
        return args, self._lm_thr, self._scan_thr
