"""The marker a command leaves in a folder it made (``.xvmatch-output.json``, naming the
command), so that it later replaces only its own folders: one format, read and written here for
the command line (``demo``, ``associate --draw``) and for ``ablate``'s report folders alike."""

from __future__ import annotations

import json
import os
from pathlib import Path

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.input_files import MAX_INPUT_BYTES, read_input_text

__all__ = ["MARKER", "files_under", "is_own_folder", "mark_own_folder", "own_files",
           "record_own_files", "remove_own_files"]

MARKER = ".xvmatch-output.json"
"""The file a command leaves in a folder it made: ``{"written_by": "xvmatch demo"}``."""


def _record(folder: str | os.PathLike) -> dict | None:
    """The marker's record, or None when missing, unreadable or malformed: a marker that is a
    FIFO, a device or not text is no marker, refused at once, never read (it would block or
    never end). Its one compact JSON line may be long (the list of files a run wrote)."""
    try:
        text = read_input_text(Path(folder) / MARKER, max_line=MAX_INPUT_BYTES)
        record = json.loads(text)
    except (OSError, ValueError, RecursionError):  # InputFileError is a ValueError
        return None
    return record if isinstance(record, dict) else None


def is_own_folder(folder: str | os.PathLike, command: str) -> bool:
    """Whether ``folder`` holds the marker of ``command`` (``"xvmatch demo"``); a missing,
    unreadable or malformed marker (deep nesting included) is no marker."""
    record = _record(folder)
    return record is not None and record.get("written_by") == command


def mark_own_folder(folder: str | os.PathLike, command: str) -> Path:
    """Create ``folder`` if missing and leave ``command``'s marker in it (kept when there)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    if not is_own_folder(out, command):
        atomic_write_text(out / MARKER, json.dumps({"written_by": command}) + "\n")
    return out


def own_files(folder: str | os.PathLike, command: str) -> set[str]:
    """The files (paths relative to ``folder``, ``/``-separated) that ``command``'s marker
    lists as written by it; empty for a folder not marked by ``command``. Only names that stay
    inside the folder are returned (no absolute path, no ``..``), whatever the marker holds."""
    record = _record(folder)
    if record is None or record.get("written_by") != command:
        return set()
    names = record.get("files")
    if not isinstance(names, list):
        return set()
    return {n for n in names if isinstance(n, str) and n and not n.startswith("/")
            and ".." not in n.split("/") and "\\" not in n}


def record_own_files(folder: str | os.PathLike, command: str, names) -> None:
    """Mark ``folder`` as ``command``'s and list ``names`` (relative paths) as the files it
    wrote there, so that a later run removes only those (:func:`remove_own_files`)."""
    atomic_write_text(Path(folder) / MARKER,
                      json.dumps({"written_by": command, "files": sorted(set(names))}) + "\n")


def remove_own_files(folder: str | os.PathLike, command: str, keep=()) -> None:
    """Delete the files an earlier run of ``command`` listed as written in ``folder`` (its
    marker), except ``keep``: never a file the user put there (issue 65)."""
    root = Path(folder)
    for name in sorted(own_files(root, command) - set(keep)):
        path = root / name
        if path.is_file() and not path.is_symlink():
            path.unlink()


def files_under(folder: str | os.PathLike) -> set[str]:
    """Every regular file below ``folder`` but the marker, as ``/``-separated relative paths
    (what :func:`record_own_files` lists)."""
    root = Path(folder)
    return {p.relative_to(root).as_posix() for p in root.rglob("*")
            if p.is_file() and not p.is_symlink() and p.name != MARKER}

