"""Linking boxes over time by motion when the camera itself moves (a head-worn camera).

A head-worn camera turns and shakes: between two frames every box of the view jumps by about
the same number of pixels, often by more than its own width, so the overlap of a person's two
boxes is no evidence (on the multi-egocentric benchmark's tuning scenes half of a person's
consecutive boxes overlap with IoU below 0.7, a tenth not at all). Removing that common shift
first leaves each person's own motion, a few hundredths of a box height per frame. Boxes are
``x, y, w, h`` in pixels; distances are in box heights (``sqrt`` of the two boxes' heights), so
that one gate means the same at every image size and depth. Whether a view is a video at all
(its ids persist from frame to frame) is :func:`is_video`; whether its boxes move like a
video's, whatever their ids, is :func:`frame_jump` (what ``track`` warns about).
"""

from __future__ import annotations

from collections.abc import Mapping
from itertools import pairwise

import numpy as np

from xvmatch.core.array_checks import as_boxes, as_points
from xvmatch.cues.spatial_vectors import box_centres

__all__ = ["JUMP_BOXES", "JUMP_FRAME_PAIRS", "MIN_JUMPS", "MIN_VIDEO_FRAMES", "SHIFT_BLOCK",
           "VIDEO_JUMP", "VIDEO_RECURRENCE", "common_shift", "frame_jump", "id_recurrence",
           "is_video", "jump_warning", "jumps_like_frames", "motion_link_costs"]

SHIFT_BLOCK = 256
"""Shift proposals scored at once by :func:`common_shift` (a dozen people: one block)."""


VIDEO_RECURRENCE = 0.5
"""Share of a view's boxes whose id its previous frame also holds, at least, for the view to be
a video with track ids: 0.91-0.93 on the real CVMHAT head-worn views kept every 10th frame,
0.99 every frame, 1.0 in their drone views; 0 where ids are row numbers."""
MIN_VIDEO_FRAMES = 3
"""Frames with boxes a view needs, at least, to be taken for a video."""


def id_recurrence(frames: Mapping) -> float:
    """Share of a view's boxes (after its first frame with boxes) whose id the previous frame
    with boxes also holds: how far the ids are track ids, persisting over time (NaN without two
    such frames).

    Args:
        frames: ``{frame: record}`` with ``ids`` (``FrameBoxes``).
    """
    held = [np.asarray(frames[f].ids) for f in sorted(frames) if len(frames[f].ids)]
    if len(held) < 2:
        return float("nan")
    kept = sum(int(np.isin(b, a).sum()) for a, b in pairwise(held))
    return kept / sum(len(b) for b in held[1:])


def is_video(*views: Mapping) -> bool:
    """Whether every view is a video whose ids are track ids: :data:`MIN_VIDEO_FRAMES` frames
    with boxes or more, and :data:`VIDEO_RECURRENCE` of the boxes keeping their id from one
    frame to the next (what ``--mode video`` and the pairs' consensus over tracklets read)."""
    return all(sum(1 for r in v.values() if len(r.ids)) >= MIN_VIDEO_FRAMES
               and id_recurrence(v) >= VIDEO_RECURRENCE for v in views)


VIDEO_JUMP = 0.15
"""Median frame-to-frame jump of a view's boxes (:func:`frame_jump`, box heights per frame)
above which its frames look independent rather than a video's (issue 69, item 2). Measured:
the 10 real CVMHAT head-worn views 0.009-0.035 every frame, 0.009-0.032 kept every 10th frame
(frame numbers kept), their drone views 0.027-0.041 and 0.028-0.044; with ``xvmatch noise``'s
5 % jitter, drawn anew each frame (two pairs, both views), 0.068-0.103 every frame; ``synth
--video`` 0.021 (head-worn) and 0.000 (drone). ``synth``'s pairs (independent frames): the
head-worn view 0.171-0.364 (seeds 1, 2, 4, 11, 12, drone and overview, 37 scenes of 20-30
frames), the top view 0.000-0.201 (a drone over people standing nearly still)."""
MIN_JUMPS = 20
"""Fewest matched boxes :func:`frame_jump` needs for a median (NaN below)."""
JUMP_FRAME_PAIRS = 200
"""Consecutive frame pairs :func:`frame_jump` looks at, at most (evenly spread, so that the
measure stays cheap on a long video)."""
JUMP_BOXES = 300
"""Frames with more boxes than this are left out of :func:`frame_jump` (the assignment is
cubic in the boxes)."""


def frame_jump(frames: Mapping) -> float:
    """Median jump of a view's boxes from one frame with boxes to the next: the distance of
    matched box centres in box heights (``sqrt`` of the two heights), divided by the gap in
    frame numbers, NaN with fewer than :data:`MIN_JUMPS` matched boxes.

    Boxes are matched by a minimum-cost assignment of those distances, not by their ids, so
    that a detector's boxes (no ids, or row numbers) are measured as well as a tracker's; on
    the real views it agrees with matching by ids (see :data:`VIDEO_JUMP`). Frames are taken
    as numbered: a video kept every N-th frame and renumbered 1, 2, 3 looks N times faster.

    Args:
        frames: ``{frame: record}`` with ``boxes`` (``(N, 4)`` x, y, w, h in pixels).
    """
    from scipy.optimize import linear_sum_assignment  # half a second: not at start-up

    held = [f for f in sorted(frames) if 0 < len(frames[f].boxes) <= JUMP_BOXES]
    pairs = [(a, b) for a, b in pairwise(held)]
    if len(pairs) > JUMP_FRAME_PAIRS:
        pairs = [pairs[i] for i in np.linspace(0, len(pairs) - 1, JUMP_FRAME_PAIRS).astype(int)]
    jumps = []
    for a, b in pairs:
        box_a = np.asarray(frames[a].boxes, dtype=float).reshape(-1, 4)
        box_b = np.asarray(frames[b].boxes, dtype=float).reshape(-1, 4)
        h_a, h_b = np.maximum(box_a[:, 3], 1.0), np.maximum(box_b[:, 3], 1.0)
        d = (np.linalg.norm(box_centres(box_a)[:, None] - box_centres(box_b)[None], axis=-1)
             / np.sqrt(h_a[:, None] * h_b[None, :]))
        rows, cols = linear_sum_assignment(d)
        jumps.append(d[rows, cols] / (b - a))
    values = np.concatenate(jumps) if jumps else np.zeros(0)
    return float(np.median(values)) if values.size >= MIN_JUMPS else float("nan")


def jumps_like_frames(frames: Mapping) -> bool:
    """Whether a view's boxes jump from frame to frame like independent pictures' rather than a
    video's (:func:`frame_jump` above :data:`VIDEO_JUMP`; False when it cannot be measured)."""
    return bool(frame_jump(frames) > VIDEO_JUMP)


def jump_warning(view: str, frames: Mapping) -> str:
    """The one-line warning of a tracker given a view (named ``view``) whose boxes jump like
    independent pictures' (:func:`jumps_like_frames`), else ``""``.

    Why: tracking links each box to the one it was a frame before; on pictures taken apart
    (``synth``'s pairs, a demo's frames) those links are noise, and the tracks come out short
    and wrong (``track`` scored 28.7-43.8 CVIDF1 on them, ``associate`` 85.8-98.2), with
    nothing to say why.
    """
    jump = frame_jump(frames)
    if not jump > VIDEO_JUMP:
        return ""
    return (f"warning: the {view} view's boxes jump {jump:.2f} box heights a frame (median; a "
            f"video's move less than {VIDEO_JUMP:g}): these look like independent pictures, "
            "not a video, and tracks over them will be short and wrong; match such frames one "
            "by one with associate (or give a video, e.g. synth --video)")


def common_shift(displacement: np.ndarray, scale: np.ndarray, valid: np.ndarray,
                 radius: float, penalty: np.ndarray | None = None) -> np.ndarray:
    """The image shift most box pairs agree on: the camera's own motion between two frames.

    Every valid pair ``(k, j)`` (track ``k``'s last box, detection ``j``) proposes its
    displacement as the shift, as does zero. A pair agrees with a proposal when its distance
    from it, in the pair's scale, plus its ``penalty`` is at most ``radius``; a proposal's
    support is the number of detections with an agreeing pair (one vote per detection, so that
    a crowd of tracks near one detection cannot outvote the others). The best-supported
    proposal wins, the smallest shift (in scales) breaking ties, and the shift is then refined
    to the median of its supporters' displacements (each detection's nearest pair). Exhaustive
    over the ``M N`` proposals, so deterministic; ``O((M N)^2)`` distances, in blocks of
    :data:`SHIFT_BLOCK` proposals so that memory stays bounded in a crowd.

    Args:
        displacement: (M, N, 2) detection centre minus the track's box centre, pixels.
        scale: (M, N) positive pixel scale of each pair (a box height).
        valid: (M, N) bool, the pairs that may be linked at all.
        radius: agreement radius, in scales.
        penalty: (M, N) added to each pair's distance (None: zeros); the height term of
            :func:`motion_link_costs`, so that only boxes of like size agree on a shift.

    Returns:
        (2,) shift in pixels; zero when no pair is valid or none agrees with any proposal.
    """
    d = as_points(displacement, 2, "displacement", finite=True)
    s = np.asarray(scale, dtype=float)
    ok = np.asarray(valid, dtype=bool)
    extra = np.zeros(s.shape) if penalty is None else np.asarray(penalty, dtype=float)
    if d.ndim != 3 or s.shape != d.shape[:2] or ok.shape != s.shape or extra.shape != s.shape:
        raise ValueError(f"displacement must be (M, N, 2) and scale, valid, penalty (M, N), "
                         f"got {d.shape}, {s.shape}, {ok.shape}, {extra.shape}")
    able = ok & (extra <= radius)  # the pairs that can agree with some proposal
    if not able.any():
        return np.zeros(2)
    k, j = np.nonzero(ok)
    proposals = np.concatenate([np.zeros((1, 2)), d[k, j]])  # (P, 2), zero first
    ka, ja = np.nonzero(able.T)[::-1]  # grouped by detection, for the one vote per detection
    starts = np.flatnonzero(np.r_[True, ja[1:] != ja[:-1]])
    support = np.zeros(proposals.shape[0], dtype=np.int64)
    for b in range(0, proposals.shape[0], SHIFT_BLOCK):
        block = proposals[b:b + SHIFT_BLOCK]
        far = (np.linalg.norm(d[ka, ja][None, :, :] - block[:, None, :], axis=-1) / s[ka, ja]
               + extra[ka, ja])
        support[b:b + SHIFT_BLOCK] = np.logical_or.reduceat(far <= radius, starts,
                                                            axis=1).sum(axis=1)
    size = np.linalg.norm(proposals, axis=1) / np.median(s[k, j])
    best = int(np.lexsort((size, -support))[0])
    if support[best] == 0:
        return np.zeros(2)
    to_best = np.full(ok.shape, np.inf)
    to_best[ka, ja] = (np.linalg.norm(d[ka, ja] - proposals[best], axis=-1) / s[ka, ja]
                       + extra[ka, ja])
    agree = np.flatnonzero((to_best <= radius).any(axis=0))  # the supporting detections
    return np.median(d[np.argmin(to_best[:, agree], axis=0), agree], axis=0)


def motion_link_costs(last: np.ndarray, boxes: np.ndarray, valid: np.ndarray | None = None,
                      radius: float = 0.3) -> np.ndarray:
    """Cost of linking each track to each detection: the distance of the detection from the
    track's last box once the common shift (:func:`common_shift`) is removed, plus the log ratio
    of the box heights, both in box heights.

    The prediction is the last box itself, not a constant-velocity one: a walker moves a few
    hundredths of a box height per frame, while the last step of a head-worn view is mostly the
    camera's shake, which does not persist (in a first version of these links, without the
    height term in the shift's vote, the constant velocity of the last two boxes made 0.930 of
    the links right against 0.946 without, on the benchmark's tuning scenes with noisy boxes).

    Args:
        last: (M, 4) each track's last box.
        boxes: (N, 4) the detections.
        valid: (M, N) bool, the pairs that may be linked (None: all); others cost ``inf`` and
            propose no shift.
        radius: the agreement radius of the common shift, in box heights.

    Returns:
        (M, N) costs ``|c_j - c_k - shift| / sqrt(h_k h_j) + |log(h_j / h_k)|``, ``inf`` where
        not ``valid`` (heights below one pixel count as one).
    """
    a, b = as_boxes(last, "last"), as_boxes(boxes, "boxes")
    ok = (np.ones((a.shape[0], b.shape[0]), dtype=bool) if valid is None
          else np.asarray(valid, dtype=bool))
    if ok.shape != (a.shape[0], b.shape[0]):
        raise ValueError(f"valid must be ({a.shape[0]}, {b.shape[0]}), one per track and "
                         f"detection, got {ok.shape}")
    h_a, h_b = np.maximum(a[:, 3], 1.0), np.maximum(b[:, 3], 1.0)
    scale = np.sqrt(h_a[:, None] * h_b[None, :])
    displacement = box_centres(b)[None, :, :] - box_centres(a)[:, None, :]
    size = np.abs(np.log(h_b[None, :] / h_a[:, None]))
    shift = common_shift(displacement, scale, ok, radius, size)
    cost = np.linalg.norm(displacement - shift, axis=-1) / scale + size
    return np.where(ok, cost, np.inf)
