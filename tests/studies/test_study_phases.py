"""``quadslam study bound --phases`` (agents/lab/estimator_studies/phases.py): the pooled ratio per
phase is a recount by hand on two made-up seeds, a phase no seed reaches is left out, and bad edges
are refused with what is allowed."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from agents.lab.cli import main as cli
from agents.lab.estimator_studies.bound import BLOCKS
from agents.lab.estimator_studies.phases import format_phases, phase_ratios


@dataclass
class _Seed:
    t: np.ndarray
    err_norm: np.ndarray
    bound: dict[str, np.ndarray]


def _seed(pos_err: np.ndarray, pos_bound: float) -> _Seed:
    k = pos_err.size
    ones = np.ones(k)
    err = np.column_stack([pos_err, ones, np.full(k, math.radians(1.0))])
    bound = {"pos_m2": pos_bound * ones, "vel_m2ps2": 4.0 * ones, "att_rad2": ones}
    return _Seed(0.1 * np.arange(1, k + 1), err, bound)


def test_ratios_are_pooled_over_seeds_by_hand() -> None:
    # Seed a: |e| = 2 m for t ≤ 0.5 s, 1 m after; seed b: 0 m then 3 m; bound traces 1 and 4 m².
    a = _seed(np.array([2.0] * 5 + [1.0] * 5), 1.0)
    b = _seed(np.array([0.0] * 5 + [3.0] * 5), 4.0)
    phases = phase_ratios([a, b], [0.0, 0.5, 1.0, 2.0], BLOCKS)
    assert [(p["from_s"], p["to_s"], p["seeds"]) for p in phases] == [(0.0, 0.5, 2), (0.5, 1.0, 2)]
    first, second = phases
    # pos: √((4 + 0)/2) / √((1 + 4)/2) and √((1 + 9)/2) / √((1 + 4)/2)
    assert first["pos"]["ratio"] == pytest.approx(math.sqrt(2.0 / 2.5))
    assert second["pos"]["ratio"] == pytest.approx(math.sqrt(5.0 / 2.5))
    assert second["pos"]["est"] == pytest.approx(math.sqrt(5.0))
    # vel: |e| = 1 against a trace of 4: 0.5 in every phase; attitude reported in degrees.
    assert first["vel"]["ratio"] == pytest.approx(0.5)
    assert first["att"]["est"] == pytest.approx(1.0) and first["att"]["ratio"] == pytest.approx(
        math.radians(1.0)
    )
    text = format_phases(phases, BLOCKS)
    assert "0–0.5 s" in text and f"{math.sqrt(2.0):.3f}" in text


@pytest.mark.parametrize("edges", ["5", "2,1", "0,a", "-1,2", "0,2,2"])
def test_bad_phase_edges_are_refused(edges: str, capsys: pytest.CaptureFixture) -> None:
    with pytest.raises(SystemExit):
        cli.main(["study", "bound", f"--phases={edges}"])
    assert "two or more increasing times in s from 0" in capsys.readouterr().err
