"""Sweep specs: expansion into jobs, and every kind of bad input failing before any job starts.

A bad spec ends ``quadslam sweep`` with exit status 2 and one stderr line naming the job block,
the key, the value and what is allowed; no output folder is created. None of this needs Ray
(the spec is checked before Ray is imported), except the unreachable-address case.
"""

from __future__ import annotations

import os
import socket
import sys
from pathlib import Path

import pytest
import yaml

from agents.lab.cli.main import main
from agents.lab.sweep.spec import SweepSpecError, load_spec, parse_spec, shipped_specs

SHORT = {"episode.duration_s": 2}


def _write(tmp_path: Path, spec: dict | str, name: str = "spec.yaml") -> Path:
    path = tmp_path / name
    path.write_text(spec if isinstance(spec, str) else yaml.safe_dump(spec, sort_keys=False))
    return path


def _sweep_error(capsys, tmp_path: Path, spec: dict | str, *extra: str) -> str:
    """Run ``quadslam sweep`` on a bad spec: status 2, one line, nothing written."""
    out = tmp_path / "out"
    code = main(["sweep", str(_write(tmp_path, spec)), "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 2
    lines = err.strip("\n").splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("quadslam sweep: error: ")
    assert not out.exists()  # failed before any job (or folder)
    return lines[0]


# ----------------------------------------------------------------------------- expansion
def test_minimal_spec_expands_to_a_grid_with_seeds_innermost():
    jobs = parse_spec(
        {
            "jobs": [
                {
                    "kind": "run",
                    "scenario": ["paper_ekf_figure8", "paper_ekf_figure8_known"],
                    "seeds": 4,
                    "set": {"episode.duration_s": 5},
                }
            ]
        }
    )
    assert [(j.columns["scenario"], j.seed) for j in jobs] == [
        (s, i) for s in ("paper_ekf_figure8", "paper_ekf_figure8_known") for i in range(4)
    ]
    assert all(j.kind == "run" and j.columns["estimator"] == "ekf_slam" for j in jobs)
    assert jobs[0].params["overrides"] == {"episode": {"duration_s": 5}}
    assert len({j.job_id for j in jobs}) == 8
    # The ids depend on the job's content, not on its place in the spec.
    again = parse_spec(
        {
            "jobs": [
                {
                    "kind": "run",
                    "scenario": "paper_ekf_figure8_known",
                    "seeds": [2],
                    "set": {"episode.duration_s": 5},
                }
            ]
        }
    )
    assert again[0].job_id == jobs[6].job_id


def test_set_lists_are_axes_and_lists_of_lists_are_values():
    jobs = parse_spec(
        {
            "jobs": [
                {
                    "kind": "run",
                    "estimator": ["ekf_slam", "oracle"],
                    "seed": 10,
                    "seeds": 2,
                    "seeds_per_job": 2,
                    "set": {
                        "lidar.sigma_range_m": [0.05, 0.2, 0.5],
                        "episode.initial_position": [[0.0, 0.0, -1.0]],
                    },
                }
            ]
        }
    )
    assert len(jobs) == 2 * 3
    assert all(j.seeds == (10, 11) for j in jobs)
    assert sorted({(j.columns["estimator"], j.columns["lidar.sigma_range_m"]) for j in jobs}) == [
        (e, s) for e in ("ekf_slam", "oracle") for s in (0.05, 0.2, 0.5)
    ]
    assert jobs[0].params["overrides"]["episode"]["initial_position"] == [0.0, 0.0, -1.0]
    assert jobs[0].columns["episode.initial_position"] == "[0.0, 0.0, -1.0]"


def test_train_block_resolves_the_agent_entry():
    jobs = parse_spec(
        {
            "jobs": [
                {
                    "kind": "train",
                    "algo": "ppo",
                    "env": ["QuadSLAM-EKF-v0", "QuadSLAM-Oracle-v0"],
                    "seeds": 2,
                    "timesteps": 1000,
                    "hyperparams": {"n_steps": [64, 128]},
                    "set": SHORT,
                }
            ]
        }
    )
    assert len(jobs) == 2 * 2 * 2
    job = jobs[0]
    assert job.columns["scenario"] == "ekf_figure8_biased_imu"  # from ppo.yaml's entry
    assert [j.columns["estimator"] for j in jobs[::4]] == ["ekf_slam", "oracle"]
    assert job.params["hyperparams"]["env_kwargs"] == {"episode": {"duration_s": 2}}
    assert job.columns["hyperparams.n_steps"] == 64


def test_shipped_specs_are_valid():
    names = shipped_specs()
    assert {"rauniyar2023_table", "lidar_noise", "cost_of_estimation"} <= set(names)
    for name in names:
        assert load_spec(name), name
    table = load_spec("rauniyar2023_table")
    assert [j.seed for j in table] == list(range(20))
    assert {j.columns["scenario"] for j in table} == {"paper_ekf_figure8"}


# ----------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    ("spec", "expected"),
    [
        # unknown job kind
        ({"jobs": [{"kind": "fly"}]}, ["jobs[0].kind", "'fly'", "'run'", "'train'"]),
        # unknown key (a typo), naming the allowed keys
        (
            {"jobs": [{"kind": "run", "sceanrio": "x"}]},
            ["jobs[0].sceanrio", "unknown key", "'scenario'"],
        ),
        ({"jobs": [{"kind": "run", "algo": "ppo"}]}, ["jobs[0].algo", "unknown key for a run"]),
        ({"jobs": [{"kind": "run"}], "extra": 1}, ["'extra'", "unknown key", "'jobs'"]),
        # empty grids
        ({"jobs": [{"kind": "run", "scenario": []}]}, ["jobs[0].scenario", "empty"]),
        (
            {"jobs": [{"kind": "run", "set": {"lidar.sigma_range_m": []}}]},
            ["jobs[0].set.lidar.sigma_range_m", "empty"],
        ),
        ({"jobs": [{"kind": "run", "seeds": []}]}, ["jobs[0].seeds", "empty"]),
        ({"jobs": [{"kind": "run", "seeds": 0}]}, ["jobs[0].seeds", "got 0", "positive"]),
        ({"jobs": []}, ["jobs", "non-empty list"]),
        ({"description": "x"}, ["jobs", "non-empty list"]),
        # unknown scenario, estimator, env id, algorithm
        (
            {"jobs": [{"kind": "run", "scenario": "nope"}]},
            ["jobs[0]", "scenario", "'nope'", "paper_ekf_figure8"],
        ),
        ({"jobs": [{"kind": "run", "estimator": "kalman9000"}]}, ["kalman9000", "ekf_slam"]),
        (
            {"jobs": [{"kind": "evaluate", "policy": "dflqr", "env": "QuadSLAM-v9"}]},
            ["env", "'QuadSLAM-v9'", "QuadSLAM-EKF-v0"],
        ),
        ({"jobs": [{"kind": "train", "algo": "dqn"}]}, ["algo", "'dqn'", "ppo"]),
        # bad --set keys and values
        (
            {"jobs": [{"kind": "run", "set": {"lidar.sigma_rng_m": 0.1}}]},
            ["lidar.sigma_rng_m", "unknown", "sigma_range_m"],
        ),
        (
            {"jobs": [{"kind": "run", "set": {"duration": 5}}]},
            ["jobs[0].set", "'duration'", "section.key"],
        ),
        (
            {"jobs": [{"kind": "run", "set": {"episode.duration_s": [5, -1]}}]},
            ["episode.duration_s=-1", "episode.duration_s", "-1"],
        ),
        (
            {"jobs": [{"kind": "run", "set": {"estimator.params": {}, "estimator.params.x": 2}}]},
            ["'estimator.params' conflicts with 'estimator.params.x'"],
        ),
        # train hyperparameters and missing required keys
        (
            {"jobs": [{"kind": "train", "algo": "ppo", "hyperparams": {"n_stepz": 64}}]},
            ["n_stepz", "unknown hyperparameter", "n_steps"],
        ),
        ({"jobs": [{"kind": "train"}]}, ["jobs[0].algo", "missing"]),
        ({"jobs": [{"kind": "evaluate"}]}, ["jobs[0].policy", "missing", "dflqr"]),
        (
            {"jobs": [{"kind": "evaluate", "policy": "no/such/run"}]},
            ["policy", "'no/such/run'", "run folder"],
        ),
        # other values
        ({"jobs": [{"kind": "run", "cpus": 0}]}, ["jobs[0].cpus", "positive"]),
        ({"jobs": [{"kind": "run", "plots": "yes"}]}, ["jobs[0].plots", "true or false"]),
        ({"jobs": [{"kind": "run", "seeds": [1, 2], "seed": 3}]}, ["jobs[0].seed", "list"]),
        ({"jobs": [{"kind": "run"}, {"kind": "run"}]}, ["jobs[1]", "same job", "jobs[0]"]),
        ("jobs: [1, 2\n", ["malformed YAML"]),
        ("jobs:\n  - kind: run\n    kind: train\n", ["duplicate key", "'kind'"]),
    ],
)
def test_bad_spec_is_one_line_before_any_job(capsys, tmp_path, spec, expected):
    line = _sweep_error(capsys, tmp_path, spec)
    for fragment in expected:
        assert fragment in line, f"{fragment!r} not in {line!r}"
    with pytest.raises(SweepSpecError):
        load_spec(tmp_path / "spec.yaml")


def test_missing_spec_file(capsys, tmp_path):
    code = main(["sweep", str(tmp_path / "missing.yaml")])
    line = capsys.readouterr().err.strip()
    assert code == 2 and "missing.yaml" in line and "rauniyar2023_table" in line


def test_out_folder_with_results_needs_resume(capsys, tmp_path):
    pytest.importorskip("ray")
    spec = {"jobs": [{"kind": "run", "set": SHORT}]}
    job = parse_spec(spec)[0]
    done = tmp_path / "out" / "jobs" / job.job_id / "result.json"
    done.parent.mkdir(parents=True)
    done.write_text("{}")
    code = main(["sweep", str(_write(tmp_path, spec)), "--out", str(tmp_path / "out")])
    line = capsys.readouterr().err.strip()
    assert code == 2 and "--resume" in line and "1 finished job" in line


def test_without_ray_says_how_to_install_it(capsys, tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    spec = _write(tmp_path, {"jobs": [{"kind": "run", "set": SHORT}]})
    code = main(["sweep", str(spec), "--out", str(tmp_path / "out")])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1
    assert not (tmp_path / "out").exists()
    assert "Ray is not installed" in lines[0]
    assert "pip install 'quadslam[ray]'" in lines[0]


def _closed_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


@pytest.mark.parametrize("scheme", ["", "ray://"])
def test_unreachable_address_is_one_line(capsys, tmp_path, scheme):
    pytest.importorskip("ray")
    address = f"{scheme}127.0.0.1:{_closed_port()}"
    spec = _write(tmp_path, {"jobs": [{"kind": "run", "set": SHORT}]})
    code = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--address", address])
    lines = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(lines) == 1, lines
    assert address in lines[0] and "cannot reach" in lines[0]
    assert not (tmp_path / "out").exists()


def test_malformed_address(capsys, tmp_path):
    pytest.importorskip("ray")
    spec = _write(tmp_path, {"jobs": [{"kind": "run", "set": SHORT}]})
    code = main(["sweep", str(spec), "--out", str(tmp_path / "out"), "--address", "nowhere"])
    line = capsys.readouterr().err.strip()
    assert code == 2 and "'nowhere'" in line and "HOST:PORT" in line


def test_joining_a_cluster_uses_the_token_at_hand(tmp_path, monkeypatch):
    """Ray 2.60 refuses a driver without RAY_AUTH_MODE=token on a `ray start` cluster."""
    from agents.lab.sweep.cluster import use_cluster_token

    monkeypatch.setenv("RAY_AUTH_MODE", "placeholder")  # restored after the test
    monkeypatch.delenv("RAY_AUTH_MODE")
    monkeypatch.delenv("RAY_AUTH_TOKEN", raising=False)
    monkeypatch.delenv("RAY_AUTH_TOKEN_PATH", raising=False)
    monkeypatch.delitem(sys.modules, "ray", raising=False)  # as before Ray is imported
    monkeypatch.setattr(Path, "home", lambda: tmp_path)
    use_cluster_token()
    assert "RAY_AUTH_MODE" not in os.environ  # no token: nothing to ask for
    (tmp_path / ".ray").mkdir()
    (tmp_path / ".ray" / "auth_token").write_text("secret")
    use_cluster_token()
    assert os.environ["RAY_AUTH_MODE"] == "token"
    monkeypatch.setenv("RAY_AUTH_MODE", "disabled")
    use_cluster_token()
    assert os.environ["RAY_AUTH_MODE"] == "disabled"  # the user's choice stays
