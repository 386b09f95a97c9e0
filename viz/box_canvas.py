"""Canvases for pictures of box-only results: the horizontal view blank at its image size, the
top view as a plan (issue 29, item 5).

Without images, ``xvmatch associate --draw`` still draws each frame's matches
(:func:`~xvmatch.viz.match_drawing.draw_matches`): the horizontal boxes on a blank canvas
of the horizontal image size (:func:`blank_view`), the top boxes on a plan framing every top box
of the sequence (:func:`top_plan`: the top image's size is unknown and no feature needs it), the
same framing for every frame so that people move on it as they walk. numpy and OpenCV only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.viz.match_drawing import draw_matches

__all__ = ["CANVAS_COLOUR", "GRID_COLOUR", "TopPlan", "blank_view", "draw_box_frame", "top_plan"]

CANVAS_COLOUR: tuple[int, int, int] = (236, 236, 236)
"""BGR colour of a blank view (light grey: white boxes' interiors stay visible)."""
GRID_COLOUR: tuple[int, int, int] = (212, 212, 212)
"""BGR colour of the plan's grid lines."""


def blank_view(size: tuple[int, int]) -> np.ndarray:
    """A blank ``(H, W, 3)`` uint8 BGR canvas of ``size = (W, H)`` pixels.

    Raises:
        ValueError: a side < 1.
    """
    width, height = (int(v) for v in size)
    if width < 1 or height < 1:
        raise ValueError(f"size must be (width, height) >= 1, got {size}")
    canvas = np.empty((height, width, 3), np.uint8)
    canvas[:] = CANVAS_COLOUR
    return canvas


@dataclass(frozen=True)
class TopPlan:
    """The top view drawn as a plan: a canvas framing every top box of a sequence.

    Attributes:
        image: ``(H, W, 3)`` uint8 BGR canvas with a light grid (10 cells along its longer side).
        offset: ``(dx, dy)`` pixels added to a top box's ``x, y`` before scaling.
        scale: canvas pixels per top-image pixel (1 unless the plan would exceed its size).
    """

    image: np.ndarray
    offset: tuple[float, float]
    scale: float = 1.0

    def place(self, boxes: np.ndarray) -> np.ndarray:
        """``(N, 4)`` ``x, y, w, h`` top boxes moved onto the plan (canvas pixels)."""
        out = np.array(boxes, dtype=float).reshape(-1, 4)
        out[:, 0] += self.offset[0]
        out[:, 1] += self.offset[1]
        return out * self.scale


def top_plan(frames: Mapping, pad: float = 0.05, max_side: int = 2048) -> TopPlan:
    """The plan of a top view's ``{frame: FrameBoxes}``: every box inside it, with a margin of
    ``pad`` times the boxes' extent (at least 8 px) on each side.

    Args:
        frames: the top view's boxes (pixels of its unknown image).
        pad: margin, a share of the larger side of the boxes' extent.
        max_side: the canvas is at most this many pixels along its longer side (the boxes keep
            their own pixel units: :func:`~xvmatch.viz.match_drawing.draw_matches` scales
            the canvas and the boxes together, so only the plan's aspect ratio matters).

    Returns:
        The :class:`TopPlan`; a 64x64 one without boxes.
    """
    boxes = [np.asarray(r.boxes, dtype=float).reshape(-1, 4) for r in frames.values()]
    b = np.concatenate(boxes) if boxes else np.zeros((0, 4))
    if not len(b):
        return TopPlan(blank_view((64, 64)), (0.0, 0.0))
    x0, y0 = float(b[:, 0].min()), float(b[:, 1].min())
    x1, y1 = float((b[:, 0] + b[:, 2]).max()), float((b[:, 1] + b[:, 3]).max())
    margin = max(pad * max(x1 - x0, y1 - y0), 8.0)
    width, height = x1 - x0 + 2 * margin, y1 - y0 + 2 * margin
    # The boxes' pixel units up to max_side; beyond it a smaller canvas, place() scales boxes.
    scale = min(1.0, max_side / max(width, height))
    size = (max(math.ceil(width * scale), 1), max(math.ceil(height * scale), 1))
    image = blank_view(size)
    step = max(size) / 10.0
    for k in range(1, 10):
        at = round(k * step)
        if at < size[0]:
            image[:, at] = GRID_COLOUR
        if at < size[1]:
            image[at, :] = GRID_COLOUR
    return TopPlan(image, (margin - x0, margin - y0), scale)


def draw_box_frame(top: Mapping, hor: Mapping, frame: int, hor_size: tuple[int, int],
                   pairs: list[tuple[int, int]] | None = None, *, labels: bool = True,
                   source: str = "pairs") -> np.ndarray:
    """One frame of two box files drawn as ``xvmatch show --top --hor`` does: the horizontal
    boxes on a blank view of ``hor_size``, the top ones on the sequence's plan (:func:`top_plan`).

    Args:
        top, hor: each view's ``{frame: FrameBoxes}``; ``frame`` must have boxes in both.
        frame: the frame to draw.
        hor_size: ``(width, height)`` of the horizontal image.
        pairs: ``(top_id, hor_id)`` pairs to draw (a prediction), or None: the ids found in both
            views (ground truth).
        labels: print each box's id by it.
        source: the name of ``pairs``' file, for the error message.

    Returns:
        The ``(H, W, 3)`` uint8 BGR picture, titled with what it shows.

    Raises:
        ValueError: a pair naming an id without a box in the frame.
    """
    t_ids, h_ids = top[frame].ids.tolist(), hor[frame].ids.tolist()
    if pairs is not None:
        for a, b in pairs:
            if a not in t_ids or b not in h_ids:
                raise ValueError(f"{source}: frame {frame}: pair ({a}, {b}) names a box "
                                 "that is not in the box files")
        what = f"{len(pairs)} pairs of {source}"
    else:
        pairs = [(i, i) for i in t_ids if i in h_ids]
        what = f"{len(pairs)} people with the same id in both views"
    rows = [(t_ids.index(a), h_ids.index(b)) for a, b in pairs]
    plan = top_plan(top)
    return draw_matches(
        plan.image, blank_view(hor_size), plan.place(top[frame].boxes), hor[frame].boxes,
        np.array(rows, dtype=np.int64).reshape(-1, 2),
        t_ids if labels else None, h_ids if labels else None,
        title=f"frame {frame}: {what} (same colour: same person; grey: unmatched; top view as "
        "a plan)")
