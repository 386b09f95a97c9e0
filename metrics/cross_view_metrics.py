"""Cross-view association metrics: CVIDP, CVIDR, CVIDF1, CVMA and the Eq. 9 accuracy.

The metrics score, frame by frame, the predicted pairs ``(top_id, hor_id)`` between the boxes of
a top view and a horizontal view whose ids are ground truth (the same id in both views is the same
person). For frame ``t``:

- ``G_t``: the ids present in both views (top ids ∩ horizontal ids), the pairs that should be
  found; ``P_t``: the predicted pairs; ``TP_t``: the predicted pairs with ``top_id == hor_id``.
- A wrong pair (``top_id != hor_id``) is a *mismatch* when its horizontal id is in ``G_t`` (that
  person had a true partner and got another one), otherwise a *false positive*.
- A *miss* is an id of ``G_t`` whose horizontal box is in no predicted pair.
- ``U_t``: the number of distinct ids over both views; a *true negative* is an id seen in one
  view only that was left unmatched (in no predicted pair on its side).

Scores, in percent (CVMA of the CVMHAT paper of Han et al., TPAMI 2021; Eq. 9 of the
geometric-priors paper):

- CVIDP = mean over frames with ``P_t`` non-empty of ``TP_t / |P_t|``;
- CVIDR = mean over frames with ``G_t`` non-empty of ``TP_t / |G_t|``;
- CVIDF1 = ``2 P R / (P + R)``;
- CVMA = ``1 - sum_t (miss_t + fp_t + 2 mismatch_t) / sum_t |G_t|`` (a mismatch is an error on
  both sides, hence counted twice);
- ACC9 (Eq. 9) = mean over frames with ``U_t > 0`` of ``(TP_t + TN_t) / U_t``.

Every id of either view counts, including the top-view id 0 of CVMHAT (the wearer of the
horizontal camera, never seen in the horizontal view): it is in ``U_t`` and is a true negative
whenever it is left unmatched. This is the reading that reproduces the reference figures of
``shared/data/cvmhat/REFERENCE.md`` exactly, in both modes; leaving id 0 out of ``U_t`` does not.

Empty cases never divide by zero and never give NaN: with no frame where ``P_t`` is non-empty,
CVIDP is 0 (nothing was predicted, so nothing was right); with no frame where ``G_t`` is
non-empty, CVIDR and CVMA are 0 (there was nothing to find, the scores are undefined and reported
as 0); CVIDF1 is 0 when P + R = 0, ACC9 is 0 with no frame where ``U_t > 0``.

Counts are accumulated per frame (:func:`count_frame`, :func:`count_sequence`; with detections
that may stand for no person, :func:`count_pair`) and the ratios are derived once
(:func:`summarize`), so sequences can be pooled, optionally with per-frame weights.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, fields

import numpy as np

from xvmatch.formats.mot_boxes import FALSE_POSITIVE, FrameBoxes

__all__ = [
    "CrossViewScores",
    "FrameCounts",
    "count_frame",
    "count_pair",
    "count_sequence",
    "format_table",
    "scores_to_dict",
    "summarize",
]

_NO_IDS = np.empty(0, dtype=np.int64)


@dataclass(frozen=True)
class FrameCounts:
    """What happened in one frame; all the metrics derive from these counts.

    Attributes:
        frame: frame number (0 when :func:`count_frame` was not told it).
        n_pred: ``|P_t|``, predicted pairs.
        n_gt: ``|G_t|``, ids present in both views.
        tp: pairs with ``top_id == hor_id``.
        fp: wrong pairs whose horizontal id is not in ``G_t``.
        mismatch: wrong pairs whose horizontal id is in ``G_t``.
        miss: ids of ``G_t`` whose horizontal box is in no pair.
        n_union: ``U_t``, distinct ids over both views.
        tn: ids in one view only that are in no pair on their side.
    """

    frame: int
    n_pred: int
    n_gt: int
    tp: int
    fp: int
    mismatch: int
    miss: int
    n_union: int
    tn: int


@dataclass(frozen=True)
class CrossViewScores:
    """Scores of a frame set, in percent, with the summed (unweighted) counts they came from.

    Attributes:
        cvidp: cross-view ID precision, mean of ``TP/|P|`` over frames with predictions.
        cvidr: cross-view ID recall, mean of ``TP/|G|`` over frames with shared ids.
        cvidf1: harmonic mean of ``cvidp`` and ``cvidr``.
        cvma: cross-view matching accuracy, ``1 - (miss + fp + 2 mismatch) / |G|``; can be < 0.
        acc9: Eq. 9 accuracy, mean of ``(TP + TN) / U`` over frames with at least one id.
        n_frames: number of frames scored.
        n_pred, n_gt, tp, fp, mismatch, miss, n_union, tn: the counts of :class:`FrameCounts`
            summed over the frames.
    """

    cvidp: float
    cvidr: float
    cvidf1: float
    cvma: float
    acc9: float
    n_frames: int
    n_pred: int
    n_gt: int
    tp: int
    fp: int
    mismatch: int
    miss: int
    n_union: int
    tn: int


def _id_set(ids: Iterable[int] | np.ndarray, name: str, frame: int) -> set[int]:
    """Ids as a set of Python ints, rejecting an id listed twice."""
    values = np.asarray(ids).reshape(-1)
    if values.size and not np.issubdtype(values.dtype, np.integer):
        if not np.all(values == np.round(values)):
            raise ValueError(f"frame {frame}: {name} must be integers, got {values.tolist()}")
    out = {int(v) for v in values.tolist()}
    if len(out) != values.size:
        raise ValueError(f"frame {frame}: {name} lists an id twice: {sorted(values.tolist())}")
    return out


def count_frame(
    top_ids: Iterable[int] | np.ndarray,
    hor_ids: Iterable[int] | np.ndarray,
    pairs: Sequence[tuple[int, int]],
    *,
    frame: int = 0,
) -> FrameCounts:
    """Count TP, FP, mismatches, misses and Eq. 9 true negatives of one frame.

    Args:
        top_ids: (N,) ground-truth ids of the top-view boxes.
        hor_ids: (M,) ground-truth ids of the horizontal-view boxes.
        pairs: predicted ``(top_id, hor_id)`` pairs, one-to-one.
        frame: frame number, only recorded (and used in error messages).

    Returns:
        The frame's :class:`FrameCounts`.

    Raises:
        ValueError: an id listed twice in a view, a pair naming an id that has no box in its view,
            or a top or horizontal id used by two pairs (the association is one-to-one).
    """
    top = _id_set(top_ids, "top_ids", frame)
    hor = _id_set(hor_ids, "hor_ids", frame)
    pair_list = [(int(t), int(h)) for t, h in pairs]
    pred_top = {t for t, _ in pair_list}
    pred_hor = {h for _, h in pair_list}
    if len(pred_top) != len(pair_list) or len(pred_hor) != len(pair_list):
        raise ValueError(f"frame {frame}: pairs must be one-to-one, got {pair_list}")
    if not pred_top <= top or not pred_hor <= hor:
        raise ValueError(
            f"frame {frame}: pairs name ids without a box in their view: top ids "
            f"{sorted(pred_top - top)}, horizontal ids {sorted(pred_hor - hor)}"
        )
    shared = top & hor
    tp = sum(t == h for t, h in pair_list)
    mismatch = sum(t != h and h in shared for t, h in pair_list)
    return FrameCounts(
        frame=int(frame),
        n_pred=len(pair_list),
        n_gt=len(shared),
        tp=tp,
        fp=len(pair_list) - tp - mismatch,
        mismatch=mismatch,
        miss=len(shared - pred_hor),
        n_union=len(top | hor),
        tn=len((top - hor) - pred_top) + len((hor - top) - pred_hor),
    )


def count_sequence(
    pred: Mapping[int, Sequence[tuple[int, int]]],
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    frames: Iterable[int] | None = None,
) -> list[FrameCounts]:
    """Count every evaluated frame of a sequence.

    Args:
        pred: ``{frame: [(top_id, hor_id), ...]}``; a frame absent here predicted no pair.
        top: ``{frame: FrameBoxes}`` of the top view (ground truth).
        hor: ``{frame: FrameBoxes}`` of the horizontal view (ground truth).
        frames: the frames to evaluate, e.g. the processed subset of a subsampled run; default
            the union of the frames of ``top`` and ``hor``. A frame with no boxes in a view
            counts with no ids there. Predictions on frames outside an explicit subset are
            ignored.

    Returns:
        One :class:`FrameCounts` per evaluated frame, frames ascending.

    Raises:
        ValueError: as :func:`count_frame`, naming the frame; or, when ``frames`` is None, a
            predicted frame that has boxes in neither view.
    """
    if frames is None:
        selected = sorted(set(top) | set(hor))
        stray = sorted({f for f, p in pred.items() if len(p)} - set(selected))
        if stray:
            raise ValueError(
                f"predictions on frames with no box in either view: {stray[:10]}; "
                "pass frames= to evaluate a subset"
            )
    else:
        selected = sorted({int(f) for f in frames})
    empty = FrameBoxes(0, _NO_IDS, np.empty((0, 4)))
    return [
        count_frame(top.get(t, empty).ids, hor.get(t, empty).ids, pred.get(t, ()), frame=t)
        for t in selected
    ]


def _weighted_mean(values: np.ndarray, weights: np.ndarray, mask: np.ndarray) -> float:
    """Weighted mean of ``values`` over ``mask``; 0.0 when the mask has no weight."""
    total = float(weights[mask].sum())
    return float((weights[mask] * values[mask]).sum() / total) if total > 0 else 0.0


def summarize(
    counts: Sequence[FrameCounts], weights: Sequence[float] | np.ndarray | None = None
) -> CrossViewScores:
    """Derive the cross-view scores (in percent) from per-frame counts.

    With ``weights``, every per-frame term (the ratios averaged by CVIDP, CVIDR and ACC9, and the
    error and ``|G_t|`` sums of CVMA) is weighted. To pool sequences whose frames were subsampled
    at different rates, weight each frame by ``1 / (its sequence's sampled fraction)`` = total
    frames / processed frames of its sequence: the pooled figure then estimates the one over all
    frames (this is how the OVERALL rows of the CVMHAT reference are computed).

    Args:
        counts: per-frame counts, e.g. from :func:`count_sequence` (concatenate to pool).
        weights: (len(counts),) non-negative finite weights; default all 1.

    Returns:
        The :class:`CrossViewScores`; see the module docstring for the empty cases (0, not NaN).

    Raises:
        ValueError: ``weights`` of the wrong length, negative or not finite.
    """
    n = len(counts)
    table = np.array(
        [(c.n_pred, c.n_gt, c.tp, c.fp, c.mismatch, c.miss, c.n_union, c.tn) for c in counts],
        dtype=np.int64,
    ).reshape(n, 8)
    n_pred, n_gt, tp, fp, mismatch, miss, n_union, tn = table.T
    if weights is None:
        w = np.ones(n)
    else:
        w = np.asarray(weights, dtype=np.float64).reshape(-1)
        if w.shape != (n,) or not np.isfinite(w).all() or (w < 0).any():
            raise ValueError(
                f"weights must be {n} finite non-negative numbers (one per frame), "
                f"got shape {w.shape}"
            )
    with np.errstate(divide="ignore", invalid="ignore"):
        precision = _weighted_mean(tp / n_pred, w, n_pred > 0)
        recall = _weighted_mean(tp / n_gt, w, n_gt > 0)
        acc9 = _weighted_mean((tp + tn) / n_union, w, n_union > 0)
    f1 = 2.0 * precision * recall / (precision + recall) if precision + recall > 0 else 0.0
    gt_total = float((w * n_gt).sum())
    errors = float((w * (miss + fp + 2 * mismatch)).sum())
    cvma = 1.0 - errors / gt_total if gt_total > 0 else 0.0
    sums = table.sum(axis=0).tolist()
    return CrossViewScores(
        cvidp=100.0 * precision,
        cvidr=100.0 * recall,
        cvidf1=100.0 * f1,
        cvma=100.0 * cvma,
        acc9=100.0 * acc9,
        n_frames=n,
        n_pred=sums[0],
        n_gt=sums[1],
        tp=sums[2],
        fp=sums[3],
        mismatch=sums[4],
        miss=sums[5],
        n_union=sums[6],
        tn=sums[7],
    )


_TABLE_COLUMNS = (
    ("frames", "n_frames"),
    ("CVIDP", "cvidp"),
    ("CVIDR", "cvidr"),
    ("CVIDF1", "cvidf1"),
    ("CVMA", "cvma"),
    ("ACC9", "acc9"),
)


def _percent(value: float) -> str:
    """``value`` to 0.1, ties to even (numpy's rounding), without a ``-0.0``."""
    return f"{float(np.round(value, 1)) + 0.0:.1f}"


def format_table(rows: Sequence[tuple[str, CrossViewScores]]) -> str:
    """An aligned text table, one row per named score set, scores in percent to 0.1.

    Rounding is half to even (``np.round``), as the CVMHAT reference figures are: a score that is
    exactly on a tie (mode A ``V0-S_canteen_0-G_3`` ACC9 = 1933/2000 = 96.65 %) prints as 96.6.

    Args:
        rows: ``(name, scores)`` pairs, printed in the given order.

    Returns:
        The table, header line first, lines joined by ``\\n`` (no trailing newline).
    """
    header = ["name", *(title for title, _ in _TABLE_COLUMNS)]
    body = [
        [name]
        + [
            str(getattr(s, attr)) if attr == "n_frames" else _percent(getattr(s, attr))
            for _, attr in _TABLE_COLUMNS
        ]
        for name, s in rows
    ]
    widths = [max(len(r[k]) for r in [header, *body]) for k in range(len(header))]
    lines = [
        "  ".join(
            cell.ljust(width) if k == 0 else cell.rjust(width)
            for k, (cell, width) in enumerate(zip(r, widths, strict=True))
        ).rstrip()
        for r in [header, *body]
    ]
    return "\n".join(lines)


def scores_to_dict(scores: CrossViewScores) -> dict[str, float | int]:
    """The scores as a JSON-ready dict of plain floats and ints (field names as keys)."""
    kinds = {f.name: f.type for f in fields(scores)}
    return {
        name: (int(value) if kinds[name] in ("int", int) else float(value))
        for name, value in asdict(scores).items()
    }


def _true_ids(ids: np.ndarray, gt: set[int], name: str, frame: int) -> np.ndarray:
    arr = np.asarray(ids).reshape(-1).astype(np.int64)
    real = arr[arr != FALSE_POSITIVE]
    if np.unique(real).size != real.size:
        raise ValueError(f"frame {frame}: {name} stand for one ground-truth id twice: "
                         f"{sorted(real.tolist())}")
    unknown = sorted(set(real.tolist()) - gt)
    if unknown:
        raise ValueError(f"frame {frame}: {name} name ids absent from the view's ground truth: "
                         f"{unknown}")
    return arr


def count_pair(
    gt_top_ids: np.ndarray,
    gt_ego_ids: np.ndarray,
    det_top_ids: np.ndarray,
    det_ego_ids: np.ndarray,
    pairs: np.ndarray,
    *,
    frame: int = 0,
) -> FrameCounts:
    """Count one image pair against the ground truth, detections allowed (Eq. 9, Accuracy*).

    ``U`` (the unique persons of Eq. 9) are the ground-truth ids of either view and ``G`` those
    of both. A predicted pair is a true positive when both of its boxes stand for the same
    ground-truth id; a wrong pair is a mismatch when its egocentric box stands for an id of
    ``G``, otherwise a false positive. A miss is an id of ``G`` whose egocentric box is
    undetected or in no pair. A true negative is an id seen in one view only (in the ground
    truth) whose box there was detected and left unmatched. With the ground-truth boxes as
    detections this equals :func:`xvmatch.metrics.cross_view_metrics.count_frame`.

    Args:
        gt_top_ids: (G1,) ground-truth ids of the top view.
        gt_ego_ids: (G2,) ground-truth ids of the egocentric view.
        det_top_ids: (M,) id each associated top box stands for (``FALSE_POSITIVE``, -1, for a
            false positive), in the order of the association's rows.
        det_ego_ids: (N,) the same for the egocentric boxes (columns).
        pairs: (K, 2) ``(row, column)`` pairs of the association.
        frame: frame number, recorded and used in error messages.

    Returns:
        The :class:`~xvmatch.metrics.cross_view_metrics.FrameCounts`.

    Raises:
        ValueError: repeated ground-truth ids, a detection standing for an id twice or for an id
            the view does not have, or pairs out of range or not one-to-one.
    """
    gt_top = [int(v) for v in np.asarray(gt_top_ids).reshape(-1)]
    gt_ego = [int(v) for v in np.asarray(gt_ego_ids).reshape(-1)]
    top_set, ego_set = set(gt_top), set(gt_ego)
    if len(top_set) != len(gt_top) or len(ego_set) != len(gt_ego):
        raise ValueError(f"frame {frame}: a ground-truth id is listed twice in a view")
    det_top = _true_ids(det_top_ids, top_set, "det_top_ids", frame)
    det_ego = _true_ids(det_ego_ids, ego_set, "det_ego_ids", frame)
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if p.size and ((p < 0).any() or (p[:, 0] >= det_top.size).any()
                   or (p[:, 1] >= det_ego.size).any()):
        raise ValueError(f"frame {frame}: pairs out of range for {det_top.size} x {det_ego.size}")
    if np.unique(p[:, 0]).size != len(p) or np.unique(p[:, 1]).size != len(p):
        raise ValueError(f"frame {frame}: pairs must be one-to-one, got {p.tolist()}")
    shared = top_set & ego_set
    a, b = det_top[p[:, 0]], det_ego[p[:, 1]]
    correct = (a == b) & (a != FALSE_POSITIVE)
    tp = int(correct.sum())
    mismatch = int(sum(1 for ok, h in zip(correct, b, strict=True) if not ok and int(h) in shared))
    paired_ego = {int(h) for h in b if h != FALSE_POSITIVE}
    paired_top = {int(t) for t in a if t != FALSE_POSITIVE}
    detected_top = {int(t) for t in det_top if t != FALSE_POSITIVE}
    detected_ego = {int(h) for h in det_ego if h != FALSE_POSITIVE}
    tn = len(((top_set - ego_set) & detected_top) - paired_top) + len(
        ((ego_set - top_set) & detected_ego) - paired_ego
    )
    return FrameCounts(
        frame=int(frame),
        n_pred=len(p),
        n_gt=len(shared),
        tp=tp,
        fp=len(p) - tp - mismatch,
        mismatch=mismatch,
        miss=len(shared - paired_ego),
        n_union=len(top_set | ego_set),
        tn=tn,
    )
