"""Judging a site adaptation by the pairs it makes, on frames it never saw, without labels.

A better verification AUC of the adapted appearance cue on mined pairs does not make better
matches: on rendered videos ``adapt`` printed a held-out AUC gain every time while the matches
of ``associate --model SITE/`` moved by +6.5 to -3.7 CVIDF1 (issue 69; look-alike people
swapped). So ``adapt`` judges the bundle as the user will use it: it holds out the last block of
the video (:func:`split_for_judgement`), fits on the rest, then matches the held-out block with
the images twice, with the source bundle and with the site bundle (``associate``'s appearance
check on, as by default), and compares the two runs' *pairs* (:func:`judge_pairs`) against two
yardsticks that need no identities:

* **the box-only matcher's sure pairs**: in each window of consecutive frames, a top and a
  horizontal IoU tracklet the box-only matcher is sure of on ``agree`` consecutive frames, neither
  sure of anyone else (the pseudo-matches ``adapt`` mines,
  :func:`~xvmatch.inference.adaptation.adaptation_pairs.agreed_pairs`); on every frame where both
  tracklets have a box, a run should pair those two boxes;
* **steadiness along each view's own tracklets**: a person keeps one partner while both are in
  view; a pair whose top tracklet and horizontal tracklet are not each other's most frequent
  partner in the window is a *flip* (two look-alike people swapped for a while show as flips).

Each top box of each judged frame scores +1 (it keeps a sure pair, or makes a steady pair), -1
(it breaks a sure pair: pairs it otherwise or not at all, pairs a sure pair's horizontal box with
someone else, or flips) or 0 (unpaired, and no sure pair says otherwise). The site bundle is
accepted when the sum of its scores minus the source's, over all boxes, is above zero by more
than :data:`MIN_SIGMAS` times its standard error, computed over top tracklets as clusters (a
swap lasts many frames: its frames are not independent evidence). Deterministic; numpy only.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.adaptation.adaptation_pairs import (
    MiningConfig,
    agreed_pairs,
    box_tracklets,
    confident_pairs,
)

__all__ = [
    "JUDGE_FRAMES",
    "JUDGE_SHARE",
    "JUDGE_WINDOW",
    "MIN_JUDGED",
    "MIN_SIGMAS",
    "PairFigures",
    "PairJudgement",
    "judge_pairs",
    "judging_windows",
    "split_for_judgement",
]

JUDGE_SHARE = 0.25
"""Share of the video's frames (its last ones) held out to judge the site bundle."""
JUDGE_FRAMES = 300
"""Most frames held out to judge (two runs of the matcher with images on each)."""
JUDGE_WINDOW = 50
"""Consecutive frames of a judging window (tracklets and sure pairs are found per window)."""
MIN_JUDGED = 30
"""Fewest held-out frames (in windows of consecutive frames) to judge at all."""
MIN_SIGMAS = 2.0
"""How many standard errors the site bundle's gain in pair score must exceed."""


@dataclass(frozen=True)
class PairFigures:
    """What one run's pairs did on the judged frames (no identities involved).

    Attributes:
        sure: box-only sure-pair instances (frame, top box, horizontal box) on the frames.
        sure_kept: of these, the ones the run paired the same way.
        steady: the run's other pairs whose tracklets are each other's main partner.
        flips: the run's other pairs that are not (a tracklet changing partner), and pairs
            that take a sure pair's horizontal box for another top box.
        score: the sum of the top boxes' scores (+1 kept or steady, -1 broken or flipped).
    """

    sure: int
    sure_kept: int
    steady: int
    flips: int
    score: int


@dataclass(frozen=True)
class PairJudgement:
    """The comparison of the site bundle's pairs with the source bundle's (:func:`judge_pairs`).

    Attributes:
        frames: judged frames (those in windows of consecutive frames).
        first, last: the first and last judged frame (0 and -1 when none).
        source, site: each run's :class:`PairFigures`.
        gain: the site's score minus the source's.
        error: the standard error of ``gain`` (top tracklets as clusters).
        accepted: ``gain > MIN_SIGMAS * error`` (and > 0) on at least :data:`MIN_JUDGED` frames.
    """

    frames: int
    first: int
    last: int
    source: PairFigures
    site: PairFigures
    gain: int
    error: float
    accepted: bool

    def message(self) -> str:
        """The measured figures in plain words (for ``adapt``'s one line)."""
        if self.frames < MIN_JUDGED:
            return (f"only {self.frames} held-out frames in runs of consecutive frames "
                    f"({MIN_JUDGED} needed) to check the pairs the site bundle makes: give a "
                    "longer video")
        s, n = self.site, self.source
        worse = self.gain < 0 and -self.gain > MIN_SIGMAS * self.error
        verdict = "better" if self.accepted else "worse" if worse else "not shown better"
        return (f"on the {self.frames} held-out frames ({self.first}-{self.last}, not used to "
                f"fit), matching with the images kept {s.sure_kept} of the box-only matcher's "
                f"{s.sure} sure pairs with the site bundle against {n.sure_kept} without, and "
                f"{s.flips} pairs switched partner along a tracklet against {n.flips} without "
                f"(pair score {s.score:+d} against {n.score:+d}: {self.gain:+d} +/- "
                f"{self.error:.1f}, {verdict})")


def split_for_judgement(frames: Sequence[int], burst: int, share: float = JUDGE_SHARE,
                        most: int = JUDGE_FRAMES) -> tuple[list[int], list[int]]:
    """``(fit frames, judged frames)``: the last ``share`` of ``frames`` (ascending, with boxes in
    both views), at most ``most`` and at least ``burst`` of them, are held out; the frames before
    them fit the adaptation. A time split: the judged block is later than anything fitted."""
    frames = sorted(int(f) for f in frames)
    n = min(max(round(len(frames) * share), burst), most, len(frames))
    return frames[:len(frames) - n], frames[len(frames) - n:]


def judging_windows(frames: Sequence[int], window: int, least: int) -> list[np.ndarray]:
    """``frames`` cut into windows of consecutive frames: each run of consecutive frames in
    pieces of ``window``, a last piece shorter than half a window joined to the one before,
    pieces shorter than ``least`` dropped."""
    present = np.unique(np.asarray(list(frames), dtype=np.int64))
    out: list[np.ndarray] = []
    for run in np.split(present, np.flatnonzero(np.diff(present) != 1) + 1):
        pieces = [run[i:i + window] for i in range(0, len(run), window)]
        if len(pieces) > 1 and len(pieces[-1]) < window // 2:
            pieces[-2:] = [np.concatenate(pieces[-2:])]
        out += [p for p in pieces if len(p) >= max(least, 1)]
    return out


def _rows(records: Mapping, frame: int) -> dict[int, int]:
    return {int(i): r for r, i in enumerate(records[frame].ids.tolist())}


def _run_values(top: Mapping, hor: Mapping, frames: np.ndarray, k: int,
                owner: Mapping[str, Mapping[tuple[int, int], int]],
                sure: Mapping[int, dict[int, int]], sure_hor: Mapping[int, set[int]],
                pred: Mapping[int, Sequence[tuple[int, int]]]
                ) -> tuple[dict[tuple[int, int], int], list[int]]:
    """One run's score per top tracklet of window ``k``, and its counts (sure kept, steady,
    flips). ``sure``: ``{frame: {top row: hor row}}``; ``sure_hor``: the sure horizontal rows."""
    pairs: dict[int, list[tuple[int, int]]] = {}
    votes: dict[str, dict[int, Counter]] = {"top": {}, "hor": {}}
    for f in frames.tolist():
        t_rows, h_rows = _rows(top, f), _rows(hor, f)
        pairs[f] = [(t_rows[int(a)], h_rows[int(b)]) for a, b in pred.get(f, ())
                    if int(a) in t_rows and int(b) in h_rows]
        for i, j in pairs[f]:
            a, b = owner["top"][(f, i)], owner["hor"][(f, j)]
            votes["top"].setdefault(a, Counter())[b] += 1
            votes["hor"].setdefault(b, Counter())[a] += 1
    main = {v: {t: min(c.items(), key=lambda kv: (-kv[1], kv[0]))[0] for t, c in d.items()}
            for v, d in votes.items()}
    value: dict[tuple[int, int], int] = {}
    kept = steady = flips = 0
    for f in frames.tolist():
        paired = dict(pairs[f])
        for i in range(len(top[f].ids)):
            cluster = (k, owner["top"][(f, i)])
            j = paired.get(i)
            if i in sure.get(f, {}):
                good = j == sure[f][i]
                kept += good
                v = 1 if good else -1
            elif j is None:
                v = 0
            elif j in sure_hor.get(f, set()):
                flips += 1
                v = -1
            else:
                a, b = owner["top"][(f, i)], owner["hor"][(f, j)]
                good = main["top"][a] == b and main["hor"][b] == a
                steady += good
                flips += not good
                v = 1 if good else -1
            value[cluster] = value.get(cluster, 0) + v
    return value, [kept, steady, flips]


def judge_pairs(
    top: Mapping,
    hor: Mapping,
    frames: Sequence[int],
    box_costs: Mapping[int, np.ndarray],
    gamma: float,
    source: Mapping[int, Sequence[tuple[int, int]]],
    site: Mapping[int, Sequence[tuple[int, int]]],
    config: MiningConfig | None = None,
    window: int = JUDGE_WINDOW,
    min_sigmas: float = MIN_SIGMAS,
) -> PairJudgement:
    """Compare two runs' pairs on held-out frames (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view (ids name the boxes of a frame only).
        frames: the held-out frames with boxes in both views.
        box_costs: ``{frame: (M, N)}`` the box-only matcher's costs of those frames (input order).
        gamma: its non-association cost.
        source, site: ``{frame: [(top id, hor id)]}`` the pairs of the source bundle's run and
            of the site bundle's.
        config: the sure-pair margin and agreement, and the tracklets' IoU links.
        window: consecutive frames per window; a shorter run of frames is not judged.
        min_sigmas: the gain must exceed this many standard errors.
    """
    config = config or MiningConfig()
    windows = judging_windows([f for f in frames if f in box_costs], window, config.agree)
    totals = {"source": [0, 0, 0], "site": [0, 0, 0]}
    values: dict[str, dict[tuple[int, int], int]] = {"source": {}, "site": {}}
    n_sure = n_frames = 0
    for k, w in enumerate(windows):
        owner = {v: box_tracklets(r, w, k, config) for v, r in (("top", top), ("hor", hor))}
        seen: dict[tuple[int, int], list[int]] = {}
        for f in w.tolist():
            for i, j in confident_pairs(box_costs[f], gamma, config.margin):
                seen.setdefault((owner["top"][(f, i)], owner["hor"][(f, j)]), []).append(f)
        agreed = dict(agreed_pairs(seen, config.agree))
        sure: dict[int, dict[int, int]] = {}
        for f in w.tolist():
            h_of = {owner["hor"][(f, j)]: j for j in range(len(hor[f].ids))}
            for i in range(len(top[f].ids)):
                b = agreed.get(owner["top"][(f, i)])
                if b is not None and b in h_of:
                    sure.setdefault(f, {})[i] = h_of[b]
        sure_hor = {f: set(m.values()) for f, m in sure.items()}
        n_sure += sum(len(m) for m in sure.values())
        n_frames += len(w)
        for name, pred in (("source", source), ("site", site)):
            v, counts = _run_values(top, hor, w, k, owner, sure, sure_hor, pred)
            values[name].update(v)
            totals[name] = [a + b for a, b in zip(totals[name], counts, strict=True)]
    figures = {name: PairFigures(n_sure, c[0], c[1], c[2], int(sum(values[name].values())))
               for name, c in totals.items()}
    clusters = sorted(set(values["source"]) | set(values["site"]))
    diff = np.array([values["site"].get(c, 0) - values["source"].get(c, 0) for c in clusters],
                    dtype=np.float64)
    gain = int(diff.sum())
    error = float(math.sqrt(float((diff ** 2).sum())))
    accepted = n_frames >= MIN_JUDGED and gain > 0 and gain > min_sigmas * error
    first = int(windows[0][0]) if windows else 0
    last = int(windows[-1][-1]) if windows else -1
    return PairJudgement(n_frames, first, last, figures["source"], figures["site"], gain, error,
                         accepted)
