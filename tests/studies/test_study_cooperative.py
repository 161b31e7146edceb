"""``quadslam study cooperative`` on a tiny budget: a team of one is the single env, the pooled
landmark ANEES and the ratios are their definitions, the table, the JSON and the figure."""

from __future__ import annotations

import importlib.util
import json

import gymnasium as gym
import numpy as np
import pytest

import agents.lab.estimator_studies.cooperative as study
from agents.control.dflqr import DFLQRPolicy
from quadslam_env.metrics.step import anees_bounds

pytest.importorskip("pettingzoo")


def test_tiny_study_against_the_single_env_and_its_definitions(
    tmp_path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(study, "ROWS", {k: study.ROWS[k] for k in ("independent", "ci_every_scan")})
    monkeypatch.setattr(study, "RANGE_ROWS", {"ranges": study.RANGE_ROWS["independent_ranges"]})
    result = study.run_study(seeds=2, first_seed=5, quick=True, sizes=(1, 2), duration_s=4.0)
    gtsam = importlib.util.find_spec("gtsam") is not None
    isam2 = [(2, row) for row in study.ISAM2_ROWS] if gtsam else []
    assert [(r["n_vehicles"], r["row"]) for r in result["rows"]] == [
        (1, "independent"),
        (2, "independent"),
        (2, "ci_every_scan"),
        *isam2,  # with GTSAM: iSAM2 per vehicle and one smoother of the team
        (2, "ranges"),  # the largest team's rows with ranges
        *([(2, "centralised_ranges")] if gtsam else []),
    ]
    rows = {(r["n_vehicles"], r["row"]): r["summary"] for r in result["rows"]}
    omega = rows[2, "ranges"]["range_omega_median"]
    assert omega is not None and 0.0 < omega < 1.0
    assert result["rows"][2]["summary"]["range_omega_median"] is None
    # A team of one is the single env: its position RMSE and final map RMSE, seed for seed.
    env = gym.make("QuadSLAM-v0", scenario=study.SCENARIO, episode={"duration_s": 4.0})
    policy = DFLQRPolicy.from_env(env)
    for episode in result["rows"][0]["episodes"]:
        obs, info = env.reset(seed=episode["seed"])
        done = False
        while not done:
            obs, _, terminated, truncated, info = env.step(policy.predict(obs)[0])
            done = terminated or truncated
        assert episode["pos_rmse_m"] == pytest.approx(info["episode_est_pos_rmse_m"], rel=1e-12)
        assert episode["map_rmse_m"] == pytest.approx(info["est_map_rmse_m"], rel=1e-12)
    env.close()
    for row in result["rows"]:
        eps, summary = row["episodes"], row["summary"]
        count = sum(e["landmarks"] for e in eps)
        assert summary["landmark_anees"] == pytest.approx(sum(e["nees_sum"] for e in eps) / count)
        assert summary["anees_95"] == pytest.approx(list(anees_bounds(3, count)))
        assert summary["map_rmse_m"] == pytest.approx(np.mean([e["map_rmse_m"] for e in eps]))
        m = eps[0]["map0"]  # vehicle 0's final map, read back
        errors = np.array(m["means"]) - np.array(m["truth"])
        if row["n_vehicles"] == 1:
            want = np.sqrt(np.mean(np.sum(errors**2, axis=1)))
            assert eps[0]["map_rmse_m"] == pytest.approx(want, rel=1e-12)
    independent, ci = result["rows"][1]["summary"], result["rows"][2]["summary"]
    assert independent["vs_independent"] == 1.0
    assert ci["vs_independent"] == pytest.approx(ci["map_rmse_m"] / independent["map_rmse_m"])
    assert ci["kb_sent"] > 0 == independent["kb_sent"]
    if isam2:  # the smoother's rows against their own estimator's independent row
        alone, central = rows[2, "isam2_independent"], rows[2, "centralised"]
        assert alone["vs_independent"] == 1.0
        assert central["vs_independent"] == pytest.approx(
            central["map_rmse_m"] / alone["map_rmse_m"]
        )
        assert central["kb_sent"] > alone["kb_sent"] == 0  # the measurements sent to the graph
        ranged = rows[2, "centralised_ranges"]
        assert ranged["vs_independent"] == pytest.approx(ranged["map_rmse_m"] / alone["map_rmse_m"])
    text = study.format_study(result)
    assert "| 2 | ci_every_scan |" in text
    study.write_json(result, tmp_path / "coop.json")
    assert json.loads((tmp_path / "coop.json").read_text())["settings"]["team_sizes"] == [1, 2]
    assert study.plot_study(result, tmp_path).stat().st_size > 10_000
