"""Appearance of tracklets from the images (CVMHAT paper, Sec. 3.3.2, 3.4.1 and 4.1).

With the images of both views, each clip is read once and every box gets the 8x2x2 HSV colour
histogram of :mod:`xvmatch.cues.color_histogram`:

- horizontal-view tracklets link boxes by IoU *and* colour similarity (Sec. 4.1: IoU >= 0.5 and
  histogram similarity >= 0.3; the top view links by IoU alone, its people's colours are not
  discriminative from above);
- a tracklet's colour descriptor is the bin-wise median of its boxes' histograms, and two
  tracklets of one view compare by histogram intersection (Eq. 14);
- with an appearance network (the deployed bundle's ``appearance.onnx``), each tracklet's box in
  its middle frame is cut as the runtime cuts crops and embedded (Sec. 3.3.2: the middle frame
  stands for the clip); two tracklets compare by ``1 - |a - b| / 2`` of their unit descriptors,
  the complement of the appearance cost the network is trained on.

Numpy and OpenCV only (the network runs in onnxruntime); no torch.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.cues.color_histogram import box_histograms, histogram_intersection
from xvmatch.cues.matcher_inputs import appearance_cost
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.tracklets import Tracklet

__all__ = [
    "Embedder",
    "PairEmbedder",
    "TrackletAppearance",
    "clip_appearance",
    "colour_similarity",
    "descriptor_similarity",
    "frame_histograms",
]

Embedder = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``embed(image (H, W, 3) uint8 BGR, boxes (K, 4)) -> (K, D)`` unit descriptors, e.g.
:meth:`xvmatch.inference.matching.learned_association.LearnedMatcher.descriptors`."""
PairEmbedder = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]
"""``embed(image, boxes) -> ((K, D) descriptors, (K, C) other vectors)`` from one run of the
network (the crops are embedded once)."""
CostOfDescriptors = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``cost(top (M, D), horizontal (N, D)) -> (M, N)`` appearance cost in [0, 1] of raw
descriptors."""


@dataclass(frozen=True, eq=False)
class TrackletAppearance:
    """The appearance of the tracklets of one clip of one view, in tracklet order.

    Attributes:
        histograms: (T, 32) the median colour histogram of each tracklet (Eq. 14's descriptor).
        descriptors: (T, D) the network descriptor of each tracklet's middle box, or None
            without a network.
        cross: (T, C) the vectors the cross-view cue compares when they are not the
            descriptors (a site bundle adapted on the network's features or stages), else None.
    """

    histograms: np.ndarray
    descriptors: np.ndarray | None
    cross: np.ndarray | None = None


def frame_histograms(
    frames: Mapping[int, FrameBoxes], images: Mapping[int, np.ndarray]
) -> dict[int, np.ndarray]:
    """``{frame: (N, 32)}`` colour histograms of each frame's boxes, in record order."""
    return {f: box_histograms(images[f], frames[f].boxes).histograms for f in images}


def clip_appearance(
    tracklets: Sequence[Tracklet],
    frames: Mapping[int, FrameBoxes],
    histograms: Mapping[int, np.ndarray] | None,
    images: Mapping[int, np.ndarray],
    embed: Embedder | None = None,
    cross_embed: PairEmbedder | None = None,
) -> TrackletAppearance:
    """Median histograms and middle-box descriptors of one clip's tracklets of one view.

    Args:
        tracklets: the clip's tracklets (``rows`` are the records' ``ids``).
        frames: ``{frame: FrameBoxes}`` of the view.
        histograms: ``{frame: (N, 32)}`` from :func:`frame_histograms`, for the clip's frames;
            None: no colour descriptor (``histograms`` of the result is ``(T, 0)``).
        images: ``{frame: image}`` of the clip's frames (with ``embed``, at least the frames
            of the tracklets' middle boxes).
        embed: the appearance network, or None for colour only.
        cross_embed: with ``embed`` only, when the cross-view cue compares other vectors than
            ``embed``'s: the descriptors and those vectors from one network run (used instead
            of ``embed``), or None.
    """
    hist = np.zeros((len(tracklets), 0 if histograms is None else _bins(histograms)))
    middle: dict[int, list[tuple[int, int]]] = {}
    for k, t in enumerate(tracklets):
        if histograms is not None:
            per_box = []
            for f, r in zip(t.frames.tolist(), t.rows.tolist(), strict=True):
                j = int(np.flatnonzero(frames[f].ids == r)[0])
                per_box.append(histograms[f][j])
            hist[k] = np.median(np.array(per_box), axis=0)
        f = int(t.frames[len(t) // 2])
        middle.setdefault(f, []).append((k, int(t.rows[len(t) // 2])))
    if embed is None:
        return TrackletAppearance(hist, None)
    if cross_embed is None:
        (desc,) = _middle_vectors(lambda image, boxes: (embed(image, boxes),), 1, tracklets,
                                  middle, frames, images)
        return TrackletAppearance(hist, desc)
    desc, cross = _middle_vectors(cross_embed, 2, tracklets, middle, frames, images)
    return TrackletAppearance(hist, desc, cross)


def _middle_vectors(embed: Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, ...]],
                    outputs: int, tracklets: Sequence[Tracklet],
                    middle: Mapping[int, list[tuple[int, int]]],
                    frames: Mapping[int, FrameBoxes], images: Mapping[int, np.ndarray],
                    ) -> list[np.ndarray]:
    """Each of ``embed``'s ``outputs`` kinds of vectors of each tracklet's middle box,
    ``(T, D)`` each (``(0, 0)`` without any box); one ``embed`` call per frame."""
    out: list[np.ndarray] | None = None
    for f, wanted in sorted(middle.items()):
        rec = frames[f]
        idx = [int(np.flatnonzero(rec.ids == r)[0]) for _, r in wanted]
        vectors = [np.asarray(v, dtype=np.float64) for v in embed(images[f], rec.boxes[idx])]
        if out is None:
            out = [np.zeros((len(tracklets), v.shape[1])) for v in vectors]
        for whole, v in zip(out, vectors, strict=True):
            whole[[k for k, _ in wanted]] = v
    return out if out is not None else [np.zeros((0, 0)) for _ in range(outputs)]


def _bins(histograms: Mapping[int, np.ndarray]) -> int:
    """Bins of the histograms (32 unless none were computed)."""
    for h in histograms.values():
        return int(h.shape[1])
    return 32


def colour_similarity(a: TrackletAppearance, b: TrackletAppearance) -> np.ndarray:
    """(T_a, T_b) over-time appearance similarity of Eq. 14: histogram intersection of the
    tracklets' median colour histograms, in [0, 1]."""
    if 0 in (a.histograms.shape[1], b.histograms.shape[1]) and a.histograms.shape[0] and \
            b.histograms.shape[0]:
        raise ValueError("colour_similarity needs histograms: these tracklets have none")
    if a.histograms.shape[0] == 0 or b.histograms.shape[0] == 0:
        return np.zeros((a.histograms.shape[0], b.histograms.shape[0]))
    return histogram_intersection(a.histograms, b.histograms)


def descriptor_similarity(a: TrackletAppearance, b: TrackletAppearance,
                          cost: CostOfDescriptors | None = None,
                          cross: bool = False) -> np.ndarray:
    """(T_a, T_b) network appearance similarity ``1 - cost(d_a, d_b)`` of the tracklets'
    middle-box descriptors (Sec. 3.3.2), in [0, 1]; ``cost`` defaults to ``|d_a - d_b| / 2``
    (a site bundle's adapted cross-view cost: ``LearnedMatcher.appearance_cost``); ``cross``:
    compare the cross-view cue's vectors where the tracklets hold them."""
    if a.descriptors is None or b.descriptors is None:
        raise ValueError("descriptor_similarity needs descriptors: pass an appearance network")
    n_a, n_b = a.histograms.shape[0], b.histograms.shape[0]
    if n_a == 0 or n_b == 0:
        return np.zeros((n_a, n_b))
    cost = appearance_cost if cost is None else cost
    if cross and a.cross is not None and b.cross is not None:
        return 1.0 - np.asarray(cost(a.cross, b.cross), dtype=np.float64)
    return 1.0 - np.asarray(cost(a.descriptors, b.descriptors), dtype=np.float64)
