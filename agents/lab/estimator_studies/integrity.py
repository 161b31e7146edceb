"""``quadslam study integrity``: do EKF-SLAM's and iSAM2's integrity monitors see the faults of
the world, and do their protection levels bound the error?

DF-LQR flies on EKF-SLAM's estimate (``paper_ekf_figure8``, the unknown map) on held-out seeds,
fault-free and with each fault kind of the ``faults`` section (onset drawn in 10–15 s), with
the monitor detecting only (``integrity.monitor: detect``: the filter is the unmonitored one;
its protection levels and alarms are reported), on the filter without its χ² gate and with it,
excluding (``exclude``: the landmarks found faulty are left out and dropped from the map), and
excluding with the sequential test as well (``integrity.sequential_window``); and on the iSAM2
smoother's estimate (same scenario, ``estimator.name: isam2``), detecting, and excluding with
and without the sequential test (:mod:`estimators.isam2.fde`; without GTSAM these rows are
left out). Per row: the
false-alarm rate on fault-free scans against the budget, misleading and hazardously misleading
information, availability, the share of fault-free steps the protection levels bound and how
far above the error they sit, detection within 3 s and the time to alert (for a moving or a
phantom landmark from the first scan after the onset that returns it), and the horizontal
error over the episode's last 5 s against the fault-free row's. The Stanford diagram (true
error against protection level, 2-D histogram, with the alert limit) of each row is the figure.
``--quick`` flies 3 seeds of 20 s (a smoke run, not a result).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from agents.evaluation.episodes import json_float, run_episodes
from agents.io.outputs import atomic_produce, write_text_atomic
from agents.lab.estimator_studies.flown_tasks import has_isam2, map_tasks

SCENARIO = "paper_ekf_figure8"
ALERT_LIMIT_M = 0.5
P_FA = 1e-3
P_HMI = 1e-3
DETECT_WITHIN_S = 3.0
FREE_SEEDS = 50
"""Fault-free episodes of a full run: 50 × 50 s at 10 Hz is 25,000 scans tested."""
RECOVERY_WINDOW_S = 5.0
ONSET = {"onset_s": 10.0, "onset_max_s": 15.0}
FAULTS: dict[str, dict[str, Any]] = {
    "fault_free": {},
    "landmark_moves": {"kind": "landmark_moves", "magnitude": 0.2, **ONSET},
    "phantom_landmark": {"kind": "phantom_landmark", **ONSET},
    "range_bias": {"kind": "range_bias", "magnitude": 0.3, "fraction": 0.25, **ONSET},
    "imu_bias_step": {
        "kind": "imu_bias_step", "magnitude": 0.3, "sensor": "accel", "axis": 0, **ONSET,
    },
}  # fmt: skip
"""The cases: the ``faults`` section of each (none for the fault-free row)."""
EKF_MODES = ("detect_no_gate", "detect", "exclude", "exclude_sequential")
"""The monitor's rows on EKF-SLAM: detecting without its per-landmark χ² gate
(``gate_probability: 1``: every return used, as the paper's filter), detecting on the gated
filter, excluding, and excluding with the sequential test as well."""
ISAM2_MODES = ("isam2_detect", "isam2_exclude", "isam2_exclude_sequential")
"""The monitor's rows on the iSAM2 smoother (which has no gate on labeled returns): detecting
(the smoother is the unmonitored one), excluding, and excluding with the sequential test."""
SEQUENTIAL_WINDOW = 10
"""``integrity.sequential_window`` of the ``exclude_sequential`` row: 1 s of scans."""
_SERIES = ("t", "est_pos_err_h_m", "est_pos_err_v_m", "hpl_m", "vpl_m", "integrity_alert",
           "fault_active", "fault_in_view", "fde_alarm", "fde_tested")  # fmt: skip
_SIGHTED = ("landmark_moves", "phantom_landmark")
"""The kinds whose time to alert runs from the first scan that returns the faulty landmark
after the onset (before it no monitor can see the fault)."""


@dataclass
class StepLog:
    """The per-step integrity terms of every episode of one row, as the observer of
    :func:`~agents.evaluation.episodes.run_episodes` sees them (lane by lane)."""

    lanes: dict[int, dict[str, list[float]]] = field(default_factory=dict)

    def __call__(self, core: Any, stepped: np.ndarray, info: dict[str, Any]) -> None:
        for lane in np.flatnonzero(stepped).tolist():
            if float(np.asarray(info["t"])[lane]) == 0.0:  # a reset: a new episode
                self.lanes[lane] = {key: [] for key in _SERIES}
                continue
            log = self.lanes[lane]
            for key in _SERIES:
                value = info.get(key)
                log[key].append(0.0 if value is None else float(np.asarray(value)[lane]))

    def arrays(self) -> list[dict[str, np.ndarray]]:
        """One dict of (steps,) arrays per episode, in lane order."""
        return [{k: np.array(v) for k, v in self.lanes[i].items()} for i in sorted(self.lanes)]


def modes() -> tuple[str, ...]:
    """The rows' modes: EKF-SLAM's, and iSAM2's where GTSAM is installed."""
    return EKF_MODES + ISAM2_MODES if has_isam2("integrity") else EKF_MODES


def _overrides(case: str, mode: str, duration: float | None) -> dict[str, Any]:
    monitor = mode.removeprefix("isam2_").removesuffix("_no_gate").removesuffix("_sequential")
    out: dict[str, Any] = {
        "integrity": {"monitor": monitor, "alert_limit_m": ALERT_LIMIT_M, "p_fa": P_FA,
                      "p_hmi": P_HMI},
    }  # fmt: skip
    if mode.endswith("_sequential"):
        out["integrity"]["sequential_window"] = SEQUENTIAL_WINDOW
    if mode.endswith("_no_gate"):
        out["estimator"] = {"params": {"gate_probability": 1.0}}
    if mode.startswith("isam2_"):
        out["estimator"] = {"name": "isam2"}
    if FAULTS[case]:
        out["faults"] = FAULTS[case]
    if duration is not None:
        out["episode"] = {"duration_s": duration}
    return out


def _fly(case: str, mode: str, seeds: list[int], duration: float | None) -> tuple[list, StepLog]:
    """DF-LQR episodes of one row, with the step log."""
    import gymnasium as gym

    import quadslam_env  # noqa: F401  (registers the ids)
    from agents.control.dflqr import DFLQRPolicy

    env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **_overrides(case, mode, duration))
    log = StepLog()
    try:
        return run_episodes(env, DFLQRPolicy.from_env(env), seeds, observer=log), log
    finally:
        env.close()


def _ratio(num: float, den: float) -> float | None:
    return json_float(num / den) if den > 0 else None


def row_summary(series: list[dict[str, np.ndarray]], sighted: bool = False) -> dict[str, Any]:
    """The row's integrity figures from its step logs (module docstring), pooled over the
    episodes where a rate is asked, medians over the episodes otherwise; with ``sighted`` the
    time to alert runs from the first scan after the onset that returns the faulty landmark
    (episodes where none does are counted apart, ``never_in_view``)."""
    cat = {k: np.concatenate([s[k] for s in series]) for k in _SERIES}
    free = cat["fault_active"] < 0.5
    e_h, e_v, hpl, vpl = cat["est_pos_err_h_m"], cat["est_pos_err_v_m"], cat["hpl_m"], cat["vpl_m"]
    bounded = (e_h <= hpl) & (e_v <= vpl)
    hazard = ((e_h > ALERT_LIMIT_M) | (e_v > ALERT_LIMIT_M)) & (cat["integrity_alert"] < 0.5)
    tested = cat["fde_tested"] > 0.5
    ff_tests = int((tested & free).sum())
    ff_alarms = int((tested & free & (cat["fde_alarm"] > 0.5)).sum())
    tta, late_err, peak, unseen = [], [], [], 0
    for s in series:
        on = np.flatnonzero(s["fault_active"] > 0.5)
        window = s["t"] > s["t"][-1] - RECOVERY_WINDOW_S
        late_err.append(float(np.sqrt(np.mean(s["est_pos_err_h_m"][window] ** 2))))
        if on.size:
            peak.append(float(s["est_pos_err_h_m"][on[0] :].max()))
            if sighted:  # from the first scan that returns the faulty landmark
                on = on[np.argmax(s["fault_in_view"][on] > 0.5) :]
                if not (s["fault_in_view"][on] > 0.5).any():
                    unseen += 1
                    continue
            alarms = on[s["fde_alarm"][on] > 0.5]
            tta.append(float(s["t"][alarms[0]] - s["t"][on[0]]) if alarms.size else math.inf)
    tta_arr = np.array(tta)
    return {
        "episodes": len(series),
        "steps": int(cat["t"].size),
        "fault_free_steps": int(free.sum()),
        "false_alarm_rate": _ratio(ff_alarms, ff_tests),
        "false_alarms": ff_alarms,
        "fault_free_scans": ff_tests,
        "bounded_fault_free": _ratio(float((bounded & free).sum()), float(free.sum())),
        "mi_rate": json_float(float(np.mean(~bounded))),
        "hmi_steps": int(hazard.sum()),
        "availability": json_float(float(np.mean(cat["integrity_alert"] < 0.5))),
        "median_hpl_m": json_float(float(np.median(hpl[free]))) if free.any() else None,
        "median_err_h_m": json_float(float(np.median(e_h[free]))) if free.any() else None,
        "detected_within_3s": _ratio(float((tta_arr <= DETECT_WITHIN_S).sum()), tta_arr.size),
        "median_time_to_alert_s": json_float(float(np.median(tta_arr))) if tta else None,
        "missed": int(np.isinf(tta_arr).sum()),
        "never_in_view": unseen,
        "late_err_h_rms_m": json_float(float(np.median(late_err))),
        "peak_err_h_after_onset_m": json_float(float(np.median(peak))) if peak else None,
        "episodes_over_alert_limit": int(sum(p > ALERT_LIMIT_M for p in peak)),
    }


def _row(task: tuple[str, str, list[int], float | None]) -> tuple[list, list, float]:
    """One row's episodes, step logs (one dict of arrays per episode) and wall time, s."""
    tic = time.perf_counter()
    episodes, log = _fly(*task)
    return episodes, log.arrays(), round(time.perf_counter() - tic, 1)


def run_study(
    seeds: int, first_seed: int, quick: bool, free_seeds: int | None = None, jobs: int = 1
) -> dict[str, Any]:
    """Fly every case in every mode; the result as plain data (and the step logs apart).

    Args:
        seeds: Episodes per fault row (seeds ``first_seed`` …).
        first_seed: First held-out seed.
        quick: 20 s episodes (onsets still 10–15 s).
        free_seeds: Episodes of the fault-free rows (default 50, quick ``seeds``): enough
            scans to measure a false-alarm rate of the budget's order.
        jobs: Rows flown at a time, each in its own spawned process (1: in this one); the
            results do not depend on it.
    """
    free_count = free_seeds or (seeds if quick else FREE_SEEDS)
    duration = 20.0 if quick else None
    row_modes = modes()
    tasks = []
    for case in FAULTS:
        count = free_count if case == "fault_free" else seeds
        seed_list = list(range(first_seed, first_seed + count))
        tasks += [(case, mode, seed_list, duration) for mode in row_modes]
    flown = map_tasks(_row, tasks, jobs)
    rows: list[dict[str, Any]] = []
    logs: dict[tuple[str, str], list[dict[str, np.ndarray]]] = {}
    for (case, mode, seed_list, _), (episodes, series, wall) in zip(tasks, flown, strict=True):
        logs[(case, mode)] = series
        rows.append(
            {"case": case, "mode": mode, "faults": FAULTS[case], "seeds": seed_list,
             "summary": row_summary(series, case in _SIGHTED), "wall_s": wall,
             "episodes": episodes}
        )  # fmt: skip
    free = {r["mode"]: r["summary"]["late_err_h_rms_m"] for r in rows if r["case"] == "fault_free"}
    for r in rows:
        base = free.get(r["mode"])
        late = r["summary"]["late_err_h_rms_m"]
        r["summary"]["late_err_vs_fault_free"] = _ratio(late, base) if base else None
    settings = {"scenario": SCENARIO, "first_seed": first_seed, "quick": quick,
                "alert_limit_m": ALERT_LIMIT_M, "p_fa": P_FA, "p_hmi": P_HMI,
                "modes": list(row_modes)}  # fmt: skip
    return {"settings": settings, "rows": rows, "_logs": logs}


def format_study(result: dict[str, Any]) -> str:
    """The table of the rows (a line per case and mode)."""
    head = ("case", "mode", "FA rate", "bounded", "HMI", "avail", "PL/err", "det≤3s", "TTA s",
            "late err m", "×free")  # fmt: skip
    lines = [" | ".join(head), " | ".join("---" for _ in head)]

    def cell(value: Any, fmt: str = "{:.3g}") -> str:
        return "–" if value is None else fmt.format(value)

    for r in result["rows"]:
        s = r["summary"]
        ratio = None
        if s["median_hpl_m"] is not None and s["median_err_h_m"]:
            ratio = s["median_hpl_m"] / s["median_err_h_m"]
        lines.append(" | ".join((
            r["case"], r["mode"], cell(s["false_alarm_rate"]), cell(s["bounded_fault_free"]),
            str(s["hmi_steps"]), cell(s["availability"]), cell(ratio),
            cell(s["detected_within_3s"]), cell(s["median_time_to_alert_s"]),
            cell(s["late_err_h_rms_m"]), cell(s["late_err_vs_fault_free"]),
        )))  # fmt: skip
    return "\n".join(lines)


def write_json(result: dict[str, Any], path: Path) -> None:
    """The result as JSON (rows with their episodes; not the step logs)."""
    plain = {k: v for k, v in result.items() if not k.startswith("_")}
    write_text_atomic(path, json.dumps(plain, indent=1) + "\n")


def plot_study(result: dict[str, Any], folder: Path) -> Path:
    """``integrity_stanford.png`` in ``folder`` (returned): the Stanford diagram of each row,
    horizontal error against HPL as a 2-D histogram of steps (log scales), with the alert
    limit and the line PL = error (misleading information below it)."""
    from matplotlib.colors import LogNorm
    from matplotlib.figure import Figure

    logs = result["_logs"]
    cases = list(FAULTS)
    rows = list(dict.fromkeys(mode for _, mode in logs))
    fig = Figure(figsize=(3.0 * len(cases), 3.0 * len(rows)), constrained_layout=True)
    axes = fig.subplots(len(rows), len(cases), squeeze=False)
    bins = np.logspace(-3, 1.5, 60)
    for i, mode in enumerate(rows):
        for j, case in enumerate(cases):
            ax = axes[i, j]
            series = logs[(case, mode)]
            e = np.concatenate([s["est_pos_err_h_m"] for s in series])
            pl = np.concatenate([s["hpl_m"] for s in series])
            ax.hist2d(np.clip(e, 1e-3, None), np.clip(pl, 1e-3, None), bins=[bins, bins],
                      norm=LogNorm(), cmap="viridis")  # fmt: skip
            ax.plot(bins, bins, "k-", lw=0.8)
            ax.axvline(ALERT_LIMIT_M, color="tab:red", lw=0.8)
            ax.axhline(ALERT_LIMIT_M, color="tab:red", lw=0.8)
            ax.set_xscale("log")
            ax.set_yscale("log")
            ax.set_title(f"{case}, {mode}", fontsize=8)
            if i == len(rows) - 1:
                ax.set_xlabel("horizontal error [m]")
            if j == 0:
                ax.set_ylabel("HPL [m]")
    fig.suptitle(f"Stanford diagrams: DF-LQR on EKF-SLAM and (isam2_ rows) iSAM2, {SCENARIO}, "
                 f"alert limit {ALERT_LIMIT_M} m (red)")  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "integrity_stanford.png"
    atomic_produce(path, lambda tmp: fig.savefig(tmp, dpi=110))
    return path
