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
   produce boxes slightly past the border; a box further out belongs to another image size,
   unless the file's boxes run on past the borders (:func:`runs_past_borders`: trackers' boxes
   and amodal annotations keep a person's whole box however much of it is out of view), where
   only a box entirely outside is an error.

Where no size is given, :func:`guess_image_size` reads it from the boxes: where they are cut
by the borders, else (boxes running on past the borders) the smallest common size every box
starts inside, or (others) the smallest common size holding them all.

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
    "BORDER_TOL",
    "COMMON_SIZES",
    "CVMHAT_SIZE",
    "FRAME_ASPECTS",
    "MARGIN",
    "MIN_AT_BORDER",
    "MIN_EXTENT",
    "SNAP",
    "SPILL",
    "UNKNOWN",
    "assumed_size_note",
    "border_size",
    "box_extent",
    "box_line",
    "check_boxes_in_image",
    "common_size_holding",
    "common_size_started",
    "consistent_with",
    "ground_path_hor_size",
    "ground_path_size_note",
    "guess_image_size",
    "hor_size_note",
    "median_aspect",
    "resolve_size",
    "runs_past_borders",
    "size_guess_how",
    "unknown_size_error",
    "upright_aspect",
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
BORDER_TOL = 1.0
"""Pixels within which boxes cut by one image border end alike (annotations rounded to whole
pixels, or clipped to the last pixel's index)."""
MIN_AT_BORDER = 3
"""Fewest people whose boxes end at the farthest edge for it to be read as the image's border
(:func:`border_size`): people cut by it as they leave or pass the camera."""
SPILL = (0.1, 8.0, 0.25)
"""How far before the image's left or top border a box must start to show boxes that run on
past the borders (:func:`runs_past_borders`): a share of its own width or height and pixels,
or (a small, far person) a larger share alone. Clipped boxes start at 0, hand annotations a
few pixels either side of it (CVMHAT's -4, a 38 px wide person cut at the left edge)."""
SNAP = 0.01
"""How near (a share of each side) a size read at the borders is taken for a common size."""
FRAME_ASPECTS = (16 / 9, 4 / 3, 256 / 135)
"""Width over height of video frames, in the order :func:`border_size` tries them for the side
no boxes are cut at (16:9, 4:3, 4096x2160), that side rounded to a multiple of 8 pixels
(2048 * 16 / 9 = 3640.9 for a 3640x2048 phone: 3640)."""
ASSUMED = "the CVMHAT default"
"""The source :func:`resolve_size` gives for an assumed CVMHAT size."""
UNKNOWN = "not known"
"""The source :func:`resolve_size` gives, with ``defer``, for boxes alone that do not fit the
CVMHAT size: a path that needs the size refuses them (:func:`unknown_size_error`), the
ground-map path takes :func:`ground_path_hor_size`'s guess."""


def _fmt(value: float) -> str:
    return f"{float(value):g}"


def _all_boxes(frames: Mapping) -> np.ndarray:
    """Every ``(x, y, w, h)`` box of ``{frame: FrameBoxes}``, ``(K, 4)``."""
    boxes = [np.asarray(rec.boxes, dtype=float).reshape(-1, 4) for rec in frames.values()]
    return np.concatenate(boxes) if boxes else np.zeros((0, 4))


def box_extent(frames: Mapping) -> tuple[float, float]:
    """The rightmost and lowest box edge, ``(max x + w, max y + h)`` in pixels, of
    ``{frame: FrameBoxes}``; ``(0, 0)`` without boxes."""
    b = _all_boxes(frames)
    if not len(b):
        return 0.0, 0.0
    return float((b[:, 0] + b[:, 2]).max()), float((b[:, 1] + b[:, 3]).max())


def _outside(b: np.ndarray, size: tuple[int, int], spill: bool = False) -> np.ndarray:
    """Rows of ``(x, y, w, h)`` boxes that break rule 3 for a ``size = (W, H)`` image; with
    ``spill`` (boxes that run on past the borders) only those entirely outside."""
    width, height = (float(v) for v in size)
    x, y, w, h = b[:, 0], b[:, 1], b[:, 2], b[:, 3]
    entirely = (x >= width) | (y >= height) | (x + w <= 0) | (y + h <= 0)
    if spill:
        return entirely
    past = ((x < -MARGIN * width) | (y < -MARGIN * height) | (x + w > (1 + MARGIN) * width)
            | (y + h > (1 + MARGIN) * height))
    return entirely | past


def runs_past_borders(*views: Mapping) -> bool:
    """Whether the boxes of ``{frame: FrameBoxes}`` run on past the image's borders (trackers'
    boxes, amodal annotations) rather than being clipped to it: a box starts before the left
    or top border by more than :data:`SPILL` (a share of its own width or height and pixels,
    or a larger share), which no image size explains (clipped boxes start at 0). Several views
    (a run's files, made by one tracker or tool): where any of them shows it."""
    b = np.concatenate([_all_boxes(frames) for frames in views]) if views else np.zeros((0, 4))
    share, pixels, small = SPILL
    size = b[:, 2:]
    reach = np.maximum(share * size, np.minimum(small * size, pixels))
    return bool((b[:, :2] < -np.maximum(reach, BORDER_TOL)).any())


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


def _people(boxes: np.ndarray, ranks: np.ndarray) -> int:
    """How many people the ``(x0, y0, x1, y1)`` boxes are, boxes of successive frames
    (``ranks``, the frames' order in the clip) that overlap taken for one person's: one
    person standing at the edge, or walking along it, is one however many boxes."""
    parent = np.arange(len(boxes))

    def root(k: int) -> int:
        while parent[k] != k:
            parent[k] = parent[parent[k]]
            k = int(parent[k])
        return k

    for r in np.unique(ranks):
        now, nxt = np.flatnonzero(ranks == r), np.flatnonzero(ranks == r + 1)
        if not len(nxt):
            continue
        a, c = boxes[now][:, None], boxes[nxt][None]
        touch = ((np.minimum(a[..., 2], c[..., 2]) > np.maximum(a[..., 0], c[..., 0]))
                 & (np.minimum(a[..., 3], c[..., 3]) > np.maximum(a[..., 1], c[..., 1])))
        for i, j in zip(*np.nonzero(touch), strict=True):
            parent[root(int(now[i]))] = root(int(nxt[j]))
    return len({root(k) for k in range(len(boxes))})


def _border(far: np.ndarray, boxes: np.ndarray, ranks: np.ndarray) -> float | None:
    """The image border where boxes are cut: the farthest of the ``far`` edges, where the
    boxes of at least :data:`MIN_AT_BORDER` people (:func:`_people`) end within
    :data:`BORDER_TOL`; None where they do not."""
    at = far >= float(far.max()) - BORDER_TOL
    enough = at.sum() >= MIN_AT_BORDER and _people(boxes[at], ranks[at]) >= MIN_AT_BORDER
    return float(far.max()) if enough else None


def _to8(value: float) -> int:
    """A frame side in pixels, rounded to a multiple of 8 as video frames' sides are."""
    return int(8 * np.floor(value / 8.0 + 0.5))


def _snapped(size: tuple[int, int]) -> tuple[int, int]:
    """A size read at the borders, or the common video size within :data:`SNAP` of it on both
    sides (hand annotations stop a few pixels short of the border: 2680x1504 is 2688x1512)."""
    for common in COMMON_SIZES:
        if all(abs(v - c) <= SNAP * c for v, c in zip(size, common, strict=True)):
            return common
    return size


def border_size(frames: Mapping) -> tuple[int, int] | None:
    """The image size where boxes of ``{frame: FrameBoxes}`` are cut by its borders, as
    annotation tools and trackers clip them (a 3640x2048 phone's boxes end at x 3640 and
    y 2048): the right and lowest edges where several boxes end alike (:func:`_border`), to a
    multiple of 8 (:func:`_snapped`); with only one of them, the other side from the first of
    :data:`FRAME_ASPECTS` that holds every box (2% past allowed, as
    :func:`common_size_holding`). None where no border shows."""
    boxes = [np.asarray(frames[f].boxes, dtype=float).reshape(-1, 4) for f in sorted(frames)]
    if not sum(map(len, boxes)):
        return None
    ranks = np.concatenate([np.full(len(v), k) for k, v in enumerate(boxes)])
    b = np.concatenate(boxes)
    x1, y1 = b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
    corners = np.column_stack([b[:, 0], b[:, 1], x1, y1])
    right, bottom = _border(x1, corners, ranks), _border(y1, corners, ranks)
    if right is not None and bottom is not None:
        return _snapped((_to8(right), _to8(bottom)))
    for aspect in FRAME_ASPECTS if right is not None or bottom is not None else ():
        width = _to8(right if right is not None else bottom * aspect)
        height = _to8(bottom if bottom is not None else right / aspect)
        if float(x1.max()) <= 1.02 * width and float(y1.max()) <= 1.02 * height:
            return _snapped((width, height))
    return None


def common_size_started(frames: Mapping) -> tuple[int, int] | None:
    """The smallest of :data:`COMMON_SIZES` inside which every box of ``{frame: FrameBoxes}``
    starts (``x < W`` and ``y < H``), None when none or no boxes: the size of boxes that run
    on past the right and lowest borders (:func:`runs_past_borders`), where the boxes' extent
    would tell a larger one (a passer-by's box 1.9 times the image's height past its foot)."""
    b = _all_boxes(frames)
    if not len(b):
        return None
    for width, height in COMMON_SIZES:
        if b[:, 0].max() < width and b[:, 1].max() < height:
            return width, height
    return None


def guess_image_size(frames: Mapping, past: bool | None = None) -> tuple[int, int] | None:
    """A view's image size from its boxes alone: where they are cut by its borders
    (:func:`border_size`); else, for boxes that run on past the borders (``past``; None: as
    :func:`runs_past_borders` finds them), the smallest common video size they all start
    inside (:func:`common_size_started`), for others the smallest common video size holding
    them (:func:`common_size_holding`); None where none tells."""
    if (border := border_size(frames)) is not None:
        return border
    past = runs_past_borders(frames) if past is None else past
    return (common_size_started if past else common_size_holding)(frames)


def size_guess_how(frames: Mapping, size: tuple[int, int], past: bool | None = None) -> str:
    """How :func:`guess_image_size` came to ``size`` for these boxes (``past`` as it took it),
    for a note."""
    if border_size(frames) == tuple(size):
        return "where its boxes are cut by the image's borders"
    if runs_past_borders(frames) if past is None else past:
        return "the smallest common video size its boxes, run on past the borders, start inside"
    return "the smallest common video size holding its boxes"


def ground_path_hor_size(hor: Mapping, size: tuple[int, int], source: str,
                         past: bool | None = None) -> tuple[int, int] | None:
    """The horizontal view's size for the ground-map path where no size was given
    (:func:`resolve_size`'s ``source`` :data:`ASSUMED` or :data:`UNKNOWN`): the size guessed
    from its boxes (:func:`guess_image_size`), as that path reads distances and bearings from
    the image's width and centre, and 2688x1512 belongs to CVMHAT's head-mounted camera under a
    nadir drone (``past`` as :func:`guess_image_size` takes it). None where the size was
    given, or (assumed) no other size is found."""
    if source == UNKNOWN:  # resolve_size already took the guess
        return tuple(size)
    if source != ASSUMED:
        return None
    guess = guess_image_size(hor, past)
    return None if guess is None or tuple(guess) == tuple(size) else guess


def assumed_size_note(path: str | os.PathLike, hor: Mapping,
                      option: str = "--image-size") -> str:
    """The note saying a horizontal view's images, read from ``path`` with boxes ``hor`` and no
    size given, are taken as CVMHAT's (:func:`resolve_size`'s :data:`ASSUMED`), with how far
    its boxes reach and the ``option`` that gives the size."""
    right, bottom = box_extent(hor)
    return (f"assuming {os.fspath(path)}'s images are {CVMHAT_SIZE[0]}x{CVMHAT_SIZE[1]} "
            f"(CVMHAT; its boxes reach x {float(right):g}, y {float(bottom):g}); pass {option} "
            "WxH if not")


def hor_size_note(path: str | os.PathLike, hor: Mapping, guess: tuple[int, int],
                  source: str, past: bool | None = None) -> str:
    """The note saying a horizontal view's size was guessed from its boxes ``hor`` on the
    ground-map path (:func:`ground_path_hor_size`, ``past`` as it took it), ``source`` as
    :func:`resolve_size` gave it."""
    instead = ", not CVMHAT's" if source == ASSUMED else ""
    return (f"{os.fspath(path)}: its images taken as {guess[0]}x{guess[1]} on this path, "
            f"{size_guess_how(hor, guess, past)}{instead} (give --image-size WxH if not)")


def ground_path_size_note(path: str | os.PathLike, hor: Mapping,
                          guess: tuple[int, int] | None, source: str,
                          past: bool | None = None) -> str | None:
    """What the ground-map path says of a horizontal view's size: the size it guessed from the
    boxes ``hor`` (:func:`ground_path_hor_size`'s ``guess``, :func:`hor_size_note`), else the
    CVMHAT size kept where ``source`` assumed it (boxes that fit it,
    :func:`assumed_size_note`); None for a size given."""
    if guess is not None:
        return hor_size_note(path, hor, guess, source, past)
    return assumed_size_note(path, hor) if source == ASSUMED else None


def median_aspect(frames: Mapping) -> float | None:
    """The median box height over width of ``{frame: FrameBoxes}``, None without boxes: people
    standing upright in an oblique view are about 2.5 times as tall as wide, from above (a nadir
    view) about as tall as wide."""
    b = _all_boxes(frames)
    if not len(b):
        return None
    return float(np.median(b[:, 3] / np.maximum(b[:, 2], 1e-9)))


def upright_aspect(frames: Mapping) -> float | None:
    """:func:`median_aspect` where the view's people stand upright (at least
    :data:`~xvmatch.geometry.people_calibration.STEEP_ASPECT`: an oblique camera); None where
    they do not or there are no boxes (a view looking down)."""
    from xvmatch.geometry.people_calibration import STEEP_ASPECT  # scipy: not at start-up

    aspect = median_aspect(frames)
    return None if aspect is None or aspect < STEEP_ASPECT else aspect


def upright_size_guess(frames: Mapping, past: bool | None = None
                       ) -> tuple[float, tuple[int, int] | None] | None:
    """For a view whose size is not given: None where its people do not stand upright
    (:func:`upright_aspect`: a view looking down, read as the ground); else their median
    aspect and the size guessed for it, :func:`guess_image_size` (``past`` as it takes it;
    None: no size holds the boxes)."""
    if (aspect := upright_aspect(frames)) is None:
        return None
    return aspect, guess_image_size(frames, past)


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
                         source: str, ids: bool = True, past: bool | None = None) -> None:
    """Raise ``ValueError`` naming ``path``'s line when a box of ``{frame: FrameBoxes}`` breaks
    rule 3 for a ``size = (W, H)`` image; ``source`` says where the size comes from (e.g.
    ``--image-size``), ``ids`` whether the records' ids are the file's (else row numbers),
    ``past`` whether the boxes run on past the borders (None: as :func:`runs_past_borders`
    finds them in ``frames``)."""
    spill = runs_past_borders(frames) if past is None else past
    for frame, rec in sorted(frames.items()):
        b = np.asarray(rec.boxes, dtype=float).reshape(-1, 4)
        if not len(b):
            continue
        bad = np.flatnonzero(_outside(b, size, spill))
        if not bad.size:
            continue
        k = int(bad[0])
        line = box_line(path, int(frame), b[k])
        where = f"{os.fspath(path)}:{line}" if line is not None else os.fspath(path)
        who = f"box of id {int(rec.ids[k])}" if ids else "box"
        x, y, w, h = (_fmt(v) for v in b[k])
        straddles = not _outside(b[k:k + 1], size, spill=True)[0]
        hint = (" (if its boxes run on past the borders, as a tracker's may, clip them to the "
                "image)" if straddles else "")
        raise ValueError(
            f"{where}: frame {frame}: {who} ({x}, {y}, {w}, {h}) lies outside the "
            f"{size[0]}x{size[1]} image (from {source}) or more than {MARGIN:.0%} past its "
            f"border; are these the boxes of these images, and is the image size right?{hint}")


def resolve_size(hor: Mapping, hor_path: str | os.PathLike, given: list[tuple[tuple, str]],
                 ids: bool = True, option: str = "--image-size", defer: bool = False,
                 past: bool | None = None) -> tuple[tuple[int, int], str]:
    """The horizontal image size of a box file and where it comes from, by rules 1-3.

    Args:
        hor: the horizontal view's ``{frame: FrameBoxes}``.
        hor_path: its file (named in messages).
        given: ``[((W, H), source)]``, every size the command was given (``--image-size``, the
            images, the cameras), in order of precedence; sources are named in messages.
        ids: whether the records' ids are the file's ids (else row numbers).
        option: the option that gives the size, named in the refusal.
        defer: boxes alone that do not fit the CVMHAT size are not refused here but returned
            with the size guessed from them (:func:`guess_image_size`) and :data:`UNKNOWN`,
            for a command whose
            path is chosen later (``associate``: the ground-map path guesses it, the nadir
            path refuses with :func:`unknown_size_error`).
        past: whether the run's boxes run on past the borders (:func:`runs_past_borders` of
            all its files, made by one tracker or tool), for rule 3 and the guess; None: as
            ``hor``'s show.

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
        check_boxes_in_image(hor, size, hor_path, source, ids, past)
        return size, source
    if consistent_with(hor):
        return CVMHAT_SIZE, ASSUMED
    if defer and (guess := guess_image_size(hor, past)) is not None:
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

