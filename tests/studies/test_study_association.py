"""``quadslam study association`` on a tiny budget: structure, the known-association baseline
equal to the labeled scenario, skipped rows, the table and the figure."""

from __future__ import annotations

import importlib.util

import gymnasium as gym
import pytest

import agents.lab.estimator_studies.association as study
import quadslam_env  # noqa: F401
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import run_episodes


def test_quick_study_runs_and_its_known_row_is_the_labeled_scenario(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(
        study,
        "ROWS",
        (
            study.Row("known", "paper_ekf_figure8_unknown", study.KNOWN),
            study.Row("jcbb", "paper_ekf_figure8_unknown"),
            study.Row("missing", "no_such_scenario"),
            study.Row("isam2 jcbb", "paper_ekf_figure8_unknown", study.ISAM2),
        ),
    )
    monkeypatch.setattr(study, "SWEEP_SCENARIOS", ("paper_ekf_figure8_unknown",))
    result = study.run_study(seeds=2, quick=True)
    known, jcbb, missing, isam2 = result["rows"]
    assert "not shipped" in missing["skipped"]
    if importlib.util.find_spec("gtsam") is None:
        assert "GTSAM not installed" in isam2["skipped"]
    else:  # the smoother with the scenario's association rule, as the EKF's row
        assert all(0.0 <= e["assoc_wrong_rate"] <= 1.0 for e in isam2["episodes"])
        assert isam2["overrides"] == {"estimator": {"name": "isam2"}}
        assert [e["terminated"] for e in isam2["episodes"]] == [False, False]
    # The known-association row is the labeled paper scenario with 10% misses (same seeds).
    env = gym.make(
        "QuadSLAM-v0",
        scenario="paper_ekf_figure8",
        lidar={"detection_prob": 0.9},
        episode={"duration_s": 10.0},
    )
    want = run_episodes(env, DFLQRPolicy.from_env(env), [0, 1])
    env.close()
    for got, ref in zip(known["episodes"], want, strict=True):
        assert got["est_pos_rmse_m"] == pytest.approx(ref["est_pos_rmse_m"], rel=1e-12)
        assert "assoc_wrong_rate" not in got
    assert all(0.0 <= e["assoc_wrong_rate"] <= 1.0 for e in jcbb["episodes"])
    assert [(e["clutter_rate"], e["association"]) for e in result["clutter"]] == [
        (rate, method) for rate in (0.0, 2.0, 10.0) for method in ("nn", "jcbb")
    ]
    text = study.format_study(result)
    assert "skipped" in text and "jcbb" in text
    path = study.plot_study(result, tmp_path)
    assert path.stat().st_size > 10_000


def test_isam2_rows_are_skipped_without_gtsam(monkeypatch: pytest.MonkeyPatch) -> None:
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "gtsam" else find_spec(name)
    )
    isam2 = [r for r in study.ROWS if r.label.startswith("iSAM2")]
    assert len(isam2) == 3
    for row in isam2:
        assert study._usable(row) == "GTSAM not installed (pip install 'quadslam[gtsam]')"
    assert study._usable(study.ROWS[0]) is None
