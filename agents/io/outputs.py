"""Result files: checked before the work, written atomically, never lost.

Every command that writes results (``quadslam run/evaluate/bench/study``) checks its output
paths with :func:`check_output_file` / :func:`check_output_dir` before it flies anything: a path
naming a folder where a file is wanted (or the reverse), a folder that cannot be created, or a
folder that cannot be written ends the command at once with a one-line error naming the option
and the path (exit status 2).

The files themselves are written by a :class:`Saver`: each file is produced under a temporary
name in its destination folder and moved into place with :func:`os.replace`, so a reader never
sees half a file. When a write still fails at the end (the disk filled up, the folder was removed
or made read-only during the run), the file is written next to the intended place under another
name (only where that place is a regular file or a new name: never beside a FIFO or a device
such as ``/dev/full``, nor into ``/dev``, ``/proc`` or ``/sys``) or, failing that, into a fresh
temporary folder; :meth:`Saver.check` then raises one
:class:`OutputWriteError` that says what could not be written and where it went instead.

Which targets are written through or refused, and the checks before the work, are
:mod:`agents.io.paths`.

A full disk (``ENOSPC``) never truncates a good file, since the new one is complete before
the rename; the commands that keep work across sessions (``train``, ``sweep``) turn it into
one :class:`DiskFullError` line saying where the work is and how to resume.

SIGTERM handling (a scheduler, ``docker stop``) is :mod:`agents.io.signals`.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import math
import os
import secrets
import shutil
import stat
import sys
import tempfile
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from agents.io.paths import (
    THROUGH,
    OutputPathError,
    kind_name,
    output_target,
    own_descriptor,
    reason,
)


class OutputWriteError(ValueError):
    """Writes that failed after the work; the message says where the results went instead."""


class DiskFullError(Exception):
    """No space left on the device: the message says what is kept where and how to resume."""


def is_disk_full(exc: BaseException) -> bool:
    """True for ``ENOSPC`` (no space left) and ``EDQUOT`` (disk quota exceeded)."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def _temp_name(path: Path) -> Path:
    """A fresh hidden name in ``path``'s folder that keeps its extension (format detection)."""
    return path.with_name(f".{path.stem}.tmp-{secrets.token_hex(4)}{path.suffix}")


def _fsync_file(path: Path) -> None:
    """Flush a finished file's data to the disk (the rename must not land before it)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_dir(folder: Path) -> None:
    """Make a rename in ``folder`` durable (best effort: not every file system allows it)."""
    with contextlib.suppress(OSError):
        fd = os.open(folder, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def _with_filename(exc: OSError, path: Path) -> OSError:
    """``exc`` naming ``path`` (a failed ``write`` names no file; the message should)."""
    if exc.filename is not None or exc.errno is None:
        return exc
    return OSError(exc.errno, exc.strerror or os.strerror(exc.errno), str(path))


def commit(tmp: Path, path: Path) -> None:
    """Move a complete file ``tmp`` onto ``path`` (same folder) atomically and durably.

    The file is synced before the rename; ``path`` must be missing or a regular file (checked
    again here: it may have changed since the command started).

    Raises:
        OutputPathError: ``path`` became something other than a regular file.
        OSError: Syncing or renaming failed (``tmp`` is left for the caller to remove).
    """
    _fsync_file(tmp)
    with contextlib.suppress(FileNotFoundError):
        mode = os.lstat(path).st_mode
        if not stat.S_ISREG(mode):
            kind = "a symbolic link" if stat.S_ISLNK(mode) else kind_name(mode)
            raise OutputPathError(f"{str(path)!r} is {kind} now; it is not replaced")
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _write_through(path: Path, produce: Callable[[Path], Any]) -> None:
    """Produce the file in a temporary folder, then copy it into the FIFO or device at
    ``path`` without replacing it: through this process's own descriptor when ``path`` names
    one (``/dev/stdout``), else appended."""
    with tempfile.TemporaryDirectory(prefix="quadslam-through-") as tmp:
        staged = Path(tmp) / f"output{path.suffix}"
        produce(staged)
        if not staged.exists():  # a writer that adds its own extension (SB3's .zip)
            made = [p for p in Path(tmp).iterdir() if p.is_file()]
            staged = made[0] if len(made) == 1 else staged
        for stream in (sys.stdout, sys.stderr):  # what was printed before comes first
            with contextlib.suppress(OSError, ValueError, AttributeError):
                stream.flush()
        fd = own_descriptor(path)
        with open(staged, "rb") as src:
            if fd is None:
                with open(path, "ab") as dst:
                    shutil.copyfileobj(src, dst)
                return
            while chunk := src.read(1 << 16):
                view = memoryview(chunk)
                while view:
                    view = view[os.write(fd, view) :]


def atomic_produce(path: Path, produce: Callable[[Path], Any]) -> None:
    """Let ``produce(tmp)`` write a complete file at a temporary name beside ``path``, then
    move it into place with :func:`os.replace` (atomic on one file system).

    A FIFO or character device at ``path`` is written through instead, and a symbolic link
    to a regular file stays: the file it points to is replaced (see :func:`output_target`).

    Raises:
        OutputPathError: ``path`` is something that must not be replaced (a folder, a block
            device, a socket, a dangling link).
        OSError: Writing or renaming failed (the temporary file is removed; the file at
            ``path`` is unchanged).
    """
    kind, dest = output_target(path, "output")
    if kind == THROUGH:
        try:
            _write_through(path, produce)
        except OSError as exc:
            raise _with_filename(exc, path) from exc
        return
    tmp = _temp_name(dest)
    try:
        produce(tmp)
        commit(tmp, dest)
    except BaseException as exc:
        tmp.unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise _with_filename(exc, path) from exc
        raise


def atomic_produce_all(items: Sequence[tuple[Path, Callable[[Path], Any]]]) -> None:
    """Write files that belong together (a model and its ``VecNormalize`` statistics):
    every file is produced under its temporary name first, and only then are they moved into
    place, so a failed write (a full disk) replaces none of them.

    Args:
        items: ``(path, produce)`` pairs as for :func:`atomic_produce`; regular files only
            (a FIFO or device would be written through by :func:`atomic_produce`).

    Raises:
        OutputPathError: A path is not a regular file or a link to one.
        OSError: A write or a rename failed (no temporary file is left behind).
    """
    staged: list[tuple[Path, Path]] = []
    try:
        for path, produce in items:
            kind, dest = output_target(path, "output")
            if kind == THROUGH:
                raise OutputPathError(f"{str(path)!r} is not a regular file; it is not replaced")
            tmp = _temp_name(dest)
            staged.append((tmp, dest))
            try:
                produce(tmp)
            except OSError as exc:
                raise _with_filename(exc, path) from exc
        for tmp, dest in staged:
            commit(tmp, dest)
    finally:
        for tmp, _ in staged:
            tmp.unlink(missing_ok=True)  # those not moved into place


def _write_bytes(path: Path, data: bytes) -> None:
    with open(path, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())


def write_bytes_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temporary file in the same folder + rename).

    Raises:
        OSError: The write or the rename failed; ``path`` is then unchanged.
    """
    atomic_produce(path, lambda tmp: _write_bytes(tmp, data))


def write_text_atomic(path: Path, text: str) -> None:
    """Write ``text`` (UTF-8) to ``path`` atomically (see :func:`write_bytes_atomic`)."""
    write_bytes_atomic(path, text.encode("utf-8"))


# ------------------------------------------------------------------------------- SIGTERM
def clean_json(value: Any) -> Any:
    """``value`` with every non-finite float as ``None`` (JSON null)."""
    if isinstance(value, dict):
        return {k: clean_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean_json(v) for v in value]
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    return value


def json_text(obj: Any) -> str:
    """Pretty JSON text of a result document (two-space indent, trailing newline)."""
    return json.dumps(obj, indent=2) + "\n"


_SYSTEM_DIRS = (Path("/dev"), Path("/proc"), Path("/sys"))
"""Folders of devices and kernel files, never of results: no copy is written into them."""


def _beside_allowed(path: Path) -> bool:
    """Whether a failed write's copy may go next to ``path``: when ``path`` is a regular file
    (or a link to one) or a name not yet taken, outside :data:`_SYSTEM_DIRS`. Beside a FIFO,
    a device (``/dev/full``) or anything else that is not a file, the folder is not one of
    results, and the copy goes to a temporary folder instead."""
    try:
        kind, dest = output_target(path, "output")
    except OutputPathError:  # a folder, socket, block device or dangling link by now
        return False
    if kind == THROUGH:
        return False
    folder = Path(os.path.realpath(dest.parent))
    return not any(folder == root or folder.is_relative_to(root) for root in _SYSTEM_DIRS)


class Saver:
    """Writes result files atomically and keeps every failed write's result somewhere.

    Use one saver per command: write each file through it, then call :meth:`check`.

    Attributes:
        failures: One message per file that could not be written where asked.
        written: Where each file ended up (the intended path or its fallback).
    """

    def __init__(self) -> None:
        self.failures: list[str] = []
        self.written: list[Path] = []
        self._fallback_dir: Path | None = None

    def produce(self, path: Path, option: str, produce: Callable[[Path], Any]) -> Path:
        """Write ``path`` through ``produce(target)`` (which must write a complete file at
        ``target``); on failure write the fallback and remember the failure.

        Args:
            path: Intended destination.
            option: The option that named it (``--json``, ``--plots``, …), for the message.
            produce: Writes the whole file at the path it is given.

        Returns:
            Where the file was written (``path``, or the fallback); ``path`` also when every
            attempt failed (the failure is recorded).
        """
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            atomic_produce(path, produce)
        except (OSError, OutputPathError) as exc:  # the target may have changed meanwhile
            return self._recover(path, option, produce, exc)
        self.written.append(path)
        return path

    def write_bytes(self, path: Path, data: bytes, option: str) -> Path:
        """Write ``data`` to ``path`` (see :meth:`produce`)."""
        return self.produce(path, option, lambda target: _write_bytes(target, data))

    def write_text(self, path: Path, text: str, option: str) -> Path:
        """Write ``text`` (UTF-8) to ``path`` (see :meth:`produce`)."""
        return self.write_bytes(path, text.encode("utf-8"), option)

    def write_json(self, path: Path, obj: Any, option: str) -> Path:
        """Write ``obj`` as pretty JSON to ``path`` (see :meth:`produce`)."""
        return self.write_text(path, json_text(obj), option)

    def save_figure(self, fig: Any, path: Path, option: str, dpi: int = 110) -> Path:
        """Render a matplotlib figure to PNG in memory and write it to ``path``."""
        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi)
        return self.write_bytes(path, buf.getvalue(), option)

    def _recover(
        self,
        path: Path,
        option: str,
        produce: Callable[[Path], Any],
        exc: OSError | OutputPathError,
    ) -> Path:
        """Write the file next to ``path`` under another name (only beside a regular file or a
        new name, :func:`_beside_allowed`), else into a temporary folder."""
        beside = path.with_name(f"{path.stem}.recovered-{secrets.token_hex(3)}{path.suffix}")
        places: list[Callable[[], Path]] = [lambda: self._temp_dir() / path.name]
        if _beside_allowed(path):
            places.insert(0, lambda: beside)
        for place in places:
            try:
                target = place()
            except OSError:  # no temporary folder either
                continue
            try:
                produce(target)  # not atomic: any complete copy beats none
            except OSError:
                with contextlib.suppress(OSError):
                    target.unlink(missing_ok=True)  # a partial copy
                continue
            self.record(option, path, exc, target)
            return target
        self.record(option, path, exc, None)
        return path

    def record(
        self, option: str, path: Path, exc: OSError | OutputPathError, saved_to: Path | None
    ) -> None:
        """Remember that ``path`` could not be written and where the result is instead."""
        if saved_to is None:
            self.failures.append(
                f"{option}: could not write {str(path)!r} ({reason(exc)}), nor a copy next "
                "to it or in the temporary folder"
            )
            return
        self.failures.append(
            f"{option}: could not write {str(path)!r} ({reason(exc)}); "
            f"saved to {str(saved_to)!r} instead"
        )
        self.written.append(saved_to)

    def _temp_dir(self) -> Path:
        if self._fallback_dir is None:
            self._fallback_dir = Path(tempfile.mkdtemp(prefix="quadslam-results-"))
        return self._fallback_dir

    def check(self) -> None:
        """Raise one :class:`OutputWriteError` naming every failed write and its fallback.

        Raises:
            OutputWriteError: At least one file could not be written where asked.
        """
        if self.failures:
            raise OutputWriteError("; ".join(self.failures))
