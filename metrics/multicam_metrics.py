"""Scores of a multi-camera association (``xvmatch evaluate --multicam``, issue 32).

Every predicted box (a camera's box with its global id) is first matched to a ground-truth box
of the same camera and frame (one-to-one, intersection over union >= 0.5, Hungarian), which
gives it the true global id, or none (a false box). Then:

* **P and R of the trajectory-correspondence paper** (Eqs. 13-14), per overlapping camera pair:
  a trajectory is one camera's boxes of one global id; a true pair is two cameras' trajectories
  of one person seen by both cameras at a common frame (the set xi of the paper), an estimated
  pair two cameras' predicted trajectories sharing a global id and a frame (the set E), correct
  when both trajectories are, by majority of their boxes, that same person. ``R = |xi & E| /
  |xi|``, ``P = |xi & E| / |E|``. A camera pair overlaps when xi is not empty. Overall: the mean
  over overlapping pairs (the paper's "Average").
* **Box pairs**: at every frame, every two boxes of two cameras sharing a predicted global id is
  a predicted pair, sharing a true id a true pair; precision, recall and F1 over all frames.
* **Global IDF1** over all cameras' boxes (identities matched one-to-one over the whole
  sequence, as IDF1 of a single camera, Ristani et al. 2016).
* **Ground-position error** when true ground positions are given: each predicted global id
  stands for the true person IDF1 matched it to; the distance of its fused ground point to that
  person's at every frame both have, metres.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Mapping

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.box_overlap import box_iou

__all__ = ["format_multicam", "match_to_truth", "multicam_scores"]


def match_to_truth(pred: Mapping[int, FrameBoxes], gt: Mapping[int, FrameBoxes],
                   iou_min: float = 0.5) -> dict[int, np.ndarray]:
    """The true id of every predicted box of one camera, -1 for a box matching none.

    Returns:
        ``{frame: (N,) int64}`` aligned with ``pred[frame].ids``.
    """
    out = {}
    for f, rec in pred.items():
        truth = np.full(len(rec), -1, dtype=np.int64)
        g = gt.get(f)
        if g is not None and len(g) and len(rec):
            iou = box_iou(rec.boxes, g.boxes)
            rows, cols = linear_sum_assignment(-iou)
            ok = iou[rows, cols] >= iou_min
            truth[rows[ok]] = g.ids[cols[ok]]
        out[f] = truth
    return out


def _ratio(num: float, den: float) -> float:
    return float(num) / den if den else float("nan")


def _seen_ids(
    rows: list[tuple[int, int, int, int]], gt: Mapping[str, Mapping[int, FrameBoxes]],
    cams: list[str],
) -> tuple[dict[tuple[int, int], set[int]], dict[tuple[int, int], set[int]], list[int]]:
    """The true and predicted ids each camera sees on each frame, and all frames, sorted.

    Args:
        rows: ``(camera index, frame, predicted id, true id)`` of every predicted box.
        gt: ``{camera: {frame: FrameBoxes}}`` with true global ids.
        cams: the camera names, in index order.
    """
    true_seen: dict[tuple[int, int], set[int]] = {}  # (camera, frame) -> true ids
    for name_i, name in enumerate(cams):
        for f, rec in gt[name].items():
            true_seen[(name_i, f)] = set(rec.ids.tolist())
    pred_seen: dict[tuple[int, int], set[int]] = {}
    for c, f, p, _t in rows:
        pred_seen.setdefault((c, f), set()).add(p)
    frames = sorted({f for (_c, f) in true_seen} | {f for (_c, f) in pred_seen})
    return true_seen, pred_seen, frames


def _trajectory_scores(
    rows: list[tuple[int, int, int, int]], cams: list[str],
    true_seen: dict[tuple[int, int], set[int]], pred_seen: dict[tuple[int, int], set[int]],
    frames: list[int],
) -> tuple[list[dict], float, float, list[dict]]:
    """Trajectory P/R per camera pair (Eqs. 13-14) and their means over overlapping pairs.

    A predicted id of a camera belongs to its majority true id (ties: the smaller id).

    Returns:
        The per-pair records, mean P, mean R (NaN without overlapping pairs) and the
        overlapping pairs' records.
    """
    owner: dict[tuple[int, int], int] = {}  # (camera, predicted id) -> majority true id
    votes: dict[tuple[int, int], Counter] = {}
    for c, _f, p, t in rows:
        votes.setdefault((c, p), Counter())[t] += 1
    for key, cnt in votes.items():
        owner[key] = min(cnt.items(), key=lambda kv: (-kv[1], kv[0]))[0]
    per_pair = []
    for a in range(len(cams)):
        for b in range(a + 1, len(cams)):
            xi, est = set(), set()
            for f in frames:
                xi |= true_seen.get((a, f), set()) & true_seen.get((b, f), set())
                est |= pred_seen.get((a, f), set()) & pred_seen.get((b, f), set())
            correct = {owner[(a, g)] for g in est
                       if owner[(a, g)] == owner[(b, g)] and owner[(a, g)] in xi}
            n_correct_est = sum(1 for g in est if owner[(a, g)] == owner[(b, g)]
                                and owner[(a, g)] in xi)
            per_pair.append({"cameras": [cams[a], cams[b]], "true": len(xi), "estimated":
                             len(est), "P": _ratio(n_correct_est, len(est)),
                             "R": _ratio(len(correct), len(xi))})
    overlapping = [p for p in per_pair if p["true"] > 0]
    mean_p = float(np.nanmean([p["P"] for p in overlapping])) if overlapping else float("nan")
    mean_r = float(np.nanmean([p["R"] for p in overlapping])) if overlapping else float("nan")
    return per_pair, mean_p, mean_r, overlapping


def _box_pair_counts(
    rows: list[tuple[int, int, int, int]], n_cams: int,
    true_seen: dict[tuple[int, int], set[int]], frames: list[int],
) -> tuple[int, int, int]:
    """Cross-camera box pairs: correct, predicted and true counts over all frames."""
    tp = n_pred_pairs = n_true_pairs = 0
    by_frame: dict[int, list] = {}
    for c, f, p, t in rows:
        by_frame.setdefault(f, []).append((c, p, t))
    for f in frames:
        items = by_frame.get(f, [])
        pred_count = Counter((p, c) for c, p, _t in items)
        joint = Counter((p, t, c) for c, p, t in items if t >= 0)
        n_pred_pairs += _cross_camera_pairs(pred_count)
        tp += _cross_camera_pairs(joint)
        true_count = Counter()
        for c in range(n_cams):
            for t in true_seen.get((c, f), ()):
                true_count[(t, c)] += 1
        n_true_pairs += _cross_camera_pairs(true_count)
    return tp, n_pred_pairs, n_true_pairs


def _global_id_match(R: np.ndarray) -> tuple[int, dict[int, int]]:
    """Global IDF1's one-to-one id match over all cameras and frames.

    Args:
        R: ``(B, 4)`` rows ``(camera, frame, predicted id, true id)``; true id -1: no match.

    Returns:
        The matched box count (IDTP) and ``{predicted id: true id}``.
    """
    matched = R[R[:, 3] >= 0] if len(R) else R
    pu, pi = np.unique(matched[:, 2], return_inverse=True) if len(matched) else ([], [])
    tu, ti = np.unique(matched[:, 3], return_inverse=True) if len(matched) else ([], [])
    idtp, mapping = 0, {}
    if len(matched):
        M = np.zeros((len(pu), len(tu)), dtype=np.int64)
        np.add.at(M, (pi, ti), 1)
        r, c = linear_sum_assignment(-M)
        idtp = int(M[r, c].sum())
        mapping = {int(pu[i]): int(tu[j]) for i, j in zip(r, c, strict=True) if M[i, j] > 0}
    return idtp, mapping


def _ground_errors(ground_pred: Mapping[int, tuple[np.ndarray, np.ndarray]],
                   ground_gt: Mapping[int, tuple[np.ndarray, np.ndarray]],
                   mapping: Mapping[int, int]) -> dict:
    """Ground-position errors (metres) of matched ids on common frames: median, mean, p90."""
    errors = []
    for g, (fr, xy) in ground_pred.items():
        t = mapping.get(int(g))
        if t is None or t not in ground_gt:
            continue
        tf, txy = ground_gt[t]
        _common, ia, ib = np.intersect1d(fr, tf, return_indices=True)
        errors.append(np.linalg.norm(xy[ia] - txy[ib], axis=1))
    e = np.concatenate(errors) if errors else np.empty(0)
    return {"median": float(np.median(e)) if e.size else float("nan"),
            "mean": float(e.mean()) if e.size else float("nan"),
            "p90": float(np.percentile(e, 90)) if e.size else float("nan"),
            "count": int(e.size)}


def multicam_scores(pred: Mapping[str, Mapping[int, FrameBoxes]],
                    gt: Mapping[str, Mapping[int, FrameBoxes]],
                    ground_pred: Mapping[int, tuple[np.ndarray, np.ndarray]] | None = None,
                    ground_gt: Mapping[int, tuple[np.ndarray, np.ndarray]] | None = None,
                    ) -> dict:
    """All scores of the module docstring.

    Args:
        pred: ``{camera: {frame: FrameBoxes}}`` with predicted global ids.
        gt: ``{camera: {frame: FrameBoxes}}`` with true global ids, the same cameras.
        ground_pred, ground_gt: ``{id: (frames, (J, 2) xy)}`` predicted and true ground
            positions (optional).

    Returns:
        A JSON-ready dict: ``pairs`` (per camera pair: P, R, true and estimated pair counts),
        ``P``, ``R`` (means over overlapping pairs), ``box_pairs`` (P, R, F1), ``idf1`` (IDF1,
        IDP, IDR), and ``ground`` (median, mean, p90 error in metres, count) when given.
    """
    cams = list(pred)
    rows = []  # (camera index, frame, predicted id, true id)
    for c, name in enumerate(cams):
        truth = match_to_truth(pred[name], gt[name])
        for f, rec in pred[name].items():
            for p, t in zip(rec.ids.tolist(), truth[f].tolist(), strict=True):
                rows.append((c, f, p, t))
    R = np.array(rows, dtype=np.int64).reshape(-1, 4)
    n_gt_boxes = sum(len(r) for name in cams for r in gt[name].values())

    # --- trajectory P/R (Eqs. 13-14)
    true_seen, pred_seen, frames = _seen_ids(rows, gt, cams)
    per_pair, mean_p, mean_r, overlapping = _trajectory_scores(rows, cams, true_seen, pred_seen,
                                                                frames)

    # --- box pairs
    tp, n_pred_pairs, n_true_pairs = _box_pair_counts(rows, len(cams), true_seen, frames)
    bp, br = _ratio(tp, n_pred_pairs), _ratio(tp, n_true_pairs)
    bf = _ratio(2 * tp, n_pred_pairs + n_true_pairs)

    # --- global IDF1
    idtp, mapping = _global_id_match(R)
    scores = {
        "cameras": cams,
        "pairs": per_pair,
        "P": mean_p,
        "R": mean_r,
        "overlapping_pairs": len(overlapping),
        "box_pairs": {"P": bp, "R": br, "F1": bf, "true": n_true_pairs,
                      "estimated": n_pred_pairs},
        "idf1": {"IDF1": _ratio(2 * idtp, len(R) + n_gt_boxes), "IDP": _ratio(idtp, len(R)),
                 "IDR": _ratio(idtp, n_gt_boxes)},
    }
    if ground_pred is not None and ground_gt is not None:
        scores["ground"] = _ground_errors(ground_pred, ground_gt, mapping)
    return scores


def _cross_camera_pairs(count: Counter) -> int:
    """Pairs of boxes in two different cameras sharing the key's identity: ``count`` maps
    ``(*identity, camera)`` to a number of boxes."""
    per_id: dict[tuple, list[int]] = {}
    for key, n in count.items():
        per_id.setdefault(key[:-1], []).append(n)
    total = 0
    for ns in per_id.values():
        s = sum(ns)
        total += (s * s - sum(n * n for n in ns)) // 2
    return total


def format_multicam(scores: dict, name: str = "") -> str:
    """The scores as a plain-text table: one line per overlapping camera pair, then overall."""
    lines = [f"{name}" if name else "multicam association",
             f"{'camera pair':<24}{'true':>6}{'est.':>6}{'P':>8}{'R':>8}"]
    for p in scores["pairs"]:
        if p["true"] == 0:
            continue
        lines.append(f"{' - '.join(p['cameras']):<24}{p['true']:>6}{p['estimated']:>6}"
                     f"{p['P']:>8.3f}{p['R']:>8.3f}")
    lines.append(f"{'average (Eqs. 13-14)':<36}{scores['P']:>8.3f}{scores['R']:>8.3f}")
    bp = scores["box_pairs"]
    lines.append(f"box pairs: P {bp['P']:.3f}  R {bp['R']:.3f}  F1 {bp['F1']:.3f}")
    idf = scores["idf1"]
    lines.append(f"global IDF1 {idf['IDF1']:.3f}  (IDP {idf['IDP']:.3f}, IDR {idf['IDR']:.3f})")
    if "ground" in scores:
        g = scores["ground"]
        lines.append(f"ground error: median {g['median']:.3f} m, mean {g['mean']:.3f} m, "
                     f"p90 {g['p90']:.3f} m over {g['count']} points")
    return "\n".join(lines)
