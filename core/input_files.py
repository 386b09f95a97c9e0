"""The one way every reader opens a user's input file: without blocking, regular files only,
with a size bound, so a FIFO, a device or ``/dev/zero`` given as an input ends in one line at
once instead of a hang or a machine out of memory.

The file is opened with ``O_NONBLOCK`` (opening a FIFO for reading then returns at once) and
judged on the open descriptor (``fstat``), so what is checked is what is read. Text readers also
refuse a NUL byte (not text) and a line over :data:`MAX_LINE_BYTES` while reading, chunk by
chunk, before the whole file is held. Like :mod:`~xvmatch.core.atomic_files` it lives in
``core/`` (the lowest layer) so that every layer may use it.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

__all__ = [
    "MAX_INPUT_BYTES",
    "MAX_LINE_BYTES",
    "InputFileError",
    "check_input_file",
    "file_kind",
    "read_input_bytes",
    "read_input_text",
]

MAX_LINE_BYTES = 1_000_000
"""Longest line a text input may hold, in bytes: a box, camera or prediction line is under a
few hundred bytes, so a megabyte without a line break is not such a file."""

MAX_INPUT_BYTES = 4 * 1024**3
"""Largest input file read whole, in bytes (4 GiB): far above any box file or record the tool
reads (a 1,200-frame CVMHAT view is about 0.5 MB), below what would fill a 24 GiB machine once
parsed."""

_CHUNK = 1 << 20


class InputFileError(ValueError):
    """An input that is not to be read; the message is one line naming the path."""


def file_kind(mode: int) -> str:
    """A non-regular file's kind in words (``a FIFO``, ``a folder``, ...), for one-line refusals
    of inputs and outputs alike."""
    for test, word in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
                       (stat.S_ISDIR, "a folder")):
        if test(mode):
            return word
    return "not a regular file"


def _where(path: str | os.PathLike, what: str | None) -> str:
    """The start of a message: ``what`` (an option, e.g. ``--top``) and the path."""
    return f"{what} {os.fspath(path)}" if what else os.fspath(path)


def _open(path: str | os.PathLike, what: str | None) -> tuple[int, int]:
    """A read-only descriptor on the regular file ``path`` and its size; never blocks."""
    where = _where(path, what)
    try:
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
    except FileNotFoundError:
        raise InputFileError(f"{where}: no such file") from None
    except IsADirectoryError:
        raise InputFileError(f"{where}: is a folder, expected a file") from None
    except OSError as exc:
        raise InputFileError(f"{where}: cannot read ({exc.strerror or exc})") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise InputFileError(f"{where}: is {file_kind(st.st_mode)}, not a regular file; give "
                                 "a file")
        if st.st_size > MAX_INPUT_BYTES:
            raise InputFileError(f"{where}: {st.st_size:,} bytes, more than the "
                                 f"{MAX_INPUT_BYTES:,} an input may hold")
        os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd, st.st_size


def check_input_file(path: str | os.PathLike, what: str | None = None) -> Path:
    """Refuse, without blocking, an input that is missing or not a regular file (a FIFO, a
    device, a socket, a folder) or larger than :data:`MAX_INPUT_BYTES`; return it as a Path.

    For inputs a library opens itself (a checkpoint, an ONNX model, an image).

    Raises:
        InputFileError: one line naming ``what`` and the path.
    """
    fd, _ = _open(path, what)
    os.close(fd)
    return Path(path)


def read_input_bytes(path: str | os.PathLike, what: str | None = None,
                     max_bytes: int = MAX_INPUT_BYTES) -> bytes:
    """The whole regular file ``path``, refused at once past ``max_bytes`` (see
    :func:`check_input_file`); a file that grows while read is cut at the bound and refused."""
    fd, size = _open(path, what)
    where = _where(path, what)
    if size > max_bytes:
        os.close(fd)
        raise InputFileError(f"{where}: {size:,} bytes, more than the {max_bytes:,} it may hold")
    with os.fdopen(fd, "rb") as handle:
        data = handle.read(max_bytes + 1)
    if len(data) > max_bytes:
        raise InputFileError(f"{where}: more than the {max_bytes:,} bytes it may hold")
    return data


def read_input_text(path: str | os.PathLike, what: str | None = None,
                    max_line: int = MAX_LINE_BYTES, encoding: str = "utf-8") -> str:
    """The regular file ``path`` as text, line ends untranslated.

    Read chunk by chunk: a NUL byte (a binary file) or a line longer than ``max_line`` bytes is
    refused as soon as it is read, naming its line, so ``/dev/zero``-like content never fills
    memory. ``encoding="utf-8-sig"`` drops a leading byte-order mark.

    Raises:
        InputFileError: one line naming ``what``, the path and, where it applies, the line.
    """
    fd, _ = _open(path, what)
    where = _where(path, what)
    chunks: list[bytes] = []
    line, run = 1, 0  # the current line number and its length so far
    with os.fdopen(fd, "rb") as handle:
        while chunk := handle.read(_CHUNK):
            nul = chunk.find(b"\0")
            if nul >= 0:
                line += chunk.count(b"\n", 0, nul)
                raise InputFileError(f"{where}:{line}: not a text file (a NUL byte)")
            last = chunk.rfind(b"\n")
            if last < 0:
                run += len(chunk)
            else:
                first = chunk.find(b"\n")
                longest = max(run + first, *(len(piece) for piece in
                                             chunk[first + 1:last].split(b"\n")))
                if longest > max_line:
                    raise InputFileError(f"{where}: a line of over {max_line:,} bytes near "
                                         f"line {line}; not a text file of records")
                line += chunk.count(b"\n")
                run = len(chunk) - last - 1
            if run > max_line:
                raise InputFileError(f"{where}:{line}: a line of over {max_line:,} bytes; not "
                                     "a text file of records")
            chunks.append(chunk)
    data = b"".join(chunks)
    try:
        return data.decode(encoding)
    except UnicodeDecodeError as exc:
        line = data.count(b"\n", 0, exc.start) + 1
        raise InputFileError(f"{where}:{line}: not UTF-8 text ({exc.reason} at byte "
                             f"{exc.start})") from None
