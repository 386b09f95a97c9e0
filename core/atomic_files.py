"""Atomic file writes: the one way every writer of the project puts a file on disk, so that a
reader, or the user after a crash or Ctrl-C, sees the old file or the complete new one, never a
partial write. It lives in ``core/`` (the lowest layer) so that every layer may use it."""

from __future__ import annotations

import functools
import os
import tempfile
from pathlib import Path

__all__ = ["atomic_write_bytes", "atomic_write_text"]


@functools.cache
def _default_mode() -> int:
    """Permissions a plain ``open(..., "w")`` would give a new file (0o666 minus the umask)."""
    umask = os.umask(0o022)
    os.umask(umask)
    return 0o666 & ~umask


def atomic_write_bytes(path: str | os.PathLike, data: bytes, fsync: bool = True) -> None:
    """Write ``data`` to ``path`` atomically: the one helper every writer uses.

    The bytes go to a temporary file in the same directory, are flushed to disk (``fsync``; bulk
    image writers may skip it for speed), then renamed over ``path`` with ``os.replace``: readers
    see either the old file or the complete new one, never a partial write. The temporary file is
    removed if anything fails. An existing file keeps its permissions; a new one gets the usual
    ``0o666 & ~umask``.

    Args:
        path: destination file; its directory must exist.
        data: the full content.
        fsync: flush the data to disk before the rename.
    """
    target = Path(path)
    try:
        mode = target.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = _default_mode()
    except OSError as exc:
        raise OSError(f"{os.fspath(target)}: cannot write ({exc.strerror or exc})") from None
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        why = ("its folder does not exist" if not target.parent.is_dir()
               else exc.strerror or str(exc))
        raise OSError(f"{os.fspath(target)}: cannot write ({why})") from None
    try:
        with os.fdopen(fd, "wb") as handle:
            handle.write(data)
            if fsync:
                handle.flush()
                os.fsync(handle.fileno())
        os.chmod(tmp, mode)
        os.replace(tmp, target)
    except BaseException:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        raise


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` as UTF-8 to ``path`` atomically, flushed to disk (see atomic_write_bytes)."""
    atomic_write_bytes(path, text.encode("utf-8"))
