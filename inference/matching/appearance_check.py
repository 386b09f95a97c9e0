"""Whether a run's appearance cue can be trusted, judged on the run's own frames (issue 31).

On a site the appearance network never saw, images can make matching worse than boxes alone, and
no label says so. But a video says something: the box-only matcher is sure of some pairs in
several consecutive frames (the pseudo-matches ``xvmatch adapt`` mines,
:func:`~xvmatch.inference.adaptation.adaptation_pairs.mine_pairs`, 93-100% right on renders), and a
useful appearance cue must rank those pairs above the other boxes of their frames.
:func:`check_appearance` measures that ranking, the verification AUC of the cue the matcher
received, on the run's own frames; when it is shown below :data:`MIN_AUC` (a site bundle's
adapted cue: :data:`SITE_MIN_AUC`) by twice its standard error (a few pairs do not condemn a
cue), the cue is not trusted and the run is matched from the boxes alone (the matcher's
boxes-only setting). Where there are too few such pairs to judge (single image pairs, short
clips, scenes the box-only matcher is never sure of) the cue is kept, and so it is where the
box-only matcher's sure pairs change partners over time (:func:`sure_pair_consistency` below
:data:`MIN_CONSISTENCY`: it is then sure and wrong, as boxes alone often are under an oblique
overview camera, and its pairs would condemn a good cue); where there is no run of
consecutive frames at all (single image pairs, very short clips) and the bundle has one, each
frame is judged by its frame check (:mod:`xvmatch.inference.matching.frame_check`). ``track`` judges
its cross-view term the same way on tracklets (:func:`check_tracklet_appearance`: pairs of tracklets
the box-only matcher is sure of, in the clips it tracks) and, when it fails, leaves only that
term out; it skips the steadiness bar, which its pairs, sure over consecutive frames, did not
need on rendered overview videos (docs/tracking.md). No identities are used. Numpy only.
"""

from __future__ import annotations

import collections
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np

from xvmatch.inference.adaptation.adaptation_pairs import (
    MiningConfig,
    agreed_pairs,
    box_tracklets,
    confident_pairs,
    mine_pairs,
    plan_bursts,
)
from xvmatch.inference.adaptation.site_adaptation import auc_standard_error, pair_auc
from xvmatch.inference.linking.assignment import FrameCosts
from xvmatch.inference.linking.tracklets import Tracklet

__all__ = ["CONSISTENCY_WINDOW", "MIN_AUC", "MIN_CONSISTENCY", "MIN_PAIRS", "SITE_MIN_AUC",
           "TRACK_MIN_AUC", "TRACK_MIN_PAIRS", "AppearanceCheck", "check_appearance",
           "check_tracklet_appearance", "sure_pair_consistency"]

MIN_AUC = 0.62
"""Least verification AUC of the appearance cue on a run's pseudo-matches for the images to be
used. Read off rendered videos under simulated cameras (docs/adaptation.md, "the appearance
check"): of the 24 videos it was read from, the 11 whose cue fell below it had images below
boxes only in all but one."""
SITE_MIN_AUC = 0.75
"""The same bar for a site bundle's adapted cue (``xvmatch adapt``), higher: that cue was fitted
to rank exactly such pairs (the box-only matcher's sure ones, at the same site), so its AUC on
them overstates what it brings to the pairs the boxes doubt. Read off rendered videos under
simulated cameras (docs/adaptation.md, "the appearance check"): of the 26 shifted cells of 17
videos where a site bundle was judged, the 4 where it lost to boxes only were all below it (by
twice the standard error), and of those it also leaves out, none gained more than 0.1."""
TRACK_MIN_AUC = 0.8
"""The same bar for ``track``'s cross-view cue on tracklet pairs
(:func:`check_tracklet_appearance`), higher: Eq. 17 gives that cue 0.7 of a cross-view weight
(``1 - w1``) and nothing weighs it against the boxes, where ``associate``'s matcher weighs its
cue itself. Read off rendered videos under simulated cameras (docs/tracking.md, "under a camera
change"): of the 24 cells of 8 videos it was read from, the cross-view cue cost the tracks
CVIDF1 in all 15 whose interval stayed below it, and gained in 7 of the other 9."""
MIN_PAIRS = 30
"""Fewest pseudo-matched positives (and negatives) to judge the cue at all (about 10 tracklet
pairs, each embedded in 3 frames): in a scene the box-only matcher hardly knows, its few sure
pairs can be wrong, and would condemn a good cue (a rendered video with 5 such positives: AUC
0.39 on them, yet images added 45 CVIDF1 points; docs/adaptation.md)."""
MIN_CONSISTENCY = 0.6
"""Least :func:`sure_pair_consistency` of the box-only matcher for its pseudo-matches to judge
the cue. Read off rendered videos (docs/adaptation.md, "when the boxes are sure and wrong"): the
overview test parts below it had pseudo-matches 0 to 69% right where counted, and on one the
check had dropped clean images worth 50 CVIDF1 points; the drone test parts it judged measured
0.69 to 0.89 (one, 0.59, kept its images either way). Low on purpose: a right matcher's
tracklets also switch people now and then, so the bar catches only a plainly unsteady one."""
CONSISTENCY_WINDOW = 150
"""Consecutive frames (6 s at 25 fps) over which :func:`sure_pair_consistency` follows each
tracklet: long enough for people to move and a geometric confusion to change partner."""
MIN_SURE_FRAMES = 5
"""Fewest frames a tracklet must be in a sure pair to count in :func:`sure_pair_consistency`."""
UNCHECKED_IMAGES = "the images were used without this check"
"""How :meth:`AppearanceCheck.message` ends when the check could not judge the images."""
TRACK_MIN_PAIRS = 20
"""The same for ``track``'s tracklet pairs: each is a pair the box-only matcher was sure of on
several consecutive frames, so :data:`MIN_PAIRS` boxes (about 10 tracklets in 3 frames) stand
for about 10 of them; 20 judges a rendered video with 28 such pairs whose shifted images cost
15.9 CVIDF1 (docs/tracking.md), and leaves alone three with 3 to 16, whose clean images gained up
to 50 points."""


@dataclass(frozen=True)
class AppearanceCheck:
    """The outcome of :func:`check_appearance`.

    Attributes:
        judged: whether there were enough pairs to judge.
        trusted: whether the images are used (always when not judged).
        auc: the cue's verification AUC on the pairs (NaN when not judged).
        error: its standard error (Hanley and McNeil; NaN when not judged).
        positives, negatives: pseudo-matched pairs and the other boxes of their frames.
        min_auc: the bar it was held to.
        min_pairs: the fewest positives (and negatives) it needed to judge.
        bursts: runs of consecutive frames the pairs were mined on (0: single image pairs or
            a clip too short to judge anything, about which there is nothing to say); for
            tracklets, the clips.
        tracklets: judged on ``track``'s tracklets (:func:`check_tracklet_appearance`), whose
            fallback drops only the cross-view appearance term.
        frames: frames judged one by one instead, by the bundle's frame check
            (:mod:`xvmatch.inference.matching.frame_check`; 0: none, as when the run was judged).
        frames_dropped: of those, the frames matched from the boxes alone.
        consistency: the box-only matcher's :func:`sure_pair_consistency` on the run (NaN when
            not measured); below :data:`MIN_CONSISTENCY` the run is not judged.
    """

    judged: bool
    trusted: bool
    auc: float
    error: float
    positives: int
    negatives: int
    min_auc: float = MIN_AUC
    bursts: int = 0
    min_pairs: int = MIN_PAIRS
    tracklets: bool = False
    frames: int = 0
    frames_dropped: int = 0
    consistency: float = math.nan

    @property
    def unsteady(self) -> bool:
        """Whether the box-only matcher was too unsteady for its pairs to judge the cue
        (:attr:`consistency` below :data:`MIN_CONSISTENCY`; False when not measured)."""
        return self.consistency < MIN_CONSISTENCY

    @property
    def worth_saying(self) -> bool:
        """Whether the user is told: not for inputs without a run of consecutive frames,
        unless the frame check left images out."""
        return self.judged or self.bursts > 0 or self.frames_dropped > 0

    def to_tell(self, quiet: bool) -> bool:
        """Whether a command prints :meth:`message`: when it is :attr:`worth_saying`, and with
        ``--quiet`` only when the images were left out."""
        return self.worth_saying and (not quiet or not self.trusted or self.frames_dropped > 0)

    def message(self) -> str:
        """One line for the user."""
        pairs = "tracklet pairs" if self.tracklets else "pairs"
        if not self.judged and self.unsteady:
            return (f"appearance check: the pairs the boxes alone are sure of change partners "
                    f"over time (a person's track keeps its most frequent partner in "
                    f"{self.consistency:.2f} of those frames, {MIN_CONSISTENCY:g} needed), too "
                    f"unsteady to judge the images; {UNCHECKED_IMAGES}")
        if not self.judged:
            n = self.positives
            head = (f"appearance check: the boxes alone are sure of only {n} "
                    f"{pairs if n != 1 else pairs[:-1]} over consecutive frames, "
                    f"{self.min_pairs} needed to judge the images (a longer video gives more)"
                    if self.bursts or not self.frames else "appearance check: no run of "
                    "consecutive frames to judge the images on")
            if self.frames:
                return (f"{head}; judged frame by frame instead, matched {self.frames_dropped} "
                        f"of {self.frames} frames from the boxes alone")
            return f"{head}; {UNCHECKED_IMAGES}"
        fallback = ("the cross-view weights come from the boxes alone (the images still link "
                    "each view over time)" if self.tracklets else "matched from the boxes alone")
        verdict = ("images used" if self.trusted else
                   f"below {self.min_auc:g} by more than twice its standard error, so the images "
                   f"would drag the boxes down: {fallback}")
        return (f"appearance check: the images tell the {self.positives} {pairs} the boxes "
                f"alone are sure of from the {self.negatives} other pairs of their "
                f"{'clips' if self.tracklets else 'frames'} with AUC {self.auc:.3f} +/- "
                f"{self.error:.3f}; {verdict}")


def check_appearance(
    top: Mapping,
    hor: Mapping,
    box_costs: Mapping[int, np.ndarray],
    app_costs: Mapping[int, np.ndarray],
    gamma: float,
    config: MiningConfig | None = None,
    min_auc: float = MIN_AUC,
    min_pairs: int = MIN_PAIRS,
) -> AppearanceCheck:
    """Judge a run's appearance cue on its own frames (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view (ids only name boxes).
        box_costs: ``{frame: (M, N)}`` the matcher's boxes-only costs in input order, of the
            frames with boxes in both views.
        app_costs: ``{frame: (M, N)}`` the appearance cue the matcher received, same frames
            and order.
        gamma: the run's non-association cost.
        config: how pseudo-matches are mined (bursts of consecutive frames).
        min_auc: the least AUC for the images to be used.
        min_pairs: fewest positives and negatives to judge.
    """
    config = config or MiningConfig()
    bursts = plan_bursts(box_costs, config.burst, config.max_frames)
    if not bursts:
        return AppearanceCheck(False, True, math.nan, math.nan, 0, 0, min_auc,
                               min_pairs=min_pairs)
    mined = mine_pairs(top, hor, bursts, box_costs, gamma, config)
    pos, neg = mined.frame_pairs(top, hor)

    def costs(pairs: np.ndarray) -> np.ndarray:
        return np.array([app_costs[f][a, b] for f, a, b in pairs.tolist()], np.float64)

    verdict = _verdict(costs(pos), costs(neg), min_auc, min_pairs, len(bursts))
    if not verdict.judged:
        return verdict
    verdict = replace(verdict, consistency=sure_pair_consistency(top, hor, box_costs, gamma,
                                                                 config))
    if verdict.unsteady:  # not measured (NaN): judged as before
        return replace(verdict, judged=False, trusted=True, auc=math.nan, error=math.nan)
    return verdict


def sure_pair_consistency(
    top: Mapping,
    hor: Mapping,
    box_costs: Mapping[int, np.ndarray],
    gamma: float,
    config: MiningConfig | None = None,
    window: int = CONSISTENCY_WINDOW,
    min_sure: int = MIN_SURE_FRAMES,
) -> float:
    """How steadily the box-only matcher pairs each person over time, label-free, in [0, 1].

    In windows of ``window`` consecutive frames (spread over the run as bursts are), each view's
    boxes are linked into IoU tracklets; every frame's sure pairs
    (:func:`~xvmatch.inference.adaptation.adaptation_pairs.confident_pairs`) then give each tracklet
    a partner tracklet of the other view. The result is the share of a tracklet's sure frames
    spent with its most frequent partner, over tracklets sure on at least ``min_sure`` frames,
    averaged over the two views: near 1 when the matcher is right where it is sure, lower when
    it is sure of different partners as the people move (NaN: no window or no such tracklet).
    """
    config = config or MiningConfig()
    views = {"top": top, "hor": hor}
    partners: dict[str, dict[tuple, collections.Counter]] = {"top": {}, "hor": {}}
    for k, frames in enumerate(plan_bursts(box_costs, window, config.max_frames)):
        owner = {v: box_tracklets(records, frames, k, config) for v, records in views.items()}
        for f in frames.tolist():
            for i, j in confident_pairs(box_costs[f], gamma, config.margin):
                a, b = (k, owner["top"][(f, i)]), (k, owner["hor"][(f, j)])
                partners["top"].setdefault(a, collections.Counter())[b] += 1
                partners["hor"].setdefault(b, collections.Counter())[a] += 1
    shares = []
    for counts in partners.values():
        kept = [c for c in counts.values() if sum(c.values()) >= min_sure]
        if kept:
            shares.append(sum(max(c.values()) for c in kept) / sum(sum(c.values()) for c in kept))
    return float(np.mean(shares)) if shares else math.nan


def _verdict(pos: np.ndarray, neg: np.ndarray, min_auc: float, min_pairs: int, bursts: int,
             tracklets: bool = False) -> AppearanceCheck:
    """The check of a cue's costs on the positives and negatives (judged with enough of both;
    trusted unless its AUC is below ``min_auc`` by more than twice its standard error)."""
    n_pos, n_neg = len(pos), len(neg)
    if min(n_pos, n_neg) < min_pairs:
        return AppearanceCheck(False, True, math.nan, math.nan, n_pos, n_neg, min_auc, bursts,
                               min_pairs, tracklets)
    auc = pair_auc(pos, neg)
    error = auc_standard_error(auc, n_pos, n_neg)
    return AppearanceCheck(True, bool(auc + 2.0 * error >= min_auc), auc, error, n_pos, n_neg,
                           min_auc, bursts, min_pairs, tracklets)


def check_tracklet_appearance(
    clips: Sequence[tuple[Sequence[Tracklet], Sequence[Tracklet], np.ndarray]],
    costs: Mapping[int, FrameCosts],
    gamma: float,
    config: MiningConfig | None = None,
    min_auc: float = TRACK_MIN_AUC,
    min_pairs: int = TRACK_MIN_PAIRS,
) -> AppearanceCheck:
    """Judge ``track``'s cross-view appearance cue (the Eq. 17 term) on its own clips.

    In each clip, a top and a horizontal tracklet are a pseudo-match when the box-only matcher
    is sure of their boxes (:func:`~xvmatch.inference.adaptation.adaptation_pairs.confident_pairs`)
    on ``config.agree`` consecutive frames and neither tracklet of any other partner
    (:func:`~xvmatch.inference.adaptation.adaptation_pairs.agreed_pairs`, as ``adapt`` mines); the
    cue must cost such a pair less than the pseudo-matched tracklets against the other tracklets of
    their clip. Judged as :func:`check_appearance` judges, on tracklets instead of boxes.

    Args:
        clips: per clip, its top tracklets, its horizontal tracklets and the ``(T_top, T_hor)``
            cross-view appearance cost between them (tracklet ``rows`` are the records' ids).
        costs: the learned matcher's box-only costs of each frame
            (:attr:`~xvmatch.inference.tracks.tracking.LearnedEvidence.costs`).
        gamma: its non-association cost.
        config: the margin and the agreement of a pseudo-match.
        min_auc: the least AUC for the cue to be used (:data:`TRACK_MIN_AUC`).
        min_pairs: fewest tracklet positives and negatives to judge
            (:data:`TRACK_MIN_PAIRS`).
    """
    config = config or MiningConfig()
    pos: list[float] = []
    neg: list[float] = []
    for top_tr, hor_tr, cue in clips:
        cue = np.asarray(cue, dtype=np.float64)
        if cue.shape != (len(top_tr), len(hor_tr)):
            raise ValueError(f"a clip's appearance cost is {cue.shape}, its tracklets "
                             f"{len(top_tr)} x {len(hor_tr)}")
        owner = [{(int(f), int(r)): k for k, t in enumerate(tracklets)
                  for f, r in zip(t.frames.tolist(), t.rows.tolist(), strict=True)}
                 for tracklets in (top_tr, hor_tr)]
        seen: dict[tuple[int, int], list[int]] = {}
        for f in sorted({int(f) for t in top_tr for f in t.frames.tolist()}):
            frame = costs.get(f)
            if frame is None:
                continue
            for i, j in confident_pairs(frame.cost, gamma, config.margin):
                a = owner[0].get((f, int(frame.top_rows[i])))
                b = owner[1].get((f, int(frame.hor_rows[j])))
                if a is not None and b is not None:
                    seen.setdefault((a, b), []).append(f)
        for a, b in sorted(agreed_pairs(seen, config.agree)):
            pos.append(float(cue[a, b]))
            neg += np.delete(cue[a], b).tolist() + np.delete(cue[:, b], a).tolist()
    return _verdict(np.asarray(pos), np.asarray(neg), min_auc, min_pairs, len(clips), True)
