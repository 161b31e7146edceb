"""Integrity metrics against the truth: misleading information per step, and the episode's
availability, integrity and fault-detection summaries (docs/integrity.md "Metrics").

Per step, with the horizontal error ``e_h = |ρ̂_NE − ρ_NE|`` and the vertical ``e_v = |ρ̂_D − ρ_D|``
(m), the protection levels HPL, VPL and the alert limits HAL, VAL:

* ``integrity_mi`` — misleading information: ``e_h > HPL`` or ``e_v > VPL``;
* ``integrity_hmi`` — hazardously misleading information: ``e_h > HAL`` or ``e_v > VAL`` while
  no alert is raised (HPL ≤ HAL and VPL ≤ VAL).

Per episode (:class:`IntegrityEpisode`): availability (the share of steps without an alert),
the MI and HMI rates, the false-alarm rate (alarms over the scans tested while no fault was
active), and for an episode with a fault: whether it was missed (no alarm while it was active)
and the time to alert (from the fault's first active step to the first alarm at or after it).
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.types import POS, FloatArray

STEP_KEYS = ("est_pos_err_h_m", "est_pos_err_v_m", "integrity_mi", "integrity_hmi")
"""The per-step ``info`` terms of :func:`misleading`."""
SUMMARY_KEYS = (
    "episode_integrity_availability",
    "episode_integrity_mi_rate",
    "episode_integrity_hmi_rate",
    "episode_fde_tests",
    "episode_fde_alarms",
    "episode_fde_false_alarm_rate",
    "episode_fde_missed_detection",
    "episode_fde_time_to_alert_s",
)
"""The episode summaries of :meth:`IntegrityEpisode.summary`."""


def misleading(
    true_pos: FloatArray,
    est_pos: FloatArray,
    hpl: FloatArray,
    vpl: FloatArray,
    alert: np.ndarray,
    limits: tuple[float, float],
) -> dict[str, FloatArray]:
    """The step's true errors and misleading-information flags of B lanes (module docstring).

    Args:
        true_pos: (B, ≥3) true states (ρ first) in N, m.
        est_pos: (B, 3) estimated positions ρ̂ in N, m.
        hpl, vpl: (B,) protection levels, m.
        alert: (B,) bool, an alert is raised.
        limits: The horizontal and vertical alert limits, m.

    Returns:
        :data:`STEP_KEYS` → (B,) float (flags as 1.0 / 0.0).
    """
    err = est_pos - true_pos[:, POS]
    e_h = np.hypot(err[:, 0], err[:, 1])
    e_v = np.abs(err[:, 2])
    mi = (e_h > hpl) | (e_v > vpl)
    hazard = ((e_h > limits[0]) | (e_v > limits[1])) & ~alert
    return dict(zip(STEP_KEYS, (e_h, e_v, mi.astype(float), hazard.astype(float)), strict=True))


class IntegrityEpisode:
    """Running integrity sums of B lanes over their episodes (module docstring).

    Args:
        num_lanes: B.
    """

    _FIELDS = ("steps", "available", "mi", "hmi", "tests", "alarms", "ff_tests", "ff_alarms")

    def __init__(self, num_lanes: int) -> None:
        self._sums = np.zeros((len(self._FIELDS), num_lanes))
        self._onset = np.full(num_lanes, math.nan)  # the fault's first active step, s
        self._alerted = np.full(num_lanes, math.nan)  # the first alarm at or after it, s

    def reset(self, lanes: np.ndarray) -> None:
        """Start the ``lanes``' sums afresh."""
        self._sums[:, lanes] = 0.0
        self._onset[lanes] = math.nan
        self._alerted[lanes] = math.nan

    def add(self, info: dict[str, FloatArray], lanes: np.ndarray) -> None:
        """Add one step of the ``lanes`` (B,) bool, from its ``info`` (the monitor's terms,
        ``integrity_mi``/``integrity_hmi``, ``t`` and, with faults, ``fault_active``)."""
        active = info.get("fault_active")
        faulty = np.zeros_like(lanes) if active is None else active > 0.5
        tested, alarm = info["fde_tested"] > 0.5, info["fde_alarm"] > 0.5
        terms = (
            np.ones(lanes.shape[0]),
            1.0 - info["integrity_alert"],
            info["integrity_mi"],
            info["integrity_hmi"],
            tested,
            alarm,
            tested & ~faulty,
            alarm & ~faulty,
        )
        for row, term in enumerate(terms):
            self._sums[row] += np.where(lanes, term, 0.0)
        t = info["t"]
        start = lanes & faulty & np.isnan(self._onset)
        self._onset[start] = t[start]
        caught = lanes & alarm & ~np.isnan(self._onset) & np.isnan(self._alerted)
        caught &= faulty
        self._alerted[caught] = t[caught]

    def summary(self) -> dict[str, FloatArray]:
        """:data:`SUMMARY_KEYS` → (B,) float of every lane's episode so far (NaN where a term
        has nothing to count: no scan tested while fault-free, or no fault)."""
        steps, available, mi, hmi, tests, alarms, ff_tests, ff_alarms = self._sums
        per_step = np.maximum(steps, 1.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            false_alarm = np.where(ff_tests > 0, ff_alarms / ff_tests, math.nan)
        had_fault = ~np.isnan(self._onset)
        missed = np.where(had_fault, np.isnan(self._alerted).astype(float), math.nan)
        values = (
            available / per_step,
            mi / per_step,
            hmi / per_step,
            tests,
            alarms,
            false_alarm,
            missed,
            self._alerted - self._onset,
        )
        return dict(zip(SUMMARY_KEYS, values, strict=True))
