"""A folder of match pictures, one per drawn frame (``xvmatch associate --draw DIR``): each
frame's matches side by side (:func:`~xvmatch.viz.match_drawing.draw_matches`), on the views'
images or, without them, on the canvases of :mod:`xvmatch.viz.box_canvas`; written into a
temporary folder and moved into place only once all are made.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Mapping
from pathlib import Path

import numpy as np

from xvmatch.core.output_paths import claim_folder
from xvmatch.viz.box_canvas import blank_view, top_plan
from xvmatch.viz.match_drawing import (
    draw_matches,
    frames_to_draw,
    picture_path,
    write_match_picture,
)

__all__ = ["write_match_pictures"]


def write_match_pictures(folder: str | os.PathLike, every: int, top: Mapping, hor: Mapping,
                         pairs: Mapping, frames: list[int], sources: dict | None,
                         hor_size: tuple[int, int], labels: bool = True, *, owner: str,
                         option: str) -> None:
    """The pictures of every ``every``-th of ``frames``, written into a temporary folder and
    moved into ``folder`` only once all are made.

    Args:
        folder: the folder: new, empty, or one ``owner`` made before
            (:func:`~xvmatch.core.output_paths.claim_folder`).
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
    """
    out = claim_folder(folder, owner, option)
    tmp = Path(tempfile.mkdtemp(prefix=".draw-", dir=out))
    plan = hor_canvas = None
    if sources is None:
        plan, hor_canvas = top_plan(top), blank_view(hor_size)
    legend = "same colour: same person; grey: unmatched"
    if sources is None:
        legend += "; boxes only: top view as a plan, horizontal view blank"
    try:
        written = []
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
            picture = draw_matches(*images, *boxes, rows, top[f].ids if labels else None,
                                   hor[f].ids if labels else None,
                                   title=f"frame {f}: {len(rows)} matches ({legend})")
            path = picture_path(tmp, f)
            write_match_picture(path, picture)
            written.append(path)
        for path in written:
            path.replace(out / path.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
