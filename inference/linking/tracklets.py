"""Single-view tracklets in short clips (CVMHAT paper, Sec. 3.1 and 4.1, "Tracklet Extraction").

The video is cut into clips of a fixed length (10 frames in the paper); inside a clip, boxes of
adjacent frames are linked one-to-one by IoU (Hungarian assignment, a link needs IoU >= 0.5, the
paper's threshold; a box may also continue a tracklet last seen a few frames earlier, so that a
missed detection does not cut it) and each chain of links is a tracklet. With colour histograms
of the boxes (the horizontal view, when images are given), a link also needs a histogram
similarity of at least 0.3 (Sec. 4.1), and the assignment maximises IoU plus colour similarity.
For a moving camera (a head-worn one, whose shake makes a person's boxes of two frames overlap
little), ``motion`` links instead by the distance from each tracklet's last box once the view's
common shift is removed (:func:`xvmatch.cues.box_motion.motion_link_costs`); IoU linking
is the default and unchanged. Boxes are ``x, y, w, h`` in pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.cues.box_motion import motion_link_costs
from xvmatch.cues.color_histogram import histogram_intersection
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.box_overlap import box_iou

__all__ = [
    "BOX_TRACK_IOU",
    "Tracklet",
    "box_track_ids",
    "clip_tracklets",
    "motion_assignment",
    "split_clips",
    "view_tracklets",
]

BOX_TRACK_IOU = 0.3
"""Least IoU of a link of :func:`box_track_ids`: below the paper's 0.5, as the boxes may be a
few frames apart (every 10th frame of a 30 fps video: a walker moves about half a box width)."""


@dataclass(frozen=True, eq=False)
class Tracklet:
    """One person's boxes inside one clip of one view.

    Attributes:
        clip: index of the clip (0-based).
        frames: (K,) ascending frame numbers.
        rows: (K,) the detection each box is (the ``ids`` of the input records).
        boxes: (K, 4) ``x, y, w, h`` in pixels.
    """

    clip: int
    frames: np.ndarray
    rows: np.ndarray
    boxes: np.ndarray

    def __len__(self) -> int:
        return int(self.frames.shape[0])


def split_clips(frames: Sequence[int], length: int) -> list[np.ndarray]:
    """Cut the frames present into consecutive clips of ``length`` frame numbers, from the first.

    Both views must be cut the same way (Sec. 3.1 splits the two videos synchronously), so
    pass the union of their frames. Clip ``k`` spans frame numbers ``first + k * length`` to
    ``first + (k + 1) * length - 1`` but holds only the frames present (frames without boxes
    add nothing to a tracklet); a run of clips without any frame becomes one empty clip, which
    breaks the tracks there as the whole run would. So the work grows with the frames present,
    not with the span: frames 1 and 10**9 give three clips, not 10**8.

    Returns:
        One ``(K,)`` int64 array of ascending frame numbers per clip (``K`` may be 0).
    """
    if length < 1:
        raise ValueError(f"clip length must be >= 1, got {length}")
    present = np.unique(np.asarray(frames, dtype=np.int64))
    if present.size == 0:
        return []
    index = (present - present[0]) // length
    starts = np.flatnonzero(np.r_[True, index[1:] != index[:-1]])
    ends = np.r_[starts[1:], present.size]
    after_gap = np.r_[False, np.diff(index[starts]) > 1]
    clips: list[np.ndarray] = []
    for s, e, gap in zip(starts.tolist(), ends.tolist(), after_gap.tolist(), strict=True):
        if gap:
            clips.append(np.zeros(0, dtype=np.int64))
        clips.append(present[s:e])
    return clips


def motion_assignment(last: np.ndarray, boxes: np.ndarray, gate: float, gaps: np.ndarray,
                      valid: np.ndarray | None = None
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one links of tracks (their ``last`` boxes) to ``boxes`` by motion: Hungarian on
    :func:`~xvmatch.cues.box_motion.motion_link_costs` (``valid`` pairs only) plus
    ``1e-3`` times the frames missed (``gaps``, broadcast to ``(M, N)``: a shorter gap wins a
    tie); returns the assignment's rows, columns and ``(M, N)`` whether each pair is within
    ``gate``."""
    cost = motion_link_costs(last, boxes, valid)
    ok = cost <= gate
    r, c = linear_sum_assignment(np.where(ok, cost + 1e-3 * gaps, gate + 1.0))
    return r, c, ok


def clip_tracklets(
    frames: Mapping[int, FrameBoxes],
    clip_frames: np.ndarray,
    clip: int,
    min_iou: float = 0.5,
    max_gap: int = 3,
    histograms: Mapping[int, np.ndarray] | None = None,
    min_colour: float = 0.3,
    motion: float | None = None,
) -> list[Tracklet]:
    """Link the boxes of one clip into tracklets by IoU (Sec. 4.1), over short gaps.

    Each frame's boxes are assigned (Hungarian, IoU >= ``min_iou``) to the tracklets whose last
    box is at most ``max_gap`` frames before (a detector's misses would otherwise cut a person
    into several tracklets of one clip, and only one of them could continue over time); a
    tracklet last seen one frame earlier wins a tie. Ordered by first frame, then file order.

    With ``histograms`` (``{frame: (N, B)}`` colour histograms of each frame's boxes, record
    order), a link also needs the histogram intersection of the two boxes to be at least
    ``min_colour``, and the assignment maximises IoU plus that similarity (Sec. 4.1).

    With ``motion`` (a gate, in box heights) the links ignore IoU: a link costs the distance of
    the box from the tracklet's last box once the frame's common shift (the camera's own motion)
    is removed, plus the log ratio of the heights
    (:func:`~xvmatch.cues.box_motion.motion_link_costs`), must cost at most ``motion``, and
    the assignment minimises the cost (a shorter gap winning a tie).

    Raises:
        ValueError: both ``histograms`` and ``motion`` given.
    """
    if histograms is not None and motion is not None:
        raise ValueError("clip_tracklets: give histograms (IoU and colour links) or motion "
                         "(motion links), not both")
    chains: list[list[tuple[int, int, np.ndarray]]] = []
    colour: list[np.ndarray] = []  # per chain, the histogram of its last box
    for f in clip_frames.tolist():
        rec = frames.get(f)
        if rec is None or len(rec) == 0:
            continue
        open_chains = [k for k, c in enumerate(chains) if f - 1 - max_gap <= c[-1][0] < f]
        current = [-1] * len(rec)
        if open_chains:
            last = np.array([chains[k][-1][2] for k in open_chains])
            gaps = np.array([f - chains[k][-1][0] - 1 for k in open_chains], dtype=float)
            if motion is not None:
                r, c, ok = motion_assignment(last, rec.boxes, motion, gaps[:, None])
            elif histograms is None:
                iou = box_iou(last, rec.boxes)
                r, c = linear_sum_assignment(-(iou - 1e-3 * gaps[:, None]))
                ok = iou >= min_iou
            else:
                iou = box_iou(last, rec.boxes)
                sim = histogram_intersection(np.array([colour[k] for k in open_chains]),
                                             histograms[f])
                ok = (iou >= min_iou) & (sim >= min_colour)
                r, c = linear_sum_assignment(-np.where(ok, iou + sim - 1e-3 * gaps[:, None],
                                                       -1.0))
            for i, j in zip(r.tolist(), c.tolist(), strict=True):
                if ok[i, j]:
                    current[j] = open_chains[i]
        for j in range(len(rec)):
            if current[j] < 0:
                current[j] = len(chains)
                chains.append([])
                colour.append(np.zeros(0))
            chains[current[j]].append((f, int(rec.ids[j]), rec.boxes[j]))
            if histograms is not None:
                colour[current[j]] = histograms[f][j]
    return [
        Tracklet(
            clip=clip,
            frames=np.array([f for f, _, _ in chain], dtype=np.int64),
            rows=np.array([r for _, r, _ in chain], dtype=np.int64),
            boxes=np.array([b for _, _, b in chain], dtype=float).reshape(-1, 4),
        )
        for chain in chains
    ]


def view_tracklets(
    frames: Mapping[int, FrameBoxes],
    clips: Sequence[np.ndarray],
    min_iou: float = 0.5,
    max_gap: int = 3,
    motion: float | None = None,
) -> list[list[Tracklet]]:
    """The tracklets of every clip of one view (one list per clip), by IoU alone, or by motion
    with a ``motion`` gate (:func:`clip_tracklets`)."""
    return [clip_tracklets(frames, c, k, min_iou, max_gap, motion=motion)
            for k, c in enumerate(clips)]


def box_track_ids(frames: Mapping[int, FrameBoxes], min_iou: float = BOX_TRACK_IOU,
                  max_gap: int = 3) -> np.ndarray:
    """A track number for every box of ``frames``, in :func:`~xvmatch.formats.mot_boxes.
    stack_frames` order, from the boxes alone (the records' ids are not read): the view's boxes
    linked by IoU over the whole clip (:func:`clip_tracklets`, one clip), ``max_gap`` counted
    in the frames that have boxes (a file of every 10th frame links its neighbours). For what
    needs a person followed over time where the file's ids may not be used (frame mode)."""
    order = sorted(f for f in frames if len(frames[f].ids))
    rows, n = {}, 0
    for rank, f in enumerate(order):
        k = len(frames[f].ids)
        rows[rank] = FrameBoxes(rank, np.arange(n, n + k, dtype=np.int64), frames[f].boxes)
        n += k
    ids = np.zeros(n, np.int64)
    for t, tracklet in enumerate(clip_tracklets(rows, np.arange(len(order)), 0, min_iou,
                                                max_gap)):
        ids[tracklet.rows] = t
    return ids
