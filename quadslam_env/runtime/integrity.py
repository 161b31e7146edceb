"""The integrity monitor in the env: the estimator told its settings, and each step's protection
levels, alerts and monitor outcomes in ``info`` (docs/integrity.md).

With ``integrity.monitor`` other than ``off``, :class:`IntegrityTerms` gives the estimator its
:class:`~quadslam_env.estimation.integrity.MonitorSettings` (the section refuses the settings
that would run copies of it) and reads back, each step, the monitor's counts and solution
separations from the snapshot's diagnostics: ``hpl_m``, ``vpl_m``
(:func:`~quadslam_env.estimation.integrity.levels_lanes` from the position covariance and the
last scan's separations), ``integrity_alert`` (a level
above its alert limit), ``fde_tested``, ``fde_alarm`` and ``fde_excluded`` (the scans tested,
those that alarmed, and the landmarks left out on this step), then against the truth the
misleading-information terms and the episode sums of :mod:`quadslam_env.metrics.integrity`.
With the monitor off it does nothing and adds no terms.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import Any, cast

import numpy as np

from quadslam_env.config.integrity import IntegrityConfig
from quadslam_env.estimation.integrity import (
    COUNT_KEYS,
    SEPARATION_KEYS,
    LevelFactors,
    levels_lanes,
)
from quadslam_env.estimation.protocol import MonitorsIntegrity
from quadslam_env.estimation.snapshot import BatchEstimate
from quadslam_env.metrics.integrity import STEP_KEYS as MISLEADING_KEYS
from quadslam_env.metrics.integrity import IntegrityEpisode, misleading_lanes
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

STEP_KEYS = (
    "hpl_m",
    "vpl_m",
    "integrity_alert",
    "fde_tested",
    "fde_alarm",
    "fde_excluded",
    *MISLEADING_KEYS,
)
"""The ``info`` terms of every step with the monitor on (module docstring)."""
ALERT_REASON = "integrity_alert"
"""The ``termination_reason`` of an episode ended by an alert (``terminate_on_alert``)."""


@kernel
def _step_terms(
    pose_cov: FloatArray,
    sep_n: FloatArray,
    sep_e: FloatArray,
    sep_d: FloatArray,
    hypotheses: FloatArray,
    tests: FloatArray,
    alarms: FloatArray,
    exclusions: FloatArray,
    counts: FloatArray,
    tables: FloatArray,
    h_limit: float,
    v_limit: float,
    state: FloatArray,
    est_pos: FloatArray,
    out: FloatArray,
) -> None:
    """The rows of ``out`` (12, B) in the order of :data:`STEP_KEYS`: the protection levels
    (:func:`~quadslam_env.estimation.integrity.levels_lanes`), the alert, this step's tests,
    alarms and exclusions (the monitor's counts less ``counts`` (3, B), which becomes the
    counts), then the misleading-information terms
    (:func:`~quadslam_env.metrics.integrity.misleading_lanes`)."""
    levels_lanes(pose_cov, sep_n, sep_e, sep_d, hypotheses, tables, out[0], out[1])
    for b in range(out.shape[1]):
        hpl, vpl = out[0, b], out[1, b]
        finite = math.isfinite(hpl) and math.isfinite(vpl)
        out[2, b] = 1.0 if (hpl > h_limit or vpl > v_limit or not finite) else 0.0
        out[3, b] = 1.0 if tests[b] > counts[0, b] else 0.0
        out[4, b] = 1.0 if alarms[b] > counts[1, b] else 0.0
        out[5, b] = exclusions[b] - counts[2, b]
        counts[0, b], counts[1, b], counts[2, b] = tests[b], alarms[b], exclusions[b]
    misleading_lanes(state, est_pos, out[0], out[1], out[2], h_limit, v_limit, out[6:])


class IntegrityTerms:
    """The ``integrity`` section's terms of B lanes.

    Args:
        cfg: The validated section.
        num_lanes: B.
        settle_s: End of the episodes' transient, s (``terminate_on_alert`` acts after it).
    """

    def __init__(self, cfg: IntegrityConfig, num_lanes: int, settle_s: float = 0.0) -> None:
        self.cfg = cfg
        self.settle_s = settle_s
        self.enabled = cfg.enabled
        self.limits = (cfg.alert_limit_m, cfg.vertical_limit_m)
        settings = cfg.monitor_settings()  # the landmark test's budget bounds the levels
        self.factors = LevelFactors(settings.snapshot_p_fa if settings else cfg.p_fa, cfg.p_hmi)
        self._counts = np.zeros((3, num_lanes))  # tests, alarms, exclusions at the last step
        self.episode = IntegrityEpisode(num_lanes)

    def configure(self, estimators: Iterable[Any]) -> None:
        """Tell the ``estimators`` (the env's; their class flag was checked with the scenario)
        the monitor's settings."""
        if self.enabled:
            for estimator in estimators:
                cast(MonitorsIntegrity, estimator).set_monitor(self.cfg.monitor_settings())

    def reset(self, lanes: np.ndarray, est: BatchEstimate) -> None:
        """Start the ``lanes``' counts and episode sums afresh (after the estimator's reset)."""
        if self.enabled:
            d = est.diagnostics
            for row, key in enumerate(COUNT_KEYS[:3]):
                self._counts[row, lanes] = d[key][lanes]
            self.episode.reset(lanes)

    def info(self, est: BatchEstimate, state: FloatArray) -> dict[str, FloatArray]:
        """The step's terms (module docstring) of every lane, from the snapshot ``est`` and the
        true states ``state`` (B, 12); empty with the monitor off. Call once per step."""
        if not self.enabled:
            return {}
        d = est.diagnostics
        hypotheses = d[SEPARATION_KEYS[3]]
        out = np.empty((len(STEP_KEYS), hypotheses.shape[0]))
        sep_n, sep_e, sep_d = (d[key] for key in SEPARATION_KEYS[:3])
        tests, alarms, exclusions = (d[key] for key in COUNT_KEYS[:3])
        tables = self.factors.tables(int(hypotheses.max(initial=0.0)))
        _step_terms(
            cast(FloatArray, est.pose_cov), sep_n, sep_e, sep_d, hypotheses, tests, alarms,
            exclusions, self._counts, tables, self.limits[0], self.limits[1], state,
            est.position, out,
        )  # fmt: skip
        return dict(zip(STEP_KEYS, out, strict=True))

    @staticmethod
    def levels(info: dict[str, Any]) -> tuple[FloatArray, FloatArray] | None:
        """The step's ``(hpl, vpl)`` (B,) from its ``info`` (``None`` with the monitor off), for
        the observation's ``protection_levels``."""
        return (info["hpl_m"], info["vpl_m"]) if "hpl_m" in info else None

    def terminate(
        self,
        info: dict[str, Any],
        active: np.ndarray,
        terminated: np.ndarray,
        truncated: np.ndarray,
        reasons: list[str],
    ) -> bool:
        """With ``integrity.terminate_on_alert``: end the ``active`` (B,) lanes that raise an
        alert after the transient (``terminated``, ``reasons`` updated in place, ``truncated``
        cleared there). Returns whether a lane ended here."""
        if not self.cfg.terminate_on_alert:
            return False
        late = info["t"] > self.settle_s
        ends = active & (info["integrity_alert"] > 0.5) & late & ~terminated
        for lane in np.flatnonzero(ends).tolist():
            reasons[lane] = ALERT_REASON
        terminated |= ends
        truncated &= ~ends
        return bool(ends.any())

    def penalise(self, reward: FloatArray, info: dict[str, Any]) -> None:
        """With ``integrity.alert_weight`` > 0: the term ``reward_alert = −w·alert`` added to
        the step's ``reward`` (B,) in place and to ``info``."""
        weight = self.cfg.alert_weight
        if self.enabled and weight > 0.0:
            term = -weight * info["integrity_alert"]
            reward += term
            info["reward_alert"] = term

    def add(self, info: dict[str, Any], lanes: np.ndarray) -> None:
        """Add the step of the ``lanes`` (B,) bool to the episode sums."""
        if self.enabled:
            self.episode.add(info, lanes)

    def summary(self) -> dict[str, FloatArray]:
        """The episode summaries of every lane (empty with the monitor off)."""
        return self.episode.summary() if self.enabled else {}
