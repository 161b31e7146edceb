"""Episode summaries: running sums of the per-step metrics over the whole episode and over
its two phases (the transient ``t ≤ settle_s`` and the steady state), kept in one array per
lane so nothing grows with the episode.

See docs/design.md §4, §5. RMSEs, the average NEES (ANEES) and the share of steps whose NEES
lies inside the two-sided 95% χ² interval.
"""

from __future__ import annotations

import math

import numpy as np

from quadslam_env.metrics.association import ASSOCIATION_KEYS
from quadslam_env.metrics.step import NEES_POSE_BOUNDS_95
from quadslam_env.models.jit import kernel
from quadslam_env.types import FloatArray

# Episode accumulators, one column each: (summary key, per-step info key). The RMS columns
# hold sums of squares; the "last" columns the latest value; the NEES columns are handled apart.
_RMS = (
    ("episode_est_pos_rmse_m", "est_pos_err_m"),
    ("episode_est_vel_rmse_mps", "est_vel_err_mps"),
    ("episode_est_att_rmse_deg", "est_att_err_deg"),
    ("episode_track_pos_rmse_m", "track_pos_err_m"),
    ("episode_est_wind_rmse_mps", "est_wind_err_mps"),
)
_LAST = (
    ("episode_map_rmse_m", "est_map_rmse_m"),
    ("episode_n_mapped", "est_n_mapped"),
    ("episode_accel_bias_rel_err", "est_accel_bias_rel_err"),
    ("episode_gyro_bias_rel_err", "est_gyro_bias_rel_err"),
)
_INPUT_KEYS = (*(k for _, k in _RMS), *(k for _, k in _LAST), "est_nees_pose", "est_nees_pos", "t")
_N_RMS, _N_LAST = len(_RMS), len(_LAST)
# Accumulator columns: steps, RMS sums, last values, then NEES pose (sum, count, inside the 95%
# bounds) and NEES position (sum, count).
_COLS = 1 + _N_RMS + _N_LAST + 5
_ALL_INPUT_COLS = np.arange(len(_INPUT_KEYS))
PHASES = ("transient", "steady")
"""The two phases of an episode: ``t ≤ settle_s`` and ``t > settle_s`` (docs: metrics)."""
SETTLE_TOL_S = 1e-9
"""A step at ``t ≤ settle_s + SETTLE_TOL_S`` is in the transient (``t`` is ``steps·dt``)."""


def phase_key(name: str, phase: str) -> str:
    """The per-phase name of an episode summary: the phase before the unit suffix
    (``episode_track_pos_rmse_m`` → ``episode_track_pos_rmse_steady_m``), else at the end
    (``episode_anees_pose`` → ``episode_anees_pose_steady``)."""
    stem, _, unit = name.rpartition("_")
    if unit in ("m", "mps", "deg"):
        return f"{stem}_{phase}_{unit}"
    return f"{name}_{phase}"


def input_columns(rows: dict[str, int]) -> np.ndarray:
    """The row of each episode input key in an array whose rows are named by ``rows``
    (key → index), -1 for a key it lacks: the ``cols`` of :meth:`EpisodeMetrics.add_columns`."""
    return np.array([rows.get(key, -1) for key in _INPUT_KEYS], dtype=np.int64)


@kernel
def _accumulate(
    acc: FloatArray,
    values: FloatArray,
    cols: np.ndarray,
    sel: np.ndarray,
    lo: float,
    hi: float,
    settle: float,
) -> None:
    """Add one step's terms to the lanes selected by ``sel`` (B,): term j of
    :data:`_INPUT_KEYS` is the (B,) row ``values[cols[j]]`` (NaN where ``cols[j]`` < 0).

    ``acc`` is (3, B, cols): the whole episode, the transient and the steady state; each step
    goes to the whole episode and to the phase its time ``t`` falls in."""
    n_rms, n_last = len(_RMS), len(_LAST)
    nees_col = 1 + n_rms + n_last
    t_col = cols[n_rms + n_last + 2]
    nan = math.nan
    for b in range(acc.shape[1]):
        if not sel[b]:
            continue
        t = values[t_col, b] if t_col >= 0 else nan
        phase = 2 if t > settle else 1  # NaN time (no "t" row): the transient
        for ph in (0, phase):
            a = acc[ph, b]
            a[0] += 1.0
            for j in range(n_rms):
                a[1 + j] += (values[cols[j], b] if cols[j] >= 0 else nan) ** 2
            for j in range(n_last):
                c = cols[n_rms + j]
                a[1 + n_rms + j] = values[c, b] if c >= 0 else nan
            for k in range(2):  # pose, position; NaN/inf NEES values stay out of the ANEES
                c = cols[n_rms + n_last + k]
                v = values[c, b] if c >= 0 else nan
                if math.isfinite(v):
                    col = nees_col + 3 * k
                    a[col] += v
                    a[col + 1] += 1.0
                    if k == 0 and lo <= v <= hi:
                        a[col + 2] += 1.0


class EpisodeMetrics:
    """Accumulates per-step terms of B lanes into the ``episode_*`` summaries.

    Running sums only (O(1) memory per lane), so hour-long episodes do not grow with the step
    count. Each RMSE and NEES summary is kept over the whole episode and over each of
    :data:`PHASES` (named by :func:`phase_key`): the transient ``t ≤ settle_s`` and the steady
    state ``t > settle_s``, ``t`` being the step's ``t`` term.

    With ``association`` (unknown data association) it also sums the
    :data:`ASSOCIATION_KEYS` counts into ``episode_assoc_wrong_rate`` (wrong / associated
    returns), ``episode_assoc_missed_rate`` (missed / true returns) and keeps the last
    ``spurious_landmarks``.

    Args:
        num_lanes: B.
        association: Summarise the association terms too.
        settle_s: End of the transient, s.
    """

    def __init__(
        self, num_lanes: int = 1, association: bool = False, settle_s: float = 0.0
    ) -> None:
        self.num_lanes = num_lanes
        self.association = association
        self.settle_s = float(settle_s)
        self._acc = np.zeros((1 + len(PHASES), num_lanes, _COLS))  # whole, transient, steady
        self._assoc = np.zeros((num_lanes, len(ASSOCIATION_KEYS) + 1))  # sums, last spurious
        self._all = np.ones(num_lanes, dtype=bool)
        self.reset(np.arange(num_lanes))

    def reset(self, lanes: np.ndarray) -> None:
        """Zero the sums of the lanes selected by the (B,) mask or index array ``lanes``."""
        self._acc[:, lanes] = 0.0
        self._acc[:, lanes, 1 + _N_RMS : 1 + _N_RMS + _N_LAST] = math.nan
        self._assoc[lanes] = 0.0

    def add(self, info: dict[str, FloatArray], lanes: np.ndarray | None = None) -> None:
        """Record one step's terms of the lanes selected by the (B,) mask ``lanes``.

        Values are (B,) arrays (or numbers, broadcast to every lane). NaN/inf NEES values are
        left out of the ANEES; a missing key counts as NaN (a missing ``t``: the transient).
        """
        values = np.empty((len(_INPUT_KEYS), self.num_lanes))
        for j, key in enumerate(_INPUT_KEYS):
            values[j] = info.get(key, math.nan)
        self.add_columns(values, _ALL_INPUT_COLS, lanes)
        if self.association:
            self.add_association(info, lanes)

    def add_columns(
        self, values: FloatArray, cols: np.ndarray, lanes: np.ndarray | None = None
    ) -> None:
        """Record one step's terms from the rows of one array (no association terms).

        Args:
            values: (K, B) terms of the lanes, one row per term.
            cols: (len(_INPUT_KEYS),) int, the row of each input key (-1: absent, NaN);
                see :func:`input_columns`.
            lanes: (B,) bool lanes to record (default: all).
        """
        sel = self._all if lanes is None else lanes
        lo, hi = NEES_POSE_BOUNDS_95
        _accumulate(self._acc, values, cols, sel, lo, hi, self.settle_s + SETTLE_TOL_S)

    def add_association(self, info: dict[str, FloatArray], lanes: np.ndarray | None) -> None:
        """Record one step's :data:`ASSOCIATION_KEYS` counts and ``spurious_landmarks``."""
        sel = self._all if lanes is None else lanes
        if self.association:
            for j, key in enumerate(ASSOCIATION_KEYS):  # counts: never NaN
                np.add(self._assoc[:, j], info[key], out=self._assoc[:, j], where=sel)
            np.copyto(self._assoc[:, -1], info["spurious_landmarks"], where=sel)

    def summary(self) -> dict[str, FloatArray]:
        """Episode RMSEs, ANEES and the share of steps inside the 95% χ² bounds, each (B,),
        over the whole episode and per phase (NaN for a phase without steps)."""
        out = {"episode_steps": self._acc[0, :, 0].copy()}
        out.update(_rms_nees(self._acc[0], ""))
        for j, (name, _) in enumerate(_LAST):
            out[name] = self._acc[0, :, 1 + _N_RMS + j].copy()
        for p, phase in enumerate(PHASES, start=1):
            out[f"episode_steps_{phase}"] = self._acc[p, :, 0].copy()
            out.update(_rms_nees(self._acc[p], phase))
        if self.association:
            with np.errstate(invalid="ignore", divide="ignore"):
                _, n_assoc, n_wrong, n_true, n_missed, spurious = self._assoc.T
                out["episode_assoc_wrong_rate"] = n_wrong / n_assoc
                out["episode_assoc_missed_rate"] = n_missed / n_true
                out["episode_spurious_landmarks"] = spurious.copy()
        return out


def _rms_nees(acc: FloatArray, phase: str) -> dict[str, FloatArray]:
    """The RMSE and NEES summaries of one phase's (B, cols) sums (``phase`` "" = whole)."""

    def key(name: str) -> str:
        return phase_key(name, phase) if phase else name

    n = acc[:, 0]
    out: dict[str, FloatArray] = {}
    with np.errstate(invalid="ignore", divide="ignore"):
        for j, (name, _) in enumerate(_RMS):
            out[key(name)] = np.where(n > 0, np.sqrt(acc[:, 1 + j] / n), math.nan)
        s, c, inside, s3, c3 = acc[:, 1 + _N_RMS + _N_LAST :].T
        out[key("episode_anees_pose")] = np.where(c > 0, s / c, math.nan)
        out[key("episode_nees_pose_in_bounds")] = np.where(c > 0, inside / c, math.nan)
        out[key("episode_anees_pos")] = np.where(c3 > 0, s3 / c3, math.nan)
    return out
