"""How the commands read box files: a header line skipped, ``--min-score`` (the detector's
score column) and ``--first-frame`` (files counting from 0), once for every command.

A command adds the options with :func:`add_box_reading_options` (or
``add_box_inputs(parser, reading=True)`` of :mod:`xvmatch.commands._options`), builds one
:class:`BoxReading` with :func:`box_reading` and reads each file with :func:`read_boxes` (boxes
by person id) or :func:`read_detections` (every row, for ``track`` and ``associate-multi``); the
reader's notes and warnings come out as ``xvmatch: note: ...`` and ``xvmatch: warning: ...``
lines. The reading itself is :func:`xvmatch.formats.mot_boxes.read_mot_boxes`'s.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass

from xvmatch.commands._types import float_in

__all__ = ["BoxReading", "add_box_reading_options", "box_reading", "read_boxes",
           "read_detections"]


@dataclass(frozen=True)
class BoxReading:
    """How a command reads its box files, beyond ``--duplicates``.

    Attributes:
        min_score: ``--min-score``: drop the boxes whose detector score (MOT's 7th field,
            ``conf``) is below it; None keeps every box.
        first_frame: ``--first-frame``: 1 (MOTChallenge) or 0 for files counting from 0.
    """

    min_score: float | None = None
    first_frame: int = 1


def add_box_reading_options(parser, min_score: bool = True) -> None:
    """``--min-score`` (unless not ``min_score``: ``evaluate``, whose files are the ground
    truth) and ``--first-frame`` on a parser or an argument group; a command that adds them
    reads its files with ``read_boxes(path, duplicates, box_reading(args))``."""
    if min_score:
        parser.add_argument(
            "--min-score", default=None, metavar="S",
            type=float_in(-1e6, 1e6, "a detector's confidence, as in the score column"),
            help="drop the boxes whose detector score (MOT's 7th field, conf; or the column a "
            "header line names conf or score) is below S, in [-1e6, 1e6], with a note of how "
            "many; a file without scores is an error (default: keep every box)")
    parser.add_argument(
        "--first-frame", type=int, choices=(0, 1), default=1, metavar="{0,1}",
        help="the number of a box file's first frame: 1 (default, as MOTChallenge) or 0 for "
        "files that count from 0 (read as frame + 1, with a note; outputs count from 1)")


def box_reading(args: argparse.Namespace) -> BoxReading:
    """The :class:`BoxReading` of the options of :func:`add_box_reading_options` (the
    defaults for a command without them)."""
    return BoxReading(getattr(args, "min_score", None), getattr(args, "first_frame", 1))


def _print_reader_messages(caught) -> None:
    """The box reader's warnings as ``xvmatch: warning: ...`` lines on stderr, its
    :class:`~xvmatch.formats.mot_boxes.BoxFileNote` as ``xvmatch: note: ...`` lines."""
    from xvmatch.formats.mot_boxes import BoxFileNote

    for w in caught:
        kind = "note" if issubclass(w.category, BoxFileNote) else "warning"
        print(f"xvmatch: {kind}: {w.message}", file=sys.stderr)


def read_boxes(path: str, duplicates: str, reading: BoxReading = BoxReading()):
    """``{frame: FrameBoxes}`` of a MOT box file read as ``reading`` says (a header line
    skipped, weak boxes dropped, frames from 0); the reader's warnings and notes are printed
    on stderr as ``xvmatch: warning: ...`` and ``xvmatch: note: ...`` lines."""
    import warnings

    from xvmatch.formats.mot_boxes import read_mot_boxes

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = read_mot_boxes(path, duplicates=duplicates, min_score=reading.min_score,
                                first_frame=reading.first_frame)
    _print_reader_messages(caught)
    return frames


def read_detections(path: str, reading: BoxReading = BoxReading()):
    """:func:`xvmatch.formats.detection_rows.read_detection_rows` of a detection file (``track``
    and ``associate-multi``: every row kept, ids may repeat) read as ``reading`` says, its
    notes printed as :func:`read_boxes` prints them."""
    import warnings

    from xvmatch.formats.detection_rows import read_detection_rows

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        rows = read_detection_rows(path, min_score=reading.min_score,
                                   first_frame=reading.first_frame)
    _print_reader_messages(caught)
    return rows
