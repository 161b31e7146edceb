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

from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

STEP_KEYS = ("est_pos_err_h_m", "est_pos_err_v_m", "integrity_mi", "integrity_hmi")
"""The per-step ``info`` terms of :func:`misleading_lanes`."""
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


@kernel
def misleading_lanes(
    true_pos: FloatArray,
    est_pos: FloatArray,
    hpl: FloatArray,
    vpl: FloatArray,
    alert: FloatArray,
    h_limit: float,
    v_limit: float,
    out: FloatArray,
) -> None:
    """Rows of ``out`` (4, B), :data:`STEP_KEYS`: ``e_h``, ``e_v``, MI and HMI of each lane
    (module docstring), from the true states ``true_pos`` (B, ≥3; ρ first, N, m), the
    estimated positions ``est_pos`` (B, 3), the protection levels ``hpl``, ``vpl`` (B,) m,
    ``alert`` (B,) 1.0 where raised, and the horizontal and vertical alert limits in m."""
    for b in range(out.shape[1]):
        dn = est_pos[b, 0] - true_pos[b, 0]
        de = est_pos[b, 1] - true_pos[b, 1]
        e_h = math.sqrt(dn * dn + de * de)
        e_v = abs(est_pos[b, 2] - true_pos[b, 2])
        out[0, b] = e_h
        out[1, b] = e_v
        out[2, b] = 1.0 if (e_h > hpl[b] or e_v > vpl[b]) else 0.0
        hazard = (e_h > h_limit or e_v > v_limit) and not alert[b] > 0.5
        out[3, b] = 1.0 if hazard else 0.0


@kernel
def _accumulate(
    sums: FloatArray,
    onset: FloatArray,
    alerted: FloatArray,
    lanes: np.ndarray,
    alert: FloatArray,
    mi: FloatArray,
    hmi: FloatArray,
    tested: FloatArray,
    alarm: FloatArray,
    faulty: FloatArray,
    t: FloatArray,
) -> None:
    """Add one step of the ``lanes`` (B,) bool to the rows of ``sums`` (8, B) (the fields of
    :class:`IntegrityEpisode`), and note each lane's fault onset and first alarm during the
    fault (s; NaN until then)."""
    for b in range(lanes.shape[0]):
        if not lanes[b]:
            continue
        is_test, is_alarm, is_fault = tested[b] > 0.5, alarm[b] > 0.5, faulty[b] > 0.5
        sums[0, b] += 1.0
        sums[1, b] += 1.0 - alert[b]
        sums[2, b] += mi[b]
        sums[3, b] += hmi[b]
        sums[4, b] += is_test
        sums[5, b] += is_alarm
        sums[6, b] += is_test and not is_fault
        sums[7, b] += is_alarm and not is_fault
        if is_fault and math.isnan(onset[b]):
            onset[b] = t[b]
        if is_fault and is_alarm and math.isnan(alerted[b]):
            alerted[b] = t[b]


class IntegrityEpisode:
    """Running integrity sums of B lanes over their episodes (module docstring).

    Args:
        num_lanes: B.
    """

    _FIELDS = ("steps", "available", "mi", "hmi", "tests", "alarms", "ff_tests", "ff_alarms")

    def __init__(self, num_lanes: int) -> None:
        self._sums = np.zeros((len(self._FIELDS), num_lanes))
        self._onset = np.full(num_lanes, math.nan)  # the fault's first active step, s
        self._alerted = np.full(num_lanes, math.nan)  # the first alarm during the fault, s
        self._no_fault = np.zeros(num_lanes)

    def reset(self, lanes: np.ndarray) -> None:
        """Start the ``lanes``' sums afresh."""
        self._sums[:, lanes] = 0.0
        self._onset[lanes] = math.nan
        self._alerted[lanes] = math.nan

    def add(self, info: dict[str, FloatArray], lanes: np.ndarray) -> None:
        """Add one step of the ``lanes`` (B,) bool, from its ``info`` (the monitor's terms,
        ``integrity_mi``/``integrity_hmi``, ``t`` and, with faults, ``fault_active``)."""
        faulty = info.get("fault_active", self._no_fault)
        _accumulate(
            self._sums, self._onset, self._alerted, lanes, info["integrity_alert"],
            info["integrity_mi"], info["integrity_hmi"], info["fde_tested"], info["fde_alarm"],
            faulty, info["t"],
        )  # fmt: skip

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
