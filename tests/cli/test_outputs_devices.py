"""A result that cannot be written to a device (``--json /dev/full``) is kept in a temporary
folder, never beside the device: no ``full.recovered-*`` file in ``/dev`` or next to any other
FIFO or device (``agents.io.outputs.Saver``)."""

from __future__ import annotations

import json
import os
import stat
from pathlib import Path

import pytest

from agents.io.outputs import OutputWriteError, Saver

FULL = Path("/dev/full")


def _full_device(folder: Path) -> Path:
    """A character device with /dev/full's numbers in ``folder``: every write to it fails
    with ENOSPC."""
    node = folder / "full.json"
    try:
        os.mknod(node, stat.S_IFCHR | 0o666, os.makedev(1, 7))
    except OSError:
        pytest.skip("cannot create a device node here")
    return node


def _kept_in_temp(saver: Saver, path: Path, temp_root: Path) -> Path:
    """The one fallback copy of a failed write of ``{"x": 1}`` to ``path``: in the temporary
    folder, under the intended name, named by the one-line error."""
    with pytest.raises(OutputWriteError) as err:
        saver.check()
    message = str(err.value)
    assert len(message.splitlines()) == 1
    assert message.startswith(f"--json: could not write {str(path)!r} (No space left on device)")
    (saved,) = saver.written
    assert saved.is_relative_to(temp_root) and saved.name == path.name
    assert f"saved to {str(saved)!r} instead" in message
    assert json.loads(saved.read_text()) == {"x": 1}
    return saved


def test_a_failed_write_to_a_device_leaves_nothing_beside_it(
    tmp_path: Path, temp_root: Path
) -> None:
    folder = tmp_path / "devices"
    folder.mkdir()
    node = _full_device(folder)
    saver = Saver()
    saver.write_json(node, {"x": 1}, "--json")
    _kept_in_temp(saver, node, temp_root)
    assert sorted(p.name for p in folder.iterdir()) == ["full.json"]
    assert stat.S_ISCHR(os.lstat(node).st_mode)  # still the device


@pytest.mark.skipif(not FULL.exists(), reason="no /dev/full on this system")
def test_json_to_dev_full_writes_nothing_into_dev(temp_root: Path) -> None:
    before = set(Path("/dev").glob("full.recovered-*"))
    saver = Saver()
    saver.write_json(FULL, {"x": 1}, "--json")
    _kept_in_temp(saver, FULL, temp_root)
    assert set(Path("/dev").glob("full.recovered-*")) == before


def test_a_failed_write_of_a_regular_file_is_still_kept_beside_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Beside a regular file the copy still goes next to it (the rename failed here)."""
    target = tmp_path / "r.json"
    target.write_text("old")

    def failing_replace(src: object, dst: object) -> None:
        raise OSError(5, "Input/output error")

    monkeypatch.setattr(os, "replace", failing_replace)
    saver = Saver()
    saved = saver.write_json(target, {"x": 1}, "--json")
    assert saved.parent == tmp_path and saved.name.startswith("r.recovered-")
    assert json.loads(saved.read_text()) == {"x": 1} and target.read_text() == "old"
