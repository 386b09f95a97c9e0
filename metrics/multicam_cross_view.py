"""Cross-view scores of N views with global ids: CVIDP, CVIDR, CVIDF1, CVMA over every view pair,
and per-view MOTA, IDF1 and HOTA (``xvmatch evaluate --multicam``, issue 68).

Input: per view, the predicted boxes with their global ids (one id per person across all views,
as a multi-camera tracker writes them) and the ground-truth boxes, whose ids are also global (the
same id in every view is the same person). Each predicted box first stands for the ground-truth
id of the box it overlaps (:func:`xvmatch.metrics.track_metrics.gt_identity`: one-to-one per
frame, IoU >= 0.5), or for no person.

**Per view pair** ``(a, b)``, ``a`` before ``b`` in the order the views are given, at frame
``t``: the predicted pairs are the boxes of ``a`` and ``b`` that carry the same global id, and
the frame is counted exactly as the two-view metrics count a frame pair
(:func:`xvmatch.metrics.cross_view_metrics.count_pair`, view ``a`` in the top view's role and
``b`` in the horizontal view's): ``G_t`` the people seen in both views, ``TP_t`` the pairs whose
two boxes are one person, a wrong pair a mismatch when its ``b`` box is a person of ``G_t``
(else a false positive), a miss a person of ``G_t`` whose ``b`` box is in no pair. Then
(CVMHAT paper, Eqs. 19-20):

- CVIDP = mean over frames with a predicted pair of ``TP_t / |P_t|``;
- CVIDR = mean over frames with ``G_t`` non-empty of ``TP_t / |G_t|``;
- CVIDF1 = ``2 CVIDP CVIDR / (CVIDP + CVIDR)``;
- CVMA = ``1 - sum_t (miss_t + fp_t + 2 mismatch_t) / sum_t |G_t|``.

The frames of a pair are those where either view has a ground-truth or a predicted box (a
predicted pair on a frame without ground truth is a false positive, not ignored).

**Over all pairs** the headline figures pool the frame pairs: every ``(view pair, frame)`` is one
frame pair, CVIDP and CVIDR average over all of them and CVMA sums its errors and ``|G_t|`` over
all of them. This is the CVMHAT paper's average: its dataset has several horizontal views per
top view (several video pairs per scene), and it reports "the average ... over all the frame
pairs" of all video pairs, with the sums of Eq. 20 running over them; a view pair with many
shared people weighs more, as a sequence with more frames does. The plain mean over view pairs
(each pair counting once, as :func:`xvmatch.metrics.multi_view_metrics.mean_scores` does for a
joint association) is reported beside it as ``pair_mean``; the two agree when every pair has the
same frames and shared people.

With two views the pooled figures are those of
:func:`xvmatch.metrics.cross_view_metrics.summarize` on the same frames. Empty cases give 0, never
NaN or a division by zero (see :mod:`xvmatch.metrics.cross_view_metrics`).

**Per view**, MOTA, IDF1 and HOTA come from the TrackEval package, as in
:mod:`xvmatch.metrics.track_metrics`; without TrackEval they are left out
(:func:`view_tracking_scores` returns None) and the cross-view scores stand alone.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping
from dataclasses import asdict

import numpy as np

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    scores_to_dict,
    summarize,
)
from xvmatch.metrics.track_metrics import ViewTrackScores, gt_identity, view_track_scores

__all__ = [
    "cross_view_scores",
    "format_cross_view",
    "pair_counts",
    "view_tracking_scores",
]

_EMPTY = FrameBoxes(0, np.zeros(0, np.int64), np.zeros((0, 4)))
_MEAN_FIELDS = ("cvidp", "cvidr", "cvidf1", "cvma")


def pair_counts(
    pred_a: Mapping[int, FrameBoxes],
    pred_b: Mapping[int, FrameBoxes],
    gt_a: Mapping[int, FrameBoxes],
    gt_b: Mapping[int, FrameBoxes],
    frames: Iterable[int] | None = None,
) -> list[FrameCounts]:
    """Per-frame cross-view counts of one view pair; the pairs are the boxes with one global id.

    Args:
        pred_a, pred_b: ``{frame: FrameBoxes}`` of views ``a`` and ``b``, ids global.
        gt_a, gt_b: ``{frame: FrameBoxes}`` of the same views' ground truth, ids global.
        frames: the frames to count; default every frame with a box in any of the four.

    Returns:
        One :class:`~xvmatch.metrics.cross_view_metrics.FrameCounts` per frame, ascending.
    """
    if frames is None:
        frames = set(pred_a) | set(pred_b) | set(gt_a) | set(gt_b)
    out = []
    for f in sorted({int(t) for t in frames}):
        ga, gb = gt_a.get(f, _EMPTY), gt_b.get(f, _EMPTY)
        pa, pb = pred_a.get(f, _EMPTY), pred_b.get(f, _EMPTY)
        column = {int(k): j for j, k in enumerate(pb.ids.tolist())}
        pairs = [(i, column[int(k)]) for i, k in enumerate(pa.ids.tolist()) if int(k) in column]
        out.append(count_pair(ga.ids, gb.ids, gt_identity(ga, pa), gt_identity(gb, pb),
                              np.array(pairs, dtype=np.int64).reshape(-1, 2), frame=f))
    return out


def _check_views(pred: Mapping[str, Mapping], gt: Mapping[str, Mapping]) -> list[str]:
    if list(pred) != list(gt):
        raise ValueError(f"the predicted views {list(pred)} and the ground-truth views "
                         f"{list(gt)} differ; give both for the same views, in the same order")
    return list(pred)


def cross_view_scores(
    pred: Mapping[str, Mapping[int, FrameBoxes]], gt: Mapping[str, Mapping[int, FrameBoxes]]
) -> dict:
    """CVIDP, CVIDR, CVIDF1 and CVMA of every view pair, pooled and averaged (module docstring).

    Args:
        pred: ``{view: {frame: FrameBoxes}}``, predicted boxes with global ids.
        gt: ``{view: {frame: FrameBoxes}}``, ground truth with global ids, the same views in the
            same order (their order decides which view of a pair plays the top view's role).

    Returns:
        A JSON-ready dict: ``pairs`` (per view pair ``a < b``: ``views`` and the fields of
        :class:`~xvmatch.metrics.cross_view_metrics.CrossViewScores`, percent), ``pooled`` (the
        same fields over all frame pairs: the headline), ``pair_mean`` (the mean over view pairs
        of CVIDP, CVIDR, CVIDF1 and CVMA; 0 with fewer than two views).

    Raises:
        ValueError: the views of ``pred`` and ``gt`` differ.
    """
    views = _check_views(pred, gt)
    per_pair: list[tuple[tuple[str, str], CrossViewScores]] = []
    pooled: list[FrameCounts] = []
    for a, b in itertools.combinations(views, 2):
        counts = pair_counts(pred[a], pred[b], gt[a], gt[b])
        pooled += counts
        per_pair.append(((a, b), summarize(counts)))
    mean = {k: float(np.mean([getattr(s, k) for _, s in per_pair])) if per_pair else 0.0
            for k in _MEAN_FIELDS}
    return {
        "pairs": [{"views": list(names), **scores_to_dict(s)} for names, s in per_pair],
        "pooled": scores_to_dict(summarize(pooled)),
        "pair_mean": mean,
    }


def view_tracking_scores(
    pred: Mapping[str, Mapping[int, FrameBoxes]], gt: Mapping[str, Mapping[int, FrameBoxes]]
) -> dict[str, dict] | None:
    """Per view, TrackEval's MOTA, IDF1, HOTA (and the rest of
    :class:`~xvmatch.metrics.track_metrics.ViewTrackScores`, percent); None without TrackEval.

    Raises:
        ValueError: the views of ``pred`` and ``gt`` differ.
    """
    views = _check_views(pred, gt)
    try:
        from xvmatch.metrics.track_metrics import _trackeval

        _trackeval()
    except ValueError:
        return None
    out = {}
    for name in views:
        s: ViewTrackScores = view_track_scores(gt[name], pred[name])
        out[name] = asdict(s)
    return out


def format_cross_view(scores: dict, tracking: dict[str, dict] | None) -> str:
    """The cross-view scores (one line per view pair, the pooled and mean lines) and the
    per-view tracking scores as plain text, percent to 0.1."""
    head = f"{'view pair':<24}{'frames':>7}{'CVIDP':>8}{'CVIDR':>8}{'CVIDF1':>8}{'CVMA':>8}"
    lines = ["cross-view association (CVMHAT Eqs. 19-20), every view pair", head]
    for p in scores["pairs"]:
        lines.append(f"{' - '.join(p['views']):<24}{p['n_frames']:>7}{p['cvidp']:>8.1f}"
                     f"{p['cvidr']:>8.1f}{p['cvidf1']:>8.1f}{p['cvma']:>8.1f}")
    s = scores["pooled"]
    lines.append(f"{'all frame pairs':<24}{s['n_frames']:>7}{s['cvidp']:>8.1f}{s['cvidr']:>8.1f}"
                 f"{s['cvidf1']:>8.1f}{s['cvma']:>8.1f}")
    m = scores["pair_mean"]
    lines.append(f"{'mean over view pairs':<31}{m['cvidp']:>8.1f}{m['cvidr']:>8.1f}"
                 f"{m['cvidf1']:>8.1f}{m['cvma']:>8.1f}")
    if tracking is None:
        lines.append("per-view MOTA/IDF1/HOTA: need TrackEval (pip install --no-deps "
                     "'trackeval>=1.3'); left out")
        return "\n".join(lines)
    lines.append(f"{'view':<24}{'MOTA':>7}{'IDF1':>8}{'HOTA':>8}{'IDSW':>8}")
    for name, v in tracking.items():
        lines.append(f"{name:<24}{v['mota']:>7.1f}{v['idf1']:>8.1f}{v['hota']:>8.1f}"
                     f"{v['idsw']:>8d}")
    return "\n".join(lines)
