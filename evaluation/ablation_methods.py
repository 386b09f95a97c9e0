"""The rows of the ablation (``xvmatch ablate``): every cue alone, the handcrafted fusion rules,
the CVMHAT search and the learned matcher, scored on the same trials.

Rows (:data:`ROWS`), each an association of the shuffled boxes of a
:class:`~xvmatch.datasets.pair_trials.PairTrial` scored with Eq. 9 and the cross-view ID scores
(:func:`~xvmatch.metrics.cross_view_metrics.count_pair`):

* single cues: the learned appearance cost alone, the colour histogram alone (Eq. 3), the ray
  distance alone (Eq. 6), the ray distance with the cheirality veto (Eq. 7), and the CVMHAT
  spatial-distribution search on the boxes (:func:`~xvmatch.cues.spatial_search.
  associate_frame`, paper parameters, O searched);
* the handcrafted rules of the geometric-priors paper on histogram + ray (sum with w = 0.5 and
  the product of Eq. 8, each with and without cheirality), with the paper's gammas (0.25 and
  0.1) and with gammas tuned on the validation trials; the same two rules (with cheirality) on
  the learned appearance cost + ray, gammas tuned;
* the learned matcher (ONNX bundle, :func:`~xvmatch.evaluation.deployed_matcher_eval.
  matcher_costs`) in its four input settings: the geometry encoder alone (boxes), with the camera
  cues (cameras), the learned fusion with images, and with images and cameras; the bundle's gamma.

Tuned gammas (:func:`tune_gamma`): the value of
:data:`~xvmatch.inference.linking.assignment.GAMMA_GRID` with the best mean Eq. 9 accuracy on the
validation trials, the middle one of ties.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.cues.cost_fusion import ProductFusion, SumFusion, add_cheirality
from xvmatch.cues.spatial_search import associate_frame
from xvmatch.datasets.pair_trials import PairTrial
from xvmatch.evaluation.deployed_matcher_eval import matcher_costs
from xvmatch.evaluation.handcrafted_baseline import GAMMA_PRODUCT, GAMMA_SUM, Method, fused_cost
from xvmatch.inference.linking.assignment import GAMMA_GRID, assign
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.metrics.cross_view_metrics import FrameCounts, count_pair, summarize

__all__ = [
    "FAMILIES",
    "LEARNED_FUSION",
    "ROWS",
    "Row",
    "RowResult",
    "row_by_key",
    "score_rows",
    "tune_gamma",
]

FAMILIES: dict[str, str] = {
    "cue": "single cue",
    "handcrafted": "handcrafted fusion",
    "learned": "learned (ONNX)",
}
"""Row families; "learned" rows are the matcher's, every other row is a non-learned baseline
(the rules on the learned appearance cost included: their fusion is handcrafted)."""


@dataclass(frozen=True)
class Row:
    """One method of the ablation.

    Attributes:
        key: short unique name (``ray+cheir``, ``sum+cheir/tuned``, ``learned/images``).
        label: the table's row name.
        family: one of :data:`FAMILIES`.
        rule: how the boxes are associated: a single cue (``"app"``, ``"hist"``, ``"ray"``),
            a fusion rule (``"sum"``, ``"product"``) of ``fused``, the CVMHAT ``"search"``, or
            ``"learned"`` (the matcher in the input setting ``setting``).
        gamma: where its non-association cost comes from: ``"tuned"`` (validation trials),
            ``"paper"``, ``"bundle"`` or ``"none"`` (the search has none).
        cheirality: the cheirality veto (Eq. 7) is added to the cost.
        fused: the two normalised cues a fusion rule combines with the ray distance's ``geo``:
            ``"hist"`` (the paper's) or ``"app"`` (the learned appearance cost).
        setting: the learned matcher's input setting
            (:data:`~xvmatch.cues.matcher_inputs.INPUT_SETTINGS`).
    """

    key: str
    label: str
    family: str
    rule: str
    gamma: str
    cheirality: bool = False
    fused: str = "hist"
    setting: str = ""

    @property
    def uses_app(self) -> bool:
        """The row needs the learned appearance cost (a bundle with an appearance network)."""
        if self.rule == "learned":
            return "images" in self.setting
        return self.rule == "app" or (self.rule in ("sum", "product") and self.fused == "app")


def _fusion_rows() -> list[Row]:
    rows = [Row(f"{rule}{'+cheir' if cheir else ''}/{source}",
                f"hist + ray, {rule}{' + cheir.' if cheir else ''}, {source} gamma",
                "handcrafted", rule, source, cheir)
            for rule in ("sum", "product") for cheir in (False, True)
            for source in ("paper", "tuned")]
    rows += [Row(f"app+ray {rule}+cheir/tuned",
                 f"learned app. + ray, {rule} + cheir., tuned gamma",
                 "handcrafted", rule, "tuned", True, fused="app")
             for rule in ("sum", "product")]
    return rows


ROWS: tuple[Row, ...] = (
    Row("app", "appearance (learned cost) alone", "cue", "app", "tuned"),
    Row("hist", "colour histogram alone", "cue", "hist", "tuned"),
    Row("ray", "ray distance alone", "cue", "ray", "tuned"),
    Row("ray+cheir", "ray distance + cheirality veto", "cue", "ray", "tuned", True),
    Row("search", "CVMHAT spatial search (boxes)", "cue", "search", "none"),
    *_fusion_rows(),
    Row("learned/boxes", "learned encoder: boxes", "learned", "learned", "bundle",
        setting="boxes"),
    Row("learned/cameras", "learned encoder: boxes + cameras", "learned", "learned", "bundle",
        setting="cameras"),
    Row("learned/images", "learned fusion: boxes + images", "learned", "learned", "bundle",
        setting="images"),
    Row("learned/images+cameras", "learned fusion: images + cameras", "learned", "learned",
        "bundle", setting="images+cameras"),
)
"""Every row, in table order."""

LEARNED_FUSION = "learned/images+cameras"
"""The learned fusion, the row the ablation's target is about."""

_PAPER_GAMMA = {"sum": GAMMA_SUM, "product": GAMMA_PRODUCT}


def row_by_key(key: str) -> Row:
    """The :class:`Row` named ``key``."""
    for row in ROWS:
        if row.key == key:
            return row
    raise KeyError(f"no ablation row {key!r}")


@dataclass(frozen=True, eq=False)
class RowResult:
    """One row on the test trials.

    Attributes:
        gamma: the non-association cost used (None for the search).
        counts: per test trial, its :class:`~xvmatch.metrics.cross_view_metrics.FrameCounts`.
        pairs: per test trial, the ``(K, 2)`` (top row, ego column) pairs.
        costs: per test trial, the ``(M, N)`` cost matrix, or None for the search.
    """

    gamma: float | None
    counts: list[FrameCounts]
    pairs: list[np.ndarray]
    costs: list[np.ndarray] | None


def _count(trial: PairTrial, pairs: np.ndarray) -> FrameCounts:
    return count_pair(trial.gt_top_ids, trial.gt_ego_ids, trial.det_top_ids, trial.det_ego_ids,
                      pairs, frame=trial.frame)


def tune_gamma(trials: Sequence[PairTrial], costs: Sequence[np.ndarray],
               grid: Sequence[float] = GAMMA_GRID) -> float:
    """The gamma of ``grid`` with the best mean Eq. 9 accuracy of ``trials`` (their cost
    matrices ``costs``); the middle one of ties (the lower middle for an even count).

    Raises:
        ValueError: no trials, or an empty grid.
    """
    if not trials or not grid:
        raise ValueError("tune_gamma needs validation trials and a non-empty grid")
    curve = {float(g): summarize([_count(t, assign(c, g))
                                  for t, c in zip(trials, costs, strict=True)]).acc9
             for g in grid}
    best = max(curve.values())
    tied = [g for g, acc in curve.items() if acc == best]
    return tied[(len(tied) - 1) // 2]


def _hand_costs(row: Row, trial: PairTrial) -> np.ndarray:
    """The (M, N) cost matrix of a non-learned cost row: a normalised cue, or a rule of two
    (:class:`~xvmatch.cues.cost_fusion.SumFusion` with w = 0.5, or
    :class:`~xvmatch.cues.cost_fusion.ProductFusion`, Eq. 8), plus the cheirality veto."""
    cues = trial.cues()
    if row.rule in ("sum", "product") and row.fused == "hist":
        return fused_cost(trial.costs, Method(row.rule, row.cheirality, _PAPER_GAMMA[row.rule]))
    if row.rule == "sum":
        cost = SumFusion({"geo": 0.5, row.fused: 0.5})(cues)
    elif row.rule == "product":
        cost = ProductFusion(("geo", row.fused))(cues)
    else:
        cost = cues["geo" if row.rule == "ray" else row.rule]
    return add_cheirality(cost, trial.costs.cheirality) if row.cheirality else cost


def _assign_all(trials: Sequence[PairTrial], costs: list[np.ndarray], gamma: float) -> RowResult:
    pairs = [assign(c, gamma) for c in costs]
    return RowResult(gamma, [_count(t, p) for t, p in zip(trials, pairs, strict=True)], pairs,
                     costs)


def score_rows(val: Sequence[PairTrial], test: Sequence[PairTrial],
               matcher: LearnedMatcher) -> dict[str, RowResult]:
    """Every row of :data:`ROWS` on the test trials (gammas tuned on ``val`` where the row's are).

    Args:
        val: validation trials (built with the matcher's appearance coster).
        test: test trials, the same setting.
        matcher: the bundle (it must take the appearance and camera cues).

    Returns:
        ``{row key: RowResult}`` in :data:`ROWS` order.
    """
    out: dict[str, RowResult] = {}
    for row in ROWS:
        if row.rule == "learned":
            out[row.key] = _assign_all(test, matcher_costs(matcher, test, row.setting),
                                       matcher.gamma)
        elif row.rule == "search":
            pairs = [associate_frame(t.top_boxes, t.ego_boxes, t.cameras["ego"].width).pairs
                     for t in test]
            out[row.key] = RowResult(None, [_count(t, p)
                                            for t, p in zip(test, pairs, strict=True)],
                                     pairs, None)
        else:
            costs = [_hand_costs(row, t) for t in test]
            gamma = (_PAPER_GAMMA[row.rule] if row.gamma == "paper"
                     else tune_gamma(val, [_hand_costs(row, t) for t in val]))
            out[row.key] = _assign_all(test, costs, gamma)
    return out
