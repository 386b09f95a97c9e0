"""Which image size the horizontal boxes belong to, and whether they fit it.

The geometry features are resolution-free only when the horizontal image size is right: the
CVMHAT size assumed for boxes of a 1399x787 camera squeezes every person into the left half of
the view, and the search finds few pairs without any sign of trouble (issue 29, item 1). So every
command that reads box files (``associate``, ``track``, ``offset``, ``associate-multi``,
``fit-geometry``) settles the size by one rule:

1. **Given**: ``--image-size WxH``, the horizontal images' size, the ego cameras' size: each
   one that is given must agree with the others (else one error line naming both).
2. **Boxes only, no size given**: the CVMHAT default 2688x1512 is assumed, with one note on
   stderr, only when the horizontal boxes are consistent with it (:func:`consistent_with`): all
   inside it (rule 3) and the rightmost box edge beyond :data:`MIN_EXTENT` (60%) of 2688 pixels,
   1612.8 (the note, :func:`xvmatch.commands._box_reading.note_if_assumed`, printed once every check
   has passed, is left out with ``--quiet``).
   Boxes of a 1399-pixel-wide camera reach at most 1399 (plus the margin, 1538.9), so they are
   never taken for CVMHAT's. Otherwise the command stops with one line saying to pass
   ``--image-size``; ``associate`` and ``associate-multi`` first see whether the top view is
   oblique, whose ground-map path guesses the size from the boxes, with a note
   (:func:`ground_path_hor_size`; a nadir top view still stops).
3. **Boxes inside the image**: a box is an error (naming the file and line) when it lies
   entirely outside the image, or goes past a border by more than :data:`MARGIN` (10%) of that
   side: ``x < -0.1 W``, ``y < -0.1 H``, ``x + w > 1.1 W`` or ``y + h > 1.1 H``. Detectors
   produce boxes slightly past the border; a box further out belongs to another image size.

The top view's size is used by no feature (top-view positions are relative to each other), so
top-view boxes are checked only against the top images when they are given.
"""

from __future__ import annotations

import os
from collections.abc import Mapping

import numpy as np

from xvmatch.core.input_files import InputFileError, read_input_text

__all__ = [
    "ASSUMED",
    "COMMON_SIZES",
    "CVMHAT_SIZE",
    "MARGIN",
    "MIN_EXTENT",
    "UNKNOWN",
    "box_extent",
    "box_line",
    "check_boxes_in_image",
    "common_size_holding",
    "consistent_with",
    "ground_path_hor_size",
    "hor_size_note",
    "median_aspect",
    "resolve_size",
    "unknown_size_error",
    "upright_size_guess",
]

CVMHAT_SIZE = (2688, 1512)
"""The image size of the CVMHAT videos, assumed for box files consistent with it."""
MARGIN = 0.10
"""How far past a border a box may go, as a share of that side of the image."""
MIN_EXTENT = 0.6
"""Boxes are taken for CVMHAT's only if their rightmost edge is beyond this share of 2688."""
COMMON_SIZES = ((640, 360), (640, 480), (1280, 720), (1920, 1080), (2560, 1440), (2688, 1512),
                (2720, 1530), (3840, 2160), (4096, 2160), (5472, 3078), (7680, 4320))
"""Video frame sizes of cameras and drones, smallest first: the candidates
:func:`common_size_holding` chooses from."""
ASSUMED = "the CVMHAT default"
"""The source :func:`resolve_size` gives for an assumed CVMHAT size."""
UNKNOWN = "not known"
"""The source :func:`resolve_size` gives, with ``defer``, for boxes alone that do not fit the
CVMHAT size: a path that needs the size refuses them (:func:`unknown_size_error`), the
ground-map path takes :func:`ground_path_hor_size`'s guess."""


def _fmt(value: float) -> str:
    return f"{float(value):g}"


def box_extent(frames: Mapping) -> tuple[float, float]:
    """The rightmost and lowest box edge, ``(max x + w, max y + h)`` in pixels, of
    ``{frame: FrameBoxes}``; ``(0, 0)`` without boxes."""
    boxes = [np.asarray(rec.boxes, dtype=float).reshape(-1, 4) for rec in frames.values()]
    b = np.concatenate(boxes) if boxes else np.zeros((0, 4))
    if not len(b):
        return 0.0, 0.0
    return float((b[:, 0] + b[:, 2]).max()), float((b[:, 1] + b[:, 3]).max())


def _outside(b: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Rows of ``(x, y, w, h)`` boxes that break rule 3 for a ``size = (W, H)`` image."""
    width, height = (float(v) for v in size)
    x, y, w, h = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    entirely = (x >= width) | (y >= height) | (x + w <= 0) | (y + h <= 0)
    past = ((x < -MARGIN * width) | (y < -MARGIN * height) | (x + w > (1 + MARGIN) * width)
            | (y + h > (1 + MARGIN) * height))
    return entirely | past


def consistent_with(frames: Mapping, size: tuple[int, int] = CVMHAT_SIZE) -> bool:
    """Whether boxes look like boxes of a ``size`` image: every box inside it (rule 3) and the
    rightmost edge beyond :data:`MIN_EXTENT` of its width."""
    for rec in frames.values():
        b = np.asarray(rec.boxes, dtype=float).reshape(-1, 4)
        if len(b) and _outside(b, size).any():
            return False
    return box_extent(frames)[0] > MIN_EXTENT * size[0]


def common_size_holding(frames: Mapping) -> tuple[int, int] | None:
    """The smallest of :data:`COMMON_SIZES` that holds every box of ``{frame: FrameBoxes}``
    (each edge at most 2% past its border), None when none does or there are no boxes: a
    guess of an image size from boxes alone, for a view whose size matters only through its
    centre and aspect (the top view's calibration from its people), said to the user."""
    right, bottom = box_extent(frames)
    if right <= 0 or bottom <= 0:
        return None
    for width, height in COMMON_SIZES:
        if right <= 1.02 * width and bottom <= 1.02 * height:
            return width, height
    return None


def ground_path_hor_size(hor: Mapping, size: tuple[int, int], source: str
                         ) -> tuple[int, int] | None:
    """The horizontal view's size for the ground-map path where no size was given
    (:func:`resolve_size`'s ``source`` :data:`ASSUMED` or :data:`UNKNOWN`): the smallest common
    video size holding its boxes (:func:`common_size_holding`), as that path reads distances and
    bearings from the image's width and centre, and 2688x1512 belongs to CVMHAT's head-mounted
    camera under a nadir drone. None where the size was given, or (assumed) no other size is
    found."""
    if source == UNKNOWN:  # resolve_size already took the smallest common size holding them
        return tuple(size)
    if source != ASSUMED:
        return None
    guess = common_size_holding(hor)
    return None if guess is None or tuple(guess) == tuple(size) else guess


def hor_size_note(path: str | os.PathLike, guess: tuple[int, int], source: str) -> str:
    """The note saying a horizontal view's size was guessed on the ground-map path
    (:func:`ground_path_hor_size`), ``source`` as :func:`resolve_size` gave it."""
    instead = ", not CVMHAT's" if source == ASSUMED else ""
    return (f"{os.fspath(path)}: its images taken as {guess[0]}x{guess[1]} on this path, the "
            f"smallest common video size holding its boxes{instead} (give --image-size WxH if "
            "not)")


def median_aspect(frames: Mapping) -> float | None:
    """The median box height over width of ``{frame: FrameBoxes}``, None without boxes: people
    standing upright in an oblique view are about 2.5 times as tall as wide, from above (a nadir
    view) about as tall as wide."""
    boxes = [np.asarray(rec.boxes, dtype=float).reshape(-1, 4) for rec in frames.values()]
    b = np.concatenate(boxes) if boxes else np.zeros((0, 4))
    if not len(b):
        return None
    return float(np.median(b[:, 3] / np.maximum(b[:, 2], 1e-9)))


def upright_size_guess(frames: Mapping) -> tuple[float, tuple[int, int] | None] | None:
    """For a view whose size is not given: None where its people do not stand upright (median
    height over width below :data:`~xvmatch.geometry.people_calibration.STEEP_ASPECT`, or no
    boxes: a view looking down, read as the ground); else that median and the size guessed for
    it, :func:`common_size_holding` (None: no common size holds the boxes)."""
    from xvmatch.geometry.people_calibration import STEEP_ASPECT  # scipy: not at start-up

    aspect = median_aspect(frames)
    if aspect is None or aspect < STEEP_ASPECT:
        return None
    return aspect, common_size_holding(frames)


def box_line(path: str | os.PathLike, frame: int, box: np.ndarray) -> int | None:
    """The 1-based line of ``path`` holding ``box`` of ``frame`` (the first such line), None
    when no line does: how a check of boxes already read names the line at fault."""
    try:
        lines = read_input_text(path, encoding="utf-8-sig").split("\n")
    except (InputFileError, OSError):
        return None
    for k, line in enumerate(lines, start=1):
        fields = line.strip().split(",")
        if len(fields) < 6:
            continue
        try:
            values = [float(v) for v in fields[:6]]
        except ValueError:
            continue
        if values[0] == frame and np.allclose(values[2:6], box, rtol=1e-12, atol=1e-9):
            return k
    return None


def check_boxes_in_image(frames: Mapping, size: tuple[int, int], path: str | os.PathLike,
                         source: str, ids: bool = True) -> None:
    """Raise ``ValueError`` naming ``path``'s line when a box of ``{frame: FrameBoxes}`` breaks
    rule 3 for a ``size = (W, H)`` image; ``source`` says where the size comes from (e.g.
    ``--image-size``), ``ids`` whether the records' ids are the file's (else row numbers)."""
    for frame, rec in sorted(frames.items()):
        b = np.asarray(rec.boxes, dtype=float).reshape(-1, 4)
        if not len(b):
            continue
        bad = np.flatnonzero(_outside(b, size))
        if not bad.size:
            continue
        k = int(bad[0])
        line = box_line(path, int(frame), b[k])
        where = f"{os.fspath(path)}:{line}" if line is not None else os.fspath(path)
        who = f"box of id {int(rec.ids[k])}" if ids else "box"
        x, y, w, h = (_fmt(v) for v in b[k])
        raise ValueError(
            f"{where}: frame {frame}: {who} ({x}, {y}, {w}, {h}) lies outside the "
            f"{size[0]}x{size[1]} image (from {source}) or more than {MARGIN:.0%} past its "
            "border; are these the boxes of these images, and is the image size right?")


def resolve_size(hor: Mapping, hor_path: str | os.PathLike, given: list[tuple[tuple, str]],
                 ids: bool = True, option: str = "--image-size", defer: bool = False
                 ) -> tuple[tuple[int, int], str]:
    """The horizontal image size of a box file and where it comes from, by rules 1-3.

    Args:
        hor: the horizontal view's ``{frame: FrameBoxes}``.
        hor_path: its file (named in messages).
        given: ``[((W, H), source)]``, every size the command was given (``--image-size``, the
            images, the cameras), in order of precedence; sources are named in messages.
        ids: whether the records' ids are the file's ids (else row numbers).
        option: the option that gives the size, named in the refusal.
        defer: boxes alone that do not fit the CVMHAT size are not refused here but returned
            with the smallest common size holding them and :data:`UNKNOWN`, for a command whose
            path is chosen later (``associate``: the ground-map path guesses it, the nadir
            path refuses with :func:`unknown_size_error`).

    Returns:
        ``((W, H), source)``; with no size given, the CVMHAT default and :data:`ASSUMED`
        (:func:`xvmatch.commands._box_reading.note_if_assumed` says so), or with ``defer``
        a guess and :data:`UNKNOWN`.

    Raises:
        ValueError: two given sizes that disagree, boxes only that are not consistent with the
            CVMHAT default, or a box outside the image (rule 3).
    """
    if given:
        (size, source), *others = [(tuple(int(v) for v in s), src) for s, src in given]
        for other, where in others:
            if other != size:
                raise ValueError(f"{source} {size[0]}x{size[1]} disagrees with {where} "
                                 f"({other[0]}x{other[1]}): give the horizontal image size once")
        check_boxes_in_image(hor, size, hor_path, source, ids)
        return size, source
    if consistent_with(hor):
        return CVMHAT_SIZE, ASSUMED
    if defer and (guess := common_size_holding(hor)) is not None:
        return guess, UNKNOWN
    raise unknown_size_error(hor, hor_path, option)


def unknown_size_error(hor: Mapping, hor_path: str | os.PathLike,
                       option: str = "--image-size") -> ValueError:
    """The one-line refusal of boxes alone that do not fit the CVMHAT size, on a path that
    needs the horizontal image size (``option`` gives it)."""
    right, bottom = box_extent(hor)
    return ValueError(
        f"{os.fspath(hor_path)}: the horizontal image size is unknown: pass {option} WxH "
        f"(the camera's image size in pixels) or the images (the boxes reach x {_fmt(right)},"
        f" y {_fmt(bottom)}, not the CVMHAT 2688x1512 it would otherwise assume)")

