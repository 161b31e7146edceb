"""``quadslam study bound`` on short episodes: the recorded truth lines up with the env's own
metrics, both episode paths record the same, and the command writes its JSON and figure."""

from __future__ import annotations

import json
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import quadslam_env  # noqa: F401  (registers the ids)
from agents.control.dflqr import DFLQRPolicy
from agents.evaluation.episodes import run_episodes
from agents.lab.cli import main as cli
from agents.lab.estimator_studies.bound import TruthRecorder, run_bound_study
from agents.lab.estimator_studies.bound_report import figure_name

SCENARIO = "paper_ekf_figure8_known"


@pytest.fixture(scope="module")
def short_study() -> tuple[dict, list]:
    return run_bound_study(SCENARIO, [0, 1], duration_s=3.0)


def test_estimate_errors_are_the_envs_and_the_bound_is_positive(short_study) -> None:
    result, series = short_study
    for rec, ep, s in zip(result["seeds"], result["episodes"], series, strict=True):
        assert rec["seed"] == ep["seed"]
        # The recorder's errors over steps 1 … K are the env's per-episode RMSEs.
        assert rec["est_pos_rmse_m"] == pytest.approx(ep["est_pos_rmse_m"], rel=1e-12)
        assert rec["est_vel_rmse_mps"] == pytest.approx(ep["est_vel_rmse_mps"], rel=1e-12)
        assert rec["est_att_rmse_deg"] == pytest.approx(ep["est_att_rmse_deg"], rel=1e-9)
        assert len(s.t) == 300 and s.t[-1] == pytest.approx(3.0)
        for key in ("pos_m2", "vel_m2ps2", "att_rad2"):
            assert np.all(s.bound[key] > 0.0)
        # The known map adds no landmark states; the start at the truth gives a zero prior.
        assert rec["n_landmarks_in_bound"] == 0
    assert series[0].bound["pos_m2"][0] < 1e-6
    summary = result["summary"]
    for block in ("pos_rmse_m", "vel_rmse_mps", "att_rmse_deg"):
        for kind in ("bound", "est"):
            for span in ("", "_steady"):
                stats = summary[f"{kind}_{block}{span}"]
                assert stats["min"] <= stats["median"] <= stats["max"]
                assert stats["min"] <= stats["pooled"] <= stats["max"]


def test_observer_records_the_same_on_lanes_and_one_by_one() -> None:
    kwargs = {"scenario": "paper_ekf_figure8", "episode": {"duration_s": 1.0}}
    recs = []
    for wrap in (False, True):
        env = gym.make("QuadSLAM-v0", **kwargs)
        if wrap:  # an extra wrapper sends run_episodes down the one-episode-at-a-time path
            env = gym.wrappers.RecordEpisodeStatistics(env)
        rec = TruthRecorder()
        run_episodes(env, DFLQRPolicy.from_env(env), [3, 4], observer=rec)
        env.close()
        recs.append(rec)
    for a, b in zip(recs[0].lanes, recs[1].lanes, strict=True):
        assert len(a.states) == 101 and len(a.rates) == 100
        np.testing.assert_array_equal(np.array(a.states), np.array(b.states))
        np.testing.assert_array_equal(np.array(a.rates), np.array(b.rates))
        assert a.scan_steps == b.scan_steps == list(range(10, 101, 10))
        for ia, ib in zip(a.scan_ids, b.scan_ids, strict=True):
            np.testing.assert_array_equal(ia, ib)
        np.testing.assert_array_equal(np.array(a.err_axes), np.array(b.err_axes))


def test_cli_writes_json_and_figure(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    out = tmp_path / "bound.json"
    code = cli.main(
        ["study", "bound", "--scenario", SCENARIO, "--seeds", "2", "--duration", "1",
         "--json", str(out), "--plots", str(tmp_path / "fig")]
    )  # fmt: skip
    assert code == 0
    data = json.loads(out.read_text())
    assert data["summary"]["bound_pos_rmse_m"]["median"] > 0.0
    assert data["summary"]["est_pos_rmse_m"]["median"] > 0.0
    assert [s["seed"] for s in data["seeds"]] == [0, 1]
    assert (tmp_path / "fig" / f"bound_{SCENARIO}.png").stat().st_size > 10_000
    assert "pooled" in capsys.readouterr().out


def test_cli_rejects_a_bad_output_path_before_flying(tmp_path: Path) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    code = cli.main(["study", "bound", "--seeds", "1", "--json", str(blocker / "b.json")])
    assert code == 2


def test_figure_name_names_a_replaced_estimator() -> None:
    result = {"scenario": "s", "estimator": "fastslam", "settings": {"estimator_override": None}}
    assert figure_name(result) == "bound_s.png"
    result["settings"]["estimator_override"] = "fastslam"
    assert figure_name(result) == "bound_s_fastslam.png"


def test_unknown_map_writes_the_map_bound_beside_the_envs_map(
    tmp_path: Path, capsys: pytest.CaptureFixture
) -> None:
    out = tmp_path / "bound.json"
    code = cli.main(
        ["study", "bound", "--scenario", "paper_ekf_figure8", "--seeds", "2", "--duration", "2",
         "--json", str(out), "--plots", str(tmp_path / "fig")]
    )  # fmt: skip
    assert code == 0
    data = json.loads(out.read_text())
    gauge = 3 * 0.001  # trace of the position block of the scenario's P0 (seed 001 Table 7)
    for rec, ep in zip(data["seeds"], data["episodes"], strict=True):
        # The recorder's map at the last step is the env's own episode map RMSE.
        assert rec["est_map_rmse_m_final"] == pytest.approx(ep["map_rmse_m"], rel=1e-12)
        assert rec["n_mapped_final"] == ep["n_mapped"] > 0
        assert len(rec["landmarks"]) >= rec["n_mapped_final"]
        for row in rec["landmarks"]:
            # The SLAM gauge: no landmark is bound below the prior's position variance.
            assert row["bound_m"] ** 2 >= gauge and row["scans"] >= 1
            assert 0.0 <= row["first_seen_s"] <= 2.0
        assert rec["bound_map_rmse_m_final"] ** 2 >= gauge
    for key in ("bound_map_rmse_m", "est_map_rmse_m_steady", "bound_map_rmse_m_final"):
        assert data["summary"][key]["pooled"] > 0.0
    assert (tmp_path / "fig" / "bound_map_paper_ekf_figure8.png").stat().st_size > 10_000
    assert "map RMSE" in capsys.readouterr().out
