"""Pictures of each frame's pairs (``xvmatch associate --draw DIR``, ``xvmatch track --draw DIR``
and ``--draw-video FILE.mp4``): each frame's matches side by side
(:func:`~xvmatch.viz.match_drawing.draw_matches`), on the views' images or, without them, on the
canvases of :mod:`xvmatch.viz.box_canvas`. The folder's pictures are written into a temporary
folder and moved into place only once all are made; the video (OpenCV's ``mp4v``) is written
beside its path and renamed into place once complete. With ground truth (:func:`truth_marks`),
right pairs are green, wrong ones red, and the camera wearer is marked in the top view.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator, Mapping
from pathlib import Path

import cv2
import numpy as np

from xvmatch.core.output_paths import claim_folder
from xvmatch.viz.box_canvas import blank_view, top_plan
from xvmatch.viz.match_drawing import (
    GAP_COLOUR,
    draw_matches,
    frames_to_draw,
    pairs_correct,
    picture_path,
    write_match_picture,
)

__all__ = ["VIDEO_FPS", "MatchVideo", "truth_marks", "write_match_pictures"]

VIDEO_FPS = 10.0
"""Frames per second of a ``--draw-video`` (one drawn frame per video frame)."""


def truth_marks(top: Mapping, hor: Mapping, camera_id: int | None = None,
                top_ids: np.ndarray | None = None, hor_ids: np.ndarray | None = None) -> dict:
    """The ground-truth keyword arguments of :func:`write_match_pictures` (``--draw-truth``):
    the boxes' ids are the people's true identities, as ``xvmatch evaluate`` reads them.

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view.
        camera_id: the true top-view id of the horizontal camera's wearer, marked where it has
            a box; None: not marked.
        top_ids, hor_ids: where the records' ids are row numbers of a detection file
            (``xvmatch track``), each row's true id (the file's id column); None: the
            records' ids are the true ids.

    Returns:
        ``{"truth": (top ids, hor ids), "wearer": {frame: top box index} or None}``, each
        ``{frame: (N,) true ids of the frame's boxes}``.
    """
    def true_ids(view: Mapping, table: np.ndarray | None) -> dict[int, np.ndarray]:
        return {f: np.asarray(r.ids) if table is None else np.asarray(table)[np.asarray(r.ids)]
                for f, r in view.items()}

    truth = (true_ids(top, top_ids), true_ids(hor, hor_ids))
    wearer = None
    if camera_id is not None:
        wearer = {f: int(np.flatnonzero(ids == camera_id)[0])
                  for f, ids in truth[0].items() if (ids == camera_id).any()}
    return {"truth": truth, "wearer": wearer}


class MatchVideo:
    """An ``mp4v`` video of pictures, written to a hidden file beside ``path`` and renamed to
    ``path`` by :meth:`finish` (a reader never sees a partial video); :meth:`discard` removes
    it. Every picture is fitted to the first one's size (rounded up to even sides)."""

    def __init__(self, path: str | os.PathLike, fps: float = VIDEO_FPS) -> None:
        self.path = Path(path)
        if self.path.suffix.lower() != ".mp4":
            raise ValueError(f"{os.fspath(path)}: a --draw-video file ends in .mp4 (mp4v)")
        self.part = self.path.with_name(f".{self.path.stem}.part.mp4")
        self.fps, self.writer, self.size = float(fps), None, None

    def add(self, picture: np.ndarray) -> None:
        """Append one picture (``(H, W, 3)`` uint8 BGR)."""
        if self.writer is None:
            h, w = picture.shape[:2]
            self.size = (w + w % 2, h + h % 2)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = cv2.VideoWriter(os.fspath(self.part), cv2.VideoWriter_fourcc(*"mp4v"),
                                          self.fps, self.size)
            if not self.writer.isOpened():
                self.discard()
                raise ValueError(f"{self.path}: OpenCV cannot write an mp4v video here")
        w, h = self.size
        if picture.shape[:2] != (h, w):
            ph, pw = picture.shape[:2]
            if ph <= h and pw <= w and (h - ph, w - pw) in ((0, 1), (1, 0), (1, 1)):
                picture = cv2.copyMakeBorder(picture, 0, h - ph, 0, w - pw, cv2.BORDER_CONSTANT,
                                             value=GAP_COLOUR)
            else:
                picture = cv2.resize(picture, (w, h), interpolation=cv2.INTER_AREA)
        self.writer.write(np.ascontiguousarray(picture))

    def finish(self) -> None:
        """Close the video and move it into place (nothing is written without a picture)."""
        if self.writer is not None:
            self.writer.release()
            self.writer = None
            self.part.replace(self.path)

    def discard(self) -> None:
        """Close and remove the unfinished video."""
        if self.writer is not None:
            self.writer.release()
            self.writer = None
        self.part.unlink(missing_ok=True)


def _pictures(every: int, top: Mapping, hor: Mapping, pairs: Mapping, frames: list[int],
              sources: dict | None, hor_size: tuple[int, int], labels: bool,
              truth: tuple[Mapping, Mapping] | None, wearer: Mapping | None,
              tracks: tuple[Mapping, Mapping] | None) -> Iterator[tuple[int, np.ndarray]]:
    """``(frame, picture)`` of every ``every``-th of ``frames`` (the arguments of
    :func:`write_match_pictures`)."""
    plan = hor_canvas = None
    if sources is None:
        plan, hor_canvas = top_plan(top), blank_view(hor_size)
    legend = ("green: right pair; red: wrong pair (by the files' ids)" if truth is not None
              else "same colour: same person") + "; grey: unmatched"
    if sources is None:
        legend += "; boxes only: top view as a plan, horizontal view blank"
    for f in frames_to_draw(frames, every):
        t_ids, h_ids = list(top[f].ids), list(hor[f].ids)
        rows = np.array([(t_ids.index(a), h_ids.index(b)) for a, b in pairs.get(f, [])],
                        dtype=np.int64).reshape(-1, 2)
        if sources is None:
            images = (plan.image, hor_canvas)
            boxes = (plan.place(top[f].boxes), hor[f].boxes)
        else:
            images = (sources["top"].get(f), sources["hor"].get(f))
            boxes = (top[f].boxes, hor[f].boxes)
        shown = (top[f].ids, hor[f].ids)
        marks = {}
        if tracks is not None:
            shown = tuple([view_tracks.get(i, "-") for i in ids]
                          for view_tracks, ids in zip(tracks, shown, strict=True))
            marks["keys"] = [tracks[0][a] for a, _ in pairs.get(f, [])]
        if truth is not None:
            marks["correct"] = pairs_correct(truth[0][f], truth[1][f], rows)
        if wearer is not None and f in wearer:
            marks["wearer"] = wearer[f]
        picture = draw_matches(*images, *boxes, rows, *(shown if labels else (None, None)),
                               title=f"frame {f}: {len(rows)} matches ({legend})", **marks)
        yield f, picture


def write_match_pictures(folder: str | os.PathLike | None, every: int, top: Mapping,
                         hor: Mapping, pairs: Mapping, frames: list[int], sources: dict | None,
                         hor_size: tuple[int, int], labels: bool = True, *, owner: str,
                         option: str, truth: tuple[Mapping, Mapping] | None = None,
                         wearer: Mapping[int, int] | None = None,
                         tracks: tuple[Mapping, Mapping] | None = None,
                         video: str | os.PathLike | None = None,
                         fps: float = VIDEO_FPS) -> None:
    """The pictures of every ``every``-th of ``frames``, written into a temporary folder and
    moved into ``folder`` only once all are made, and/or as the frames of a ``video``.

    Args:
        folder: the folder: new, empty, or one ``owner`` made before
            (:func:`~xvmatch.core.output_paths.claim_folder`); None: the video only.
        every: the frame step (``--draw-every``).
        top, hor: ``{frame: FrameBoxes}`` of each view (the top one re-timed as the pairs).
        pairs: ``{frame: [(top id, hor id)]}``.
        frames: the frames that may be drawn (those with boxes in both views).
        sources: ``{"top": source, "hor": source}`` of the images; None: boxes only, drawn on a
            blank canvas of ``hor_size`` and the top view as a plan
            (:mod:`xvmatch.viz.box_canvas`).
        hor_size: the horizontal image size ``(width, height)``.
        labels: print each box's id (``--no-labels``: none).
        owner: the folder's owner mark (the command that writes it).
        option: the option naming the folder, for the messages.
        truth: ``{frame: true ids of the boxes}`` of each view (:func:`truth_marks`): right
            pairs drawn green, wrong ones red; None: each pair its own colour.
        wearer: ``{frame: index of the camera wearer's top box}``, marked; None: not marked.
        tracks: ``{box id: track id}`` of each view (``track``): the track ids are printed
            instead of the box ids (a box without one is labelled ``-``), and each pair is
            drawn in its track's colour, the same in every frame (unless ``truth``); None: the
            ids, and each pair its own colour.
        video: an ``.mp4`` file to write the same pictures into (:class:`MatchVideo`), or None.
        fps: the video's frames per second.
    """
    out = None if folder is None else claim_folder(folder, owner, option)
    tmp = None if out is None else Path(tempfile.mkdtemp(prefix=".draw-", dir=out))
    movie = None if video is None else MatchVideo(video, fps)
    try:
        written = []
        for f, picture in _pictures(every, top, hor, pairs, frames, sources, hor_size, labels,
                                    truth, wearer, tracks):
            if tmp is not None:
                path = picture_path(tmp, f)
                write_match_picture(path, picture)
                written.append(path)
            if movie is not None:
                movie.add(picture)
        for path in written:
            path.replace(out / path.name)
        if movie is not None:
            movie.finish()
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if movie is not None:
            movie.discard()
