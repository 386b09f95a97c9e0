"""MOTChallenge-style box files and cross-view prediction CSVs: reading, validation, writing.

Box files (one per sequence and view, e.g. the CVMHAT ``NAME_top.txt`` / ``NAME_hor.txt``) hold one
box per line, ``frame,id,x,y,w,h[,...]``: ``frame`` is 1-based, ``(x, y)`` is the top-left corner
in pixels and ``(w, h)`` the size; trailing fields (``-1,-1,-1,-1`` in MOT files) are ignored,
but for the detector's score (MOT's 7th field, ``conf``) when ``min_score`` drops the weak boxes.
A first line of column names is skipped, and a file that counts frames from 0 is read with
``first_frame=0`` (its frames become 1-based), each with a :class:`BoxFileNote`.
Prediction files hold the cross-view pairs of an association run, ``frame,top_id,hor_id`` with that
header, one matched pair per line.

Parsing is vectorised (one ``np.loadtxt`` call plus array checks) because the CLI reads several
files of ~10k lines per sequence; only when that fast path rejects a file does a line-by-line scan
run, to name the exact bad line. Every problem is a :class:`BoxFileError` whose message is one line,
``"<path>:<line>: <what is wrong>"``, so editors and terminals can jump to it: lines are counted at
``\\n`` only (``\\r\\n`` too), and a file holding another line-break character (form feed,
U+2028, ...) is refused at that line. A box file without any box is refused as well. Files are
opened through :mod:`~xvmatch.core.input_files`: a FIFO, a device or a folder is refused at
once, a NUL byte or a line over a megabyte as soon as it is read. Frames and ids are integers
read exactly: one beyond 2**53 in size is refused, as a float would round it onto another.

All writes go through :func:`~xvmatch.core.atomic_files.atomic_write_text` (temporary file
in the same directory, then ``os.replace``), so a crash never leaves a half-written file that a
later run would trust.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.input_files import InputFileError, read_input_text

__all__ = [
    "FALSE_POSITIVE",
    "MAX_PIXELS",
    "PREDICTION_HEADER",
    "SCORE_NAMES",
    "BoxFileError",
    "BoxFileNote",
    "FrameBoxes",
    "align_frames",
    "align_views",
    "check_common_frames",
    "read_mot_boxes",
    "read_predictions",
    "scale_frames",
    "shift_frames",
    "stack_frames",
    "write_mot_boxes",
    "write_predictions",
]

PREDICTION_HEADER = "frame,top_id,hor_id"
"""First line of every prediction CSV."""

FALSE_POSITIVE: int = -1
"""Ground-truth id of a detection that stands for no person (it overlaps no ground-truth box
enough); evaluations score pairs that include one as false positives."""

# Largest integer a float64 holds exactly: frames and ids beyond it cannot round-trip.
_MAX_EXACT_INT = 2**53

MAX_PIXELS = 1_000_000.0
"""Largest |x|, |y|, w or h a box file may hold, in pixels: no camera's image is a million pixels
across, so a value beyond is a data error (an exponent or unit slip). Refused at its line
because it is silent downstream: from every candidate camera location such a box lies at the same
bearing and a depth that dwarfs everyone else's, so in each hypothesis that sees it, it alone
sets the depth scale of Eq. 11 and every other depth ratio saturates; one box at x = 1e22 took a
frame's learned association from 11 pairs to 0."""

# What np.loadtxt accepts as a float, spelled out so the line-by-line scan agrees with the fast
# path (Python's float() would also take "1_000" or non-ASCII digits, which loadtxt rejects).
_NUMBER = re.compile(
    r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)", re.IGNORECASE
)


# Characters that ``str.splitlines`` breaks lines at besides "\n" (and a "\r" not followed by
# "\n"): lines are counted at "\n" only, as editors and ``grep -n`` count them, and one of these
# inside a line is refused with its line number rather than read as a line break or as content.
_OTHER_BREAKS = re.compile("[\v\f\x1c\x1d\x1e\x85\u2028\u2029]|\r(?!\n)")


class BoxFileError(ValueError):
    """A box or prediction file that cannot be read as such.

    The message is always a single line, ``"<path>:<line>: <what is wrong>"``; the line number is
    left out only for whole-file problems (a missing file, a FIFO, a device or a folder).
    ``path`` and ``line`` are also kept as attributes for programs that want them.
    """

    def __init__(self, message: str, *, path: str | None = None, line: int | None = None):
        super().__init__(" ".join(str(message).splitlines()))
        self.path = path
        self.line = line


class BoxFileNote(UserWarning):
    """Something the box reader did that a user should hear of but that is no problem: a
    header line skipped, rows dropped by ``min_score``, frames counted from 0. The CLI prints
    these as ``xvmatch: note: ...`` lines (:func:`xvmatch.commands._options.read_boxes`)."""


SCORE_NAMES = ("conf", "confidence", "score", "det_score")
"""Header names (any case) of the detector's score column; without a header the score is the
7th field, MOTChallenge's ``conf`` (``frame,id,bb_left,bb_top,bb_width,bb_height,conf,...``)."""


def _error(path: str | os.PathLike, line: int | None, what: str) -> BoxFileError:
    """Build the one-line error for ``path`` (and ``line`` when given)."""
    where = f"{os.fspath(path)}:{line}" if line is not None else os.fspath(path)
    return BoxFileError(f"{where}: {what}", path=os.fspath(path), line=line)


@dataclass(frozen=True, eq=False)
class FrameBoxes:
    """The boxes of one frame of one view.

    Equality is identity (``eq=False``): comparing records that hold arrays element-wise is
    ambiguous, compare ``ids`` and ``boxes`` with numpy instead.

    Attributes:
        frame: 1-based frame number.
        ids: (N,) int64 person ids, in file order.
        boxes: (N, 4) float64 ``x, y, w, h`` in pixels, ``(x, y)`` the top-left corner.
    """

    frame: int
    ids: np.ndarray
    boxes: np.ndarray

    def __post_init__(self) -> None:
        raw_ids = np.asarray(self.ids)
        if raw_ids.size and raw_ids.dtype.kind not in "iu":
            if raw_ids.dtype.kind != "f" or not np.all(raw_ids == np.round(raw_ids)):
                raise ValueError(
                    f"FrameBoxes(frame={self.frame}): ids must be integers, got {raw_ids!r}"
                )
        ids = raw_ids.astype(np.int64, copy=False)
        boxes = np.asarray(self.boxes, dtype=np.float64)
        if boxes.size == 0 and ids.size == 0:
            ids, boxes = ids.reshape(0), boxes.reshape(0, 4)
        if ids.ndim != 1 or boxes.shape != (ids.shape[0], 4):
            raise ValueError(
                f"FrameBoxes(frame={self.frame}): ids must have shape (N,) and boxes (N, 4), "
                f"got ids {ids.shape} and boxes {boxes.shape}"
            )
        object.__setattr__(self, "frame", int(self.frame))
        object.__setattr__(self, "ids", ids)
        object.__setattr__(self, "boxes", boxes)

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def stack_frames(frames: Mapping[int, FrameBoxes]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every box of ``{frame: FrameBoxes}`` in one table, frames ascending: the frame numbers
    ``(N,)``, the ids ``(N,)`` and the boxes ``(N, 4)`` (empty arrays for no box)."""
    order = sorted(f for f in frames if len(frames[f].ids))
    if not order:
        return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros((0, 4))
    return (np.concatenate([np.full(len(frames[f].ids), f) for f in order]),
            np.concatenate([np.asarray(frames[f].ids) for f in order]),
            np.concatenate([np.asarray(frames[f].boxes, float).reshape(-1, 4) for f in order]))


def shift_frames(frames: Mapping[int, FrameBoxes], offset: int) -> dict[int, FrameBoxes]:
    """A view re-timed by ``offset`` frames: the result's frame ``f`` holds input frame
    ``f + offset`` (the convention of ``xvmatch offset``: top frame = horizontal frame + offset),
    so a shifted top view lines up with the horizontal one. Frames that would fall below 1 are
    dropped."""
    offset = int(offset)
    return {
        f - offset: FrameBoxes(f - offset, r.ids, r.boxes)
        for f, r in sorted(frames.items())
        if f - offset >= 1
    }


def align_frames(views: Sequence[Mapping[int, FrameBoxes]], offsets: Sequence[int]
                 ) -> tuple[list[dict[int, FrameBoxes]], list[int]]:
    """The views (top first) re-timed so that top frame ``t + N_k`` and frame ``t`` of each
    horizontal view ``k`` share a number (``N_k``: ``offsets[k]``, the convention of ``xvmatch
    offset``: top frame = horizontal frame + N), no frame dropped: view ``v``'s frame ``f``
    becomes ``f + shift_v``, every shift >= 0 and the smallest 0 (the views that start earlier
    are moved later). Returns the views and the shifts. For commands that write each view in
    its own timing (``track``, ``associate-multi``); :func:`shift_frames` puts the top view on
    the horizontal timeline instead."""
    if len(views) != len(offsets) + 1:
        raise ValueError(f"{len(views)} views need {len(views) - 1} offsets, got {len(offsets)}")
    base = max(0, *(-int(n) for n in offsets)) if len(offsets) else 0
    shifts = [base, *(int(n) + base for n in offsets)]
    return [shift_frames(v, -s) for v, s in zip(views, shifts, strict=True)], shifts


def align_views(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes], offset: int
                ) -> tuple[dict[int, FrameBoxes], dict[int, FrameBoxes]]:
    """:func:`align_frames` of a top and a horizontal view: top frame ``f + offset`` and
    horizontal frame ``f`` share a number."""
    (top, hor), _ = align_frames([top, hor], [offset])
    return top, hor


def _frame_span(frames: Mapping[int, FrameBoxes]) -> str:
    """``first..last`` of the frames with boxes, or ``none``."""
    used = [f for f, rec in frames.items() if len(rec)]
    return f"{min(used)}..{max(used)}" if used else "none"


def check_common_frames(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                        offset: int = 0, names: tuple[str, str] = ("top", "horizontal"),
                        what: str = "nothing to pair") -> None:
    """Refuse a top and a horizontal view that share no frame with boxes in both once the top
    one is re-timed by ``offset`` (top frame = horizontal frame + offset): pairing them gives
    an empty result that would pass for a real one ("wrote 0 pairs").

    Args:
        top: the top view, in its file's frame numbers.
        hor: the horizontal view, in its file's frame numbers.
        offset: the offset applied (``xvmatch offset``'s convention), 0 for none.
        names: the two files (or views) as the message names them.
        what: what the refusal means for the command, first in the message.

    Raises:
        ValueError: one line naming both files, their frame ranges and the offset.
    """
    offset = int(offset)
    top_used = {f for f, rec in top.items() if len(rec)}
    if any(len(rec) and f + offset in top_used for f, rec in hor.items()):
        return
    shifted = (f" after --offset {offset} (top frame = horizontal frame {offset:+d})"
               if offset else "")
    raise ValueError(f"{what}: {names[0]} and {names[1]} share no frame with boxes in both "
                     f"views{shifted} (top frames {_frame_span(top)}, horizontal frames "
                     f"{_frame_span(hor)}); check the files and --offset")


def scale_frames(frames: Mapping[int, FrameBoxes], factor: float) -> dict[int, FrameBoxes]:
    """A view's boxes at another resolution: every coordinate multiplied by ``factor`` (the same
    video exported ``factor`` times as wide)."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"scale factor must be a finite number > 0, got {factor}")
    return {f: FrameBoxes(f, r.ids, r.boxes * float(factor)) for f, r in frames.items()}


# --------------------------------------------------------------------------------------------
# Reading helpers


@dataclass(frozen=True)
class _Column:
    """One leading column of a table: its name and what values it admits."""

    name: str
    kind: str  # "frame" (integer >= 1), "box_frame" (the same in a box file, whose message
    # names --first-frame), "frame0" (integer >= 0), "id" (integer), "coord" (|v| <=
    # MAX_PIXELS), "size" (0 < v <= MAX_PIXELS), "number" (any finite number)


_FRAME_KINDS = ("frame", "box_frame", "frame0")

_BOX_COLUMNS = (
    _Column("frame", "box_frame"),
    _Column("id", "id"),
    _Column("x", "coord"),
    _Column("y", "coord"),
    _Column("w", "size"),
    _Column("h", "size"),
)
_PRED_COLUMNS = (_Column("frame", "frame"), _Column("top_id", "id"), _Column("hor_id", "id"))


def _read_text(path: str | os.PathLike) -> str:
    """The whole file as text, line ends untranslated (:func:`_split_lines` splits them), a
    byte-order mark dropped, read through :func:`~xvmatch.core.input_files.read_input_text`
    (no blocking on a FIFO, no device, no NUL byte, no line over a megabyte), its refusals
    turned into :class:`BoxFileError`."""
    try:
        return read_input_text(path, encoding="utf-8-sig")
    except InputFileError as exc:
        message = str(exc)
        numbered = re.match(re.escape(os.fspath(path)) + r":(\d+): ", message)
        line = int(numbered.group(1)) if numbered else None
        raise BoxFileError(message, path=os.fspath(path), line=line) from None
    except OSError as exc:  # a read error after the open
        raise _error(path, None, f"cannot read: {exc.strerror or exc}") from None


def _split_lines(path: str | os.PathLike, text: str) -> list[str]:
    """The lines of ``text`` split at "\n" only (a "\r\n" end loses its "\r"), so that item
    ``i`` is line ``i + 1`` of the file; any other line-break character is a
    :class:`BoxFileError` naming its line."""
    odd = _OTHER_BREAKS.search(text)
    if odd is not None:
        line = text.count("\n", 0, odd.start()) + 1
        raise _error(path, line, f"line-break character U+{ord(odd.group()):04X} inside the "
                                 "line; lines must end in \\n or \\r\\n")
    lines = text.split("\n")
    if lines[-1] == "":
        lines.pop()
    return [ln[:-1] if ln.endswith("\r") else ln for ln in lines]


def _require_rows(path: str | os.PathLike, data: np.ndarray) -> None:
    """Refuse a box file without a single box (empty, or blank lines only): every command that
    reads one needs boxes, and an empty result would pass for a real one."""
    if data.shape[0] == 0:
        raise _error(path, None, "no boxes (the file is empty or holds only blank lines)")


def _is_int(values: np.ndarray) -> np.ndarray:
    """Element-wise: finite, integer-valued and below :data:`_MAX_EXACT_INT` in size.

    A value of that size or more may be the rounding of another integer's text (2**53 + 1
    reads as 2**53), so it fails here and :func:`_check_value` judges its text instead."""
    with np.errstate(invalid="ignore"):
        exact = np.abs(values) < _MAX_EXACT_INT
        return np.isfinite(values) & (values == np.round(values)) & exact


def _columns_ok(data: np.ndarray, columns: Sequence[_Column]) -> bool:
    """Vectorised version of the per-value checks of :func:`_check_value`."""
    if not np.isfinite(data).all():
        return False
    for k, col in enumerate(columns):
        values = data[:, k]
        if col.kind in _FRAME_KINDS and not (
                _is_int(values) & (values >= (col.kind != "frame0"))).all():
            return False
        if col.kind == "id" and not _is_int(values).all():
            return False
        if col.kind == "size" and not (values > 0).all():
            return False
        if col.kind in ("coord", "size") and not (np.abs(values) <= MAX_PIXELS).all():
            return False
    return True


def _repeats(frames: np.ndarray, keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rows whose ``(frame, key)`` already occurred on an earlier row, vectorised.

    Returns:
        ``(rows, firsts)``: indices of the repeating rows in ascending order, and for each the
        index of the first row with the same ``(frame, key)``.
    """
    n = frames.shape[0]
    if n < 2:
        return np.empty(0, dtype=np.intp), np.empty(0, dtype=np.intp)
    order = np.lexsort((keys, frames))  # stable: equal keys stay in file order
    f, k = frames[order], keys[order]
    same = np.r_[False, (f[1:] == f[:-1]) & (k[1:] == k[:-1])]
    run_start = np.maximum.accumulate(np.where(same, 0, np.arange(n)))
    dup = np.flatnonzero(same)
    rows, firsts = order[dup], order[run_start[dup]]
    by_row = np.argsort(rows, kind="stable")
    return rows[by_row], firsts[by_row]


def _line_numbers(lines: Sequence[str], first_lineno: int) -> np.ndarray:
    """File line number of each non-blank line, i.e. of each row of the parsed table."""
    return np.flatnonzero([bool(ln.strip()) for ln in lines]) + first_lineno


def _integer_problem(text: str, value: float, col: _Column) -> str | None:
    """What is wrong with a frame or id field ``text`` (read as ``value``), or None.

    From :data:`_MAX_EXACT_INT` up the float may be another integer's rounding, so there the
    text itself is read exactly: frame 9007199254740993 would otherwise become 2**53 and be
    matched with that frame."""
    if value != round(value):
        return f"{col.name} must be an integer, got {text!r}"
    if abs(value) < _MAX_EXACT_INT:
        return None
    shown = text if len(text) <= 40 else text[:37] + "..."
    try:
        exact = Fraction(text)
    except ValueError:  # digits beyond what Python converts to an integer
        exact = None
    if exact is not None and exact.denominator != 1:
        return f"{col.name} must be an integer, got {shown!r}"
    if exact is None or abs(exact) > _MAX_EXACT_INT:
        return (f"{col.name} {shown} is beyond 2**53 = {_MAX_EXACT_INT} in size, the largest "
                "integer read exactly; renumber the file")
    return None


def _check_value(text: str, col: _Column) -> str | float:
    """Parse one field; returns the value or, when it is invalid, what is wrong with it."""
    if not _NUMBER.fullmatch(text):
        return f"{col.name} is not a number: {text!r}"
    value = float(text)
    if not np.isfinite(value):
        return f"{col.name} must be finite, got {text!r}"
    if col.kind in (*_FRAME_KINDS, "id"):
        problem = _integer_problem(text, value, col)
        if problem:
            return problem
        if col.kind == "frame" and value < 1:
            return f"frame must be >= 1 (frames are 1-based), got {text!r}"
        if col.kind == "box_frame" and value < 1:
            return (f"frame must be >= 1 (frames are 1-based, as in MOTChallenge; a file that "
                    f"counts from 0 needs --first-frame 0), got {text!r}")
        if col.kind == "frame0" and value < 0:
            return f"frame must be >= 0 (--first-frame 0: frames count from 0), got {text!r}"
    if col.kind == "size" and value <= 0:
        return f"box size {col.name} must be > 0, got {text!r}"
    if col.kind in ("coord", "size") and abs(value) > MAX_PIXELS:
        return (f"{col.name} = {text} is far outside any image (|{col.name}| must be at most "
                f"{MAX_PIXELS:.0f} pixels)")
    return value


def _scan(
    path: str | os.PathLike,
    rows: Sequence[tuple[int, str]],
    columns: Sequence[_Column],
    exact_fields: bool,
) -> np.ndarray:
    """Line-by-line parse that raises on the first bad line; the slow, precise path.

    Args:
        rows: ``(line_number, text)`` of the non-blank data lines.
        columns: the leading columns to parse; later fields are ignored unless ``exact_fields``.
        exact_fields: whether a line must have exactly ``len(columns)`` fields.

    Returns:
        (M, len(columns)) float64 values, when every line is valid.
    """
    ncols = len(columns)
    spelled = ",".join(c.name for c in columns)
    out = np.empty((len(rows), ncols), dtype=np.float64)
    for r, (lineno, line) in enumerate(rows):
        fields = [f.strip() for f in line.split(",")]
        if len(fields) < ncols or (exact_fields and len(fields) != ncols):
            need = f"exactly {ncols}" if exact_fields else f"at least {ncols}"
            raise _error(
                path,
                lineno,
                f"expected {need} comma-separated fields ({spelled}), "
                f"got {len(fields)}: {line.strip()!r}",
            )
        for k, col in enumerate(columns):
            value = _check_value(fields[k], col)
            if isinstance(value, str):
                raise _error(path, lineno, value)
            out[r, k] = value
    return out


def _parse_table(
    path: str | os.PathLike,
    lines: Sequence[str],
    first_lineno: int,
    columns: Sequence[_Column],
    exact_fields: bool,
) -> np.ndarray:
    """Parse and validate data lines into an (M, len(columns)) float64 array, fast path first.

    The fast path is one ``np.loadtxt`` call and vectorised checks; if anything fails there, the
    line-by-line :func:`_scan` runs and raises with the exact line (or, should the two ever
    disagree, returns its own parse, so the scan is the single definition of what is valid).
    Blank lines are skipped: row ``i`` of the result is the ``i``-th non-blank line.
    """
    ncols = len(columns)
    text_rows = [ln for ln in lines if ln.strip()]
    if not text_rows:
        return np.empty((0, ncols), dtype=np.float64)
    try:
        data = np.loadtxt(
            text_rows,
            delimiter=",",
            usecols=None if exact_fields else range(ncols),
            dtype=np.float64,
            comments=None,
            ndmin=2,
        )
    except ValueError:
        data = None
    if data is not None and data.shape[1] == ncols and _columns_ok(data, columns):
        return data
    rows = [(first_lineno + i, ln) for i, ln in enumerate(lines) if ln.strip()]
    return _scan(path, rows, columns, exact_fields)


def _check_repeats(
    path: str | os.PathLike,
    lines: Sequence[str],
    first_lineno: int,
    data: np.ndarray,
    key_column: int,
    label: str,
    drop: bool,
) -> np.ndarray:
    """Raise on (or, with ``drop``, warn about and remove) a ``label`` repeated within a frame.

    Returns:
        ``data`` without the repeated rows (only ever changed when ``drop``).
    """
    rows, firsts = _repeats(data[:, 0], data[:, key_column])
    if rows.size == 0:
        return data
    linenos = _line_numbers(lines, first_lineno)
    errors = [
        _error(
            path,
            int(linenos[r]),
            f"duplicate {label} {int(data[r, key_column])} in frame {int(data[r, 0])} "
            f"(first on line {linenos[f]})",
        )
        for r, f in zip(rows.tolist(), firsts.tolist(), strict=True)
    ]
    if not drop:
        raise errors[0]
    for error in errors:
        warnings.warn(f"{error}, dropped", stacklevel=3)
    return np.delete(data, rows, axis=0)


# A header field: a column name such as frame, id, bb_left, "bb width", conf (a leading # too).
_HEADER_NAME = re.compile(r"#?\s*[A-Za-z_][\w .\-]*")


def _header_fields(lines: Sequence[str]) -> tuple[int, list[str]] | None:
    """``(index, names)`` of a header line: the first non-blank line when its first six fields
    are not numbers and every field looks like a column name (``frame,id,x,y,w,h,conf``);
    None when the first line is data (or bad data, which the parser then names)."""
    for index, line in enumerate(lines):
        if not line.strip():
            continue
        names = [f.strip() for f in line.split(",")]
        if len(names) >= 6 and all(_HEADER_NAME.fullmatch(n) and not _NUMBER.fullmatch(n)
                                   for n in names[:6]) and all(
                _HEADER_NAME.fullmatch(n) or not n for n in names[6:]):
            return index, [n.lstrip("#").strip().lower() for n in names]
        return None
    return None


def _read_box_table(path: str | os.PathLike, min_score: float | None, first_frame: int
                    ) -> tuple[list[str], np.ndarray]:
    """The lines of a box file and its ``(M, 6)`` table ``frame,id,x,y,w,h``, frames 1-based.

    A header line is skipped (a :class:`BoxFileNote`); with ``first_frame == 0`` frame ``f`` is
    read as ``f + 1`` (a note); with ``min_score`` the rows whose score (the 7th field, or the
    column a header names ``conf``/``score``) is below it are dropped (a note says how many).
    Lines skipped or dropped are blanked, so the returned lines' non-blank ones are the table's
    rows and keep their file line numbers."""
    if first_frame not in (0, 1):
        raise ValueError(f"first_frame must be 0 or 1, got {first_frame!r}")
    if min_score is not None and not math.isfinite(min_score):
        raise ValueError(f"min_score must be a finite number, got {min_score!r}")
    lines = _split_lines(path, _read_text(path))
    header = _header_fields(lines)
    names: list[str] = []
    if header is not None:
        index, names = header
        warnings.warn(BoxFileNote(f"{os.fspath(path)}:{index + 1}: header line skipped "
                                  f"({lines[index].strip()[:60]!r})"), stacklevel=3)
        lines = [*lines[:index], "", *lines[index + 1:]]
    columns = list(_BOX_COLUMNS)
    if first_frame == 0:
        columns[0] = _Column("frame", "frame0")
    score = None
    if min_score is not None:
        named = [k for k, n in enumerate(names) if n in SCORE_NAMES and k >= 6]
        score = named[0] if named else 6
        columns += [_Column(names[k] if k < len(names) else f"field {k + 1}", "number")
                    for k in range(6, score)]
        columns.append(_Column("score", "number"))
        _require_score_field(path, lines, score)
    data = _parse_table(path, lines, 1, columns, False)
    if score is not None and data.shape[0]:
        lines, data = _drop_low_scores(path, lines, data, score, float(min_score))
    if first_frame == 0 and data.shape[0]:
        data[:, 0] += 1
        warnings.warn(BoxFileNote(f"{os.fspath(path)}: frames counted from 0 (--first-frame 0):"
                                  " frame f is read as f + 1, and what xvmatch writes counts "
                                  "from 1"), stacklevel=3)
    return lines, np.ascontiguousarray(data[:, :6])


def _require_score_field(path: str | os.PathLike, lines: Sequence[str], score: int) -> None:
    """Refuse ``min_score`` on a file whose first row has no field ``score`` (0-based): the
    file holds no detector scores to compare with."""
    for lineno, line in enumerate(lines, start=1):
        if line.strip():
            count = len(line.split(","))
            if count <= score:
                raise _error(path, lineno, f"--min-score needs the detector's score in field "
                             f"{score + 1} (MOT: frame,id,x,y,w,h,conf,...), but the line has "
                             f"{count} fields: the file has no score column; drop --min-score")
            return


def _drop_low_scores(path: str | os.PathLike, lines: list[str], data: np.ndarray, score: int,
                     min_score: float) -> tuple[list[str], np.ndarray]:
    """The rows whose score is at least ``min_score``, their dropped lines blanked; a note
    says how many were dropped. A file whose scores are all -1 (MOT's "not given") or whose
    every row falls below is refused."""
    scores = data[:, score]
    where = os.fspath(path)
    if (scores == -1).all():
        raise _error(path, None, f"field {score + 1} is -1 on every row (MOT's 'no score'): the "
                     "file holds no detector scores; drop --min-score")
    keep = scores >= min_score
    if not keep.any():
        raise _error(path, None, f"--min-score {min_score:g} drops every box (scores "
                     f"{scores.min():g}..{scores.max():g} in field {score + 1})")
    dropped = int((~keep).sum())
    if dropped:
        rows = np.flatnonzero([bool(ln.strip()) for ln in lines])[~keep]
        lines = list(lines)
        for row in rows.tolist():
            lines[row] = ""
    warnings.warn(BoxFileNote(f"{where}: --min-score {min_score:g} dropped {dropped} of "
                              f"{scores.size} boxes (score in field {score + 1})"), stacklevel=4)
    return lines, data[keep]


def read_mot_boxes(
    path: str | os.PathLike, *, duplicates: str = "error", allow_empty: bool = False,
    min_score: float | None = None, first_frame: int = 1,
) -> dict[int, FrameBoxes]:
    """Read a MOTChallenge-style box file, ``frame,id,x,y,w,h[,...]`` per line.

    Lines end in ``\\n`` or ``\\r\\n`` and are numbered as editors number them; blank lines
    are skipped; fields after the sixth are ignored (but the score, with ``min_score``). A
    first line of column names (``frame,id,x,y,w,h,conf``: its first six fields not numbers)
    is skipped with a :class:`BoxFileNote`. Integer-valued floats such as
    ``5.0`` are accepted for ``frame`` and ``id`` (some MOT tools write them), ``5.5`` is not.

    Args:
        path: the box file.
        duplicates: what to do with an id that occurs twice in one frame. ``"error"`` (default)
            raises; ``"first"`` keeps the first box and drops the later ones with a
            ``UserWarning`` naming each dropped line. The released CVMHAT annotations need
            ``"first"``: three files have one stray second box for an id (e.g.
            ``V1-S_55-G_1_top.txt`` frame 1 id 11), and in each case the first box is the one
            that continues the track in the neighbouring frames.
        allow_empty: accept a file without boxes (an empty result) instead of raising; only for
            files that may legitimately hold nothing, such as a tracker's output.
        min_score: drop the boxes whose detector score is below it (the 7th field, MOT's
            ``conf``, or the column a header names ``conf``/``score``), with a
            :class:`BoxFileNote` saying how many; None (default) keeps every box.
        first_frame: 1 (default, MOTChallenge) or 0 for a file that counts frames from 0,
            read as ``frame + 1`` (with a note) so that the result is 1-based either way.

    Returns:
        ``{frame: FrameBoxes}`` with keys in ascending order; within a frame, boxes keep the file
        order. Frames without boxes are absent.

    Raises:
        BoxFileError: missing or unreadable file, not a regular file (a FIFO, a device, a
            folder), not text (a NUL byte, a line over a megabyte, not UTF-8), no boxes at all
            (unless ``allow_empty``), a line-break character other than ``\\n`` /
            ``\\r\\n``, fewer than 6 fields, a non-numeric, NaN or infinite field, a frame
            that is not an integer >= 1, a non-integer id, a frame or id beyond 2**53 in size
            (not read exactly), ``w`` or ``h`` <= 0, a coordinate or size beyond
            :data:`MAX_PIXELS`, or (unless ``duplicates="first"``) the same ``(frame, id)``
            twice; with ``min_score``, no score field, scores all -1 (MOT's "none") or every
            box below it. The message names file and line.
        ValueError: ``duplicates`` is neither ``"error"`` nor ``"first"``, ``first_frame``
            neither 0 nor 1, or ``min_score`` not finite.
    """
    if duplicates not in ("error", "first"):
        raise ValueError(f"duplicates must be 'error' or 'first', got {duplicates!r}")
    lines, data = _read_box_table(path, min_score, first_frame)
    if not allow_empty:
        _require_rows(path, data)
    data = _check_repeats(path, lines, 1, data, 1, "id", drop=duplicates == "first")
    if data.shape[0] == 0:
        return {}
    frames = data[:, 0].astype(np.int64)
    order = np.argsort(frames, kind="stable")
    frames = frames[order]
    ids = data[order, 1].astype(np.int64)
    boxes = np.ascontiguousarray(data[order, 2:6])
    starts = np.flatnonzero(np.r_[True, frames[1:] != frames[:-1]])
    ends = np.r_[starts[1:], frames.size]
    return {
        int(frames[s]): FrameBoxes(int(frames[s]), ids[s:e], boxes[s:e])
        for s, e in zip(starts.tolist(), ends.tolist(), strict=True)
    }


def read_predictions(path: str | os.PathLike) -> dict[int, list[tuple[int, int]]]:
    """Read a prediction CSV of cross-view pairs, header ``frame,top_id,hor_id``.

    Args:
        path: the CSV file; the first line must be the header, blank lines are skipped.

    Returns:
        ``{frame: [(top_id, hor_id), ...]}`` with frames ascending and pairs in file order.
        Frames without a predicted pair are absent (an empty prediction, not an error).

    Raises:
        BoxFileError: missing file, not a regular text file (as :func:`read_mot_boxes`), wrong
            header, a line-break character other than ``\\n`` / ``\\r\\n``, not exactly 3
            fields, a non-integer value or one beyond 2**53 in size, a frame < 1, or a
            ``top_id`` or ``hor_id`` used twice in one frame (the association is one-to-one).
            The message names file and line.
    """
    lines = _split_lines(path, _read_text(path))
    if not lines or not lines[0].strip():
        raise _error(path, 1, f"missing header, expected {PREDICTION_HEADER!r}")
    header = ",".join(f.strip() for f in lines[0].split(","))
    if header != PREDICTION_HEADER:
        raise _error(path, 1, f"wrong header {lines[0].strip()!r}, expected {PREDICTION_HEADER!r}")
    data = _parse_table(path, lines[1:], 2, _PRED_COLUMNS, True)
    for column, label in ((1, "top_id"), (2, "hor_id")):
        _check_repeats(path, lines[1:], 2, data, column, label, drop=False)
    data = data.astype(np.int64)
    order = np.argsort(data[:, 0], kind="stable")
    result: dict[int, list[tuple[int, int]]] = {}
    for frame, top_id, hor_id in data[order].tolist():
        result.setdefault(frame, []).append((top_id, hor_id))
    return result


# --------------------------------------------------------------------------------------------
# Writing


def _fmt(value: float) -> str:
    """Shortest text that reads back to the same float; integers without ``.0`` (MOT style)."""
    text = repr(float(value))
    return text[:-2] if text.endswith(".0") else text


def write_mot_boxes(path: str | os.PathLike, frames: Mapping[int, FrameBoxes]) -> None:
    """Write boxes as a MOTChallenge file, ``frame,id,x,y,w,h,-1,-1,-1,-1`` per box.

    Frames are written in ascending order, boxes within a frame in record order; values are
    written exactly (shortest round-trip text), so ``read_mot_boxes`` gives them back unchanged.
    Frames with no boxes leave no trace in the file. The write is atomic.

    Args:
        path: destination file.
        frames: ``{frame: FrameBoxes}``; each key must equal its record's ``frame``.

    Raises:
        ValueError: a key that differs from its record's frame, a frame < 1, a non-finite value,
            ``w`` or ``h`` <= 0, or an id twice in one frame; nothing is written then.
    """
    out: list[str] = []
    for key in sorted(frames):
        rec = frames[key]
        if int(key) != rec.frame or rec.frame < 1:
            raise ValueError(
                f"write_mot_boxes({os.fspath(path)}): frame key {key} must be >= 1 and equal "
                f"to its record's frame {rec.frame}"
            )
        if len(rec) == 0:
            continue
        if not np.isfinite(rec.boxes).all() or not (rec.boxes[:, 2:] > 0).all():
            raise ValueError(
                f"write_mot_boxes({os.fspath(path)}): frame {key} has a non-finite box or w/h <= 0"
            )
        if np.unique(rec.ids).size != rec.ids.size:
            raise ValueError(f"write_mot_boxes({os.fspath(path)}): frame {key} repeats an id")
        for pid, box in zip(rec.ids.tolist(), rec.boxes.tolist(), strict=True):
            out.append(f"{key},{pid},{','.join(_fmt(v) for v in box)},-1,-1,-1,-1\n")
    atomic_write_text(path, "".join(out))


def write_predictions(
    path: str | os.PathLike, pairs: Mapping[int, Sequence[tuple[int, int]]]
) -> None:
    """Write cross-view pairs as a prediction CSV (header ``frame,top_id,hor_id``), atomically.

    Rows are sorted by frame; pairs of a frame keep their given order.

    Args:
        path: destination file.
        pairs: ``{frame: [(top_id, hor_id), ...]}``.

    Raises:
        ValueError: a frame < 1 or a top or horizontal id used twice in one frame, which
            :func:`read_predictions` would reject; nothing is written then.
    """
    out = [PREDICTION_HEADER + "\n"]
    for frame in sorted(pairs):
        frame_pairs = [(int(t), int(h)) for t, h in pairs[frame]]
        tops = [t for t, _ in frame_pairs]
        hors = [h for _, h in frame_pairs]
        if int(frame) < 1 or len(set(tops)) != len(tops) or len(set(hors)) != len(hors):
            raise ValueError(
                f"write_predictions({os.fspath(path)}): frame {frame} must be >= 1 and use each "
                "top_id and hor_id at most once"
            )
        out.extend(f"{int(frame)},{t},{h}\n" for t, h in frame_pairs)
    atomic_write_text(path, "".join(out))
