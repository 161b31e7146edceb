"""The EKF update compiled by the warm-up process is the one the filter loads (cold numba cache)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import ClassVar

import pytest

from estimators.ekf import warmup
from quadslam_env.models.jit import COMPILE_NOTICE

# A fresh process with an empty cache that asks for the warm-up: building the filter starts the
# warm-up process, the first update waits for it; numba's compile events say which kernels this
# process compiled itself. The filter alone, not an env: the env's other kernels (physics,
# sensors, metrics) would only add their compile time.
PROBE = """
import json
from numba.core import event
compiled = []
class Listener(event.Listener):
    def on_start(self, ev): compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev): pass
event.register("numba:compile", Listener())
import numpy as np
from estimators.ekf import EkfSlamBatch, warmup
from quadslam_env.models.jit import announce_compilation
notices = []
announce_compilation(notices.append)
warmup.enable()
ekf = EkfSlamBatch(1, 4)
started = warmup._process is not None
lanes, active = np.zeros(1, dtype=np.int64), np.ones(1, dtype=bool)
ekf.reset_lanes(lanes, np.zeros((1, 12)), np.eye(12)[None] * 1e-2, [np.random.default_rng(0)])
hover = np.array([[0.0, 0.0, -9.81]])
ekf.predict(np.zeros(1), hover, np.zeros((1, 3)), 0.03, 0.002, np.ones(1), np.zeros((1, 3)),
            0.01, active)
visible = np.array([[True, True, False, False]])
meas = np.array([[[0.1, 0.1, 5.0], [-0.2, 0.05, 7.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])
ekf.update(np.zeros(1), lanes, visible, meas, np.array([0.006, 0.005, 0.1]))
print(json.dumps({"started": started, "compiled": compiled, "notices": notices}))
"""


def _probe(cache_dir: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != warmup.ENV_VAR}
    env["NUMBA_CACHE_DIR"] = str(cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_filter_loads_the_update_the_warmup_process_compiled(tmp_path: Path) -> None:
    result = _probe(tmp_path)
    assert result["started"]
    assert "update_lanes" not in result["compiled"]  # loaded from the warm-up's cache entry
    assert "predict_lanes" in result["compiled"]  # this process did compile (cache was cold)
    assert result["notices"] == [COMPILE_NOTICE]  # one line saying why, once
    again = _probe(tmp_path)  # warm cache: no warm-up process, nothing compiled, no notice
    assert not again["started"]
    assert again["compiled"] == [] and again["notices"] == []


class _FakePopen:
    calls: ClassVar[list[list[str]]] = []

    def __init__(self, args: list[str], **_: object) -> None:
        _FakePopen.calls.append(args)

    def wait(self, timeout: float) -> int:
        return 0


def test_warmup_starts_only_when_asked_on_a_cold_cache_and_can_be_turned_off(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(warmup.subprocess, "Popen", _FakePopen)
    monkeypatch.setattr(warmup, "_process", None)
    monkeypatch.setattr(warmup, "_enabled", False)
    index = tmp_path / "update.nbi"
    monkeypatch.setattr(warmup, "_index_path", lambda: index)
    monkeypatch.delenv(warmup.ENV_VAR, raising=False)
    warmup.start()  # not asked: a library user gets no second process
    assert _FakePopen.calls == []
    warmup.enable()
    monkeypatch.setenv(warmup.ENV_VAR, "0")
    warmup.start()
    assert _FakePopen.calls == []
    monkeypatch.delenv(warmup.ENV_VAR)
    index.write_bytes(b"")  # cached already
    warmup.start()
    assert _FakePopen.calls == []
    index.unlink()
    warmup.start()
    warmup.start()  # once per process
    assert _FakePopen.calls == [[sys.executable, "-m", "estimators.ekf.compile_update"]]
    warmup.wait()
    assert warmup._process is None
