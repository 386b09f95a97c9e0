"""The learned matcher against the handcrafted baseline on synthetic test scenes.

Every image pair of a test dataset is associated by the handcrafted rules of
:mod:`xvmatch.evaluation.handcrafted_baseline` and by the learned rows, on exactly the same
boxes: the ground-truth boxes (``"gt"``, Table I setting) and the detector-noise boxes
(``"det"``, Table II setting), shuffled per frame and view with the baseline's seeds ("ids
scrambled"), and scored with the same functions (:func:`~xvmatch.evaluation.
handcrafted_baseline.count_pair`, Eq. 9 accuracy averaged over pairs). :func:`scene_box_trials`
rebuilds the baseline's trials with the boxes kept (a test checks the parity).

Cues, each an ``(M, N)`` cost in [0, 1] (:meth:`BoxTrial.cues`):

* ``"app"``: the learned appearance cost ``|a - b| / 2`` of the Siamese descriptors of the two
  crops (:class:`AppearanceCoster`, :mod:`xvmatch.models.appearance_net`);
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

import os
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import torch
from torch import nn

from xvmatch.datasets.synthetic_io import SceneRecord
from xvmatch.evaluation.cross_view_metrics import CrossViewScores, FrameCounts, summarize
from xvmatch.evaluation.handcrafted_baseline import (
    FALSE_POSITIVE,
    GAMMA_GRID,
    SETTINGS,
    BaselineConfig,
    Method,
    PairCosts,
    PairTrial,
    count_pair,
    fused_cost,
    open_dataset,
    pair_costs,
    scene_samples,
)
from xvmatch.geometry.cost_fusion import add_cheirality
from xvmatch.inference.assignment import assign
from xvmatch.models.appearance_net import AppearanceNet, appearance_distance
from xvmatch.models.fusion_heads import ProductFusionHead, SumFusionHead

__all__ = [
    "CUES",
    "AppearanceCoster",
    "BoxTrial",
    "CueRule",
    "LearnedResult",
    "ResultRow",
    "dataset_box_trials",
    "default_rules",
    "evaluate_learned_matcher",
    "format_learned_table",
    "rule_cost",
    "scene_box_trials",
    "score_rule",
    "tune_gamma",
]

CUES: tuple[str, ...] = ("app", "geo", "cheir", "hist")
"""Names of the normalised cues a fusion head can take (see the module docstring)."""


# --------------------------------------------------------------------------------------------
# Learned appearance costs


class AppearanceCoster:
    """Learned appearance costs between the boxes of two images.

    Crops every box as in training (:func:`~xvmatch.training.image_datamodule.box_crops`, the
    network's input size from its weights record), embeds them with the network in eval mode
    and returns ``|a - b| / 2``.

    Args:
        net: the trained network.
        device: where to run it.
        batch_size: crops per forward pass.
        context: relative margin around each box (as in training).
    """

    def __init__(self, net: AppearanceNet, *, device: str | torch.device = "cpu",
                 batch_size: int = 256, context: float = 0.1) -> None:
        self.net = net.eval().to(device)
        self.device = torch.device(device)
        self.batch_size = int(batch_size)
        self.context = float(context)

    @torch.no_grad()
    def embed(self, image: np.ndarray, boxes: np.ndarray) -> torch.Tensor:
        """``(K, D)`` descriptors of the ``(K, 4)`` boxes of ``image`` (BGR uint8)."""
        from xvmatch.training.image_datamodule import box_crops

        crops = box_crops(image, boxes, self.net.preprocessing.crop_size, self.context)
        if crops.shape[0] == 0:
            return torch.zeros(0, self.net.embedding_dim, device=self.device)
        out = []
        for k in range(0, crops.shape[0], self.batch_size):
            chunk = torch.from_numpy(crops[k : k + self.batch_size]).to(self.device)
            out.append(self.net.embed_crops(chunk))
        return torch.cat(out)

    def __call__(self, top_image: np.ndarray, top_boxes: np.ndarray, ego_image: np.ndarray,
                 ego_boxes: np.ndarray) -> np.ndarray:
        """``(M, N)`` appearance costs in [0, 1] between top and egocentric boxes."""
        top = self.embed(top_image, top_boxes)
        ego = self.embed(ego_image, ego_boxes)
        return appearance_distance(top, ego).double().cpu().numpy()


# --------------------------------------------------------------------------------------------
# Trials with boxes


@dataclass(frozen=True, eq=False)
class BoxTrial:
    """One image pair in one setting, boxes shuffled: the baseline's trial, boxes kept.

    Attributes:
        scene: scene name.
        frame: 1-based frame number.
        setting: ``"gt"`` or ``"det"``.
        top_boxes: ``(M, 4)`` shuffled top-view boxes.
        ego_boxes: ``(N, 4)`` shuffled egocentric boxes.
        costs: the handcrafted cues between them.
        app: ``(M, N)`` learned appearance costs, or None when no network was given.
        gt_top_ids: ground-truth ids of the top view.
        gt_ego_ids: ground-truth ids of the egocentric view.
        det_top_ids: ``(M,)`` id each top box stands for (-1: false positive).
        det_ego_ids: ``(N,)`` id each egocentric box stands for.
    """

    scene: str
    frame: int
    setting: str
    top_boxes: np.ndarray
    ego_boxes: np.ndarray
    costs: PairCosts
    app: np.ndarray | None
    gt_top_ids: np.ndarray
    gt_ego_ids: np.ndarray
    det_top_ids: np.ndarray
    det_ego_ids: np.ndarray

    def cues(self) -> dict[str, np.ndarray]:
        """The normalised cues ``{"geo", "hist", "cheir"[, "app"]}``, each ``(M, N)`` in [0, 1]."""
        norm = self.costs.normalised()
        out = {"geo": norm["geo"], "hist": norm["hist"],
               "cheir": (self.costs.cheirality > 0).astype(np.float64)}
        if self.app is not None:
            out["app"] = np.asarray(self.app, dtype=np.float64)
        return out

    def match(self) -> np.ndarray:
        """``(M, N)`` bool: both boxes stand for the same ground-truth person."""
        top, ego = self.det_top_ids[:, None], self.det_ego_ids[None, :]
        return (top == ego) & (top != FALSE_POSITIVE)

    def solo(self) -> tuple[np.ndarray, np.ndarray]:
        """``(M,)`` and ``(N,)`` bool: the box stands for a person seen in its view only (a
        correct true negative of Eq. 9 when left unmatched)."""
        top = set(self.gt_top_ids.tolist())
        ego = set(self.gt_ego_ids.tolist())
        return (np.array([int(i) in top - ego for i in self.det_top_ids], bool).reshape(-1),
                np.array([int(i) in ego - top for i in self.det_ego_ids], bool).reshape(-1))

    @property
    def n_union(self) -> int:
        """Unique persons of Eq. 9: ground-truth ids of either view."""
        return len(set(self.gt_top_ids.tolist()) | set(self.gt_ego_ids.tolist()))

    def as_pair_trial(self) -> PairTrial:
        """The baseline's :class:`PairTrial` of the same boxes."""
        return PairTrial(self.scene, self.frame, self.setting, self.costs, self.gt_top_ids,
                         self.gt_ego_ids, self.det_top_ids, self.det_ego_ids)


def scene_box_trials(
    scene: SceneRecord,
    scene_index: int,
    config: BaselineConfig,
    settings: Sequence[str] = SETTINGS,
    coster: Callable[..., np.ndarray] | None = None,
) -> list[BoxTrial]:
    """The trials of every frame of a scene, as
    :func:`~xvmatch.evaluation.handcrafted_baseline.scene_trials` builds them, boxes kept.

    Args:
        scene: the parsed scene.
        scene_index: its index in the dataset (seeds the detector noise and the shuffling).
        config: cameras' margin and beta, detector noise and seeds.
        settings: subset of :data:`SETTINGS`.
        coster: optional ``coster(top_image, top_boxes, ego_image, ego_boxes) -> (M, N)``
            learned appearance costs (an :class:`AppearanceCoster`).

    Returns:
        Trials frame by frame, settings in :data:`SETTINGS` order.
    """
    trials: list[BoxTrial] = []
    for fs in scene_samples(scene, scene_index, config, settings):
        costs = pair_costs(fs.cameras["top"], fs.cameras["ego"], fs.images["top"],
                           fs.images["ego"], fs.boxes["top"], fs.boxes["ego"],
                           margin=config.margin, beta=config.beta)
        app = None
        if coster is not None:
            app = coster(fs.images["top"], fs.boxes["top"], fs.images["ego"], fs.boxes["ego"])
        trials.append(BoxTrial(fs.pair.scene, fs.pair.frame, fs.setting, fs.boxes["top"],
                               fs.boxes["ego"], costs, app, fs.gt_ids["top"], fs.gt_ids["ego"],
                               fs.stands_for["top"], fs.stands_for["ego"]))
    return trials


def dataset_box_trials(
    data: str | os.PathLike,
    config: BaselineConfig | None = None,
    settings: Sequence[str] = SETTINGS,
    coster: Callable[..., np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
) -> list[BoxTrial]:
    """:func:`scene_box_trials` of every scene of a dataset folder, in scene order.

    Args:
        data: dataset folder written by ``xvmatch synth``.
        config: seeds and noise (default :class:`BaselineConfig`).
        settings: subset of :data:`SETTINGS`.
        coster: optional learned appearance costs.
        progress: called with the number of pairs of each finished scene.
    """
    config = BaselineConfig() if config is None else config
    dataset = open_dataset(data)
    out: list[BoxTrial] = []
    for index, name in enumerate(dataset.scene_names):
        scene = dataset.scene(name)
        out += scene_box_trials(scene, index, config, settings, coster)
        if progress is not None:
            progress(len(scene.pairs))
    return out


# --------------------------------------------------------------------------------------------
# Rules, gammas and scores


@dataclass(frozen=True, eq=False)
class CueRule:
    """A learned row: a cost from the trial's cues, optionally vetoed by cheirality.

    Attributes:
        key: short unique name, e.g. ``"learned(app,geo,cheir)"``.
        name: table name.
        head: fusion head over :meth:`BoxTrial.cues` (:mod:`xvmatch.models.fusion_heads`), or
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


@torch.no_grad()
def rule_cost(trial: BoxTrial, rule: CueRule | Method) -> np.ndarray:
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
        head = rule.head.eval()
        param = next(head.parameters(), None)
        buffer = next(head.buffers(), None)
        ref = param if param is not None else buffer
        dtype = ref.dtype if ref is not None else torch.float32
        device = ref.device if ref is not None else torch.device("cpu")
        tensors = {k: torch.as_tensor(v, dtype=dtype, device=device)[None]
                   for k, v in cues.items()}
        cost = rule.head(tensors)[0].double().cpu().numpy()
    return add_cheirality(cost, trial.costs.cheirality) if rule.cheirality else cost


def score_rule(trial: BoxTrial, rule: CueRule | Method, gamma: float,
               cost: np.ndarray | None = None) -> FrameCounts:
    """Associate a trial's boxes (Eqs. 1-2, non-association cost ``gamma``) and count it."""
    c = rule_cost(trial, rule) if cost is None else cost
    pairs = assign(c, gamma)
    return count_pair(trial.gt_top_ids, trial.gt_ego_ids, trial.det_top_ids, trial.det_ego_ids,
                      pairs, frame=trial.frame)


def tune_gamma(trials: Sequence[BoxTrial], rule: CueRule | Method,
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


def _scores(trials: Sequence[BoxTrial], rule: CueRule | Method, gamma: float
            ) -> dict[str, CrossViewScores]:
    out = {}
    for s in SETTINGS:
        part = [t for t in trials if t.setting == s]
        if part:
            out[s] = summarize([score_rule(t, rule, gamma) for t in part])
    return out


def evaluate_learned_matcher(
    test_trials: Sequence[BoxTrial],
    val_trials: Sequence[BoxTrial],
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
