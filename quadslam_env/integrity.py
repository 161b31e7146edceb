"""The integrity monitor in the env: the estimator told its settings, and each step's protection
levels, alerts and monitor outcomes in ``info`` (docs/integrity.md).

With ``integrity.monitor`` other than ``off``, :class:`IntegrityTerms` gives the estimator its
:class:`~quadslam_env.estimation.integrity.MonitorSettings` (and every copy the env runs of it)
and reads back, each step, the monitor's counts and solution separations from the snapshot's
diagnostics: ``hpl_m``, ``vpl_m`` (:func:`~quadslam_env.estimation.integrity.protection_levels`
from the position covariance and the last scan's separations), ``integrity_alert`` (a level
above its alert limit), ``fde_tested``, ``fde_alarm`` and ``fde_excluded`` (the scans tested,
those that alarmed, and the landmarks left out on this step), then against the truth the
misleading-information terms and the episode sums of :mod:`quadslam_env.metrics.integrity`.
With the monitor off it does nothing and adds no terms.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, cast

import numpy as np

from quadslam_env.config_integrity import IntegrityConfig
from quadslam_env.estimation import BatchEstimate, MonitorsIntegrity, protection_levels
from quadslam_env.estimation.integrity import COUNT_KEYS, SEPARATION_KEYS
from quadslam_env.metrics.integrity import IntegrityEpisode, misleading
from quadslam_env.types import POS, FloatArray

_TESTS, _ALARMS, _EXCLUSIONS = COUNT_KEYS[:3]


class IntegrityTerms:
    """The ``integrity`` section's terms of B lanes.

    Args:
        cfg: The validated section.
        num_lanes: B.
    """

    def __init__(self, cfg: IntegrityConfig, num_lanes: int) -> None:
        self.cfg = cfg
        self.enabled = cfg.enabled
        self.limits = (cfg.alert_limit_m, cfg.vertical_limit_m)
        self._counts = np.zeros((3, num_lanes))  # tests, alarms, exclusions at the last step
        self.episode = IntegrityEpisode(num_lanes)

    def configure(self, estimators: Iterable[Any]) -> None:
        """Tell the ``estimators`` (the env's and its copies; their class flag was checked
        with the scenario) the monitor's settings."""
        if self.enabled:
            for estimator in estimators:
                cast(MonitorsIntegrity, estimator).set_monitor(self.cfg.monitor_settings())

    def reset(self, lanes: np.ndarray, est: BatchEstimate) -> None:
        """Start the ``lanes``' counts and episode sums afresh (after the estimator's reset)."""
        if self.enabled:
            self._counts[:, lanes] = self._read_counts(est)[:, lanes]
            self.episode.reset(lanes)

    def info(self, est: BatchEstimate, state: FloatArray) -> dict[str, FloatArray]:
        """The step's terms (module docstring) of every lane, from the snapshot ``est`` and the
        true states ``state`` (B, 12); empty with the monitor off. Call once per step."""
        if not self.enabled:
            return {}
        d = est.diagnostics
        pose_cov = cast(FloatArray, est.pose_cov)
        pos_var = np.diagonal(pose_cov[:, POS, POS], axis1=1, axis2=2)
        separation = np.stack([d[key] for key in SEPARATION_KEYS[:3]], axis=-1)
        cfg, hypotheses = self.cfg, d[SEPARATION_KEYS[3]]
        hpl, vpl = protection_levels(pos_var, separation, hypotheses, cfg.p_fa, cfg.p_hmi)
        alert = (hpl > self.limits[0]) | (vpl > self.limits[1]) | ~np.isfinite(hpl + vpl)
        counts = self._read_counts(est)
        new = counts - self._counts
        self._counts = counts
        out = {
            "hpl_m": hpl,
            "vpl_m": vpl,
            "integrity_alert": alert.astype(float),
            "fde_tested": (new[0] > 0).astype(float),
            "fde_alarm": (new[1] > 0).astype(float),
            "fde_excluded": new[2],
        }
        out.update(misleading(state, est.position, hpl, vpl, alert, self.limits))
        return out

    def add(self, info: dict[str, Any], lanes: np.ndarray) -> dict[str, FloatArray]:
        """Add the step of the ``lanes`` (B,) bool to the episode sums; returns the episode
        summaries of every lane (empty with the monitor off)."""
        if not self.enabled:
            return {}
        self.episode.add(info, lanes)
        return self.episode.summary()

    @staticmethod
    def _read_counts(est: BatchEstimate) -> FloatArray:
        d = est.diagnostics
        return np.stack([d[_TESTS], d[_ALARMS], d[_EXCLUSIONS]]).astype(float)
