"""Scores of complementary-view tracks: CVIDF1 and CVMA across views, IDF1 to HOTA per view.

Tracks are box files whose ids are track ids, the same id in both views meaning the same person
(``xvmatch track``). Each track box is matched, per frame and view, to a ground-truth box
(Hungarian assignment on IoU, a match needs IoU >= 0.5; the ground-truth boxes themselves match
with IoU 1); an unmatched track box stands for no person.

- Across views (CVMHAT paper, Eqs. 19-20): the predicted pairs of a frame are the boxes of the two
  views with the same track id, scored by
  :func:`xvmatch.metrics.cross_view_metrics.count_pair` exactly as the frame-level metrics.
- Per view: the maintained TrackEval package (``pip install --no-deps trackeval``; its HOTA,
  CLEAR and Identity metrics, fed through its ``eval_sequence`` interface with IoU
  similarities); these metrics are not re-implemented here.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Protocol

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.formats.mot_boxes import FALSE_POSITIVE, FrameBoxes
from xvmatch.geometry.box_overlap import box_iou
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    summarize,
)

__all__ = [
    "TrackScores",
    "TrackletScores",
    "ViewTrackScores",
    "evaluate_tracks",
    "format_track_table",
    "gt_identity",
    "pool_view_scores",
    "track_pair_counts",
    "track_scores_to_dict",
    "tracklet_scores",
    "view_track_results",
    "view_track_scores",
]

MIN_IOU = 0.5
"""IoU a track box needs with a ground-truth box to stand for it."""


@dataclass(frozen=True)
class ViewTrackScores:
    """Single-view tracking scores from TrackEval, in percent (MOTP: mean IoU of matches).

    Attributes:
        idf1, idp, idr: identity F1, precision, recall (Identity).
        mota, motp: CLEAR MOT accuracy and precision.
        hota, deta, assa: HOTA and its detection and association parts (averaged over alpha).
        idsw: identity switches (CLEAR).
        gt_ids, track_ids: distinct ids in the ground truth and in the tracks.
    """

    idf1: float
    idp: float
    idr: float
    mota: float
    motp: float
    hota: float
    deta: float
    assa: float
    idsw: int
    gt_ids: int
    track_ids: int


@dataclass(frozen=True)
class TrackScores:
    """Cross-view scores of the tracks and the per-view tracking scores."""

    cross_view: CrossViewScores
    top: ViewTrackScores
    hor: ViewTrackScores


_EMPTY = FrameBoxes(0, np.zeros(0, np.int64), np.zeros((0, 4)))


def gt_identity(gt: FrameBoxes, pred: FrameBoxes, min_iou: float = MIN_IOU) -> np.ndarray:
    """(len(pred),) the ground-truth id each predicted box stands for, ``FALSE_POSITIVE``
    (-1) when none: one-to-one by IoU (Hungarian), IoU >= ``min_iou``."""
    out = np.full(len(pred), FALSE_POSITIVE, dtype=np.int64)
    if len(pred) == 0 or len(gt) == 0:
        return out
    iou = box_iou(gt.boxes, pred.boxes)
    r, c = linear_sum_assignment(-iou)
    keep = iou[r, c] >= min_iou
    out[c[keep]] = gt.ids[r[keep]]
    return out


def track_pair_counts(
    tracks_top: Mapping[int, FrameBoxes],
    tracks_hor: Mapping[int, FrameBoxes],
    gt_top: Mapping[int, FrameBoxes],
    gt_hor: Mapping[int, FrameBoxes],
    frames: Iterable[int] | None = None,
) -> list[FrameCounts]:
    """Per-frame cross-view counts of tracks: pairs = the two views' boxes with one track id."""
    selected = sorted(set(gt_top) | set(gt_hor)) if frames is None else sorted(set(frames))
    out = []
    for f in selected:
        gt_t, gt_h = gt_top.get(f, _EMPTY), gt_hor.get(f, _EMPTY)
        tr_t, tr_h = tracks_top.get(f, _EMPTY), tracks_hor.get(f, _EMPTY)
        det_t = gt_identity(gt_t, tr_t)
        det_h = gt_identity(gt_h, tr_h)
        col = {int(k): j for j, k in enumerate(tr_h.ids.tolist())}
        pairs = [(i, col[int(k)]) for i, k in enumerate(tr_t.ids.tolist()) if int(k) in col]
        out.append(count_pair(gt_t.ids, gt_h.ids, det_t, det_h, np.array(pairs).reshape(-1, 2),
                              frame=f))
    return out


@dataclass(frozen=True)
class TrackletScores:
    """Tracklet extraction scores (CVMHAT paper, Table 10), in percent, with their counts.

    A tracklet is right when it holds exactly the boxes of one person in its clip (it joins
    them all, and nothing else); precision is over the tracklets made, recall over the
    person-clips of the ground truth.
    """

    precision: float
    recall: float
    f1: float
    n_tracklets: int
    n_person_clips: int
    n_right: int


class _Rows(Protocol):
    """A tracklet as scored: its detection rows
    (:class:`~xvmatch.inference.linking.tracklets.Tracklet`)."""

    rows: np.ndarray


def tracklet_scores(
    clips: Sequence[Sequence[_Rows]], person_of_row: Mapping[int, int | None]
) -> TrackletScores:
    """Table 10 precision, recall and F1 of one view's tracklets.

    Args:
        clips: per clip, the tracklets (their ``rows`` are detection rows).
        person_of_row: the person each row is, ``None`` for a false detection.
    """
    truth: dict[tuple[int, int], set[int]] = {}
    for k, clip in enumerate(clips):
        for t in clip:
            for r in t.rows.tolist():
                person = person_of_row.get(int(r))
                if person is not None:
                    truth.setdefault((k, person), set()).add(int(r))
    made = [(k, t) for k, clip in enumerate(clips) for t in clip]
    right = 0
    for k, t in made:
        people = {person_of_row.get(int(r)) for r in t.rows.tolist()}
        if len(people) == 1 and None not in people:
            right += truth[(k, people.pop())] == set(t.rows.tolist())
    p = right / len(made) if made else 0.0
    r = right / len(truth) if truth else 0.0
    f1 = 2 * p * r / (p + r) if p + r > 0 else 0.0
    return TrackletScores(100 * p, 100 * r, 100 * f1, len(made), len(truth), right)


def _trackeval_data(gt: Mapping[int, FrameBoxes], pred: Mapping[int, FrameBoxes]) -> dict:
    """TrackEval's per-sequence input: 0-based ids per timestep and IoU similarities."""
    frames = sorted(set(gt) | set(pred))
    gt_map = {v: k for k, v in enumerate(sorted({int(i) for r in gt.values() for i in r.ids}))}
    tr_map = {v: k for k, v in enumerate(sorted({int(i) for r in pred.values() for i in r.ids}))}
    gt_ids, tr_ids, sims = [], [], []
    for f in frames:
        g, p = gt.get(f, _EMPTY), pred.get(f, _EMPTY)
        gt_ids.append(np.array([gt_map[int(i)] for i in g.ids], dtype=int))
        tr_ids.append(np.array([tr_map[int(i)] for i in p.ids], dtype=int))
        sims.append(box_iou(g.boxes, p.boxes))
    return {
        "num_timesteps": len(frames),
        "num_gt_ids": len(gt_map),
        "num_tracker_ids": len(tr_map),
        "num_gt_dets": int(sum(len(r) for r in gt.values())),
        "num_tracker_dets": int(sum(len(r) for r in pred.values())),
        "gt_ids": gt_ids,
        "tracker_ids": tr_ids,
        "similarity_scores": sims,
    }


def _trackeval():
    try:
        # TrackEval prints a line for each optional dataset reader it cannot import (pycocotools
        # and the like, which its metrics do not use): keep that out of the user's output.
        with contextlib.redirect_stdout(io.StringIO()):
            from trackeval.metrics import CLEAR, HOTA, Identity
    except ImportError:
        raise ValueError(
            "per-view tracking metrics need the TrackEval package: "
            "pip install --no-deps 'trackeval>=1.3' (its metrics need only numpy and scipy)"
        ) from None
    return CLEAR, HOTA, Identity


def view_track_results(
    gt: Mapping[int, FrameBoxes], pred: Mapping[int, FrameBoxes]
) -> dict[str, dict]:
    """TrackEval's raw per-sequence results of one view (``CLEAR``, ``HOTA``, ``Identity``),
    to pool sequences with :func:`pool_view_scores`; ``ids`` holds the id counts."""
    clear_cls, hota_cls, identity_cls = _trackeval()
    data = _trackeval_data(gt, pred)
    return {
        "CLEAR": clear_cls({"PRINT_CONFIG": False}).eval_sequence(data),
        "HOTA": hota_cls({"PRINT_CONFIG": False}).eval_sequence(data),
        "Identity": identity_cls({"PRINT_CONFIG": False}).eval_sequence(data),
        "ids": {"gt": data["num_gt_ids"], "tracks": data["num_tracker_ids"]},
    }


def pool_view_scores(results: Sequence[dict[str, dict]]) -> ViewTrackScores:
    """One view's scores over several sequences (TrackEval's ``combine_sequences``: counts
    summed, ratios derived once); a single sequence gives its own scores."""
    clear_cls, hota_cls, identity_cls = _trackeval()
    pooled = {}
    for name, cls in (("CLEAR", clear_cls), ("HOTA", hota_cls), ("Identity", identity_cls)):
        per_seq = {str(k): r[name] for k, r in enumerate(results)}
        pooled[name] = cls({"PRINT_CONFIG": False}).combine_sequences(per_seq)
    clear, hota, ident = pooled["CLEAR"], pooled["HOTA"], pooled["Identity"]
    return ViewTrackScores(
        idf1=100.0 * float(ident["IDF1"]),
        idp=100.0 * float(ident["IDP"]),
        idr=100.0 * float(ident["IDR"]),
        mota=100.0 * float(clear["MOTA"]),
        motp=100.0 * float(clear["MOTP"]),
        hota=100.0 * float(np.mean(hota["HOTA"])),
        deta=100.0 * float(np.mean(hota["DetA"])),
        assa=100.0 * float(np.mean(hota["AssA"])),
        idsw=int(clear["IDSW"]),
        gt_ids=int(sum(r["ids"]["gt"] for r in results)),
        track_ids=int(sum(r["ids"]["tracks"] for r in results)),
    )


def view_track_scores(
    gt: Mapping[int, FrameBoxes], pred: Mapping[int, FrameBoxes]
) -> ViewTrackScores:
    """IDF1, MOTA, MOTP and HOTA of one view's tracks, computed by TrackEval."""
    return pool_view_scores([view_track_results(gt, pred)])


def evaluate_tracks(
    tracks_top: Mapping[int, FrameBoxes],
    tracks_hor: Mapping[int, FrameBoxes],
    gt_top: Mapping[int, FrameBoxes],
    gt_hor: Mapping[int, FrameBoxes],
) -> TrackScores:
    """All the tracking scores of one sequence pair."""
    counts = track_pair_counts(tracks_top, tracks_hor, gt_top, gt_hor)
    return TrackScores(
        cross_view=summarize(counts),
        top=view_track_scores(gt_top, tracks_top),
        hor=view_track_scores(gt_hor, tracks_hor),
    )


def format_track_table(rows: Sequence[tuple[str, TrackScores]]) -> str:
    """A plain-text table, one line per row: cross-view then per-view scores (percent)."""
    head = (f"{'sequence':<24} {'CVIDF1':>6} {'CVMA':>6} | {'top IDF1':>8} {'MOTA':>6} "
            f"{'MOTP':>6} {'HOTA':>6} {'IDSW':>5} | {'hor IDF1':>8} {'MOTA':>6} {'MOTP':>6} "
            f"{'HOTA':>6} {'IDSW':>5}")
    lines = [head, "-" * len(head)]
    for name, s in rows:
        cv, t, h = s.cross_view, s.top, s.hor
        lines.append(
            f"{name:<24} {cv.cvidf1:6.1f} {cv.cvma:6.1f} | {t.idf1:8.1f} {t.mota:6.1f} "
            f"{t.motp:6.1f} {t.hota:6.1f} {t.idsw:5d} | {h.idf1:8.1f} {h.mota:6.1f} "
            f"{h.motp:6.1f} {h.hota:6.1f} {h.idsw:5d}"
        )
    return "\n".join(lines)


def track_scores_to_dict(scores: TrackScores) -> dict:
    """JSON-ready nested dict of :class:`TrackScores`."""
    return {"cross_view": asdict(scores.cross_view), "top": asdict(scores.top),
            "hor": asdict(scores.hor)}
