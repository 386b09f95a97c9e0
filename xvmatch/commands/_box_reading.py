"""How the commands read box files: a header line skipped, ``--min-score`` (the detector's
score column) and ``--first-frame`` (files counting from 0), once for every command.

A command adds the options with :func:`add_box_reading_options` (or with the box files
themselves, ``add_box_inputs(parser, reading=True)``), builds one
:class:`BoxReading` with :func:`box_reading` and reads each file with :func:`read_boxes` (boxes
by person id) or :func:`read_detections` (every row, for ``track`` and ``associate-multi``); the
reader's notes and warnings come out as ``xvmatch: note: ...`` and ``xvmatch: warning: ...``
lines. The reading itself is :func:`xvmatch.formats.mot_boxes.read_mot_boxes`'s.

It also checks ``--camera-id`` against the top boxes (:func:`check_camera_id`). The
horizontal image size rule's command-line side lives here too: the rule itself (which size
the horizontal boxes belong to, and whether they fit it) is
:mod:`xvmatch.formats.box_image_size`'s; :func:`note_if_assumed` prints the one-line note of an
assumed CVMHAT size, :func:`settled_hor_size` the size a command settles from its inputs.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping
from dataclasses import dataclass

from xvmatch.commands._types import float_in
from xvmatch.formats.box_image_size import ASSUMED, assumed_size_note

__all__ = ["BoxReading", "add_box_inputs", "add_box_reading_options", "box_reading",
           "check_camera_id", "note_if_assumed", "read_boxes", "read_detections",
           "settled_hor_size"]


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
            help="drop boxes whose detector score (MOT's 7th field, or a header's conf or "
            "score column) is below S, in [-1e6, 1e6], with a note (default: keep all)")
    parser.add_argument(
        "--first-frame", type=int, choices=(0, 1), default=1, metavar="{0,1}",
        help="the number of the box files' first frame: 1 (default, as MOTChallenge) or 0 "
        "(read as frame + 1, with a note; outputs count from 1)")


def add_box_inputs(parser: argparse.ArgumentParser, reading: bool = False,
                   detector: argparse._ActionsContainer | None = None) -> None:
    """``--top``, ``--hor`` (MOT box files) and ``--duplicates`` (associate, evaluate,
    offset); with ``reading``, :func:`add_box_reading_options` too (the command then reads
    its files with :func:`box_reading`). ``detector``: an argument group for ``--duplicates``
    and the reading options, away from the common ones (``associate``); default the parser."""
    parser.add_argument("--top", required=True, help="top-view boxes (MOT format)")
    parser.add_argument("--hor", required=True, help="horizontal-view boxes (MOT format)")
    detector = parser if detector is None else detector
    detector.add_argument(
        "--duplicates",
        choices=("first", "error"),
        default="first",
        help="a repeated (frame, id) in a box file: keep the first box with a warning "
        "(default; the real CVMHAT files have a few) or stop with an error",
    )
    if reading:
        add_box_reading_options(detector)


def check_camera_id(camera_id: int | None, top: Mapping, path: str) -> None:
    """``--camera-id`` must name a person of the top view in at least one frame."""
    from xvmatch.commands._options import UsageError  # defined there, which imports this

    if camera_id is None:
        return
    if not any(camera_id in rec.ids for rec in top.values()):
        raise UsageError(f"--camera-id {camera_id}: no box of {path} has this id (the id of "
                         "the horizontal camera's wearer in the top-view file)")


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

def note_if_assumed(resolved: tuple[tuple[int, int], str], hor: Mapping,
                    hor_path: str | os.PathLike, quiet: bool = False,
                    option: str = "--image-size") -> None:
    """Print the one-line note on stderr when
    :func:`~xvmatch.formats.box_image_size.resolve_size` assumed the CVMHAT size (not with
    ``quiet``). Commands call it once every check has passed, as the work starts, so
    that a refused run prints its error line alone."""
    if quiet or resolved[1] != ASSUMED:
        return
    print(f"xvmatch: note: {assumed_size_note(hor_path, hor, option)}", file=sys.stderr)


def settled_hor_size(hor: Mapping, hor_path: str, image_size: tuple[int, int] | None,
                     images_size: tuple[int, int] | None = None, images: str | None = None,
                     cameras: str | None = None, quiet: bool = False,
                     ids: bool = True, top: Mapping | None = None, defer: bool = False
                     ) -> tuple[tuple[int, int], str]:
    """The horizontal image size of ``hor`` (read from ``hor_path``) and where it comes from:
    ``image_size`` (``--image-size``), the size of the horizontal ``images`` (None without) or
    else the ``cameras``' ego camera, which must agree
    (:func:`~xvmatch.formats.box_image_size.resolve_size`; with the run's ``top`` view, whether
    boxes run on past the borders read from both files; ``defer``: boxes alone that do not fit
    CVMHAT's size guessed, for the ground-map path); said when assumed."""
    from xvmatch.formats.box_image_size import resolve_size, runs_past_borders

    given = [] if image_size is None else [(image_size, "--image-size")]
    if images_size is not None:
        given.append((images_size, f"the horizontal images {images}"))
    elif cameras is not None:  # with images, each camera is checked against them
        from xvmatch.commands._model import ego_camera_size

        given.append(ego_camera_size(cameras))
    past = None if top is None else runs_past_borders(top, hor)
    resolved = resolve_size(hor, hor_path, given, ids=ids, defer=defer, past=past)
    note_if_assumed(resolved, hor, hor_path, quiet)
    return resolved

