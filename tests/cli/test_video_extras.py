"""``--video`` without what its file type needs: one error line naming the extras that bring
it (``[plots]`` for the frames and GIFs, ``[video]`` for MP4's encoder), before anything flies.
The packages are hidden (``sys.modules`` entries of ``None``: ``find_spec`` finds nothing)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from agents.lab.cli.main import main


def hide(monkeypatch: pytest.MonkeyPatch, *modules: str) -> None:
    for module in modules:
        monkeypatch.setitem(sys.modules, module, None)


@pytest.fixture(autouse=True)
def in_tmp_path(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Run from ``tmp_path``: a default figures folder would go to its ``runs/``."""
    monkeypatch.chdir(tmp_path)


def run_video(tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str]) -> list[str]:
    """``quadslam run --video NAME`` (no ``--plots``): the stderr lines; it must fail."""
    code = main(["run", "--duration", "0.2", "--video", str(tmp_path / "out" / name)])
    captured = capsys.readouterr()
    assert code == 2
    assert captured.out == ""  # no table: nothing was flown
    assert list(tmp_path.iterdir()) == []  # no folder made: neither for the video nor figures
    return captured.err.strip().splitlines()


def test_mp4_without_any_extra_names_both_in_one_line(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "matplotlib", "imageio_ffmpeg")
    err = run_video(tmp_path, "a.mp4", capsys)
    assert len(err) == 1
    assert "matplotlib and imageio-ffmpeg" in err[0]
    assert err[0].endswith("install them with: pip install 'quadslam[plots,video]'")


def test_mp4_with_matplotlib_names_the_video_extra(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "imageio_ffmpeg")
    err = run_video(tmp_path, "a.mp4", capsys)
    assert len(err) == 1
    assert "needs imageio-ffmpeg, which is not installed" in err[0]
    assert "'quadslam[video]'" in err[0] and "[plots" not in err[0]
    assert err[0].endswith("or give a .gif file name")  # a GIF needs matplotlib only


def test_gif_without_matplotlib_names_the_plots_extra(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    hide(monkeypatch, "matplotlib", "imageio_ffmpeg")
    err = run_video(tmp_path, "a.gif", capsys)
    assert len(err) == 1
    assert "writing .gif needs matplotlib" in err[0]
    assert err[0].endswith("pip install 'quadslam[plots]'") and "video]" not in err[0]
