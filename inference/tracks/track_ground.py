"""An oblique top view's frame association for ``track``: the ground-map path of ``associate``
(:func:`~xvmatch.inference.matching.association_run.oblique_pairs`: the top camera calibrated
from its people, the handheld camera registered on its ground map) run frame by frame on the
detection rows, the file's ids unread as ``track`` leaves them: the frame association whose
pairs weigh the tracklet pairs of CVMHAT Eq. 13, the tracker keeping them over time. The nadir
search reads an upright top view as a drone's straight down and pairs noise (the rendered
building camera of ``tests/test_track_cameras.py``: 69.0 CVIDF1, 99.7 on this path).

Frame by frame, not along tracks: ``associate``'s video mode needs each view's people followed,
and boxes linked by IoU break where a handheld camera walks and turns (oblique renders at 10
frames a second, `/tmp` probe: 9 people in 56-115 linked tracks over 40 frames); its pairs
along such tracks kept 9-50 % of the right pairs, frame by frame 95 % (precision 0.97-0.98)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.matching.association_run import Note

__all__ = ["OBLIQUE_OFFSET", "GroundChoice", "ground_frame_pairs", "oblique_track_top",
           "with_wearer"]

OBLIQUE_OFFSET = ("--offset auto estimates the offset with the nadir search, which an oblique top "
                  "view misleads: tracking at offset 0 (give --offset N)")
"""What ``track`` says where its default ``--offset auto`` meets an oblique top view."""

OVER_TIME = "each frame on its own, the tracker joining them over time"
"""How ``track`` keeps this path's pairs over time, said in its note."""


@dataclass(frozen=True)
class GroundChoice:
    """``track``'s options of the top view's geometry (as ``associate``'s; no cameras given).

    Attributes:
        top_view: ``auto`` (the boxes decide), ``nadir`` (the search) or ``oblique``.
        top_image_size: the top view's image size, or None (its images' where its people stand
            upright, else guessed from its boxes where they do).
        hor_hfov: the handheld lens in degrees, or ``"auto"`` (chosen from the people).
        fps: the frame numbers' rate, or ``"auto"`` (30 unless the top view's walkers differ).
    """

    top_view: str = "auto"
    top_image_size: tuple[int, int] | None = None
    hor_hfov: float | str = "auto"
    fps: float | str = "auto"


def with_wearer(top: Mapping[int, FrameBoxes], wearer_rows: Sequence[int] | np.ndarray | None
                ) -> tuple[Mapping[int, FrameBoxes], int | None]:
    """The top view (``ids`` = its rows) with the rows ``wearer_rows`` (the handheld camera's
    holder, ``--camera-id``) under one id past every row, and that id; as it is, and None,
    without them."""
    if wearer_rows is None or not len(wearer_rows):
        return top, None
    wearer = 1 + max((int(r.ids.max()) for r in top.values() if len(r.ids)), default=-1)
    held = np.asarray(wearer_rows, np.int64)
    return {f: FrameBoxes(f, np.where(np.isin(r.ids, held), wearer, r.ids), r.boxes)
            for f, r in top.items()}, wearer


def _association_options(top: Mapping[int, FrameBoxes], hor_size: tuple[tuple[int, int], str],
                         choice: GroundChoice, top_size: tuple[int, int] | None,
                         names: tuple[str, str], workers: int, camera_id: int | None = None):
    """``associate``'s options of its ground-map path for a track run (frame by frame). The
    top images' size ``top_size`` serves only where the top view's people stand upright, as
    ``associate`` guesses a size only for them: a nadir drone's squat boxes, given a size, can
    fit a tilted camera (a 20-frame render of one, 46 degrees)."""
    from xvmatch.formats.box_image_size import upright_aspect
    from xvmatch.inference.matching.association_run import AssociationOptions

    if top_size is not None and upright_aspect(top) is None:
        top_size = None
    return AssociationOptions(hor_size=hor_size, camera_id=camera_id, workers=workers,
                              top_boxes=names[0], hor_boxes=names[1], top_view=choice.top_view,
                              top_image_size=choice.top_image_size or top_size,
                              hor_hfov=choice.hor_hfov, fps=choice.fps)


def oblique_track_top(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                      choice: GroundChoice, top_size: tuple[int, int] | None = None,
                      name: str = "the top-view boxes") -> object | None:
    """The top camera calibrated from its people where the ground-map path takes the top view
    (forced, or found oblique; ``top_size``: its images' size, or None), else None; says
    nothing. For what must be settled before the run, as the offset, which the nadir search
    estimates; :func:`ground_frame_pairs` of the same views takes it rather than calibrating
    again."""
    from xvmatch.formats.box_image_size import CVMHAT_SIZE
    from xvmatch.inference.matching.association_run import oblique_top

    if choice.top_view == "nadir":
        return None
    options = _association_options(top, (CVMHAT_SIZE, "--image-size"), choice, top_size,
                                   (name, ""), 1)
    return oblique_top(top, options, hor)


def ground_frame_pairs(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                       hor_size: tuple[tuple[int, int], str], choice: GroundChoice,
                       top_size: tuple[int, int] | None = None,
                       wearer_rows: Sequence[int] | np.ndarray | None = None,
                       names: tuple[str, str] = ("the top-view boxes",
                                                 "the horizontal-view boxes"),
                       workers: int = 1, note: Note | None = None,
                       calibration: object | None = None
                       ) -> dict[int, list[tuple[int, int]]] | None:
    """``{frame: [(top row, horizontal row)]}`` of the ground-map path where it takes the top
    view (``associate``'s pairs frame by frame), else None (the nadir search's view).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of both views at one timing, ``ids`` = the rows.
        hor_size: the horizontal image size and where it comes from (a CVMHAT size assumed
            is guessed again from its boxes on this path, and said).
        choice: the top view's geometry options.
        top_size: the top images' size, or None (``choice.top_image_size``, else guessed).
        wearer_rows: top rows of the handheld camera's holder (``--camera-id``), or None.
        names: the box files (messages).
        workers: processes for the lens candidates (the same pairs for any number).
        note: told the path's lines (what it assumed, the lens, the rate).
        calibration: the top camera of :func:`oblique_track_top` on these same views, or
            None (calibrated here).

    Raises:
        ValueError: a top box outside the size given, a top view forced oblique that its
            people cannot calibrate (one line).
    """
    from xvmatch.inference.matching.association_run import oblique_pairs

    if choice.top_view == "nadir":
        return None
    marked, camera_id = with_wearer(top, wearer_rows)
    options = _association_options(top, hor_size, choice, top_size, names, workers, camera_id)
    pairs = oblique_pairs(marked, hor, options, note or (lambda line, always: None), OVER_TIME,
                          calibration)
    if pairs is None:
        return None
    rows: dict[int, list[tuple[int, int]]] = {}
    for f, frame_pairs in pairs.items():  # the holder's id back to its row
        row = (dict(zip(marked[f].ids.tolist(), top[f].ids.tolist(), strict=True))
               if frame_pairs else {})
        rows[f] = [(row[a], b) for a, b in frame_pairs]
    return rows
