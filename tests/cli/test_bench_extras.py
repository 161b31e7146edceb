"""``quadslam bench`` without an optional extra: the sections that need none run, the others
are named in one line with the extra to install (nothing here measures anything: the sections
are stubs).
"""

from __future__ import annotations

import importlib.metadata
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from agents.lab.bench import runner as bench
from agents.lab.bench.plan import TINY, Plan, Results
from agents.lab.cli.main import main


def hide(monkeypatch: pytest.MonkeyPatch, module: str) -> None:
    """Make ``module`` look uninstalled: its import fails, ``find_spec`` finds nothing and
    ``importlib.metadata`` knows no distribution of that name."""
    monkeypatch.setitem(sys.modules, module, None)
    real = importlib.metadata.version

    def version(name: str) -> str:
        if name.replace("-", "_").lower() == module:
            raise importlib.metadata.PackageNotFoundError(name)
        return real(name)

    monkeypatch.setattr(importlib.metadata, "version", version)


@pytest.fixture
def ran(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Every section replaced by a stub that records its name (in the order they ran)."""
    names: list[str] = []

    def stub(name: str) -> Callable[[Results, Plan], None]:
        return lambda results, plan: names.append(name)

    monkeypatch.setattr(bench, "sections", lambda: {n: stub(n) for n in bench.SECTION_NAMES})
    return names


def test_machine_info_without_stable_baselines3(monkeypatch: pytest.MonkeyPatch) -> None:
    hide(monkeypatch, "stable_baselines3")
    info = bench.machine_info()
    assert "stable_baselines3" not in info
    assert info["numpy"] == importlib.metadata.version("numpy")


def test_machine_info_records_installed_versions() -> None:
    info = bench.machine_info()
    assert info["gymnasium"] == importlib.metadata.version("gymnasium")
    assert info["numba"] == importlib.metadata.version("numba")


def test_all_sections_skip_the_one_whose_extra_is_missing(
    monkeypatch: pytest.MonkeyPatch, ran: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "stable_baselines3")
    doc = bench.run_bench(True, plan=TINY, progress=False)
    assert ran == [n for n in bench.SECTION_NAMES if n != "workers"]
    assert doc["sections"] == ran
    assert set(doc["skipped"]) == {"workers"}
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert "workers" in err[0] and "pip install 'quadslam[rl]'" in err[0]


def test_all_sections_run_with_every_extra(ran: list[str]) -> None:
    doc = bench.run_bench(True, plan=TINY, progress=False)
    assert ran == list(bench.SECTION_NAMES) and doc["skipped"] == {}


def test_only_a_section_without_its_extra_is_one_line_error(
    monkeypatch: pytest.MonkeyPatch, ran: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "stable_baselines3")
    assert main(["bench", "--only", "env", "workers"]) == 2
    assert ran == []  # refused before anything ran
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1
    assert err[0].startswith("quadslam bench: error: ") and "quadslam[rl]" in err[0]


def test_plots_without_matplotlib_is_one_line_error_before_running(
    monkeypatch: pytest.MonkeyPatch,
    ran: list[str],
    capsys: pytest.CaptureFixture[str],
    tmp_path: Path,
) -> None:
    hide(monkeypatch, "matplotlib")
    assert main(["bench", "--only", "env", "--plots", str(tmp_path / "figs")]) == 2
    assert ran == []
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "quadslam[plots]" in err[0]


def test_render_section_is_skipped_without_matplotlib(
    monkeypatch: pytest.MonkeyPatch, ran: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "matplotlib")
    bench.run_bench(True, plan=TINY, progress=False)
    assert "render" not in ran and "workers" in ran
    assert "quadslam[plots]" in capsys.readouterr().err
