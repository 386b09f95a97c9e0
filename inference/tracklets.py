"""Single-view tracklets in short clips (CVMHAT paper, Sec. 3.1 and 4.1, "Tracklet Extraction").

The video is cut into clips of a fixed length (10 frames in the paper); inside a clip, boxes of
adjacent frames are linked one-to-one by IoU (Hungarian assignment, a link needs IoU >= 0.5, the
paper's threshold) and each chain of links is a tracklet. Boxes are ``x, y, w, h`` in pixels.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.datasets.mot_boxes import FrameBoxes

__all__ = ["Tracklet", "box_iou", "clip_tracklets", "split_clips", "view_tracklets"]


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


def box_iou(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(N, M) intersection over union of ``x, y, w, h`` boxes ``a (N, 4)`` and ``b (M, 4)``."""
    a = np.asarray(a, dtype=float).reshape(-1, 4)
    b = np.asarray(b, dtype=float).reshape(-1, 4)
    ix = np.minimum(a[:, None, 0] + a[:, None, 2], b[None, :, 0] + b[None, :, 2]) - np.maximum(
        a[:, None, 0], b[None, :, 0]
    )
    iy = np.minimum(a[:, None, 1] + a[:, None, 3], b[None, :, 1] + b[None, :, 3]) - np.maximum(
        a[:, None, 1], b[None, :, 1]
    )
    inter = np.clip(ix, 0, None) * np.clip(iy, 0, None)
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None, :] - inter
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(union > 0, inter / union, 0.0)


def split_clips(frames: Sequence[int], length: int) -> list[np.ndarray]:
    """Cut the frame span ``min..max`` of ``frames`` into consecutive clips of ``length`` frames.

    Both views must be cut the same way (Sec. 3.1 splits the two videos synchronously), so
    pass the union of their frames. Returns one ``(<= length,)`` array of frame numbers per clip.
    """
    if length < 1:
        raise ValueError(f"clip length must be >= 1, got {length}")
    if len(frames) == 0:
        return []
    first, last = int(min(frames)), int(max(frames))
    return [np.arange(s, min(s + length, last + 1)) for s in range(first, last + 1, length)]


def clip_tracklets(
    frames: Mapping[int, FrameBoxes], clip_frames: np.ndarray, clip: int, min_iou: float = 0.5
) -> list[Tracklet]:
    """Link the boxes of one clip into tracklets by IoU between adjacent frames (Sec. 4.1).

    A missing frame ends every chain. Tracklets are ordered by first frame, then file order.
    """
    chains: list[list[tuple[int, int, np.ndarray]]] = []
    open_chains: list[int] = []  # chain index of each box of the previous frame
    prev_boxes = np.zeros((0, 4))
    prev_frame = None
    for f in clip_frames.tolist():
        rec = frames.get(f)
        if rec is None or len(rec) == 0:
            open_chains, prev_boxes, prev_frame = [], np.zeros((0, 4)), None
            continue
        current = [-1] * len(rec)
        if prev_frame is not None and len(prev_boxes):
            iou = box_iou(prev_boxes, rec.boxes)
            r, c = linear_sum_assignment(-iou)
            for i, j in zip(r.tolist(), c.tolist(), strict=True):
                if iou[i, j] >= min_iou:
                    current[j] = open_chains[i]
        for j in range(len(rec)):
            if current[j] < 0:
                current[j] = len(chains)
                chains.append([])
            chains[current[j]].append((f, int(rec.ids[j]), rec.boxes[j]))
        open_chains, prev_boxes, prev_frame = current, rec.boxes, f
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
    frames: Mapping[int, FrameBoxes], clips: Sequence[np.ndarray], min_iou: float = 0.5
) -> list[list[Tracklet]]:
    """The tracklets of every clip of one view (one list per clip)."""
    return [clip_tracklets(frames, c, k, min_iou) for k, c in enumerate(clips)]
