"""Training pairs for site adaptation, mined from a site's unlabelled video pair (no identities).

The frames are read in **bursts**: runs of ``burst`` consecutive frames with boxes in both views,
spread evenly over the video (at most ``max_frames`` frames in all, so a long video costs no more
than a short one). In each burst:

* **within each view**, boxes are linked over the burst into tracklets by IoU
  (:func:`xvmatch.inference.linking.tracklets.clip_tracklets`, the tracking code's links; the box
  files' ids only name the boxes of a frame): a tracklet's boxes in two frames are a positive pair,
  two boxes of one frame a negative pair;
* **across views**, the box-only learned matcher (the bundle's ``matcher.onnx`` without the
  appearance cue; with the cameras when given) scores every frame of the burst
  (``learned_association.box_only_costs``). A pair it assigns is *confident* when its cost is
  below every alternative of its row and column and below the non-association cost gamma (the
  dustbin) by at least ``margin``; a pair of tracklets is a pseudo-match when it is confident in
  at least ``agree`` consecutive frames and neither tracklet is confidently matched to another.
  Boxes nobody is sure of stay unlabelled: the camera wearer, who is not in the horizontal view, and
  anyone the matcher doubts (pseudo-labels allow "no match"). A pseudo-matched box against every
  other box of the other view in that frame is a cross-view negative.

Only ``shots`` frames of each burst (first, last, evenly between) are embedded by the network
(:attr:`MinedPairs.embed_frames`, every box of both views): the descriptors
(:func:`embed_frames`) and the index pairs make a
:class:`~xvmatch.inference.adaptation.site_adaptation.PairSet`. Each pair carries its burst number,
so a fit can hold out the last part of the video.
"""

from __future__ import annotations

import collections
import itertools
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.adaptation.site_adaptation import VIEWS, PairSet
from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.linking.tracklets import clip_tracklets

__all__ = [
    "MinedPairs",
    "MiningConfig",
    "agreed_pairs",
    "box_tracklets",
    "confident_pairs",
    "embed_frames",
    "mine_pairs",
    "plan_bursts",
    "reference_costs",
]

REFERENCE_SCENES: tuple[tuple[str, int], ...] = (("drone", 9101), ("drone", 9102),
                                                   ("overview", 9103), ("overview", 9104))
"""Rendered scenes (scenario, seed) on which :func:`reference_costs` measures the network in the
domain it was trained on (seeds no training or test set uses)."""


@dataclass(frozen=True)
class MiningConfig:
    """How pairs are mined.

    Attributes:
        burst: consecutive frames per burst (>= ``agree``).
        max_frames: most frames scored by the box-only matcher (bursts spread evenly).
        margin: a confident pair's cost is below every alternative (and gamma) by this much.
        agree: consecutive confident frames a pseudo-match needs.
        min_iou: IoU of a tracklet link.
        max_gap: frames a tracklet may skip.
        shots: frames of each burst embedded by the appearance network, evenly spaced from
            its first to its last frame (2..burst).
    """

    burst: int = 10
    max_frames: int = 1500
    margin: float = 0.3
    agree: int = 3
    min_iou: float = 0.5
    max_gap: int = 1
    shots: int = 3

    def __post_init__(self) -> None:
        if not 2 <= self.shots <= self.burst:
            raise ValueError(f"shots must be in 2..burst ({self.burst}), got {self.shots}")
        if not 1 <= self.agree <= self.burst:
            raise ValueError(f"agree must be in 1..burst ({self.burst}), got {self.agree}")
        if self.max_frames < self.burst:
            raise ValueError(f"max_frames ({self.max_frames}) must be >= burst ({self.burst})")
        if not 0.0 <= self.margin <= 1.0:
            raise ValueError(f"margin must be in [0, 1], got {self.margin}")


def plan_bursts(frames: Iterable[int], burst: int, max_frames: int) -> list[np.ndarray]:
    """Bursts of ``burst`` consecutive frame numbers among ``frames`` (those with boxes in both
    views), at most ``max_frames // burst`` of them, spread evenly in time; a run shorter than
    ``burst`` is skipped. Returns one ascending ``(burst,)`` int64 array per burst."""
    present = np.unique(np.asarray(list(frames), dtype=np.int64))
    if present.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, np.diff(present) != 1])
    ends = np.r_[starts[1:], present.size]
    windows = [present[s + k * burst: s + (k + 1) * burst]
               for s, e in zip(starts.tolist(), ends.tolist(), strict=True)
               for k in range((e - s) // burst)]
    most = max(int(max_frames) // int(burst), 1)
    if len(windows) > most:
        pick = np.unique(np.round(np.linspace(0, len(windows) - 1, most)).astype(int))
        windows = [windows[i] for i in pick.tolist()]
    return windows


def confident_pairs(cost: np.ndarray, gamma: float, margin: float) -> list[tuple[int, int]]:
    """The assigned pairs ``(row, col)`` of an ``(M, N)`` cost matrix (Hungarian with the
    non-association cost ``gamma``) whose cost is below gamma and below every other entry of its
    row and of its column by at least ``margin``."""
    cost = np.asarray(cost, dtype=np.float64)
    out = []
    for i, j in assign(cost, gamma):
        row = np.delete(cost[i], j)
        col = np.delete(cost[:, j], i)
        alternative = min(float(gamma), float(row.min()) if row.size else np.inf,
                          float(col.min()) if col.size else np.inf)
        if alternative - cost[i, j] >= margin:
            out.append((int(i), int(j)))
    return out



@dataclass(frozen=True, eq=False)
class MinedPairs:
    """Pairs among the boxes of the embedded frames (indices: boxes in frame order, then in
    record order, per view).

    Attributes:
        embed_frames: ``(F,)`` the frames whose boxes are embedded.
        n_boxes: ``{view: K_v}`` boxes of those frames.
        within_pos, within_neg, cross_pos, cross_neg: index pairs as in
            :class:`~xvmatch.inference.adaptation.site_adaptation.PairSet`.
        within_pos_group, within_neg_group, cross_pos_group, cross_neg_group: the burst of
            each pair.
        bursts: bursts scored; agreed: tracklet pairs agreed on.
    """

    embed_frames: np.ndarray
    n_boxes: dict[str, int]
    within_pos: dict[str, np.ndarray]
    within_neg: dict[str, np.ndarray]
    cross_pos: np.ndarray
    cross_neg: np.ndarray
    within_pos_group: dict[str, np.ndarray]
    within_neg_group: dict[str, np.ndarray]
    cross_pos_group: np.ndarray
    cross_neg_group: np.ndarray
    bursts: int
    agreed: int

    def frame_pairs(self, top: Mapping, hor: Mapping) -> tuple[np.ndarray, np.ndarray]:
        """The cross-view positives and negatives as ``(P, 3)`` int64 rows ``(frame, top row,
        hor row)`` (rows: a box's place in its frame's record), for ``top`` and ``hor`` the
        records they were mined from: to read any cue's cost of a pair in its frame."""
        where = {}
        for view, records in (("top", top), ("hor", hor)):
            frames = [np.full(len(records[f].ids), f, dtype=np.int64) for f in self.embed_frames]
            rows = [np.arange(len(records[f].ids), dtype=np.int64) for f in self.embed_frames]
            where[view] = (np.concatenate(frames) if frames else np.zeros(0, np.int64),
                           np.concatenate(rows) if rows else np.zeros(0, np.int64))
            if len(where[view][0]) != self.n_boxes[view]:
                raise ValueError(f"{view}: {len(where[view][0])} boxes in the records' embedded "
                                 f"frames, {self.n_boxes[view]} mined")

        def rows(pairs: np.ndarray) -> np.ndarray:
            return np.stack([where["top"][0][pairs[:, 0]], where["top"][1][pairs[:, 0]],
                             where["hor"][1][pairs[:, 1]]], axis=1).reshape(-1, 3)

        return rows(self.cross_pos), rows(self.cross_neg)

    def pair_set(self, top: np.ndarray, hor: np.ndarray) -> PairSet:
        """The :class:`PairSet` of these pairs with the boxes' descriptors
        (:func:`embed_frames`)."""
        for view, d in (("top", top), ("hor", hor)):
            if len(d) != self.n_boxes[view]:
                raise ValueError(f"{view}: {len(d)} descriptors for {self.n_boxes[view]} boxes")
        return PairSet(np.asarray(top, np.float64), np.asarray(hor, np.float64),
                       self.within_pos, self.within_neg, self.cross_pos, self.cross_neg,
                       self.within_pos_group, self.within_neg_group, self.cross_pos_group,
                       self.cross_neg_group)


def box_tracklets(records: Mapping, frames: np.ndarray, clip: int, config: MiningConfig
                  ) -> dict[tuple[int, int], int]:
    """``{(frame, row): tracklet}``: each box of ``frames`` (its row in the frame's record) and
    the IoU tracklet of one view it belongs to, linked over those frames with ``config``'s
    ``min_iou`` and ``max_gap`` (ids only name boxes within a frame)."""
    owner = {}
    for t, tr in enumerate(clip_tracklets(records, frames, clip, config.min_iou,
                                          config.max_gap)):
        for f, r in zip(tr.frames.tolist(), tr.rows.tolist(), strict=True):
            owner[(f, int(np.flatnonzero(records[f].ids == r)[0]))] = t
    return owner


def _longest_run(frames: list[int]) -> int:
    """Longest run of consecutive numbers in an ascending list."""
    best = run = 1
    for a, b in itertools.pairwise(frames):
        run = run + 1 if b == a + 1 else 1
        best = max(best, run)
    return best if frames else 0


def agreed_pairs(seen: Mapping[tuple[int, int], Sequence[int]], agree: int
                 ) -> set[tuple[int, int]]:
    """The pseudo-matches among tracklet pairs ``(top, hor)``, given the ascending frames on
    which the box-only matcher was sure of each (``seen``): those sure on at least ``agree``
    consecutive frames, neither of whose tracklets was ever sure of another partner."""
    tops = collections.Counter(p[0] for p in seen)
    hors = collections.Counter(p[1] for p in seen)
    return {p for p, frames in seen.items() if _longest_run(list(frames)) >= agree
            and tops[p[0]] == 1 and hors[p[1]] == 1}


def _pairs(idx: list[tuple[int, int]]) -> np.ndarray:
    return np.array(sorted(set(idx)), dtype=np.int64).reshape(-1, 2)


class _GroupedPairs:
    """Pairs of box indices, each with the group (burst) it was found in, in the order found."""

    def __init__(self) -> None:
        self.pairs: list[tuple[int, int]] = []
        self.groups: list[int] = []

    def extend(self, pairs: list[tuple[int, int]], group: int) -> None:
        """Add pairs found in one group."""
        self.pairs += pairs
        self.groups += [group] * len(pairs)

    def unique(self) -> tuple[np.ndarray, np.ndarray]:
        """The distinct pairs, sorted, ``(P, 2)``, and the group each was first found in."""
        first: dict[tuple[int, int], int] = {}
        for p, g in zip(self.pairs, self.groups, strict=True):
            first.setdefault(p, g)
        keys = sorted(first)
        return (np.array(keys, dtype=np.int64).reshape(-1, 2),
                np.array([first[p] for p in keys], dtype=np.int64))


def _burst_shots(burst: np.ndarray, shots: int) -> list[int]:
    """The frames of a burst whose boxes are embedded: ``shots`` evenly spaced, sorted."""
    index = np.round(np.linspace(0, len(burst) - 1, shots)).astype(int)
    return sorted({int(burst[i]) for i in index.tolist()})


def _box_offsets(views: Mapping[str, Mapping], embed: list[int]
                 ) -> tuple[dict[str, dict[int, int]], dict[str, int]]:
    """Per view, ``{frame: index of its first box}`` among the embedded frames' boxes, in
    order, and the number of those boxes."""
    offset: dict[str, dict[int, int]] = {v: {} for v in VIEWS}
    count = dict.fromkeys(VIEWS, 0)
    for f in embed:
        for v in VIEWS:
            offset[v][f] = count[v]
            count[v] += len(views[v][f].ids)
    return offset, count


def _within_view_pairs(records: Mapping, shots: list[int], owner: Mapping[tuple[int, int], int],
                       offset: Mapping[int, int], k: int, pos: _GroupedPairs,
                       neg: _GroupedPairs) -> None:
    """One view's pairs of burst k: negatives, two boxes of one frame; positives, two boxes
    of one tracklet (``owner``: ``{(frame, row): tracklet}``)."""
    for f in shots:
        n, o = len(records[f].ids), offset[f]
        a, c = np.triu_indices(n, 1)
        neg.extend(list(zip((o + a).tolist(), (o + c).tolist(), strict=True)), k)
    by_tracklet: dict[int, list[int]] = {}
    for f in shots:
        for row in range(len(records[f].ids)):
            by_tracklet.setdefault(owner[(f, row)], []).append(offset[f] + row)
    for boxes in by_tracklet.values():
        for i in range(len(boxes)):
            for j in range(i + 1, len(boxes)):
                pos.extend([(boxes[i], boxes[j])], k)


def _agreed_tracklets(burst: np.ndarray, costs: Mapping[int, np.ndarray], gamma: float,
                      owner: Mapping[str, Mapping[tuple[int, int], int]], config: MiningConfig
                      ) -> list[tuple[int, int]]:
    """The (top, horizontal) tracklet pairs the burst's confident frames agree on."""
    seen: dict[tuple[int, int], list[int]] = {}
    for f in burst.tolist():
        if f not in costs:
            continue
        for i, j in confident_pairs(costs[f], gamma, config.margin):
            seen.setdefault((owner["top"][(f, i)], owner["hor"][(f, j)]), []).append(f)
    return agreed_pairs(seen, config.agree)


def _cross_view_pairs(top: Mapping, hor: Mapping, shots: list[int],
                      owner: Mapping[str, Mapping[tuple[int, int], int]],
                      offset: Mapping[str, Mapping[int, int]], agreed: list[tuple[int, int]],
                      k: int, pos: _GroupedPairs, neg: _GroupedPairs) -> None:
    """Burst k's cross-view pairs: in each shot, the boxes of an agreed tracklet pair are a
    positive, each with the other boxes of the other view a negative."""
    for f in shots:
        t_of = {owner["top"][(f, i)]: i for i in range(len(top[f].ids))}
        h_of = {owner["hor"][(f, j)]: j for j in range(len(hor[f].ids))}
        ot, oh = offset["top"][f], offset["hor"][f]
        for tt, th in agreed:
            if tt not in t_of or th not in h_of:
                continue
            i, j = t_of[tt], h_of[th]
            pos.extend([(ot + i, oh + j)], k)
            others = [(ot + i, oh + jj) for jj in range(len(hor[f].ids)) if jj != j]
            others += [(ot + ii, oh + j) for ii in range(len(top[f].ids)) if ii != i]
            neg.extend(others, k)


def mine_pairs(
    top: Mapping,
    hor: Mapping,
    bursts: Sequence[np.ndarray],
    costs: Mapping[int, np.ndarray],
    gamma: float,
    config: MiningConfig | None = None,
) -> MinedPairs:
    """Mine the pairs of every burst (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` (``ids`` unique within a frame: they only name boxes).
        bursts: from :func:`plan_bursts`.
        costs: ``{frame: (M, N)}`` box-only costs in input order
            (``learned_association.box_only_costs``).
        gamma: the matcher's non-association cost.
        config: the mining settings.
    """
    config = config or MiningConfig()
    views = {"top": top, "hor": hor}
    embed: list[int] = []
    for b in bursts:
        embed += _burst_shots(np.asarray(b, dtype=np.int64), config.shots)
    offset, count = _box_offsets(views, embed)
    wpos = {v: _GroupedPairs() for v in VIEWS}
    wneg = {v: _GroupedPairs() for v in VIEWS}
    cpos, cneg = _GroupedPairs(), _GroupedPairs()
    agreed_total = 0
    for k, b in enumerate(bursts):
        b = np.asarray(b, dtype=np.int64)
        shots = _burst_shots(b, config.shots)
        owner = {v: box_tracklets(views[v], b, k, config) for v in VIEWS}
        for v in VIEWS:
            _within_view_pairs(views[v], shots, owner[v], offset[v], k, wpos[v], wneg[v])
        agreed = _agreed_tracklets(b, costs, gamma, owner, config)
        agreed_total += len(agreed)
        _cross_view_pairs(top, hor, shots, owner, offset, agreed, k, cpos, cneg)
    cp, cpg = cpos.unique()
    cn, cng = cneg.unique()
    wp, wn, wpg, wng = {}, {}, {}, {}
    for v in VIEWS:
        wp[v], wpg[v] = wpos[v].unique()
        wn[v], wng[v] = wneg[v].unique()
    return MinedPairs(np.array(embed, dtype=np.int64), count, wp, wn, cp, cn, wpg, wng, cpg,
                      cng, len(bursts), agreed_total)


def embed_frames(
    frames: Sequence[int],
    records: Mapping,
    source,
    embed: Callable[[np.ndarray, np.ndarray], np.ndarray],
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
) -> np.ndarray:
    """``(K, D)`` descriptors of every box of ``frames`` of one view, in frame order then record
    order (the indices of :class:`MinedPairs`).

    Args:
        frames: :attr:`MinedPairs.embed_frames`.
        records: ``{frame: FrameBoxes}`` of the view.
        source: its images (``get(frame)``).
        embed: ``embed(image, boxes) -> (K, D)`` raw descriptors (e.g.
            :meth:`~xvmatch.inference.matching.learned_association.LearnedMatcher.descriptors`).
        progress: wraps the frame iterator.
    """
    out = []
    for f in progress(list(frames)) if progress else frames:
        boxes = records[f].boxes
        if len(boxes):
            out.append(np.asarray(embed(source.get(f), boxes), dtype=np.float64))
    return np.concatenate(out) if out else np.zeros((0, 0))


def reference_costs(
    embed: Callable[[np.ndarray, np.ndarray], np.ndarray],
    scenes: Sequence[tuple[str, int]] = REFERENCE_SCENES,
    frames: Sequence[int] = (1, 6, 12),
) -> tuple[np.ndarray, np.ndarray]:
    """Raw appearance costs ``|a - b| / 2`` of the network on renders (the domain it was trained
    on): ``(positives, negatives)``, the same rendered person in both views or two different
    ones, over ``frames`` of each of ``scenes``. The scale the matcher's fusion expects, for
    the cost's recalibration; rendered (no real image), seeded, the same every time.

    Args:
        embed: ``embed(image, boxes) -> (K, D)`` raw descriptors.
        scenes: ``(scenario, seed)`` of each rendered scene.
        frames: the frames of each scene used.
    """
    from xvmatch.cues.matcher_inputs import appearance_cost
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.datasets.tracking_video import render_tracking_video

    pos, neg = [], []
    for scenario, seed in scenes:
        video = render_tracking_video(seed, max(frames), SynthConfig(scenario=scenario,
                                                                   fps=25.0))
        for f in frames:
            t, h = video.top[f], video.hor[f]
            if not (len(t.ids) and len(h.ids)):
                continue
            cost = appearance_cost(embed(video.top_images[f], t.boxes),
                                   embed(video.hor_images[f], h.boxes))
            same = t.ids[:, None] == h.ids[None, :]
            pos.append(cost[same])
            neg.append(cost[~same])
    return np.concatenate(pos), np.concatenate(neg)
