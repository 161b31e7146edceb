"""A run folder's manifest: every file of a saved session, with its size and SHA-256.

``quadslam train`` writes ``manifest.json`` into the run folder last, once the session has
saved everything (the model, the learning curve, ``timing.json``, and the ``INTERRUPTED``
marker of a session stopped by Ctrl-C or SIGTERM); each file is hashed once, there. The
commands that read a run folder (``evaluate`` and everything that loads a trained model
through :func:`agents.rl.loading.load_model`: the studies, the sweep; ``convert-run``;
``train --resume``) call :func:`verify_run` first, before anything of the folder is read:

- every listed file that is present must still have its recorded size and SHA-256, else the
  folder is refused with one line naming the file (a truncated or tampered ``model.zip``);
- the files the command is about to read (``config.yaml``, the model's arrays and statistics
  or, when trusted, its zip and ``VecNormalize`` pickle) must be listed: a file added to the
  folder afterwards is refused;
- a listed file that is missing is not an error here (a checkpoint deleted to save space);
  the command reports the files it needs;
- a folder without a manifest (a run from before manifests, or a session killed before it
  saved) is accepted with a one-line :class:`ManifestWarning`.

``train --resume`` removes the manifest before the new session changes the folder; the
session writes a new one when it has saved. The manifest shows that the files are those the
training saved, not who wrote the folder (whoever crafts a folder can write its manifest):
loading does not rely on it to make a pickle safe, it reads none (:mod:`agents.rl.loading`).
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
import warnings
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from agents.io.outputs import write_text_atomic

MANIFEST = "manifest.json"
"""The manifest's name in a run folder."""

FORMAT = "quadslam-run-manifest"
VERSION = 1
_CHUNK = 1 << 20


class ManifestError(ValueError):
    """A run folder whose files do not match its manifest (one-line message)."""


class ManifestWarning(UserWarning):
    """A run folder without a manifest: its files cannot be checked."""


def file_sha256(path: Path) -> str:
    """The SHA-256 of a file's content, as 64 hex digits (read in 1 MiB chunks)."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def _is_temporary(name: str) -> bool:
    """A save that never finished (``.model.tmp-1a2b3c4d.zip``) or a staging folder."""
    return name.startswith(".") and (".tmp-" in name or name.startswith(".curve-"))


def run_files(run_dir: Path) -> list[Path]:
    """The regular files of a run folder, sorted: recursively, without following links,
    without the manifest itself and without the temporary files of unfinished saves."""
    found: list[Path] = []
    for folder, dirs, names in os.walk(run_dir):
        dirs[:] = sorted(d for d in dirs if not _is_temporary(d))
        for name in names:
            path = Path(folder) / name
            if _is_temporary(name) or path == run_dir / MANIFEST:
                continue
            if stat.S_ISREG(os.lstat(path).st_mode):
                found.append(path)
    return sorted(found, key=lambda p: p.relative_to(run_dir).as_posix())


def write_manifest(run_dir: Path) -> Path:
    """Hash every file of ``run_dir`` and write ``manifest.json`` atomically (call it last).

    Returns:
        The manifest's path.

    Raises:
        OSError: A file could not be read, or the manifest not written (a full disk).
    """
    files: dict[str, dict[str, Any]] = {}
    for path in run_files(run_dir):
        files[path.relative_to(run_dir).as_posix()] = {
            "size": path.stat().st_size,
            "sha256": file_sha256(path),
        }
    doc = {"format": FORMAT, "version": VERSION, "files": files}
    path = run_dir / MANIFEST
    write_text_atomic(path, json.dumps(doc, indent=1) + "\n")
    return path


def read_manifest(run_dir: Path) -> dict[str, dict[str, Any]] | None:
    """The ``files`` of a run folder's manifest (relative path → size and SHA-256), or
    ``None`` when the folder has no manifest.

    Raises:
        ManifestError: The manifest cannot be read or is not one this package writes.
    """
    path = run_dir / MANIFEST
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ManifestError(f"{run_dir}: cannot read its {MANIFEST} ({exc})") from None
    files = doc.get("files") if isinstance(doc, dict) else None
    valid = (
        isinstance(doc, dict)
        and doc.get("format") == FORMAT
        and isinstance(files, dict)
        and all(
            isinstance(entry, dict)
            and isinstance(entry.get("size"), int)
            and isinstance(entry.get("sha256"), str)
            for entry in files.values()
        )
    )
    if not valid:
        raise ManifestError(
            f"{run_dir}: its {MANIFEST} is not a run manifest written by quadslam "
            f"(format {FORMAT!r} with a size and a sha256 per file)"
        )
    return files


def _relative(path: Path, run_dir: Path) -> str:
    """``path`` relative to ``run_dir``, as the manifest lists it."""
    return Path(os.path.abspath(path)).relative_to(os.path.abspath(run_dir)).as_posix()


def verify_run(run_dir: Path, needed: Iterable[Path] = ()) -> bool:
    """Check a run folder against its manifest before anything of it is loaded.

    Args:
        run_dir: The run folder.
        needed: Files in ``run_dir`` the caller is about to read; each must be listed.

    Returns:
        ``True`` when every listed file present matches; ``False`` (after a
        :class:`ManifestWarning`) when the folder has no manifest.

    Raises:
        ManifestError: A file differs from its record (size or SHA-256), a needed file is
            not listed, or the manifest is unreadable. One line naming the file.
    """
    files = read_manifest(run_dir)
    if files is None:
        warnings.warn(
            f"{run_dir} has no {MANIFEST} (a run saved before manifests existed, or a "
            "session that did not finish saving); its files are not checked",
            ManifestWarning,
            stacklevel=2,
        )
        return False
    for path in needed:
        name = _relative(path, run_dir)
        if name not in files:
            raise ManifestError(
                f"{run_dir}: {name} is not listed in its {MANIFEST}: it was not written by "
                "the training that saved this folder; refusing to load it"
            )
    for name, entry in files.items():
        path = run_dir / name
        try:
            size = path.stat().st_size
        except FileNotFoundError:
            continue  # reported by the command if it needs the file
        if size != entry["size"]:
            raise ManifestError(
                f"{run_dir}: {name} differs from its {MANIFEST} ({size:,} bytes, "
                f"{entry['size']:,} recorded): truncated or changed since it was saved; "
                "refusing to load the run"
            )
        if file_sha256(path) != entry["sha256"]:
            raise ManifestError(
                f"{run_dir}: {name} differs from its {MANIFEST} (same size, another "
                "SHA-256): changed since it was saved; refusing to load the run"
            )
    return True
