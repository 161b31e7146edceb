"""``quadslam sweep`` on a local Ray: the table equals the jobs run one by one through the CLI,
failures are isolated, ``--resume`` redoes nothing that finished, Ctrl-C loses nothing.

Needs the ``ray`` extra; one 2-CPU local Ray serves the in-process sweeps of this module.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

ray = pytest.importorskip("ray")
pd = pytest.importorskip("pandas")

from agents.evaluation.episodes import EPISODE_KEYS  # noqa: E402
from agents.lab.cli.main import main  # noqa: E402
from agents.lab.sweep.driver import SweepError, run_sweep  # noqa: E402
from agents.lab.sweep.spec import load_spec  # noqa: E402

SCENARIOS = ["paper_ekf_figure8", "paper_ekf_figure8_known"]
# Everything of an episode record but its wall-clock speed.
COMPARED = [k for k in EPISODE_KEYS if k != "steps_per_s"]


@pytest.fixture(scope="module")
def local_ray():
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    yield
    ray.shutdown()


def _spec(tmp_path: Path, jobs: list[dict], name: str = "spec.yaml") -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump({"jobs": jobs}, sort_keys=False))
    return path


def _same(a, b) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    return a == b


def _finished(out: Path) -> dict[str, int]:
    """Job id → mtime (ns) of its result file."""
    return {p.parent.name: p.stat().st_mtime_ns for p in out.glob("jobs/*/result.json")}


def test_sweep_table_equals_the_run_command_job_by_job(local_ray, tmp_path, capsys):
    spec = _spec(
        tmp_path,
        [{"kind": "run", "scenario": SCENARIOS, "seeds": 4, "set": {"episode.duration_s": 2}}],
    )
    out = tmp_path / "out"
    report = run_sweep(spec, out, progress=False)
    assert len(report.ran) == 8 and not report.failed and not report.skipped
    csv = pd.read_csv(out / "results.csv")
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == len(csv) == 8
    assert (table["kind"] == "run").all() and (table["status"] == "ok").all()
    assert (table["episode.duration_s"] == 2).all() and (table["estimator"] == "ekf_slam").all()
    assert sorted(zip(table["scenario"], table["seed"], strict=True)) == sorted(
        (s, i) for s in SCENARIOS for i in range(4)
    )
    assert list(out.glob("plots/*.png"))  # metric vs scenario
    capsys.readouterr()
    for row in table.itertuples(index=False):
        reference = tmp_path / f"{row.scenario}_{row.seed}.json"
        code = main(
            [
                "run",
                "--scenario",
                row.scenario,
                "--seed",
                str(row.seed),
                "--seeds",
                "1",
                "--set",
                "episode.duration_s=2",
                "--no-plots",
                "--json",
                str(reference),
            ]
        )
        assert code == 0
        cli = json.loads(reference.read_text())
        (episode,) = cli["episodes"]
        for key in COMPARED:
            want = float("nan") if episode.get(key) is None else episode[key]
            got = getattr(row, "episode_seed" if key == "seed" else key)
            if key == "termination_reason":
                got = "" if got is None else got
            assert _same(got, want), (row.job_id, key, got, want)
        # The job's own result file is the CLI's JSON document.
        job = json.loads((out / "jobs" / row.job_id / "result.json").read_text())
        assert {k: job[k] for k in ("scenario", "estimator", "policy")} == {
            k: cli[k] for k in ("scenario", "estimator", "policy")
        }
        assert [{k: e.get(k) for k in COMPARED} for e in job["episodes"]] == [
            {k: e.get(k) for k in COMPARED} for e in cli["episodes"]
        ]
    # Several seeds as lanes of one job: the same numbers again.
    lanes = _spec(
        tmp_path,
        [
            {
                "kind": "run",
                "scenario": SCENARIOS[0],
                "seeds": 4,
                "seeds_per_job": 4,
                "set": {"episode.duration_s": 2},
            }
        ],
        "lanes.yaml",
    )
    run_sweep(lanes, tmp_path / "lanes", progress=False)
    grouped = pd.read_parquet(tmp_path / "lanes" / "results.parquet")
    assert grouped["job_id"].nunique() == 1 and list(grouped["seed"]) == [0, 1, 2, 3]
    ref = table[table["scenario"] == SCENARIOS[0]].sort_values("seed")
    assert list(grouped["est_pos_rmse_m"]) == list(ref["est_pos_rmse_m"])


def test_failed_job_is_reported_and_resume_redoes_nothing_finished(local_ray, tmp_path):
    bad_model = tmp_path / "broken.zip"
    bad_model.write_bytes(b"not a model")
    spec = _spec(
        tmp_path,
        [
            {"kind": "run", "seeds": 4, "set": {"episode.duration_s": 1}},
            {"kind": "evaluate", "policy": str(bad_model), "set": {"episode.duration_s": 1}},
        ],
    )
    out = tmp_path / "out"
    first = run_sweep(spec, out, progress=False)
    assert len(first.ran) == 4 and len(first.failed) == 1
    (failed_id,) = first.failed
    assert failed_id.startswith("evaluate-") and "broken.zip" in first.failed[failed_id]
    assert (out / "jobs" / failed_id / "error.txt").exists()
    table = pd.read_csv(out / "results.csv")
    assert list(table["status"]).count("failed") == 1 and len(table) == 5
    assert "broken.zip" in table.loc[table["status"] == "failed", "error"].item()

    # Without --resume the folder is refused; with it, only unfinished jobs run.
    with pytest.raises(SweepError, match="--resume"):
        run_sweep(spec, out, progress=False)
    before = _finished(out)
    lost = sorted(before)[0]  # as if that job had been running when the sweep was killed
    (out / "jobs" / lost / "result.json").unlink()
    time.sleep(0.01)
    second = run_sweep(spec, out, resume=True, progress=False)
    assert second.ran == [lost]
    assert sorted(second.skipped) == sorted(set(before) - {lost})
    assert list(second.failed) == [failed_id]  # retried, and fails again
    after = _finished(out)
    for job_id in second.skipped:
        assert after[job_id] == before[job_id]  # not rewritten
    assert len(pd.read_parquet(out / "results.parquet")) == 5


def _default_signals() -> None:
    """In the child, SIGINT and SIGTERM as a terminal delivers them: a test runner started in
    the background (or under a nohup-like wrapper) passes them on ignored, and an ignored
    signal stays ignored in Python."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _start_sweep(spec: Path, out: Path) -> subprocess.Popen:
    argv = ["sweep", str(spec), "--out", str(out), "--workers", "1"]
    return subprocess.Popen(
        [sys.executable, "-m", "agents.lab.cli.main", *argv],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"},
        preexec_fn=_default_signals,
    )


@pytest.mark.parametrize(("sig", "status"), [(signal.SIGINT, 130), (signal.SIGTERM, 143)])
def test_ctrl_c_or_sigterm_then_resume_loses_nothing(local_ray, tmp_path, sig, status):
    """Ctrl-C, or SIGTERM (a scheduler, ``docker stop``; Ray's own handler would exit at once
    with no table): the finished jobs' table, the resume hint, the signal's status."""
    spec = _spec(
        tmp_path,
        [{"kind": "run", "seeds": 6, "set": {"episode.duration_s": 20}}],
    )
    out = tmp_path / "out"
    proc = _start_sweep(spec, out)
    deadline = time.monotonic() + 240
    while not _finished(out) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    done = _finished(out)
    assert proc.returncode == status, err
    assert f"rerun with --resume --out {out}" in err.strip().splitlines()[-1]
    assert 1 <= len(done) < 6
    table = pd.read_csv(out / "results.csv")
    assert len(table) == len(done)  # the table of what had finished

    report = run_sweep(spec, out, resume=True, progress=False)
    assert sorted(report.skipped) == sorted(done)
    assert len(report.ran) == 6 - len(done)
    after = _finished(out)
    assert all(after[job_id] == mtime for job_id, mtime in done.items())
    assert len(pd.read_csv(out / "results.csv")) == 6


def test_train_job_writes_a_run_folder_and_evaluates_it(local_ray, tmp_path):
    spec = _spec(
        tmp_path,
        [
            {
                "kind": "train",
                "algo": "ppo",
                "env": "QuadSLAM-EKF-v0",
                "timesteps": 128,
                "n_envs": 2,
                "hyperparams": {
                    "n_steps": 64,
                    "batch_size": 64,
                    "n_epochs": 1,
                    "eval_freq": 0,
                    "checkpoint_freq": 0,
                    "learning_rate": [3.0e-4, 1.0e-3],
                },
                "set": {"episode.duration_s": 1},
                "episodes": 2,
            }
        ],
    )
    out = tmp_path / "out"
    report = run_sweep(spec, out, progress=False)
    assert len(report.ran) == 2 and not report.failed
    table = pd.read_parquet(out / "results.parquet")
    assert len(table) == 4  # 2 learning rates × 2 held-out episodes
    assert set(table["hyperparams.learning_rate"]) == {3.0e-4, 1.0e-3}
    assert list(table["episode_seed"]) == [1000, 1001, 1000, 1001]
    assert (table["seed"] == 0).all() and (table["train_wall_s"] > 0).all()
    for run_dir in table["run_dir"].unique():
        assert (out / run_dir / "model.zip").is_file()
        assert (out / run_dir / "config.yaml").is_file()
    assert (out / "plots" / "hyperparams.learning_rate.png").is_file()
    jobs = load_spec(spec)
    assert {j.job_id for j in jobs} == set(table["job_id"])


def test_a_second_sweep_on_the_same_out_is_refused_in_one_line(tmp_path, capsys):
    """An advisory lock (flock on OUT/.sweep.lock) held by a running sweep; here by the test."""
    import fcntl

    spec = _spec(tmp_path, [{"kind": "run", "seeds": 1, "set": {"episode.duration_s": 1}}])
    out = tmp_path / "out"
    out.mkdir()
    with open(out / ".sweep.lock", "w") as held:
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        for resume in ([], ["--resume"]):
            assert main(["sweep", str(spec), "--out", str(out), *resume]) == 2
            (line,) = capsys.readouterr().err.strip().splitlines()
            assert line.startswith(f"quadslam sweep: error: --out {str(out)!r}: another quadslam")
    assert not (out / "jobs").exists() and not (out / "spec.yaml").exists()


def test_more_workers_than_cores_is_a_warning(tmp_path, capsys):
    import fcntl

    spec = _spec(tmp_path, [{"kind": "run", "seeds": 1, "set": {"episode.duration_s": 1}}])
    out = tmp_path / "out"
    out.mkdir()
    cores = len(os.sched_getaffinity(0))
    with open(out / ".sweep.lock", "w") as held:  # stops the sweep before Ray starts
        fcntl.flock(held, fcntl.LOCK_EX | fcntl.LOCK_NB)
        main(["sweep", str(spec), "--out", str(out), "--workers", str(cores)])
        assert "warning" not in capsys.readouterr().err
        main(["sweep", str(spec), "--out", str(out), "--workers", str(cores + 62)])
    warning = capsys.readouterr().err.splitlines()[0]
    assert warning == (
        f"quadslam sweep: warning: --workers {cores + 62} is more than the {cores} CPU "
        "core(s) of this machine; the jobs will share cores"
    )


def test_full_disk_keeps_the_finished_jobs_and_says_how_to_resume(
    local_ray, tmp_path, capsys, monkeypatch
):
    import errno

    import agents.io.outputs

    spec = _spec(tmp_path, [{"kind": "run", "seeds": 3, "set": {"episode.duration_s": 1}}])
    out = tmp_path / "out"
    real = agents.io.outputs._write_bytes
    results = {"n": 0}

    def write(path, data):
        if path.name.startswith(".result.tmp-"):
            results["n"] += 1
            if results["n"] > 1:  # the first job's result fits, then the disk is full
                raise OSError(errno.ENOSPC, "No space left on device")
        real(path, data)

    monkeypatch.setattr(agents.io.outputs, "_write_bytes", write)
    code = main(["sweep", str(spec), "--out", str(out), "--workers", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err
    line = err.replace("\r", "\n").strip().splitlines()[-1]
    assert line.startswith("quadslam sweep: error: no space left on device writing")
    assert f"1 of 3 job(s) are saved in {out}" in line
    assert line.endswith(f"quadslam sweep {spec} --resume --out {out}")
    assert len(_finished(out)) == 1
    assert not list(out.rglob(".*.tmp-*"))  # no torn file anywhere

    monkeypatch.setattr(agents.io.outputs, "_write_bytes", real)
    report = run_sweep(spec, out, resume=True, progress=False)
    assert len(report.skipped) == 1 and len(report.ran) == 2
    assert len(pd.read_csv(out / "results.csv")) == 3
