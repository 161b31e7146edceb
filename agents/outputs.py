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
name or, failing that, into a fresh temporary folder; :meth:`Saver.check` then raises one
:class:`OutputWriteError` that says what could not be written and where it went instead.
"""

from __future__ import annotations

import contextlib
import io
import json
import os
import secrets
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any


class OutputPathError(ValueError):
    """An output path that cannot be written (found before the work; one-line message)."""


class OutputWriteError(ValueError):
    """Writes that failed after the work; the message says where the results went instead."""


def _reason(exc: OSError) -> str:
    return exc.strerror or type(exc).__name__


def _probe(folder: Path) -> None:
    """Create and remove a temporary file in ``folder`` (what an atomic write needs).

    Raises:
        OSError: The folder does not accept new files.
    """
    fd, name = tempfile.mkstemp(prefix=".quadslam-probe-", dir=folder)
    os.close(fd)
    os.unlink(name)


def _check_ancestors(path: Path, option: str) -> None:
    """The nearest existing ancestor of ``path`` must be a folder (not a file)."""
    for ancestor in path.parents:
        if ancestor.exists():
            if not ancestor.is_dir():
                raise OutputPathError(
                    f"{option}: cannot write {str(path)!r}: {str(ancestor)!r} is a file, "
                    "not a folder; allowed: a path inside a writable folder"
                )
            return


def check_output_file(path: Path, option: str) -> None:
    """Fail early on a result file that could not be written.

    Missing parent folders are created; the folder must accept a new file (a temporary probe
    file is created and removed), since the result is written there and renamed into place.

    Args:
        path: The file the command will write.
        option: The command-line option that named it (e.g. ``"--json"``), for the message.

    Raises:
        OutputPathError: ``path`` is a folder, its parent is a file or cannot be created, or
            the parent folder is not writable.
    """
    if path.is_dir():
        raise OutputPathError(f"{option}: {str(path)!r} is a folder; allowed: a file name")
    _check_ancestors(path, option)
    parent = path.parent
    try:
        parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: cannot create the folder {str(parent)!r} for {str(path)!r} "
            f"({_reason(exc)}); allowed: a file in a writable folder"
        ) from None
    try:
        _probe(parent)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: cannot write {str(path)!r}: the folder {str(parent)!r} is not writable "
            f"({_reason(exc)}); allowed: a file in a writable folder"
        ) from None


def check_output_dir(path: Path, option: str) -> None:
    """Fail early on a result folder that could not be written (created when missing).

    Args:
        path: The folder the command will write files into.
        option: The command-line option that named it (e.g. ``"--plots"``).

    Raises:
        OutputPathError: ``path`` is a file, cannot be created or is not writable.
    """
    if path.exists() and not path.is_dir():
        raise OutputPathError(f"{option}: {str(path)!r} is a file; allowed: a folder")
    _check_ancestors(path, option)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: cannot create the folder {str(path)!r} ({_reason(exc)}); "
            "allowed: a writable folder"
        ) from None
    try:
        _probe(path)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: the folder {str(path)!r} is not writable ({_reason(exc)}); "
            "allowed: a writable folder"
        ) from None


def _temp_name(path: Path) -> Path:
    """A fresh hidden name in ``path``'s folder that keeps its extension (format detection)."""
    return path.with_name(f".{path.stem}.tmp-{secrets.token_hex(4)}{path.suffix}")


def atomic_produce(path: Path, produce: Callable[[Path], Any]) -> None:
    """Let ``produce(tmp)`` write a complete file at a temporary name beside ``path``, then
    move it into place with :func:`os.replace` (atomic on one file system).

    Raises:
        OSError: Writing or renaming failed (the temporary file is removed).
    """
    tmp = _temp_name(path)
    try:
        produce(tmp)
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


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


def json_text(obj: Any) -> str:
    """Pretty JSON text of a result document (two-space indent, trailing newline)."""
    return json.dumps(obj, indent=2) + "\n"


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
        except OSError as exc:
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
        self, path: Path, option: str, produce: Callable[[Path], Any], exc: OSError
    ) -> Path:
        """Write the file next to ``path`` under another name, else into a temporary folder."""
        beside = path.with_name(f"{path.stem}.recovered-{secrets.token_hex(3)}{path.suffix}")
        places: tuple[Callable[[], Path], ...] = (
            lambda: beside,
            lambda: self._temp_dir() / path.name,
        )
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

    def record(self, option: str, path: Path, exc: OSError, saved_to: Path | None) -> None:
        """Remember that ``path`` could not be written and where the result is instead."""
        if saved_to is None:
            self.failures.append(
                f"{option}: could not write {str(path)!r} ({_reason(exc)}), nor a copy next "
                "to it or in the temporary folder"
            )
            return
        self.failures.append(
            f"{option}: could not write {str(path)!r} ({_reason(exc)}); "
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
