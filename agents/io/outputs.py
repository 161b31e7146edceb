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

Only a regular file is ever replaced. An existing FIFO or character device (``--json
/dev/stdout``, ``/dev/null``, a named pipe) is written through, in place; a symbolic link keeps
its place and the regular file it points to is replaced atomically (a link into ``/proc`` or
``/dev/fd``, as ``/dev/stdout`` is, is written through); anything else (a folder, a block
device, a socket, a dangling link) is refused with a one-line :class:`OutputPathError`.

A full disk (``ENOSPC``) never truncates a good file, since the new one is complete before
the rename; the commands that keep work across sessions (``train``, ``sweep``) turn it into
one :class:`DiskFullError` line saying where the work is and how to resume.

SIGTERM (a scheduler, ``docker stop``) is turned into :class:`Terminated`, a
``KeyboardInterrupt``, inside :func:`sigterm_as_interrupt`, so every command stops, saves and
reports on SIGTERM as it does on Ctrl-C.
"""

from __future__ import annotations

import contextlib
import errno
import hashlib
import io
import json
import os
import re
import secrets
import shutil
import signal
import stat
import sys
import tempfile
import threading
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

#: Longest file name (bytes of one path component) and path that Linux file systems accept.
NAME_MAX = 255
PATH_MAX = 4096


class OutputPathError(ValueError):
    """An output path that cannot be written (found before the work; one-line message)."""


class OutputWriteError(ValueError):
    """Writes that failed after the work; the message says where the results went instead."""


class DiskFullError(Exception):
    """No space left on the device: the message says what is kept where and how to resume."""


def is_disk_full(exc: BaseException) -> bool:
    """True for ``ENOSPC`` (no space left) and ``EDQUOT`` (disk quota exceeded)."""
    return isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT)


def _reason(exc: BaseException) -> str:
    return getattr(exc, "strerror", None) or str(exc) or type(exc).__name__


def _short(text: str, limit: int = 60) -> str:
    """``text`` cut to ``limit`` characters (a 300-character name must not flood the line)."""
    return text if len(text) <= limit else f"{text[: limit - 1]}…"


def _probe(folder: Path) -> None:
    """Create and remove a temporary file in ``folder`` (what an atomic write needs).

    Raises:
        OSError: The folder does not accept new files.
    """
    fd, name = tempfile.mkstemp(prefix=".quadslam-probe-", dir=folder)
    os.close(fd)
    os.unlink(name)


def check_name_lengths(path: Path, option: str) -> None:
    """Every name in ``path`` fits the file system (255 bytes), and so does the whole path.

    Checked first, so that a 300-character name gives this line instead of the
    ``ENAMETOOLONG`` of whichever call meets it first.

    Raises:
        OutputPathError: A name or the path is too long.
    """
    for part in path.parts:
        size = len(os.fsencode(part))
        if size > NAME_MAX:
            raise OutputPathError(
                f"{option}: the name {_short(part)!r} in the path is {size} bytes long; "
                f"allowed: at most {NAME_MAX} bytes per file or folder name"
            )
    size = len(os.fsencode(os.path.abspath(path)))
    if size >= PATH_MAX:
        raise OutputPathError(
            f"{option}: the path {_short(str(path))!r} is {size} bytes long; "
            f"allowed: less than {PATH_MAX} bytes"
        )


def safe_name(text: str, limit: int = 80) -> str:
    """``text`` (a scenario or env name) as one harmless file or folder name.

    Anything but letters, digits, ``.``, ``_`` and ``-`` becomes ``_`` (no separator, so no
    ``..`` can leave the intended folder); leading and trailing dots and underscores go; a
    name longer than ``limit`` keeps its start and gets a hash of the whole, so long names
    stay apart.
    """
    name = re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("._") or "unnamed"
    if len(name) > limit:
        digest = hashlib.sha1(text.encode("utf-8", "surrogatepass")).hexdigest()[:10]
        name = f"{name[: limit - 11].rstrip('._')}-{digest}"
    return name


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


# ------------------------------------------------------------------ what is at the target
NEW, FILE, THROUGH = "new", "file", "through"
_ALLOWED = "allowed: a regular file name, a FIFO or a character device such as /dev/stdout"


def _kind_name(mode: int) -> str:
    for test, name in (
        (stat.S_ISDIR, "a folder"),
        (stat.S_ISBLK, "a block device"),
        (stat.S_ISSOCK, "a socket"),
        (stat.S_ISFIFO, "a FIFO"),
        (stat.S_ISCHR, "a character device"),
    ):
        if test(mode):
            return name
    return "not a regular file"


def _link_chain(path: Path) -> Iterator[str]:
    """The absolute path and each link it leads through, in order (at most 40: the kernel's
    own limit on links followed)."""
    here = os.path.abspath(path)
    for _ in range(40):
        yield here
        try:
            link = os.readlink(here)
        except OSError:
            return
        here = os.path.normpath(os.path.join(os.path.dirname(here), link))


def _via_proc(path: Path) -> bool:
    """The path or a link on the way is a process's file descriptor (``/dev/stdout`` →
    ``/proc/self/fd/1``): writing to it means writing to that descriptor, never replacing
    what it points to (a shell's ``> out.json``)."""
    return any(
        here.startswith(("/proc/", "/dev/fd/")) or here in ("/dev/stdout", "/dev/stderr")
        for here in _link_chain(path)
    )


_FD_LINK = re.compile(r"^/(?:proc/(self|thread-self|\d+)/fd|dev/fd)/(\d+)$")
_STD_NAMES = {"/dev/stdin": 0, "/dev/stdout": 1, "/dev/stderr": 2}


def _own_descriptor(path: Path) -> int | None:
    """The descriptor of this process that ``path`` names (``/dev/stdout`` → 1,
    ``/proc/self/fd/5`` → 5), or ``None``.

    Written through that descriptor, the output lands where this process's own writes to
    it go: opening the file again would start at its own offset, and with a shell's
    ``> out.json`` the printed lines and the document would overwrite each other.
    """
    for here in _link_chain(path):
        if here in _STD_NAMES:
            return _STD_NAMES[here]
        match = _FD_LINK.match(here)
        if match:
            owner = match.group(1)
            if owner is None or owner in ("self", "thread-self") or int(owner) == os.getpid():
                return int(match.group(2))
            return None
    return None


def output_target(path: Path, option: str) -> tuple[str, Path]:
    """How ``path`` is written: ``(kind, destination)``.

    Returns:
        ``("new", path)`` for a missing file; ``("file", path)`` for a regular file (replaced
        atomically); ``("file", real path)`` for a link to a regular file (the file it points
        to is replaced, the link stays); ``("through", path)`` for a FIFO, a character device
        or a process's file descriptor (written in place, appended to a regular file).

    Raises:
        OutputPathError: A folder, a block device, a socket, a dangling or looping link.
    """
    try:
        st = os.lstat(path)
    except (FileNotFoundError, NotADirectoryError):
        return NEW, path  # a file in the path is reported by _check_ancestors
    except OSError as exc:
        raise OutputPathError(
            f"{option}: cannot examine {_short(str(path))!r} ({_reason(exc)}); {_ALLOWED}"
        ) from None
    if stat.S_ISREG(st.st_mode):
        return FILE, path
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        try:
            mode = os.stat(path).st_mode
        except OSError as exc:
            what = "a missing file" if isinstance(exc, FileNotFoundError) else _reason(exc)
            raise OutputPathError(
                f"{option}: {str(path)!r} is a symbolic link to {what}; {_ALLOWED}"
            ) from None
        if _via_proc(path):
            if stat.S_ISREG(mode) or stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
                return THROUGH, path
        elif stat.S_ISREG(mode):
            return FILE, Path(os.path.realpath(path))
    if stat.S_ISDIR(mode):
        raise OutputPathError(f"{option}: {str(path)!r} is a folder; allowed: a file name")
    if stat.S_ISFIFO(mode) or stat.S_ISCHR(mode):
        return THROUGH, path
    raise OutputPathError(f"{option}: {str(path)!r} is {_kind_name(mode)}; {_ALLOWED}")


def check_output_file(path: Path, option: str) -> None:
    """Fail early on a result file that could not be written.

    Missing parent folders are created; the folder must accept a new file (a temporary probe
    file is created and removed), since the result is written there and renamed into place.
    A FIFO or character device (``/dev/stdout``) must be writable; it is written through.

    Args:
        path: The file the command will write.
        option: The command-line option that named it (e.g. ``"--json"``), for the message.

    Raises:
        OutputPathError: ``path`` is a folder, a block device, a socket or a dangling link,
            a name in it is too long, its parent is a file or cannot be created, or the parent
            folder is not writable.
    """
    check_name_lengths(path, option)
    kind, dest = output_target(path, option)
    if kind == THROUGH:
        if option == "--video" and path.suffix.lower() == ".mp4":
            # The MP4 encoder streams into its own temporary file and renames it into place
            # (agents/evaluation/video.py), which would replace the device or link.
            raise OutputPathError(
                f"{option}: {str(path)!r} is not a regular file, and an MP4 is renamed into "
                "place; allowed: a regular .mp4 file name, or a .gif (written through)"
            )
        if not os.access(path, os.W_OK):
            raise OutputPathError(f"{option}: {str(path)!r} is not writable; {_ALLOWED}")
        return
    if option == "--video" and dest != path:
        raise OutputPathError(
            f"{option}: {str(path)!r} is a symbolic link, which the video writer would "
            "replace; allowed: the file it points to, or a regular file name"
        )
    _check_ancestors(dest, option)
    parent = dest.parent
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
        OutputPathError: ``path`` is a file, a name in it is too long, it cannot be created
            or is not writable.
    """
    check_name_lengths(path, option)
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


# ------------------------------------------------------------------------- atomic writes
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
            kind = "a symbolic link" if stat.S_ISLNK(mode) else _kind_name(mode)
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
        fd = _own_descriptor(path)
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
class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread as Ctrl-C raises ``KeyboardInterrupt``: every
    ``except KeyboardInterrupt`` that saves partial work saves it on SIGTERM too.

    Attributes:
        run_dir: The run folder a training saved before passing this on (or ``None``).
    """

    def __init__(self, run_dir: Path | None = None) -> None:
        super().__init__("terminated (SIGTERM)")
        self.run_dir = run_dir


_sigterm = threading.Event()


def _raise_terminated(signum: int, frame: Any) -> None:
    _sigterm.set()
    raise Terminated()


def sigterm_received() -> bool:
    """Whether a SIGTERM arrived inside the latest :func:`sigterm_as_interrupt` block."""
    return _sigterm.is_set()


@contextlib.contextmanager
def sigterm_as_interrupt() -> Iterator[None]:
    """Inside the block, SIGTERM raises :class:`Terminated` (a ``KeyboardInterrupt``).

    An ignored SIGTERM (inherited ``SIG_IGN``) stays ignored; outside the main thread
    nothing changes (signals are delivered to the main thread only).
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _sigterm.clear()  # one command per block: an earlier SIGTERM (in a test) is not this one's
    previous = signal.getsignal(signal.SIGTERM)
    if previous is signal.SIG_IGN:
        yield
        return
    signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


@contextlib.contextmanager
def signals_deferred(note: str) -> Iterator[None]:
    """Hold Ctrl-C and SIGTERM while a set of files that belong together is written.

    A Ctrl-C inside the block only prints ``note``; a SIGTERM prints it and is delivered
    again when the block ends (the files are complete by then), so the process still stops.
    Outside the main thread nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    held: list[int] = []

    def hold(signum: int, frame: Any) -> None:
        print(note, file=sys.stderr)
        if signum == signal.SIGTERM:
            held.append(signum)

    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig, handler in previous.items():
        if handler is not signal.SIG_IGN:
            signal.signal(sig, hold)

    def restore() -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler if handler is not None else signal.SIG_DFL)

    try:
        yield
    except BaseException:
        restore()  # the error ends the work anyway; it is not replaced by the held signal
        raise
    restore()
    if held:
        signal.raise_signal(signal.SIGTERM)


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

    def record(
        self, option: str, path: Path, exc: OSError | OutputPathError, saved_to: Path | None
    ) -> None:
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
