"""Pairs kept consistent over time with each view's own track ids (video mode): a frame's pairs
are votes, and a pair of tracks holds in every frame where both are present when it was found in
at least half of those frames.

A matcher that is right in most frames is then right in all of them (on the ten real CVMHAT
development pairs, boxes only: the learned matcher's mean CVIDF1 92.9 -> 97.9, the handcrafted
video search's 91.5 -> 93.9). With ``keep_unsure``, a track whose pairs agree in no such way keeps
its frame-by-frame pairs, so that a sequence the matcher gets mostly wrong loses nothing it had
(without it, one such CVMHAT pair fell from 41.0 to 0: no pair was stable, so none was kept).
Where the frame-by-frame pairs are mostly wrong anyway, dropping the unsure ones is the better
bet: the oblique top view's ground registration, 66.1 dropping them against 63.5 keeping them
(``benchmarks/oblique_association.py --scenes 12``). Within-view ids are read as track ids: use
only on a video whose ids persist (:func:`xvmatch.cues.box_motion.is_video`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = ["MIN_SHARE", "consistent_pairs", "tracklet_consensus"]

MIN_SHARE = 0.5
"""Share of the frames where both tracks are present in which a pair must have been found."""

Pairs = dict[int, list[tuple[int, int]]]


def tracklet_consensus(pairs: Mapping[int, Sequence[tuple[int, int]]],
                       present: Mapping[int, tuple[np.ndarray, np.ndarray]],
                       min_share: float = MIN_SHARE, keep_unsure: bool = True) -> Pairs:
    """Per-frame pairs made consistent over time (module docstring): the pairs of tracks found
    in at least ``min_share`` of their co-present frames hold in all of them, a frame's conflicts
    going to the pairs found most often (Hungarian on the shares); tracks in no such pair keep
    their frame-by-frame pairs with ``keep_unsure``, else have none.

    Args:
        pairs: ``{frame: [(top id, hor id), ...]}`` of the frame-by-frame association.
        present: ``{frame: (top ids, hor ids)}`` of every frame to output.
        min_share: the share of co-present frames a pair must have been found in.
        keep_unsure: keep the frame-by-frame pairs of tracks in no pair over the clip.

    Returns:
        ``{frame: [(top id, hor id), ...]}`` for every frame of ``present``.
    """
    found: dict[tuple[int, int], int] = {}
    for f in present:
        for pair in pairs.get(f, ()):
            found[pair] = found.get(pair, 0) + 1
    together = dict.fromkeys(found, 0)  # frames where both tracks of a found pair are present
    for tops, hors in present.values():
        t_set, h_set = set(tops.tolist()), set(hors.tolist())
        for p in found:
            if p[0] in t_set and p[1] in h_set:
                together[p] += 1
    share = {p: found[p] / together[p] for p in found if together[p]}
    sure_top = {t for (t, _h), s in share.items() if s >= min_share}
    sure_hor = {h for (_t, h), s in share.items() if s >= min_share}
    out: Pairs = {}
    for f, (tops, hors) in present.items():
        t_list, h_list = tops.tolist(), hors.tolist()
        s = np.array([[share.get((t, h), 0.0) for h in h_list] for t in t_list]).reshape(
            len(t_list), len(h_list))
        kept: list[tuple[int, int]] = []
        if s.size:
            rows, cols = linear_sum_assignment(-s)
            kept = [(t_list[r], h_list[c]) for r, c in zip(rows, cols, strict=True)
                    if s[r, c] >= min_share]
        if keep_unsure:
            kept += [(t, h) for t, h in pairs.get(f, ())
                     if t not in sure_top and h not in sure_hor]
        out[f] = kept
    return out


def consistent_pairs(pairs: Mapping[int, Sequence[tuple[int, int]]], top: Mapping, hor: Mapping,
                     frames: Sequence[int], keep_unsure: bool = True) -> Pairs:
    """:func:`tracklet_consensus` of an association of ``frames``, the ids present read from
    the two views' ``{frame: FrameBoxes}``."""
    empty = np.zeros(0, dtype=np.int64)
    present = {f: (np.asarray(top[f].ids) if f in top else empty,
                   np.asarray(hor[f].ids) if f in hor else empty) for f in frames}
    return tracklet_consensus(pairs, present, keep_unsure=keep_unsure)
