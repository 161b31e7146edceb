"""The EKF update compiled by the warm-up process is the one the env loads (cold numba cache)."""

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

# A fresh process with an empty cache that asks for the warm-up: the env's filter starts the
# warm-up process, the first scan waits for it; numba's compile events say which kernels this
# process compiled itself.
PROBE = """
import json
from numba.core import event
compiled = []
class Listener(event.Listener):
    def on_start(self, ev): compiled.append(ev.data["dispatcher"].py_func.__qualname__)
    def on_end(self, ev): pass
event.register("numba:compile", Listener())
import gymnasium as gym, numpy as np, quadslam_env
from estimators.ekf import warmup
from quadslam_env.models.jit import announce_compilation
notices = []
announce_compilation(notices.append)
warmup.enable()
env = gym.make("QuadSLAM-EKF-v0")
started = warmup._process is not None
env.reset(seed=0)
for _ in range(12):  # the LiDAR scans at step 10
    env.step(np.zeros(4, dtype=np.float32))
print(json.dumps({"started": started, "compiled": compiled, "notices": notices}))
"""


def _probe(cache_dir: Path) -> dict:
    env = {k: v for k, v in os.environ.items() if k != warmup.ENV_VAR}
    env["NUMBA_CACHE_DIR"] = str(cache_dir)
    out = subprocess.run(
        [sys.executable, "-c", PROBE], env=env, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_env_loads_the_update_the_warmup_process_compiled(tmp_path: Path) -> None:
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
