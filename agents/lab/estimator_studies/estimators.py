"""``quadslam study estimators``: EKF-SLAM, FastSLAM and iSAM2 against the Cramér–Rao bound.

Each cell (scenario × estimator) is flown as :mod:`agents.lab.estimator_studies.bound` flies a
scenario (:func:`~agents.lab.estimator_studies.bound.fly_and_bound`: DF-LQR on the estimate, one
episode per seed, the posterior Cramér–Rao bound (PCRB) along each seed's true trajectory), one seed
per vector env so that the estimator's time per step is one vehicle's. Per cell it reports:

- **RMSE** of the position, inertial velocity and attitude (rotation angle) over the whole
  flight and over the steady state ``t > episode.settle_s`` (the env's own transient, see
  ``quadslam_env.episode.start``), pooled over seeds (``√(mean over seeds of MSE)``, what the
  bound bounds), next to the bound's RMSE-equivalent pooled the same way, and their ratio.
  Every row has its own bound: DF-LQR flies on the estimate, so each row's true
  trajectories (and bounds) differ slightly.
- **ANEES** of each 3-DOF block ``(ρ, v_B, Λ)`` against its marginal of the estimate's own
  covariance (:func:`agents.lab.estimator_studies.particle_nees.block_nees`; for FastSLAM the
  weighted particle moments the filter reports): ``ANEES_k = mean over the n runs of NEES_k`` at
  each step, and the share of steps inside the two-sided 95% interval of ``χ²(3n)/n``
  (Bar-Shalom, Li & Kirubarajan 2001, §5.4) over the steps all runs reached.
- **Time per step**: the estimator's wall-clock time per env step
  (``episode.report_step_time``), mean over the steady state's steps of every seed (the
  transient holds the first call of every numba kernel, i.e. its compilation).

A cell that cannot run (GTSAM not installed, a setting the estimator refuses) is reported as
such, with the reason, and never filled in.
"""

from __future__ import annotations

import importlib.util
import math
from typing import Any

import numpy as np

from agents.lab.estimator_studies.bound import BLOCKS, TruthRecorder, fly_and_bound, summarize_seeds
from agents.lab.estimator_studies.estimator_cells import (
    ROWS,
    SCENARIOS,
    Row,
    cell_overrides,
    cell_scenario,
)
from agents.lab.estimator_studies.particle_nees import block_nees
from quadslam_env.metrics.step import anees_bounds
from quadslam_env.models.frames import wrap_angle
from quadslam_env.types import EUL, POS, VEL

NEES_BLOCKS = ("pos", "vel", "att")


class NeesRecorder(TruthRecorder):
    """A :class:`~agents.lab.estimator_studies.bound.TruthRecorder` that also keeps, per episode and
    step (steps 1 … K, as the bound's series), the NEES of each block and the estimator's time."""

    def __init__(self) -> None:
        super().__init__()
        self._extra: dict[int, dict[str, list[float]]] = {}

    def __call__(self, core: Any, stepped: np.ndarray, info: dict[str, Any]) -> None:
        super().__call__(core, stepped, info)
        est, state = core.est, core.vehicle.state
        times = info.get("est_step_time_ms")
        for lane in np.flatnonzero(stepped).tolist():
            rec = self._current[lane]
            extra = self._extra.setdefault(id(rec), {b: [] for b in (*NEES_BLOCKS, "ms")})
            if core.steps[lane] == 0:  # the reset: no step yet
                continue
            x = state[lane]
            err = np.concatenate(
                [
                    est.position[lane] - x[POS],
                    est.vel_body[lane] - x[VEL],
                    np.asarray(wrap_angle(est.euler[lane] - x[EUL])),
                ]
            )
            nees = block_nees(err, est.pose_cov[lane])
            for b in NEES_BLOCKS:
                extra[b].append(nees[b])
            extra["ms"].append(math.nan if times is None else float(np.atleast_1d(times)[lane]))

    def extras(self) -> list[dict[str, np.ndarray]]:
        """Per episode (order of the seeds): ``{"pos", "vel", "att"}`` NEES (K,) and ``"ms"``."""
        return [{k: np.array(v) for k, v in self._extra[id(r)].items()} for r in self.lanes]


def anees_share(nees: list[np.ndarray], t: np.ndarray, settle_s: float) -> dict[str, Any]:
    """The n-run ANEES of one 3-DOF block and the share of steps inside its 95% interval.

    Args:
        nees: Per run, the block's NEES (K_i,) at steps 1 … K_i.
        t: (K,) times of the longest run's steps, s.
        settle_s: End of the transient, s.

    Returns:
        ``anees`` (K,) (a list) over the K = min K_i steps every run reached, its ``interval``, the
        ``share`` of steps inside it (and ``share_steady``, over ``t > settle_s``), its time
        average ``mean`` and the number of ``undefined`` steps, where a run's covariance is
        singular (an estimator told its exact start: zero variance at first). The share and
        the mean are over the defined steps.
    """
    length = min(len(n) for n in nees)
    anees = np.mean([n[:length] for n in nees], axis=0)
    lo, hi = anees_bounds(3, len(nees))
    defined = np.isfinite(anees)
    inside = (anees[defined] >= lo) & (anees[defined] <= hi)
    steady = t[:length][defined] > settle_s
    return {
        "anees": anees.tolist(),
        "interval": [lo, hi],
        "share": float(inside.mean()) if inside.size else math.nan,
        "share_steady": float(inside[steady].mean()) if steady.any() else math.nan,
        "mean": float(anees[defined].mean()) if inside.size else math.nan,
        "undefined": int(length - np.count_nonzero(defined)),
    }


def run_cell(
    cell: str, row: Row, seeds: list[int], duration_s: float | None = None
) -> dict[str, Any]:
    """Fly one cell (a key of :data:`SCENARIOS`) and summarise it (module docstring);
    ``{"applies": False, "reason"}`` when the estimator cannot run there."""
    from quadslam_env.schema import ConfigError

    if row.name == "isam2" and importlib.util.find_spec("gtsam") is None:
        return {"applies": False, "reason": "GTSAM not installed (pip install 'quadslam[gtsam]')"}
    if duration_s is None:
        duration_s = SCENARIOS[cell].get("duration_s")
    recorder = NeesRecorder()
    overrides = cell_overrides(cell, row)
    try:
        flight = fly_and_bound(cell_scenario(cell), seeds, duration_s, overrides, None, recorder, 1)
    except ConfigError as exc:
        return {"applies": False, "reason": str(exc)}
    per_seed = [s.summary(flight.settle_s) for s in flight.series]
    extras = recorder.extras()
    steady_ms = []
    for rec, ep, ex, s in zip(per_seed, flight.episodes, extras, flight.series, strict=True):
        rec["terminated"] = ep["terminated"]
        rec["termination_reason"] = ep["termination_reason"]
        steady_ms.append(ex["ms"][s.t > flight.settle_s])
        rec["est_step_time_ms"] = float(np.mean(steady_ms[-1])) if steady_ms[-1].size else None
    summary = summarize_seeds(per_seed)
    ratios = {}
    for name, unit, *_ in BLOCKS:
        for span in ("", "_steady"):
            est = summary[f"est_{name}_rmse_{unit}{span}"]["pooled"]
            bound = summary[f"bound_{name}_rmse_{unit}{span}"]["pooled"]
            ratio = est / bound if est is not None and bound else math.nan
            ratios[f"ratio_{name}{span}"] = ratio
    times = np.concatenate(steady_ms)
    longest = max(flight.series, key=lambda s: len(s.t)).t
    anees = {b: anees_share([e[b] for e in extras], longest, flight.settle_s) for b in NEES_BLOCKS}
    return {
        "applies": True,
        "scenario": flight.scenario.name,
        "estimator": flight.scenario.estimator.name,
        "params": flight.scenario.estimator.params,
        "duration_s": float(flight.scenario.episode.duration_s),
        "settle_s": flight.settle_s,
        "summary": summary,
        "ratios": ratios,
        "anees": anees,
        "est_step_time_ms": float(np.mean(times)) if times.size else math.nan,
        "ended_early": sum(1 for s in per_seed if s["terminated"]),
        "seeds": per_seed,
    }


def run_study(
    seeds: list[int],
    scenarios: list[str] | None = None,
    rows: list[str] | None = None,
    duration_s: float | None = None,
) -> dict[str, Any]:
    """Every cell of ``scenarios`` × ``rows`` (keys of :data:`SCENARIOS` and :data:`ROWS`;
    default all). Returns the JSON document: ``settings`` and ``cells[scenario][row key]``."""
    scenarios = list(SCENARIOS) if scenarios is None else scenarios
    chosen = [r for r in ROWS if rows is None or r.key in rows]
    cells: dict[str, dict[str, Any]] = {}
    for scenario in scenarios:
        cells[scenario] = {r.key: run_cell(scenario, r, seeds, duration_s) for r in chosen}
    return {
        "settings": {
            "seeds": seeds,
            "duration_s": duration_s,
            "rows": {r.key: {"label": r.label, "name": r.name} for r in chosen},
        },
        "cells": cells,
    }


def _num(value: Any, fmt: str) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    return fmt.format(value)


def _rmse_cell(cell: dict[str, Any], name: str, unit: str, span: str, fmt: str) -> str:
    """``est / bound (ratio)`` of one block and span, pooled over seeds."""
    s = cell["summary"]
    est = s[f"est_{name}_rmse_{unit}{span}"]["pooled"]
    bound = s[f"bound_{name}_rmse_{unit}{span}"]["pooled"]
    ratio = cell["ratios"][f"ratio_{name}{span}"]
    return f"{_num(est, fmt)} / {_num(bound, fmt)} ({_num(ratio, '{:.2f}')})"


def _bound_range(cells: list[dict[str, Any]], name: str, unit: str, span: str, fmt: str) -> str:
    """The pooled bound of one block over the rows' flights: one value or ``min–max``."""
    values = [c["summary"][f"bound_{name}_rmse_{unit}{span}"]["pooled"] for c in cells]
    values = [v for v in values if v is not None]
    if not values:
        return "–"
    lo, hi = _num(min(values), fmt), _num(max(values), fmt)
    return lo if lo == hi else f"{lo}–{hi}"


FORMATS = {"pos": "{:.4f}", "vel": "{:.4f}", "att": "{:.3f}"}


def _anees_cell(block: dict[str, Any]) -> str:
    """``ANEES (share inside %)``, with the steps that had no NEES when there are any."""
    share = None if block["share"] is None else 100 * block["share"]
    text = f"{_num(block['mean'], '{:.2f}')} ({_num(share, '{:.0f}')}%"
    undefined = block.get("undefined", 0)
    return text + (f"; {undefined} step(s) undefined)" if undefined else ")")


def format_markdown(result: dict[str, Any]) -> str:
    """The accuracy table (RMSE / PCRB, whole flight and steady state) and the consistency and
    cost table, as markdown."""
    labels = {k: v["label"] for k, v in result["settings"]["rows"].items()}
    spans = [(name, unit, span) for name, unit, *_ in BLOCKS for span in ("", "_steady")]
    heads = {"pos": "position [m]", "vel": "velocity [m/s]", "att": "attitude [deg]"}
    acc = [
        "| scenario | estimator | "
        + " | ".join(f"{heads[n]}{', steady' if s else ''}" for n, _, s in spans)
        + " |",
        "|---|---|" + "---|" * len(spans),
    ]
    cons = [
        "| scenario | estimator | ANEES pos (in 95%) | ANEES vel (in 95%) | ANEES att (in 95%) "
        "| estimator ms/step | ended early |",
        "|---|---|---|---|---|---|---|",
    ]
    for scenario, row_cells in result["cells"].items():
        ran = [c for c in row_cells.values() if c["applies"]]
        for key, cell in row_cells.items():
            head = f"| `{scenario}` | {labels[key]} | "
            if not cell["applies"]:
                na = f"not run: {cell['reason']}"
                acc.append(head + " | ".join([na] + [""] * (len(spans) - 1)) + " |")
                cons.append(head + na + " | | | | |")
                continue
            acc.append(
                head + " | ".join(_rmse_cell(cell, n, u, s, FORMATS[n]) for n, u, s in spans) + " |"
            )
            anees = [_anees_cell(cell["anees"][b]) for b in NEES_BLOCKS]
            n = len(cell["seeds"])
            cons.append(
                head
                + " | ".join(anees)
                + f" | {_num(cell['est_step_time_ms'], '{:.2f}')} | {cell['ended_early']}/{n} |"
            )
        if ran:
            acc.append(
                f"| `{scenario}` | PCRB | "
                + " | ".join(_bound_range(ran, n, u, s, FORMATS[n]) for n, u, s in spans)
                + " |"
            )
    return "\n".join(acc) + "\n\n" + "\n".join(cons)


def cli_estimators(args: Any) -> int:
    """``quadslam study estimators``: fly every cell, print the tables, write ``--json``."""
    from agents.io.outputs import Saver, clean_json
    from agents.io.paths import check_output_file

    if args.json is not None:
        check_output_file(args.json, "--json")
    seeds = list(range(args.seed, args.seed + args.seeds))
    result = run_study(seeds, args.scenarios, args.rows, args.duration)
    print(f"{len(seeds)} seed(s) per cell ({seeds[0]}–{seeds[-1]}); cells: est / PCRB (ratio)")
    print(format_markdown(result))
    if args.json is not None:
        saver = Saver()
        print(f"json: {saver.write_json(args.json, clean_json(result), '--json')}")
        saver.check()
    return 0
