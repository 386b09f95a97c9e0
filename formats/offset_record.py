"""The offset record ``xvmatch track`` writes beside its tracks (``offset.json``,
``{"offset": N}``: top frame = horizontal frame + N) and ``xvmatch evaluate --tracks`` reads
back, checked field by field; ``xvmatch associate --offset`` writes the same record beside its
predictions (:func:`predictions_offset_path`: ``PRED.offset.json``), which ``xvmatch evaluate``
reads."""

from __future__ import annotations

import json
import os

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.input_files import InputFileError, read_input_bytes

__all__ = ["OFFSET_RECORD_BYTES", "predictions_offset_path", "read_offset_record",
           "write_offset_record"]

OFFSET_RECORD_BYTES = 4_096
"""Largest offset record read (``track``'s ``offset.json``, ``{"offset": N}``: under 30 bytes)."""


def predictions_offset_path(predictions: str | os.PathLike) -> str:
    """Where ``associate`` records the offset it applied to a predictions CSV: beside it,
    ``PRED.offset.json`` (``pred.csv`` -> ``pred.csv.offset.json``)."""
    return os.fspath(predictions) + ".offset.json"


def write_offset_record(path: str | os.PathLike, offset: int) -> None:
    """Write ``{"offset": offset}`` to ``path`` atomically."""
    atomic_write_text(path, json.dumps({"offset": int(offset)}) + "\n")


def read_offset_record(path: str | os.PathLike, max_offset: int) -> int:
    """The offset in an offset record (``{"offset": N}``, as ``xvmatch track`` writes it
    beside its tracks), checked as ``--offset N`` is: an integer (not a bool, not a float, even
    a whole one) with ``|N| <= max_offset`` (``--offset``'s bound). Read without blocking
    and at most :data:`OFFSET_RECORD_BYTES` bytes.

    Raises:
        ValueError: one line naming the file and the field, ending with what to do.
    """
    fix = "pass --offset N"
    where = os.fspath(path)
    try:
        doc = json.loads(read_input_bytes(path, max_bytes=OFFSET_RECORD_BYTES).decode("utf-8"))
    except InputFileError as exc:
        raise ValueError(f"{exc}; {fix}") from None
    except ValueError as exc:  # JSON and UTF-8 errors, digits past Python's limit
        first = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise ValueError(f"{where}: not the offset record that xvmatch track or associate "
                         f"writes ({first}); {fix}") from None
    if not isinstance(doc, dict) or "offset" not in doc:
        raise ValueError(f"{where}: not the offset record that xvmatch track or associate "
                         f'writes (expected {{"offset": N}}); {fix}')
    offset = doc["offset"]
    if isinstance(offset, bool) or not isinstance(offset, int):
        raise ValueError(f"{where}: field 'offset' must be an integer number of frames, got "
                         f"{str(offset)[:40]!r}; {fix}")
    if abs(offset) > max_offset:
        got = str(offset) if len(str(offset)) <= 24 else f"{str(offset)[:20]}..."
        raise ValueError(f"{where}: field 'offset' must be in -{max_offset}.."
                         f"{max_offset} frames (as --offset), got {got}; {fix}")
    return offset
