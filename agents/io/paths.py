"""Output paths checked before the work: a one-line error naming the option and the path for
a folder where a file is wanted (or the reverse), a folder that cannot be created or written,
a name too long, or a target that must not be replaced (docs/design.md §7).

Only a regular file is ever replaced. An existing FIFO or character device (``--json
/dev/stdout``, ``/dev/null``, a named pipe) is written through, in place; a symbolic link keeps
its place and the regular file it points to is replaced atomically (a link into ``/proc`` or
``/dev/fd``, as ``/dev/stdout`` is, is written through); anything else (a folder, a block
device, a socket, a dangling link) is refused with a one-line :class:`OutputPathError`.
"""

from __future__ import annotations

import hashlib
import os
import re
import stat
import tempfile
from collections.abc import Iterator
from pathlib import Path

#: Longest file name (bytes of one path component) and path that Linux file systems accept.
NAME_MAX = 255
PATH_MAX = 4096


class OutputPathError(ValueError):
    """An output path that cannot be written (found before the work; one-line message)."""


def reason(exc: BaseException) -> str:
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


def kind_name(mode: int) -> str:
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


def own_descriptor(path: Path) -> int | None:
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
            f"{option}: cannot examine {_short(str(path))!r} ({reason(exc)}); {_ALLOWED}"
        ) from None
    if stat.S_ISREG(st.st_mode):
        return FILE, path
    mode = st.st_mode
    if stat.S_ISLNK(mode):
        try:
            mode = os.stat(path).st_mode
        except OSError as exc:
            what = "a missing file" if isinstance(exc, FileNotFoundError) else reason(exc)
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
    raise OutputPathError(f"{option}: {str(path)!r} is {kind_name(mode)}; {_ALLOWED}")


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
            f"({reason(exc)}); allowed: a file in a writable folder"
        ) from None
    try:
        _probe(parent)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: cannot write {str(path)!r}: the folder {str(parent)!r} is not writable "
            f"({reason(exc)}); allowed: a file in a writable folder"
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
            f"{option}: cannot create the folder {str(path)!r} ({reason(exc)}); "
            "allowed: a writable folder"
        ) from None
    try:
        _probe(path)
    except OSError as exc:
        raise OutputPathError(
            f"{option}: the folder {str(path)!r} is not writable ({reason(exc)}); "
            "allowed: a writable folder"
        ) from None


# ------------------------------------------------------------------------- atomic writes
