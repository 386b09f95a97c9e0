"""Pictures of one frame's cross-view association, for ``xvmatch associate ... --draw OUT``.

:func:`draw_matches` puts the top/overview image (left) and the horizontal/egocentric image
(right) side by side at a common height, with a small gap between them. Each matched pair gets its
own colour (golden-ratio hues, :func:`pair_colour`): both boxes are outlined in it (thickness 2)
and a line joins the two box centres across the gap, optionally labelled ``cost 0.04`` with the
pair's cost, only where the label covers no other label (a crowded frame shows fewer costs rather
than a pile of them). Unmatched boxes are outlined in grey (:data:`UNMATCHED_COLOUR`, thickness 1)
over a desaturated, dimmed interior. Ids, when given, are printed by each box, placed so that
labels do not cover one another where there is room. With ground truth (``correct``, e.g. from
:func:`pairs_correct`), right pairs are drawn in :data:`RIGHT_COLOUR` and wrong ones in
:data:`WRONG_COLOUR` instead; the horizontal camera's wearer (``wearer``) is marked in the top
view by a white outer outline and a ``camera`` label.

:func:`write_match_picture` stores a picture as JPEG (quality 90: a few hundred kB for a real
frame) or PNG (maximum compression) through the project's one atomic writer
(:func:`~xvmatch.core.atomic_files.atomic_write_bytes`); :func:`picture_path` names the file
of a frame (``frame_000212.jpg``) and :func:`frames_to_draw` picks every k-th frame of a sequence.

This module uses numpy and OpenCV only (no torch), both in the base install.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from xvmatch.core.array_checks import as_boxes
from xvmatch.core.atomic_files import atomic_write_bytes

__all__ = [
    "GAP_COLOUR",
    "JPEG_QUALITY",
    "RIGHT_COLOUR",
    "UNMATCHED_COLOUR",
    "WEARER_COLOUR",
    "WRONG_COLOUR",
    "draw_matches",
    "frames_to_draw",
    "pair_colour",
    "pairs_correct",
    "picture_path",
    "write_match_picture",
]

UNMATCHED_COLOUR: tuple[int, int, int] = (128, 128, 128)
"""BGR outline colour of an unmatched box."""
GAP_COLOUR: tuple[int, int, int] = (255, 255, 255)
"""BGR colour of the gap between the two images (the lines of matched pairs cross it)."""
RIGHT_COLOUR: tuple[int, int, int] = (60, 200, 60)
"""BGR colour of a pair that the ground truth confirms (green)."""
WRONG_COLOUR: tuple[int, int, int] = (40, 40, 230)
"""BGR colour of a pair that the ground truth contradicts (red)."""
WEARER_COLOUR: tuple[int, int, int] = (255, 255, 255)
"""BGR colour of the outer outline and label marking the camera wearer in the top view."""

_GAP = 16  # px between the two images
_HEADER_COLOUR = (32, 32, 32)
_TITLE_COLOUR = (235, 235, 235)
_UNMATCHED_TEXT = (200, 200, 200)
_OUTLINE = (0, 0, 0)  # dark halo under lines and text, for contrast on any background
_DIM = 0.55  # brightness factor of an unmatched box's greyed interior
_GOLDEN = 0.6180339887498949


def pair_colour(index: int) -> tuple[int, int, int]:
    """The BGR colour of the ``index``-th matched pair (pairs sorted by top, then hor index).

    Hues step by the golden ratio of the hue circle, so consecutive pairs differ strongly and any
    number of pairs gets distinct colours; saturation and value are high, so no colour is grey.

    Args:
        index: the pair's position (>= 0) in sorted order.

    Returns:
        ``(b, g, r)`` ints in 0..255.
    """
    hue = round((int(index) * _GOLDEN % 1.0) * 180) % 180  # OpenCV 8-bit hue is 0..179
    bgr = cv2.cvtColor(np.array([[[hue, 230, 255]]], np.uint8), cv2.COLOR_HSV2BGR)[0, 0]
    return int(bgr[0]), int(bgr[1]), int(bgr[2])


def _check_image(image: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] == 0 or arr.shape[1] == 0:
        raise ValueError(f"{name} must be a non-empty (H, W, 3) BGR image, got shape {arr.shape}")
    if arr.dtype != np.uint8:
        raise ValueError(
            f"{name} must be uint8 (OpenCV 8-bit BGR), got {arr.dtype}; "
            "convert with np.clip(img, 0, 255).astype(np.uint8)"
        )
    return arr


def _check_pairs(pairs: np.ndarray, m: int, n: int) -> np.ndarray:
    p = np.asarray(pairs)
    if p.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ValueError(f"pairs must have shape (K, 2) as (top index, hor index), got {p.shape}")
    if not np.issubdtype(p.dtype, np.integer):
        raise ValueError(f"pairs must hold integer box indices, got dtype {p.dtype}")
    bad = (p[:, 0] < 0) | (p[:, 0] >= m) | (p[:, 1] < 0) | (p[:, 1] >= n)
    if bad.any():
        k = int(np.flatnonzero(bad)[0])
        raise ValueError(
            f"pairs[{k}] = {p[k].tolist()} is out of range for {m} top and {n} hor boxes"
        )
    if len(np.unique(p[:, 0])) != len(p) or len(np.unique(p[:, 1])) != len(p):
        raise ValueError("pairs repeat a top or a hor index; a box can be matched at most once")
    order = np.lexsort((p[:, 1], p[:, 0]))
    return p[order].astype(np.int64)


def _check_ids(ids: Sequence | np.ndarray | None, count: int, name: str) -> list | None:
    if ids is None:
        return None
    values = list(np.asarray(ids).reshape(-1)) if np.ndim(ids) else None
    if values is None or len(values) != count:
        raise ValueError(f"{name} must give one id per box ({count}), got {np.shape(ids)}")
    return values


def _id_text(value: object) -> str:
    if isinstance(value, float | np.floating) and float(value).is_integer():
        return str(int(value))
    return str(value.item() if isinstance(value, np.generic) else value)


def _cost_text(value: float) -> str:
    return f"cost {value:.2f}" if np.isfinite(value) else f"cost {value}"


def _scaled_boxes(
    boxes: np.ndarray, sx: float, sy: float, width: int, height: int
) -> np.ndarray:
    """Inclusive pixel rectangles ``(x0, y0, x1, y1)`` of boxes in a scaled panel, clipped to it."""
    x0 = np.round(boxes[:, 0] * sx)
    y0 = np.round(boxes[:, 1] * sy)
    x1 = np.maximum(np.round((boxes[:, 0] + boxes[:, 2]) * sx) - 1, x0)
    y1 = np.maximum(np.round((boxes[:, 1] + boxes[:, 3]) * sy) - 1, y0)
    rect = np.stack([x0, y0, x1, y1], axis=1)
    rect[:, 0::2] = np.clip(rect[:, 0::2], 0, width - 1)
    rect[:, 1::2] = np.clip(rect[:, 1::2], 0, height - 1)
    return rect.astype(np.int64).reshape(-1, 4)


def _panel(image: np.ndarray, height: int) -> tuple[np.ndarray, float, float]:
    """The image resized to ``height`` (aspect kept), with its x and y scale factors."""
    h, w = image.shape[:2]
    width = max(round(w * height / h), 1)
    if (h, w) == (height, width):
        return image.copy(), 1.0, 1.0
    interpolation = cv2.INTER_AREA if height < h else cv2.INTER_LINEAR
    panel = cv2.resize(np.ascontiguousarray(image), (width, height), interpolation=interpolation)
    return panel, width / w, height / h


def _grey_out(panel: np.ndarray, rects: np.ndarray, unmatched: np.ndarray) -> None:
    """Desaturate and dim, in place, the unmatched boxes' interiors not covered by matched ones."""
    if not unmatched.any():
        return
    mask = np.zeros(panel.shape[:2], dtype=bool)
    for x0, y0, x1, y1 in rects[unmatched]:
        mask[y0:y1 + 1, x0:x1 + 1] = True
    for x0, y0, x1, y1 in rects[~unmatched]:
        mask[y0:y1 + 1, x0:x1 + 1] = False
    grey = (cv2.cvtColor(panel, cv2.COLOR_BGR2GRAY).astype(np.float32) * _DIM).astype(np.uint8)
    panel[mask] = grey[mask][:, None]


def _put_text(
    canvas: np.ndarray,
    text: str,
    org: tuple[int, int],
    colour: tuple[int, int, int],
    scale: float,
) -> None:
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(canvas, text, org, font, scale, _OUTLINE, 3, cv2.LINE_AA)
    cv2.putText(canvas, text, org, font, scale, colour, 1, cv2.LINE_AA)


def _text_rect(text: str, org: tuple[int, int], scale: float) -> tuple[int, int, int, int]:
    """The ``(x0, y0, x1, y1)`` pixels a label drawn at ``org`` (its baseline start) covers."""
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    return org[0] - 1, org[1] - th - 1, org[0] + tw + 1, org[1] + base + 1


def _overlap(a: tuple[int, int, int, int], placed: list[tuple[int, int, int, int]]) -> int:
    """Pixels of rectangle ``a`` covered by the rectangles ``placed`` (summed)."""
    total = 0
    for b in placed:
        w = min(a[2], b[2]) - max(a[0], b[0])
        h = min(a[3], b[3]) - max(a[1], b[1])
        total += max(w, 0) * max(h, 0)
    return total


def _place_label(text: str, candidates: list[tuple[int, int]], x_range: tuple[int, int],
                 y_range: tuple[int, int], scale: float,
                 placed: list[tuple[int, int, int, int]], free_only: bool = False
                 ) -> tuple[int, int] | None:
    """The first of ``candidates`` (baseline origins, in order of preference), kept inside
    ``x_range`` and ``y_range``, whose label covers none of the labels ``placed``; else the one
    covering the fewest pixels of them, or None with ``free_only`` (the label is not drawn).
    The chosen label's rectangle is added to ``placed``."""
    (tw, th), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    best = None
    for x, y in candidates:
        x = min(max(x, x_range[0]), max(x_range[1] - tw, x_range[0]))
        y = min(max(y, y_range[0] + th + 1), max(y_range[1] - base - 1, y_range[0] + th + 1))
        rect = _text_rect(text, (x, y), scale)
        cover = _overlap(rect, placed)
        if best is None or cover < best[0]:
            best = (cover, (x, y), rect)
        if cover == 0:
            break
    if free_only and best[0] > 0:
        return None
    placed.append(best[2])
    return best[1]


def _label_candidates(text: str, rect: np.ndarray, scale: float) -> list[tuple[int, int]]:
    """Where a box's label may go, best first: above its top-left corner, just inside it,
    below it, beside it on the right."""
    (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    x0, y0, x1, y1 = (int(v) for v in rect)
    return [(x0, y0 - 4), (x0 + 2, y0 + th + 4), (x0, y1 + th + 4), (x1 + 4, y0 + th + 2),
            (x0 - tw - 4, y0 + th + 2), (x0, (y0 + y1) // 2)]


def _check_costs(costs: np.ndarray | None, m: int, n: int) -> np.ndarray | None:
    """The ``(M, N)`` cost matrix as floats, or None; refuses another shape."""
    if costs is None:
        return None
    cost = np.asarray(costs, dtype=float)
    if cost.shape != (m, n):
        raise ValueError(
            f"costs must have shape (M, N) = ({m}, {n}) to match the boxes, got {cost.shape}"
        )
    return cost


def pairs_correct(top_ids: Sequence | np.ndarray, hor_ids: Sequence | np.ndarray,
                  pairs: np.ndarray) -> np.ndarray:
    """Which pairs the ground truth confirms, as ``xvmatch evaluate`` reads it: the two boxes
    carry the same id (the box files' ids are the people's true identities).

    Args:
        top_ids: (M,) the top boxes' true ids.
        hor_ids: (N,) the horizontal boxes' true ids.
        pairs: (K, 2) ``(top index, hor index)`` rows.

    Returns:
        (K,) bool, in the order of ``pairs``.
    """
    top, hor = np.asarray(top_ids).reshape(-1), np.asarray(hor_ids).reshape(-1)
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if p.size and (p[:, 0].max() >= len(top) or p[:, 1].max() >= len(hor) or p.min() < 0):
        raise ValueError(f"pairs index past the {len(top)} top or {len(hor)} hor ids")
    return top[p[:, 0]] == hor[p[:, 1]]


def _pair_colours(pairs_given: np.ndarray, pairs: np.ndarray,
                  correct: Sequence[bool] | np.ndarray | None,
                  keys: Sequence[int] | np.ndarray | None = None) -> list[tuple[int, int, int]]:
    """Each sorted pair's colour: :func:`pair_colour` of its position (or of its key in
    ``keys``) without ground truth, else :data:`RIGHT_COLOUR` or :data:`WRONG_COLOUR` from
    ``correct``; ``correct`` and ``keys`` are given in the order of ``pairs_given``, the
    caller's."""
    given = np.asarray(pairs_given, dtype=np.int64).reshape(-1, 2)
    if correct is None and keys is not None:
        values = np.asarray(keys).reshape(-1)
        if len(values) != len(pairs) or (values.size and values.dtype.kind not in "iu"):
            raise ValueError(f"keys must give one integer per pair ({len(pairs)}), got "
                             f"{np.shape(keys)} of {values.dtype}")
        key_of = {(int(i), int(j)): int(k) for (i, j), k in zip(given, values, strict=True)}
        return [pair_colour(key_of[(int(i), int(j))]) for i, j in pairs]
    if correct is None:
        return [pair_colour(k) for k in range(len(pairs))]
    flags = np.asarray(correct).reshape(-1)
    if (flags.size and flags.dtype != bool) or len(flags) != len(pairs):
        raise ValueError(f"correct must give one bool per pair ({len(pairs)}), got "
                         f"{np.shape(correct)} of {flags.dtype}")
    truth = {(int(i), int(j)): bool(ok) for (i, j), ok in zip(given, flags, strict=True)}
    return [RIGHT_COLOUR if truth[(int(i), int(j))] else WRONG_COLOUR for i, j in pairs]


def _check_wearer(wearer: int | None, m: int) -> int | None:
    """The wearer's top-box index, or None; refuses one out of range."""
    if wearer is None:
        return None
    if isinstance(wearer, bool) or int(wearer) != wearer or not 0 <= wearer < m:
        raise ValueError(f"wearer must be the index of a top box, 0..{m - 1}, got {wearer!r}")
    return int(wearer)


def _check_max_height(max_height: int) -> int:
    """``max_height`` as an int; refuses a bool, a fraction or a value below 1."""
    if isinstance(max_height, bool) or int(max_height) != max_height or max_height < 1:
        raise ValueError(f"max_height must be an integer >= 1 (pixels), got {max_height!r}")
    return int(max_height)


def _box_panels(
    images: tuple[np.ndarray, np.ndarray], boxes: tuple[np.ndarray, np.ndarray],
    pairs: np.ndarray, height: int, colours: list[tuple[int, int, int]],
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Scale both views to ``height`` and draw their boxes: unmatched greyed, pairs coloured.

    Args:
        images: the checked top and hor images.
        boxes: their ``(M, 4)`` and ``(N, 4)`` boxes in image pixels.
        pairs: ``(K, 2)`` sorted ``(top index, hor index)`` rows.
        height: the common panel height, pixels.
        colours: the colour of each pair.

    Returns:
        The two panels and the boxes' ``(x0, y0, x1, y1)`` corners in panel pixels.
    """
    panels, rects = [], []
    for column, (image, view_boxes) in enumerate(zip(images, boxes, strict=True)):
        panel, sx, sy = _panel(image, height)
        rect = _scaled_boxes(view_boxes, sx, sy, panel.shape[1], panel.shape[0])
        is_matched = np.zeros(len(view_boxes), dtype=bool)
        is_matched[pairs[:, column]] = True
        _grey_out(panel, rect, ~is_matched)
        for x0, y0, x1, y1 in rect[~is_matched]:
            cv2.rectangle(panel, (int(x0), int(y0)), (int(x1), int(y1)), UNMATCHED_COLOUR, 1,
                          cv2.LINE_8)
        panels.append(panel)
        rects.append(rect)
    for k, (i, j) in enumerate(pairs):
        for rect, index, panel in ((rects[0], i, panels[0]), (rects[1], j, panels[1])):
            x0, y0, x1, y1 = (int(v) for v in rect[index])
            cv2.rectangle(panel, (x0, y0), (x1, y1), colours[k], 2, cv2.LINE_8)
    return panels, rects


def _pair_lines(
    canvas: np.ndarray, pairs: np.ndarray, rects: list[np.ndarray],
    offsets: tuple[tuple[int, int], tuple[int, int]], colours: list[tuple[int, int, int]],
) -> list[list[tuple[int, int]]]:
    """Join each pair's box centres with an outlined line; returns each line's two ends."""
    ends = []
    for k, (i, j) in enumerate(pairs):
        points = []
        for rect, index, (ox, oy) in ((rects[0], i, offsets[0]), (rects[1], j, offsets[1])):
            x0, y0, x1, y1 = rect[index]
            points.append((ox + int(x0 + x1) // 2, oy + int(y0 + y1) // 2))
        cv2.line(canvas, points[0], points[1], _OUTLINE, 4, cv2.LINE_AA)
        cv2.line(canvas, points[0], points[1], colours[k], 2, cv2.LINE_AA)
        ends.append(points)
    return ends


def _id_labels(
    canvas: np.ndarray, labels: tuple[list | None, list | None], pairs: np.ndarray,
    rects: list[np.ndarray], offsets: tuple[tuple[int, int], tuple[int, int]],
    x_ranges: tuple[tuple[int, int], tuple[int, int]], y_range: tuple[int, int],
    colours: list[tuple[int, int, int]], scale: float, placed: list[tuple[int, int, int, int]],
) -> None:
    """Print the ids by their boxes, matched boxes first (they get the best places).

    ``placed`` holds the label rectangles drawn so far and is extended in place.
    """
    for side, side_labels in enumerate(labels):
        if side_labels is None:
            continue
        ox, oy = offsets[side]
        pair_of = {int(idx): k for k, idx in enumerate(pairs[:, side])}
        order = sorted(range(len(side_labels)), key=lambda i: (pair_of.get(i) is None, i))
        for index in order:
            text = _id_text(side_labels[index])
            k = pair_of.get(index)
            colour = _UNMATCHED_TEXT if k is None else colours[k]
            rect = rects[side][index] + np.array([ox, oy, ox, oy])
            org = _place_label(text, _label_candidates(text, rect, scale), x_ranges[side],
                               y_range, scale, placed)
            _put_text(canvas, text, org, colour, scale)


def _cost_labels(
    canvas: np.ndarray, cost: np.ndarray, pairs: np.ndarray, ends: list[list[tuple[int, int]]],
    y_range: tuple[int, int], colours: list[tuple[int, int, int]], scale: float,
    placed: list[tuple[int, int, int, int]],
) -> list[tuple[str, tuple[int, int]]]:
    """Print each matched pair's cost along its line (its middle first, then further towards
    either end, above or below it), only where the label covers no earlier label: in a crowded
    frame some costs are left out rather than piled up. Returns the ``(text, origin)`` of the
    labels drawn."""
    drawn = []
    for k, (i, j) in enumerate(pairs):
        text = _cost_text(float(cost[i, j]))
        tw = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)[0][0]
        (ax, ay), (bx, by) = ends[k]
        candidates = []
        for t in (0.5, 0.4, 0.6, 0.3, 0.7, 0.2, 0.8):
            mx, my = round(ax + t * (bx - ax)) - tw // 2, round(ay + t * (by - ay))
            candidates += [(mx, my - 5), (mx, my + 18)]
        org = _place_label(text, candidates, (0, canvas.shape[1]), y_range, scale, placed,
                           free_only=True)
        if org is not None:
            _put_text(canvas, text, org, colours[k], scale)
            drawn.append((text, org))
    return drawn


def _mark_wearer(canvas: np.ndarray, rect: np.ndarray, x_range: tuple[int, int],
                 y_range: tuple[int, int], scale: float,
                 placed: list[tuple[int, int, int, int]]) -> None:
    """Mark the camera wearer's top box (canvas pixels ``rect``): a white outline 3 px outside
    it over a dark halo, and a ``camera`` label in the best free place by it."""
    x0, y0, x1, y1 = (int(v) for v in rect)
    outer = (x0 - 3, y0 - 3), (x1 + 3, y1 + 3)
    cv2.rectangle(canvas, *outer, _OUTLINE, 3, cv2.LINE_8)
    cv2.rectangle(canvas, *outer, WEARER_COLOUR, 1, cv2.LINE_8)
    text = "camera"
    org = _place_label(text, _label_candidates(text, np.array([x0 - 3, y0 - 3, x1 + 3, y1 + 3]),
                                               scale), x_range, y_range, scale, placed)
    _put_text(canvas, text, org, WEARER_COLOUR, scale)


def _side_by_side(
    panels: list[np.ndarray], header: int
) -> tuple[np.ndarray, tuple[tuple[int, int], ...], tuple[tuple[int, int], ...]]:
    """Place the two panels side by side, a gap between, below a ``header``-pixel strip.

    Returns:
        The canvas, each panel's ``(x, y)`` offset in it and each panel's ``(x0, x1)`` range
        for its labels (the hor panel's runs to the canvas's right edge).
    """
    height = panels[0].shape[0]
    w_top, w_hor = panels[0].shape[1], panels[1].shape[1]
    canvas = np.empty((header + height, w_top + _GAP + w_hor, 3), dtype=np.uint8)
    canvas[:] = GAP_COLOUR
    canvas[header:, :w_top] = panels[0]
    canvas[header:, w_top + _GAP:] = panels[1]
    offsets = ((0, header), (w_top + _GAP, header))
    x_ranges = ((0, w_top), (w_top + _GAP, canvas.shape[1]))
    return canvas, offsets, x_ranges


def _draw_title(canvas: np.ndarray, header: int, title: str) -> None:
    """Fill the header strip and write ``title`` in it on one line (whitespace collapsed)."""
    canvas[:header] = _HEADER_COLOUR
    caption = " ".join(str(title).split())
    cv2.putText(canvas, caption, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, _TITLE_COLOUR, 1,
                cv2.LINE_AA)


def draw_matches(
    top_image: np.ndarray,
    hor_image: np.ndarray,
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    pairs: np.ndarray,
    top_ids: Sequence | np.ndarray | None = None,
    hor_ids: Sequence | np.ndarray | None = None,
    costs: np.ndarray | None = None,
    title: str | None = None,
    max_height: int = 720,
    correct: Sequence[bool] | np.ndarray | None = None,
    wearer: int | None = None,
    keys: Sequence[int] | np.ndarray | None = None,
) -> np.ndarray:
    """One frame's association as a picture: top view left, horizontal view right, pairs joined.

    Both images are scaled to a common height, the larger of their heights capped at
    ``max_height``, keeping their aspect ratios, and placed side by side with a
    :data:`GAP_COLOUR` gap of 16 px. Boxes are given in each image's own pixels and may run past
    the image; they are clipped for drawing. The ``k``-th pair in sorted order (by top index, then
    hor index) is drawn in :func:`pair_colour` ``(k)``: both boxes (thickness 2) and a line from
    the top box's centre to the hor box's centre. Unmatched boxes are outlined in
    :data:`UNMATCHED_COLOUR` (thickness 1) over a desaturated, dimmed interior.

    Args:
        top_image: (H1, W1, 3) uint8 BGR top/overview image.
        hor_image: (H2, W2, 3) uint8 BGR horizontal/egocentric image; its size may differ.
        top_boxes: (M, 4) float ``(x, y, w, h)`` boxes in ``top_image`` pixels; M may be 0.
        hor_boxes: (N, 4) float ``(x, y, w, h)`` boxes in ``hor_image`` pixels; N may be 0.
        pairs: (K, 2) int ``(top index, hor index)`` rows, one-to-at-most-one (as returned by
            :func:`~xvmatch.inference.linking.assignment.assign`); K may be 0.
        top_ids: M ids printed by the top boxes (e.g. track ids); ``None`` prints none. Labels
            are placed so as not to cover one another where the boxes leave room (matched
            boxes' labels first).
        hor_ids: N ids printed by the hor boxes; ``None`` prints none.
        costs: (M, N) association costs; each matched pair's cost is printed by its line as
            ``cost 0.04`` where the label covers no other label; ``None`` prints none.
        title: one line drawn in a dark header strip above the images; ``None`` for no strip.
        max_height: the largest height (px, >= 1) of the scaled images.
        correct: (K,) bool, one per row of ``pairs`` (in the given order): whether the ground
            truth confirms the pair (:func:`pairs_correct`); the pair is then drawn in
            :data:`RIGHT_COLOUR` or :data:`WRONG_COLOUR` instead of its own colour. ``None``:
            no ground truth.
        wearer: index of the top box of the horizontal camera's wearer (``--camera-id``),
            marked by a white outer outline and a ``camera`` label; ``None``: not known.
        keys: (K,) int, one per row of ``pairs`` (in the given order): the pair is drawn in
            :func:`pair_colour` ``(key)`` instead of by its position, so that a key kept from
            frame to frame (a track id) keeps its colour; ignored with ``correct``. ``None``:
            by position.

    Returns:
        (header + H, W1' + 16 + W2', 3) uint8 BGR picture, ``H <= max_height``; the inputs are
        not modified.

    Raises:
        ValueError: an image that is not non-empty (H, W, 3) uint8, boxes not (N, 4) finite with
            non-negative sizes, pairs not (K, 2) integer indices in range or not one-to-one, ids
            of the wrong length, costs not (M, N), ``correct`` not one bool per pair, ``keys``
            not one integer per pair, ``wearer`` not a top box's index, or ``max_height < 1``.

    Example:
        >>> img = np.zeros((90, 160, 3), np.uint8)
        >>> pic = draw_matches(img, img, [[10, 10, 20, 40]], [[50, 20, 30, 60]], [[0, 0]])
        >>> pic.shape, pic.dtype
        ((90, 336, 3), dtype('uint8'))
    """
    top_img = _check_image(top_image, "top_image")
    hor_img = _check_image(hor_image, "hor_image")
    top_b = as_boxes(top_boxes, "top_boxes")
    hor_b = as_boxes(hor_boxes, "hor_boxes")
    m, n = len(top_b), len(hor_b)
    p = _check_pairs(pairs, m, n)
    top_labels = _check_ids(top_ids, m, "top_ids")
    hor_labels = _check_ids(hor_ids, n, "hor_ids")
    cost = _check_costs(costs, m, n)
    wearer_index = _check_wearer(wearer, m)
    height = min(_check_max_height(max_height), max(top_img.shape[0], hor_img.shape[0]))
    colours = _pair_colours(pairs, p, correct, keys)
    panels, rects = _box_panels((top_img, hor_img), (top_b, hor_b), p, height, colours)
    header = 26 if title is not None else 0
    canvas, offsets, x_ranges = _side_by_side(panels, header)
    scale = 0.45 * max(height / 360.0, 0.8)
    ends = _pair_lines(canvas, p, rects, offsets, colours)
    placed: list[tuple[int, int, int, int]] = []  # label rectangles drawn so far
    y_range = (header, canvas.shape[0])
    if wearer_index is not None:  # first: its label gets the best place
        rect = rects[0][wearer_index] + np.array([*offsets[0], *offsets[0]])
        _mark_wearer(canvas, rect, x_ranges[0], y_range, scale, placed)
    _id_labels(canvas, (top_labels, hor_labels), p, rects, offsets, x_ranges, y_range, colours,
               scale, placed)
    if cost is not None:
        _cost_labels(canvas, cost, p, ends, y_range, colours, scale, placed)
    if title is not None:
        _draw_title(canvas, header, title)
    return canvas


JPEG_QUALITY = 90
"""Quality of the JPEG pictures (OpenCV's 0..100 scale)."""


def write_match_picture(path: str | os.PathLike, picture: np.ndarray) -> None:
    """Store a picture of :func:`draw_matches` as a JPEG (``.jpg``/``.jpeg``, quality
    :data:`JPEG_QUALITY`) or PNG (``.png``, maximum compression) file, atomically.

    The folder is created if missing. The bytes go through
    :func:`~xvmatch.core.atomic_files.atomic_write_bytes` (temporary file, then rename, without
    ``fsync`` as for other bulk image writes): a reader sees the old file or the new one, never a
    partial one, and an existing file is replaced.

    Args:
        path: destination file, ending in ``.jpg``, ``.jpeg`` or ``.png`` (see
            :func:`picture_path`).
        picture: (H, W, 3) uint8 BGR picture.

    Raises:
        ValueError: a path with another ending, a path that exists and is not a regular file
            (a folder, a FIFO, a device: renaming over it would replace it), a picture that is
            not non-empty (H, W, 3) uint8, or a picture OpenCV cannot encode.
    """
    target = Path(path)
    suffix = target.suffix.lower()
    if suffix not in (".jpg", ".jpeg", ".png"):
        raise ValueError(f"path must end in .jpg, .jpeg or .png (the pictures are JPEG or PNG), "
                         f"got {str(target)!r}")
    if target.exists() and not target.is_file():
        raise ValueError(f"{os.fspath(target)}: exists and is not a regular file; refusing to "
                         "write a picture over it")
    image = _check_image(picture, "picture")
    params = ([cv2.IMWRITE_PNG_COMPRESSION, 9] if suffix == ".png"
              else [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    ok, encoded = cv2.imencode(suffix, np.ascontiguousarray(image), params)
    if not ok:
        raise ValueError(f"OpenCV could not encode a picture of shape {image.shape} as {suffix}")
    target.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(target, encoded.tobytes(), fsync=False)


def picture_path(folder: str | os.PathLike, frame: int, suffix: str = ".jpg") -> Path:
    """The file of a frame's picture: ``folder / f"frame_{frame:06d}.jpg"`` (``suffix``
    ``.png`` for a PNG).

    Args:
        folder: the ``--draw`` output folder.
        frame: the frame number (>= 0; MOT frames are 1-based).
        suffix: the file type, ``.jpg`` (default) or ``.png``.

    Raises:
        ValueError: a negative frame or another suffix.
    """
    if int(frame) != frame or frame < 0:
        raise ValueError(f"frame must be an integer >= 0, got {frame!r}")
    if suffix not in (".jpg", ".png"):
        raise ValueError(f"suffix must be '.jpg' or '.png', got {suffix!r}")
    return Path(folder) / f"frame_{int(frame):06d}{suffix}"


def frames_to_draw(frames: Sequence[int], every: int) -> list[int]:
    """Every ``every``-th frame of the sorted, distinct ``frames``, starting with the first.

    Args:
        frames: frame numbers, in any order; repeats count once.
        every: the step (>= 1); 1 draws every frame.

    Returns:
        The chosen frame numbers, ascending.

    Raises:
        ValueError: ``every`` not an integer >= 1.

    Example:
        >>> frames_to_draw([5, 1, 2, 3, 4, 6], every=2)
        [1, 3, 5]
    """
    if isinstance(every, bool) or not isinstance(every, int | np.integer) or every < 1:
        raise ValueError(f"every must be an integer >= 1 (draw every k-th frame), got {every!r}")
    return [int(f) for f in sorted({int(f) for f in frames})[:: int(every)]]
