"""``quadslam study estimators`` (agents/lab/estimator_studies/estimators.py) on tiny inputs: the
ratio column is the pooled RMSE over the pooled bound recomputed from the per-seed values, the ANEES
share is a recount against the χ² interval computed here, the block NEES equals the env's own, and a
cell that cannot run says why."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
from scipy.stats import chi2

import quadslam_env  # noqa: F401  (registers the env ids)
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import run_episodes
from agents.lab.cli import main as cli
from agents.lab.estimator_studies.bound import bound_model
from agents.lab.estimator_studies.estimator_cells import ROWS, cell_overrides, cell_scenario
from agents.lab.estimator_studies.estimators import (
    NeesRecorder,
    anees_share,
    format_markdown,
    run_cell,
)
from estimators.isam2.settings import PRIOR_VARIANCE_FLOOR
from quadslam_env.types import POS, POSE_DIM

SCENARIO = "paper_ekf_figure8_known"
EKF = next(r for r in ROWS if r.key == "ekf_slam")
ISAM2 = next(r for r in ROWS if r.key == "isam2_lag")


def _pooled(values: list[float]) -> float:
    return math.sqrt(float(np.mean(np.square(values))))


@pytest.fixture(scope="module")
def ekf_cell() -> dict[str, Any]:
    return run_cell(SCENARIO, EKF, [0, 1], duration_s=1.5)


def test_ratio_is_pooled_rmse_over_pooled_bound(ekf_cell: dict[str, Any]) -> None:
    assert ekf_cell["applies"] and len(ekf_cell["seeds"]) == 2
    for name, unit in (("pos", "m"), ("vel", "mps"), ("att", "deg")):
        est = _pooled([s[f"est_{name}_rmse_{unit}"] for s in ekf_cell["seeds"]])
        bound = _pooled([s[f"bound_{name}_rmse_{unit}"] for s in ekf_cell["seeds"]])
        assert ekf_cell["ratios"][f"ratio_{name}"] == pytest.approx(est / bound, rel=1e-12)
        # A 1.5 s episode never reaches the 10 s transient's end: no steady state, no ratio.
        assert math.isnan(ekf_cell["ratios"][f"ratio_{name}_steady"])


def test_anees_share_is_a_recount_against_the_chi2_interval(ekf_cell: dict[str, Any]) -> None:
    n = len(ekf_cell["seeds"])
    lo, hi = chi2.ppf(0.025, 3 * n) / n, chi2.ppf(0.975, 3 * n) / n
    for block in ("pos", "vel", "att"):
        a = ekf_cell["anees"][block]
        anees = np.array(a["anees"])
        assert anees.shape == (150,)  # 1.5 s at 100 Hz, both runs to the end
        np.testing.assert_allclose(a["interval"], [lo, hi], rtol=1e-12)
        share = sum(lo <= v <= hi for v in anees.tolist()) / anees.size
        assert 0.0 <= a["share"] <= 1.0 and a["share"] == pytest.approx(share, abs=1e-15)
        assert a["mean"] == pytest.approx(float(anees.mean()))


class _WithInfo(NeesRecorder):
    """Also keeps the env's own position NEES (a Cholesky kernel) per lane and step."""

    def __init__(self) -> None:
        super().__init__()
        self.env_nees: dict[int, list[float]] = {}

    def __call__(self, core: Any, stepped: np.ndarray, info: dict[str, Any]) -> None:
        super().__call__(core, stepped, info)
        for lane in np.flatnonzero(stepped).tolist():
            if core.steps[lane] > 0:  # steps 1 … K, as the recorder's
                self.env_nees.setdefault(lane, []).append(float(info["est_nees_pos"][lane]))


def test_block_nees_equals_the_envs_position_nees() -> None:
    overrides = cell_overrides("paper_ekf_figure8", EKF)
    overrides["episode"]["duration_s"] = 1.0
    env = gym.make("QuadSLAM-v0", scenario="paper_ekf_figure8", **overrides)
    rec = _WithInfo()
    run_episodes(env, DFLQRPolicy.from_env(env), [2, 3], observer=rec)
    env.close()
    for lane, extra in enumerate(rec.extras()):
        # Two factorisations of a covariance whose attitude block starts at zero (the
        # scenario's P0): 1e-7 apart at most here.
        np.testing.assert_allclose(extra["pos"], rec.env_nees[lane], rtol=1e-6)
        assert np.all(extra["ms"] > 0.0)  # episode.report_step_time reached the recorder


def test_missing_gtsam_is_reported_not_filled_in(monkeypatch: pytest.MonkeyPatch) -> None:
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "gtsam" else find_spec(name)
    )
    cell = run_cell(SCENARIO, ISAM2, [0], duration_s=0.5)
    assert cell == {
        "applies": False,
        "reason": "GTSAM not installed (pip install 'quadslam[gtsam]')",
    }
    table = format_markdown(
        {"settings": {"rows": {"isam2_lag": {"label": "iSAM2 fixed lag"}}},
         "cells": {SCENARIO: {"isam2_lag": cell}}}
    )  # fmt: skip
    assert "| iSAM2 fixed lag | not run: GTSAM not installed" in table


def test_cli_prints_the_tables_and_writes_json(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    pytest.importorskip("gtsam")
    out = tmp_path / "estimators.json"
    code = cli.main(
        ["study", "estimators", "--seeds", "1", "--duration", "1", "--scenarios", SCENARIO,
         "--rows", "ekf_slam,isam2_lag", "--json", str(out)]
    )  # fmt: skip
    assert code == 0
    text = capsys.readouterr().out
    assert f"| `{SCENARIO}` | iSAM2 fixed lag |" in text and f"| `{SCENARIO}` | PCRB |" in text
    data = json.loads(out.read_text())
    cells = data["cells"][SCENARIO]
    assert set(cells) == {"ekf_slam", "isam2_lag"}
    assert cells["isam2_lag"]["estimator"] == "isam2" and cells["isam2_lag"]["ended_early"] == 0
    with pytest.raises(SystemExit):
        cli.main(["study", "estimators", "--rows", "ukf"])


def test_told_start_cell_gives_every_estimator_the_bounds_prior() -> None:
    """In ``paper_ekf_figure8_known@start`` the estimate starts at the truth with a zero pose
    covariance: the prior the bound computes with (a zero prior when the error is not drawn)."""
    cell = "paper_ekf_figure8_known@start"
    assert cell_scenario(cell) == SCENARIO
    for row in ROWS:
        if row.name == "isam2" and importlib.util.find_spec("gtsam") is None:
            continue
        env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **cell_overrides(cell, row))
        env.reset(seed=4)
        core = env.unwrapped._core  # type: ignore[attr-defined]
        np.testing.assert_array_equal(bound_model(core).cov0, np.zeros((POSE_DIM, POSE_DIM)))
        est = core.est
        np.testing.assert_allclose(est.position[0], core.vehicle.state[0, POS], atol=1e-12)
        # iSAM2's prior factor needs a variance: its floor (FastSLAM's particles start on one
        # point, no spread to report).
        floor = PRIOR_VARIANCE_FLOOR if row.name == "isam2" else 0.0
        if est.pose_cov is not None:
            np.testing.assert_allclose(np.diagonal(est.pose_cov[0]), floor, rtol=1e-6, atol=1e-12)
        env.close()
        # The plain cell starts at the truth too, under Table 6's P0: a belief, not the bound's.
        env = gym.make("QuadSLAM-v0", scenario=SCENARIO, **cell_overrides(SCENARIO, row))
        env.reset(seed=4)
        cov = env.unwrapped._core.est.pose_cov  # type: ignore[attr-defined]
        assert cov is None or np.diagonal(cov[0])[:3].min() > 1e-3
        env.close()


def test_anees_share_leaves_out_undefined_steps() -> None:
    """A step where a run's covariance is singular has no NEES (NaN): it is counted, and left
    out of the share and the mean, which are a recount over the other steps."""
    lo, hi = chi2.ppf(0.025, 6) / 2, chi2.ppf(0.975, 6) / 2
    runs = [np.array([np.nan, 3.0, 0.1, 3.0, 20.0]), np.array([1.0, 3.0, 0.1, 3.0, 20.0])]
    out = anees_share(runs, np.arange(1, 6, dtype=float), settle_s=2.5)
    assert out["undefined"] == 1 and math.isnan(out["anees"][0])
    assert lo <= 3.0 <= hi and lo > 0.1 and hi < 20.0
    assert out["share"] == pytest.approx(2 / 4) and out["share_steady"] == pytest.approx(1 / 3)
    assert out["mean"] == pytest.approx((3.0 + 0.1 + 3.0 + 20.0) / 4)
