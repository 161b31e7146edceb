"""``quadslam bench`` runs every section and writes well-formed JSON (no timing assertions).

The run uses the ``tiny`` plan (in place of ``quick``) so that it takes seconds; the compile
section's subprocesses (a cold numba compile takes ~20 s) are replaced by a stub.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import math
import os
from pathlib import Path

import pytest

from agents.lab.bench import process as bench_process
from agents.lab.bench import runner as bench
from agents.lab.bench.envs import VECTOR_SCENARIOS
from agents.lab.bench.plan import TINY
from agents.lab.bench.runner import SECTION_NAMES, sections
from agents.lab.cli.main import main


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict, Path, str, list[str]]:
    """``quadslam bench --quick --json --plots`` with the tiny plan and a compile stub."""
    out_dir = tmp_path_factory.mktemp("bench")
    caches: list[str] = []

    def first_use_stub(cache_dir: str) -> float:
        caches.append(cache_dir)
        assert os.path.isdir(cache_dir)
        return 1.0 + len(caches)

    stdout = io.StringIO()  # capsys is function-scoped, the run module-scoped
    with pytest.MonkeyPatch.context() as mp, contextlib.redirect_stdout(stdout):
        mp.setattr(bench, "QUICK", TINY)
        mp.setattr(bench_process, "first_use_seconds", first_use_stub)
        code = main(
            ["bench", "--quick", "--json", str(out_dir / "b.json"), "--plots", str(out_dir)]
        )
    assert code == 0
    return json.loads((out_dir / "b.json").read_text()), out_dir, stdout.getvalue(), caches


def test_sections_table_matches_cli_names() -> None:
    assert tuple(sections()) == SECTION_NAMES


def test_document_is_wellformed(tiny_run) -> None:
    doc, _, _, _ = tiny_run
    assert doc["quick"] is True and doc["plan"] == "tiny"
    assert tuple(doc["sections"]) == SECTION_NAMES
    assert tuple(doc["section_wall_s"]) == SECTION_NAMES
    assert all(s >= 0 for s in doc["section_wall_s"].values())
    assert sum(doc["section_wall_s"].values()) <= doc["wall_time_s"]
    assert {"cpu", "cores", "python", "numpy", "numba", "load_average"} <= set(doc["machine"])
    groups = {e["group"] for e in doc["results"]}
    assert groups == {
        "ekf_slam", "fastslam", "env", "vector", "physics", "team", "association", "memory",
        "compile", "render",
    }  # fmt: skip
    for entry in doc["results"]:
        assert {"group", "name", "params", "unit", "median", "min", "max", "n"} <= set(entry)
        assert entry["n"] >= 1 and entry["unit"]
        assert all(math.isfinite(entry[k]) and entry[k] > 0 for k in ("median", "min", "max"))
        assert entry["min"] <= entry["median"] <= entry["max"]
    names = {e["name"] for e in doc["results"]}
    assert {"predict", "update", "registration"} <= names
    labels = ["oracle", "ekf_slam", f"fastslam_N{TINY.fast_env_particles[0]}"]
    if importlib.util.find_spec("gtsam") is not None:
        labels += ["isam2_known_map", "isam2", "isam2_integrity"]
    for label in labels:
        assert f"steps_per_s/{label}/dflqr" in names
        assert f"real_time_factor/{label}/dflqr" in names


def test_physics_ratio_pairs_the_alternating_samples(tiny_run) -> None:
    """The full-physics ratio is, round by round, the quotient of the two envs' samples taken
    side by side (each median alone would compare different minutes of the machine)."""
    from agents.lab.bench.paired import FULL_PHYSICS, NOMINAL, ROUNDS_PER_REPEAT

    doc, _, _, _ = tiny_run
    got = {e["name"]: e for e in doc["results"] if e["group"] == "physics"}
    nominal, full = got[f"env_steps_per_s/{NOMINAL}"], got[f"env_steps_per_s/{FULL_PHYSICS}"]
    ratio = got["full_over_nominal"]
    assert nominal["n"] == full["n"] == ratio["n"] == TINY.repeats * ROUNDS_PER_REPEAT
    assert nominal["params"]["num_envs"] == max(TINY.vec_batches)  # the tiny plan has no 256
    # The quotient's extremes are bounded by the extremes of its numerator and denominator.
    assert full["min"] / nominal["max"] <= ratio["min"] <= ratio["max"]
    assert ratio["max"] <= full["max"] / nominal["min"]


def test_team_ratios_pair_the_alternating_samples(tiny_run) -> None:
    """Each team's ratio is, round by round, its vehicle-steps/s over the vector env's taken in
    the same round, and carries the lower-bound target the end of the output judges."""
    from agents.lab.bench.team import N_VEHICLES, TARGET, TEAMS

    doc, _, stdout, _ = tiny_run
    got = {e["name"]: e for e in doc["results"] if e["group"] == "team"}
    vector = got["vehicle_steps_per_s/vector"]
    assert vector["n"] == 2 * TINY.repeats and vector["params"]["num_envs"] == N_VEHICLES
    for label in TEAMS:
        team, ratio = got[f"vehicle_steps_per_s/{label}"], got[f"{label}_over_vector"]
        assert team["n"] == ratio["n"] == vector["n"]
        assert team["min"] / vector["max"] <= ratio["min"] <= ratio["max"]
        assert ratio["max"] <= team["max"] / vector["min"]
        assert ratio["params"]["target_min"] == TARGET
        verdict = "met" if ratio["median"] >= TARGET else "NOT met"
        assert f"target team {label}_over_vector: " in stdout
        assert f"against >= {TARGET:g} ratio: {verdict}" in stdout


def test_association_entries(tiny_run) -> None:
    """Scalar known/NN/JCBB (EKF-SLAM, and iSAM2 with GTSAM) and vector known/NN at every B,
    each with its returns per scan."""
    doc, _, _, _ = tiny_run
    assoc = _by_name(doc, "association")
    scalar_names = {f"steps_per_s/scalar/{m}" for m in ("known", "nn", "jcbb")}
    if importlib.util.find_spec("gtsam") is not None:
        scalar_names |= {f"steps_per_s/scalar/isam2/{m}" for m in ("known", "nn", "jcbb")}
        assert assoc["steps_per_s/scalar/isam2/jcbb"][0]["params"]["estimator"] == "isam2"
    vector_names = {"env_steps_per_s/vector/known", "env_steps_per_s/vector/nn"}
    assert set(assoc) == scalar_names | vector_names
    assert assoc["steps_per_s/scalar/jcbb"][0]["params"]["estimator"] == "ekf_slam"
    assert len(assoc["env_steps_per_s/vector/nn"]) == len(TINY.vec_batches)
    scalar = assoc["steps_per_s/scalar/jcbb"][0]["params"]
    assert (
        scalar["returns_per_scan"]
        > assoc["steps_per_s/scalar/known"][0]["params"]["returns_per_scan"]
    )  # the unknown runs carry the false returns too


def _by_name(doc: dict, group: str) -> dict[str, list[dict]]:
    out: dict[str, list[dict]] = {}
    for e in doc["results"]:
        if e["group"] == group:
            out.setdefault(e["name"], []).append(e)
    return out


def test_vector_and_worker_entries(tiny_run) -> None:
    doc, _, _, _ = tiny_run
    vector = _by_name(doc, "vector")
    expected = {f"env_steps_per_s/{label}" for label, _, _ in VECTOR_SCENARIOS}
    expected |= {f"{name}/{TINY.n_workers}_workers" for name in expected}
    expected.add(f"env_steps_per_s/ekf_unknown_map/{TINY.n_workers}_workers_all_info")
    assert set(vector) == expected
    for name, entries in vector.items():
        workers = 1 if name.count("/") == 1 else TINY.n_workers
        batches = TINY.vec_batches if workers == 1 else TINY.worker_batches
        assert sorted(e["params"]["num_envs"] for e in entries) == sorted(batches)
        for e in entries:
            assert e["unit"] == "env-steps/s" and e["params"]["workers"] == workers
            assert e["params"]["warmup_steps"] == TINY.vec_warmup and "warm-up" in e["note"]
            assert e["n"] == TINY.repeats
    assert set(doc["best_batch"]) == expected
    assert all(b["num_envs"] in TINY.vec_batches for b in doc["best_batch"].values())


def test_memory_and_compile_entries(tiny_run) -> None:
    doc, _, _, caches = tiny_run
    memory = _by_name(doc, "memory")
    assert set(memory) == {"peak_rss/ekf_unknown_map"}
    rows = memory["peak_rss/ekf_unknown_map"]
    assert sorted(e["params"]["num_envs"] for e in rows) == sorted(TINY.memory_batches)
    assert all(e["unit"] == "MB" and e["params"]["steps"] == TINY.memory_steps for e in rows)
    compile_ = _by_name(doc, "compile")
    assert set(compile_) == {"first_use/empty_cache", "first_use/warm_cache"}
    assert all(e[0]["unit"] == "s" for e in compile_.values())
    assert compile_["first_use/empty_cache"][0]["params"]["target_s"] == 20.0
    assert compile_["first_use/warm_cache"][0]["params"]["target_s"] == 2.0
    # Empty cache first, then the same (now warm) directory; a new directory per repeat.
    assert len(caches) == 2 * TINY.process_repeats
    assert caches[0] == caches[1] and not os.path.exists(caches[0])


def test_render_entries(tiny_run) -> None:
    doc, _, _, _ = tiny_run
    rows = {e["name"]: e for e in doc["results"] if e["group"] == "render"}
    assert {"frames_per_s/ekf_slam", "frames_per_s/fastslam", "episode_render_s"} <= set(rows)
    for label in ("ekf_slam", "fastslam"):
        entry = rows[f"frames_per_s/{label}"]
        assert entry["unit"] == "frames/s" and entry["n"] == TINY.repeats
    episode = rows["episode_render_s"]
    steps = round(episode["params"]["episode_s"] * 100)  # render() after reset and every step
    assert episode["unit"] == "s" and episode["params"]["calls"] == steps + 1


def test_peak_rss_is_plausible() -> None:
    assert 1.0 < bench_process.peak_rss_mb() < 1e5


def test_table_and_plots(tiny_run) -> None:
    _, out_dir, stdout, _ = tiny_run
    assert "steps_per_s" in stdout and "medians vs lanes B:" in stdout
    # The compile stub's empty cache took 2 s (target 20 s), its warm cache 3 s (target 2 s).
    targets = [line for line in stdout.splitlines() if line.startswith("target compile")]
    assert targets == [
        "target compile first_use/empty_cache: 2 s (median of 1) against <= 20 s: met",
        "target compile first_use/warm_cache: 3 s (median of 1) against <= 2 s: NOT met",
    ]
    assert "wall time per section: ekf " in stdout and "load average" in stdout
    assert "wall time " in stdout and "budget" not in stdout  # the tiny plan has none
    assert "env_steps_per_s/ekf_unknown_map" in stdout.split("medians vs lanes B:")[1]
    assert sorted(p.name for p in out_dir.glob("*.png")) == [
        "ekf_scaling.png",
        "fastslam_scaling.png",
        "vector_scaling.png",
    ]
