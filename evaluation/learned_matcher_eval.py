"""The learned matcher against the handcrafted baseline on synthetic test scenes.

Every image pair of a test dataset is associated by the handcrafted rules of
:mod:`xvmatch.evaluation.handcrafted_baseline` and by the learned rows, on exactly the same
boxes: the ground-truth boxes (``"gt"``, Table I setting) and the detector-noise boxes
(``"det"``, Table II setting), shuffled per frame and view with the baseline's seeds ("ids
scrambled"), and scored with the same functions (:func:`~xvmatch.evaluation.
cross_view_metrics.count_pair`, Eq. 9 accuracy averaged over pairs): the trials of
:mod:`xvmatch.datasets.pair_trials`.

Cues, each an ``(M, N)`` cost in [0, 1] (:meth:`~xvmatch.datasets.pair_trials.PairTrial.cues`):

* ``"app"``: the learned appearance cost ``|a - b| / 2`` of the Siamese descriptors of the two
  crops (from the coster the trials were built with);
* ``"geo"``: ``tanh`` of the ray distance of Eq. 6 (the baseline's geometry);
* ``"cheir"``: 1 where the cheirality test of Eq. 7 fails, else 0;
* ``"hist"``: the baseline's normalised histogram distance (for completeness).

Learned rows (:class:`CueRule`): appearance only (with and without the cheirality veto), the
sum and product rules on the learned appearance and the geometry (plus the veto), and learned
fusion heads (:class:`~xvmatch.models.fusion_heads.LearnedFusionHead`, trained by
:mod:`xvmatch.training.fusion_module`) on ``{geo, cheir}`` ("geometry only") and on
``{app, geo, cheir}`` ("fused").

Non-association costs. Every row's gamma, handcrafted or learned, is chosen on a validation
dataset that shares no scene with the test set, by the rule of :func:`~xvmatch.evaluation.
handcrafted_baseline.tune_gammas` (best mean Eq. 9 accuracy over :data:`GAMMA_GRID`, middle of
ties), here over the validation pairs of both settings. The handcrafted rows are also reported
with their published gammas (the baseline's table).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from xvmatch.cues.cost_fusion import add_cheirality
from xvmatch.datasets.pair_trials import CUES, SETTINGS, PairTrial
from xvmatch.evaluation.handcrafted_baseline import BaselineConfig, Method, fused_cost
from xvmatch.inference.linking.assignment import GAMMA_GRID, assign
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    summarize,
)

if TYPE_CHECKING:  # torch is imported only by the functions that run a fusion head
    from torch import nn

__all__ = [
    "CueRule",
    "LearnedResult",
    "ResultRow",
    "default_rules",
    "evaluate_learned_matcher",
    "format_learned_table",
    "rule_cost",
    "score_rule",
    "tune_gamma",
]

@dataclass(frozen=True, eq=False)
class CueRule:
    """A learned row: a cost from the trial's cues, optionally vetoed by cheirality.

    Attributes:
        key: short unique name, e.g. ``"learned(app,geo,cheir)"``.
        name: table name.
        head: fusion head over :meth:`PairTrial.cues` (:mod:`xvmatch.models.fusion_heads`), or
            None to use the single cue ``cue``.
        cue: the cue used when ``head`` is None.
        cheirality: add the cheirality cost (0 or beta) after the head (Eq. 7 as a veto).
    """

    key: str
    name: str
    head: nn.Module | None = None
    cue: str | None = None
    cheirality: bool = False

    def __post_init__(self) -> None:
        if (self.head is None) == (self.cue is None):
            raise ValueError(f"CueRule {self.key!r}: give exactly one of head and cue")
        if self.cue is not None and self.cue not in CUES:
            raise ValueError(f"CueRule {self.key!r}: cue must be one of {', '.join(CUES)}, got "
                             f"{self.cue!r}")


def rule_cost(trial: PairTrial, rule: CueRule | Method) -> np.ndarray:
    """``(M, N)`` association cost of a trial under a learned rule or a handcrafted method."""
    if isinstance(rule, Method):
        return fused_cost(trial.costs, rule)
    cues = trial.cues()
    if rule.head is None:
        if rule.cue not in cues:
            raise ValueError(f"{rule.key}: the trial has no {rule.cue!r} cue; pass an "
                             "appearance coster when building the trials")
        cost = cues[rule.cue]
    else:
        import torch

        head = rule.head.eval()
        param = next(head.parameters(), None)
        buffer = next(head.buffers(), None)
        ref = param if param is not None else buffer
        dtype = ref.dtype if ref is not None else torch.float32
        device = ref.device if ref is not None else torch.device("cpu")
        with torch.no_grad():
            tensors = {k: torch.as_tensor(v, dtype=dtype, device=device)[None]
                       for k, v in cues.items()}
            cost = rule.head(tensors)[0].double().cpu().numpy()
    return add_cheirality(cost, trial.costs.cheirality) if rule.cheirality else cost


def score_rule(trial: PairTrial, rule: CueRule | Method, gamma: float,
               cost: np.ndarray | None = None) -> FrameCounts:
    """Associate a trial's boxes (Eqs. 1-2, non-association cost ``gamma``) and count it."""
    c = rule_cost(trial, rule) if cost is None else cost
    pairs = assign(c, gamma)
    return count_pair(trial.gt_top_ids, trial.gt_ego_ids, trial.det_top_ids, trial.det_ego_ids,
                      pairs, frame=trial.frame)


def tune_gamma(trials: Sequence[PairTrial], rule: CueRule | Method,
               grid: Sequence[float] = GAMMA_GRID) -> tuple[float, dict[float, float]]:
    """The gamma of ``grid`` with the best mean Eq. 9 accuracy over ``trials`` (middle of ties,
    as :func:`~xvmatch.evaluation.handcrafted_baseline.tune_gammas`).

    Returns:
        (gamma, {gamma: accuracy in percent}).
    """
    candidates = sorted({float(g) for g in grid})
    if not candidates or candidates[0] <= 0:
        raise ValueError(f"grid must hold gammas > 0, got {list(grid)}")
    costs = [rule_cost(t, rule) for t in trials]
    curve = {g: summarize([score_rule(t, rule, g, c) for t, c in zip(trials, costs, strict=True)]
                          ).acc9 for g in candidates}
    best = max(curve.values())
    tied = [g for g, acc in curve.items() if acc == best]
    return tied[(len(tied) - 1) // 2], curve


def default_rules(heads: Mapping[str, nn.Module] | None = None) -> list[CueRule]:
    """The learned rows: appearance only (without / with the cheirality veto), sum and product
    of appearance and geometry with the veto, and one row per trained head.

    Args:
        heads: ``{name: head}`` of trained fusion heads, e.g. ``{"geometry only": head_geo,
            "fused": head_all}``; each becomes the row ``"learned head: NAME"``.
    """
    from xvmatch.models.fusion_heads import ProductFusionHead, SumFusionHead

    rules = [
        CueRule("app", "Learned appearance only", cue="app"),
        CueRule("app+cheirality", "Learned appearance only", cue="app", cheirality=True),
        CueRule("sum(app,geo)+cheirality", "Sum (learned app, geo)",
                head=SumFusionHead({"app": 0.5, "geo": 0.5}), cheirality=True),
        CueRule("product(app,geo)+cheirality", "Product (learned app, geo)",
                head=ProductFusionHead(("app", "geo")), cheirality=True),
    ]
    for name, head in (heads or {}).items():
        names = ",".join(getattr(head, "names", ()))
        rules.append(CueRule(f"learned({names})", f"Learned head: {name}", head=head))
    return rules


@dataclass(frozen=True)
class ResultRow:
    """One row of the comparison.

    Attributes:
        key: unique key of the rule.
        name: table name.
        family: ``"handcrafted"`` (published gamma), ``"handcrafted, tuned"`` or ``"learned"``.
        cheirality: whether Eq. 7 is used (as a veto or a head input).
        gamma: the non-association cost used.
        scores: ``{setting: CrossViewScores}``.
    """

    key: str
    name: str
    family: str
    cheirality: bool
    gamma: float
    scores: dict[str, CrossViewScores]

    def accuracy(self, setting: str) -> float:
        """Eq. 9 accuracy as a fraction."""
        return self.scores[setting].acc9 / 100.0


@dataclass(frozen=True)
class LearnedResult:
    """The comparison on one test dataset.

    Attributes:
        test_data: the test folder.
        val_data: the validation folder the gammas were tuned on.
        scenario: ``"overview"`` or ``"drone"``.
        n_pairs: image pairs per setting.
        rows: the rows, handcrafted first.
        info: free-form notes (weights files, training cost), printed under the table.
    """

    test_data: str
    val_data: str
    scenario: str
    n_pairs: int
    rows: list[ResultRow]
    info: dict = field(default_factory=dict)

    def row(self, key: str, family: str | None = None) -> ResultRow:
        """The row with this key (and family, when several share the key)."""
        for r in self.rows:
            if r.key == key and (family is None or r.family == family):
                return r
        raise KeyError(f"no row {key!r}" + (f" in family {family!r}" if family else ""))

    def best(self, family_prefix: str, setting: str) -> ResultRow:
        """The row of a family with the best accuracy in ``setting``."""
        rows = [r for r in self.rows if r.family.startswith(family_prefix)]
        return max(rows, key=lambda r: r.accuracy(setting))


def _scores(trials: Sequence[PairTrial], rule: CueRule | Method, gamma: float
            ) -> dict[str, CrossViewScores]:
    out = {}
    for s in SETTINGS:
        part = [t for t in trials if t.setting == s]
        if part:
            out[s] = summarize([score_rule(t, rule, gamma) for t in part])
    return out


def evaluate_learned_matcher(
    test_trials: Sequence[PairTrial],
    val_trials: Sequence[PairTrial],
    rules: Sequence[CueRule],
    *,
    config: BaselineConfig | None = None,
    grid: Sequence[float] = GAMMA_GRID,
    test_data: str = "",
    val_data: str = "",
    scenario: str = "",
) -> LearnedResult:
    """Score the handcrafted methods and the learned rules on the same test trials.

    Args:
        test_trials: trials of the test set (with ``app`` costs if a rule needs them).
        val_trials: trials of the validation set, for the gammas.
        rules: the learned rows (:func:`default_rules`).
        config: the baseline's configuration (published gammas of the handcrafted rows).
        grid: candidate gammas.
        test_data, val_data, scenario: recorded in the result.

    Returns:
        The :class:`LearnedResult`: handcrafted rows with published gammas, handcrafted rows
        with gammas tuned on the validation trials, learned rows with tuned gammas.
    """
    config = BaselineConfig() if config is None else config
    rows = []
    for m in config.methods():
        rows.append(ResultRow(m.key, m.name, "handcrafted", m.cheirality, m.gamma,
                              _scores(test_trials, m, m.gamma)))
    for m in config.methods():
        g, _ = tune_gamma(val_trials, m, grid)
        tuned = Method(m.rule, m.cheirality, g)
        rows.append(ResultRow(m.key, m.name, "handcrafted, tuned", m.cheirality, g,
                              _scores(test_trials, tuned, g)))
    for rule in rules:
        g, _ = tune_gamma(val_trials, rule, grid)
        uses_cheir = rule.cheirality or "cheir" in getattr(rule.head, "names", ())
        rows.append(ResultRow(rule.key, rule.name, "learned", uses_cheir, g,
                              _scores(test_trials, rule, g)))
    n_pairs = sum(1 for t in test_trials if t.setting == test_trials[0].setting) if test_trials \
        else 0
    return LearnedResult(test_data, val_data, scenario, n_pairs, rows)


def format_learned_table(result: LearnedResult) -> str:
    """The comparison as a table: one row per method, Eq. 9 accuracy as fractions to 0.001.

    Returns:
        The table, lines joined by ``\\n`` (no trailing newline).
    """
    header = ["Method", "Family", "Cheirality", "gamma", "Acc (GT)", "Acc* (det)"]
    lines_rows = []
    for r in result.rows:
        cells = [r.name, r.family, "Yes" if r.cheirality else "No", f"{r.gamma:g}"]
        for s in SETTINGS:
            cells.append(f"{r.accuracy(s):.3f}" if s in r.scores else "-")
        lines_rows.append(cells)
    widths = [max(len(c[k]) for c in [header, *lines_rows]) for k in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if k < 3 else c.rjust(w)
                         for k, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    out = [
        f"Eq. 9 accuracy, {result.n_pairs} test pairs ({result.scenario}) {result.test_data}; "
        f"gammas tuned on {result.val_data} (published gammas in family 'handcrafted')",
        line(header),
        line(["-" * w for w in widths]),
        *(line(c) for c in lines_rows),
    ]
    out += [f"{k}: {v}" for k, v in result.info.items()]
    return "\n".join(out)
