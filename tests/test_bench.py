"""``quadslam bench --quick`` runs and writes well-formed JSON (no timing assertions)."""

from __future__ import annotations

import json
import math

from agents.cli import main


def test_bench_quick_writes_wellformed_json(tmp_path, capsys) -> None:
    out = tmp_path / "bench.json"
    plots = tmp_path / "plots"
    assert main(["bench", "--quick", "--json", str(out), "--plots", str(plots)]) == 0
    doc = json.loads(out.read_text())
    assert doc["quick"] is True
    assert set(doc["sections"]) == {"ekf", "fastslam", "env", "vector"}
    assert {"cpu", "cores", "python", "numpy"} <= set(doc["machine"])
    groups = {e["group"] for e in doc["results"]}
    assert groups == {"ekf_slam", "fastslam", "env", "vector"}
    for entry in doc["results"]:
        assert {"group", "name", "params", "unit", "median", "min", "max", "n"} <= set(entry)
        assert entry["n"] >= 1 and entry["unit"]
        assert all(math.isfinite(entry[k]) and entry[k] > 0 for k in ("median", "min", "max"))
        assert entry["min"] <= entry["median"] <= entry["max"]
    names = {e["name"] for e in doc["results"]}
    assert {"predict", "update", "registration"} <= names
    assert any(n.startswith("steps_per_s/ekf_slam/") for n in names)
    assert sorted(p.name for p in plots.glob("*.png")) == [
        "ekf_scaling.png",
        "fastslam_scaling.png",
    ]
    assert "steps_per_s" in capsys.readouterr().out
