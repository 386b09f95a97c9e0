"""The marker a command leaves in a folder it made (``.xvmatch-output.json``, naming the
command), so that it later replaces only its own folders: one format, read and written here for
the command line (``demo``, ``associate --draw``) and for ``ablate``'s report folders alike."""

from __future__ import annotations

import json
import os
from pathlib import Path

from xvmatch.geometry.atomic_files import atomic_write_text

__all__ = ["MARKER", "is_own_folder", "mark_own_folder"]

MARKER = ".xvmatch-output.json"
"""The file a command leaves in a folder it made: ``{"written_by": "xvmatch demo"}``."""


def is_own_folder(folder: str | os.PathLike, command: str) -> bool:
    """Whether ``folder`` holds the marker of ``command`` (``"xvmatch demo"``); a missing,
    unreadable or malformed marker (deep nesting included) is no marker."""
    try:
        record = json.loads((Path(folder) / MARKER).read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, ValueError, RecursionError):
        return False
    return isinstance(record, dict) and record.get("written_by") == command


def mark_own_folder(folder: str | os.PathLike, command: str) -> Path:
    """Create ``folder`` if missing and leave ``command``'s marker in it (kept when there)."""
    out = Path(folder)
    out.mkdir(parents=True, exist_ok=True)
    if not is_own_folder(out, command):
        atomic_write_text(out / MARKER, json.dumps({"written_by": command}) + "\n")
    return out
