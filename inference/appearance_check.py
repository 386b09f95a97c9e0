"""Whether a run's appearance cue can be trusted, judged on the run's own frames (issue 31).

On a site the appearance network never saw, images can make matching worse than boxes alone,
and no label says so. But a video says something: the box-only matcher is sure of some pairs
in several consecutive frames (the pseudo-matches ``xvmatch adapt`` mines,
:func:`~xvmatch.inference.adaptation_pairs.mine_pairs`, 93-100% right on renders), and a
useful appearance cue must rank those pairs above the other boxes of their frames.
:func:`check_appearance` measures that ranking, the verification AUC of the cue the matcher
received, on the run's own frames; when it is shown below :data:`MIN_AUC` (by twice its
standard error: a few pairs do not condemn a cue) the cue is not trusted and the run is matched
from the boxes alone (the matcher's boxes-only setting). Where there are too few such
pairs to judge (single image pairs, short clips, scenes the box-only matcher is never sure of)
the cue is kept, as before. No identities are used. Numpy only.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.inference.adaptation_pairs import MiningConfig, mine_pairs, plan_bursts
from xvmatch.inference.site_adaptation import auc_standard_error, pair_auc

__all__ = ["MIN_AUC", "MIN_PAIRS", "AppearanceCheck", "check_appearance"]

MIN_AUC = 0.62
"""Least verification AUC of the appearance cue on a run's pseudo-matches for the images to be
used. Read off rendered videos under simulated cameras (docs/adaptation.md, "the appearance
check"): of the 24 videos it was read from, the 11 whose cue fell below it had images below
boxes only in all but one."""
MIN_PAIRS = 30
"""Fewest pseudo-matched positives (and negatives) to judge the cue at all (about 10 tracklet
pairs, each embedded in 3 frames): in a scene the box-only matcher hardly knows, its few sure
pairs can be wrong, and would condemn a good cue (a rendered video with 5 such positives: AUC
0.39 on them, yet images added 45 CVIDF1 points; docs/adaptation.md)."""


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
        bursts: runs of consecutive frames the pairs were mined on (0: single image pairs or
            a clip too short to judge anything, about which there is nothing to say).
    """

    judged: bool
    trusted: bool
    auc: float
    error: float
    positives: int
    negatives: int
    min_auc: float = MIN_AUC
    bursts: int = 0

    @property
    def worth_saying(self) -> bool:
        """Whether the user is told: not for inputs without a run of consecutive frames."""
        return self.judged or self.bursts > 0

    def message(self) -> str:
        """One line for the user."""
        if not self.judged:
            return (f"appearance check: {self.positives} pairs the box-only matcher is sure of "
                    f"over consecutive frames, {MIN_PAIRS} needed to judge the images; they "
                    "were used as they are")
        verdict = ("images used" if self.trusted else
                   f"below {self.min_auc:g} by more than twice its standard error, so the images "
                   "would drag the boxes down: matched from the boxes alone")
        return (f"appearance check: the appearance cue ranks this video's {self.positives} "
                f"box-only pseudo-matches against {self.negatives} other pairs of their frames "
                f"with AUC {self.auc:.3f} +/- {self.error:.3f}; {verdict}")


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
        return AppearanceCheck(False, True, math.nan, math.nan, 0, 0, min_auc)
    mined = mine_pairs(top, hor, bursts, box_costs, gamma, config)
    # mined pairs index the boxes of mined.embed_frames, stacked view by view in that order
    where = {}
    for view, records in (("top", top), ("hor", hor)):
        frames = [np.full(len(records[f].ids), f, dtype=np.int64) for f in mined.embed_frames]
        rows = [np.arange(len(records[f].ids)) for f in mined.embed_frames]
        where[view] = (np.concatenate(frames) if frames else np.zeros(0, np.int64),
                       np.concatenate(rows) if rows else np.zeros(0, np.int64))

    def costs(pairs: np.ndarray) -> np.ndarray:
        frame, i = where["top"][0][pairs[:, 0]], where["top"][1][pairs[:, 0]]
        j = where["hor"][1][pairs[:, 1]]
        return np.array([app_costs[int(f)][a, b] for f, a, b in
                         zip(frame.tolist(), i.tolist(), j.tolist(), strict=True)], np.float64)

    n_pos, n_neg = len(mined.cross_pos), len(mined.cross_neg)
    if min(n_pos, n_neg) < min_pairs:
        return AppearanceCheck(False, True, math.nan, math.nan, n_pos, n_neg, min_auc,
                               len(bursts))
    auc = pair_auc(costs(mined.cross_pos), costs(mined.cross_neg))
    error = auc_standard_error(auc, n_pos, n_neg)
    return AppearanceCheck(True, bool(auc + 2.0 * error >= min_auc), auc, error, n_pos, n_neg,
                           min_auc, len(bursts))
