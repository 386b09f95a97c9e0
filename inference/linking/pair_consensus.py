"""Pairs kept consistent over time with each view's own track ids (video mode).

Each top-view track's partner over its frames is chosen as a piecewise-constant sequence (a
Viterbi over the horizontal tracks it was paired with): a partner holds over a stretch where it
agrees with most of the frames' own pairs, a change of partner must be worth 15 frames of
evidence (a tracker's id switch, in either view, is such a change), and a track no partner holds
keeps its frames' own pairs. A matcher that is right in most frames is then right in all of them.

Real CVMHAT development pairs, boxes only, mean CVIDF1 (``benchmarks/video_consensus.py``), each
frame alone -> with the consensus: with the files' whole tracks, the search 87.3 -> 96.1 and the
learned matcher 92.9 -> 96.8; with a tracker's ids swapping about every 300 frames per track,
87.3 -> 92.6 and 92.9 -> 94.0, where one partner per whole track falls to 78.8 and 79.6 (it
gains 1.1 on the learned matcher's whole tracks: 97.9). Within-view ids are read as track ids:
use only on a video whose ids persist (:func:`xvmatch.cues.box_motion.is_video`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from xvmatch.inference.linking.piecewise_labels import label_path

__all__ = ["FREE_COST", "SWITCH_COST", "consistent_pairs", "tracklet_consensus"]

SWITCH_COST = 15.0
"""Frames of disagreement a change of a track's partner must save (:func:`tracklet_consensus`)."""
FREE_COST = 0.5
"""Cost a frame of following the frame's own pair: a partner holds where it agrees with more than
half of the frames."""

Pairs = dict[int, list[tuple[int, int]]]


def _stretch_support(path: np.ndarray, obs: np.ndarray, here: np.ndarray) -> np.ndarray:
    """Per frame, the share of its stretch (a run of one state) whose frames' own pairs name
    the stretch's partner, over the frames where that partner is present (0 for the free
    state): how strongly a track claims its partner against another track's claim."""
    out = np.zeros(len(path))
    starts = np.flatnonzero(np.r_[True, path[1:] != path[:-1]])
    for a, b in zip(starts, np.r_[starts[1:], len(path)], strict=True):
        state = path[a]
        if state:
            seen = here[a:b, state]
            out[a:b] = float((obs[a:b][seen] == state).mean()) if seen.any() else 0.0
    return out


def tracklet_consensus(pairs: Mapping[int, Sequence[tuple[int, int]]],
                       present: Mapping[int, tuple[np.ndarray, np.ndarray]],
                       switch_cost: float = SWITCH_COST, free_cost: float = FREE_COST,
                       keep_free: bool = True) -> Pairs:
    """Per-frame pairs made consistent over time (module docstring): each top-view track's
    partner over its frames is a piecewise-constant choice among the horizontal tracks it was
    paired with, or the frames' own pairs where no partner holds
    (:func:`~xvmatch.inference.linking.piecewise_labels.label_path`); two tracks claiming one
    partner in a frame go to the one the frame's own pair agrees with.

    Args:
        pairs: ``{frame: [(top id, hor id), ...]}`` of the frame-by-frame association.
        present: ``{frame: (top ids, hor ids)}`` of every frame to output.
        switch_cost: frames of disagreement a change of partner must save (a tracker's id
            switch, in either view, is such a change).
        free_cost: cost a frame of following the frame's own pair; a partner holds over a
            stretch where it agrees with more than ``1 - free_cost`` of the frames.
    Returns:
        ``{frame: [(top id, hor id), ...]}`` for every frame of ``present``.
    """
    order = sorted(present)
    own = {f: dict(pairs.get(f, ())) for f in order}
    hors_at = {f: set(present[f][1].tolist()) for f in order}
    frames_of: dict[int, list[int]] = {}
    for f in order:
        for t in present[f][0].tolist():
            frames_of.setdefault(t, []).append(f)
    claims: dict[int, list[tuple[float, int, int]]] = {f: [] for f in order}
    for t in sorted(frames_of):
        frames = frames_of[t]
        cands = sorted({own[f][t] for f in frames if t in own[f]})
        if not cands:
            continue
        slot = {h: j + 1 for j, h in enumerate(cands)}
        obs = np.array([slot.get(own[f].get(t), 0) for f in frames])
        here = np.array([[False] + [h in hors_at[f] for h in cands] for f in frames])
        path = label_path(obs, here, switch_cost, free_cost)
        support = _stretch_support(path, obs, here)
        for k, (f, state, seen) in enumerate(zip(frames, path, obs, strict=True)):
            if state == 0 and seen and keep_free:  # no partner holds: the frame's own pair
                claims[f].append((0.0, t, cands[seen - 1]))
            elif state and here[k, state]:  # the partner, as strong as its stretch's support
                claims[f].append((1.0 + support[k] + 0.5 * (seen == state), t,
                                  cands[state - 1]))
    out: Pairs = {}
    for f in order:
        kept: dict[int, tuple[float, int]] = {}
        for score, t, h in sorted(claims[f], key=lambda c: (-c[0], c[1], c[2])):
            if h not in kept:
                kept[h] = (score, t)
        out[f] = sorted(((t, h) for h, (_s, t) in kept.items()))
    return out


def consistent_pairs(pairs: Mapping[int, Sequence[tuple[int, int]]], top: Mapping, hor: Mapping,
                     frames: Sequence[int], **costs: float) -> Pairs:
    """:func:`tracklet_consensus` of an association of ``frames``, the ids present read from
    the two views' ``{frame: FrameBoxes}``."""
    empty = np.zeros(0, dtype=np.int64)
    present = {f: (np.asarray(top[f].ids) if f in top else empty,
                   np.asarray(hor[f].ids) if f in hor else empty) for f in frames}
    return tracklet_consensus(pairs, present, **costs)
