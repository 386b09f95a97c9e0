"""Scores of a joint association of several views: every view pair, and cycle consistency.

Each view pair ``(a, b)`` of a frame is scored as a top/egocentric pair is
(:func:`~xvmatch.metrics.cross_view_metrics.count_pair`: Eq. 9 accuracy of the
geometric-priors paper and the CVMHAT CVIDF1 / CVMA, view ``a`` in the role of the top view);
the per-pair counts pool over frames (:func:`summarize_views`) and the figures of a method are
the mean over the view pairs.

Cycle consistency (:func:`cycle_counts`): over every triple of views and boxes ``(i, j, k)``
with at least two of the three matches ``(i, j)``, ``(j, k)``, ``(i, k)`` made, the share with
exactly two (a person matched ego1-top and top-ego2 but not ego1-ego2) is the inconsistency
rate. A joint solution has none; pairwise Hungarian may have some.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping, Sequence

import numpy as np

from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    summarize,
)

__all__ = ["count_views", "cycle_counts", "mean_scores", "summarize_views"]


def count_views(
    gt_ids: Sequence[np.ndarray],
    stands_for: Sequence[np.ndarray],
    pairs: Mapping[tuple[int, int], np.ndarray],
    frame: int = 0,
) -> dict[tuple[int, int], FrameCounts]:
    """The counts of every view pair ``a < b`` of one frame.

    Args:
        gt_ids: per view, the ground-truth ids present in it.
        stands_for: per view, the ground-truth id each box stands for (-1: a false box), in the
            order of the association's rows.
        pairs: ``{(a, b): (K, 2) (row in a, row in b)}``; a missing pair means no match.
        frame: frame number for error messages.
    """
    if len(gt_ids) != len(stands_for):
        raise ValueError(f"{len(gt_ids)} ground-truth views but {len(stands_for)} box views")
    return {
        (a, b): count_pair(gt_ids[a], gt_ids[b], stands_for[a], stands_for[b],
                           np.asarray(pairs.get((a, b), np.zeros((0, 2))), np.int64),
                           frame=frame)
        for a, b in itertools.combinations(range(len(gt_ids)), 2)
    }


def summarize_views(counts: Sequence[Mapping[tuple[int, int], FrameCounts]]
                    ) -> dict[tuple[int, int], CrossViewScores]:
    """Per view pair, the scores pooled over the frames' counts of :func:`count_views`."""
    keys = sorted({k for c in counts for k in c})
    return {k: summarize([c[k] for c in counts if k in c]) for k in keys}


def mean_scores(scores: Mapping[tuple[int, int], CrossViewScores]) -> dict[str, float]:
    """Mean over view pairs of ACC9, CVIDF1 and CVMA (percent)."""
    if not scores:
        return {"acc9": 0.0, "cvidf1": 0.0, "cvma": 0.0}
    return {name: float(np.mean([getattr(s, name) for s in scores.values()]))
            for name in ("acc9", "cvidf1", "cvma")}


def cycle_counts(pairs: Mapping[tuple[int, int], np.ndarray], sizes: Sequence[int]
                 ) -> tuple[int, int]:
    """``(broken, closed)``: box triples over three views with exactly two of their three
    matches made, and with all three. The inconsistency rate is ``broken / (broken + closed)``."""
    n = [int(s) for s in sizes]
    x = {}
    for a, b in itertools.combinations(range(len(n)), 2):
        m = np.zeros((n[a], n[b]), np.int8)
        p = np.asarray(pairs.get((a, b), np.zeros((0, 2))), np.int64).reshape(-1, 2)
        m[p[:, 0], p[:, 1]] = 1
        x[(a, b)] = m
    broken = closed = 0
    for a, b, c in itertools.combinations(range(len(n)), 3):
        total = x[(a, b)][:, :, None] + x[(b, c)][None, :, :] + x[(a, c)][:, None, :]
        broken += int((total == 2).sum())
        closed += int((total == 3).sum())
    return broken, closed
