"""The handcrafted association baseline of the geometric-priors paper (Tables I and II).

For every image pair of a synthetic dataset (``xvmatch synth``; the paper's setting is the
``overview`` scenario), the boxes of the top view (rows) and of the egocentric view (columns)
are compared with two handcrafted cues, each normalised to [0, 1] as in Section III-C:

* geometry: ``d'_geo = tanh(d_geo)``, with ``d_geo`` the distance in metres between the rays
  through the top centres of the two boxes (Eqs. 4-6, Section IV-A);
* appearance ("Hist"): ``d'_hist = tanh(d_hist)``, with ``d_hist`` the chi-square bin-ratio
  distance (Eq. 3) of the L2-normalised 8x2x2 HSV histograms of the two crops. A pair with an
  empty crop (a box entirely outside its image) has no appearance evidence and gets the largest
  normalised cost, 1.

They are used alone or fused by the weighted sum (``w = 0.5``, ``gamma = 0.25``) or the product
of Eq. 8 (``gamma = 0.1``), each with and without the cheirality term of Eq. 7 (``+ beta`` where
the midpoint of the two rays is not at least 0.5 m in front of both cameras: the synthetic
cameras are metric). The association is the Hungarian solution of Eqs. 1-2 with the rule's
non-association cost gamma (:func:`xvmatch.inference.linking.assignment.assign`).

Non-association costs. The paper gives gamma only for the two fusion rules (Section IV-A).
For "geometry only" and "histogram only" the defaults :data:`GAMMA_GEO` and :data:`GAMMA_HIST`
were tuned on a validation dataset that shares nothing with the test scenes (``xvmatch synth
--scenario overview --scenes 20 --frames 5 --seed 2000``), on its ground-truth boxes, without
cheirality, over :data:`GAMMA_GRID`, by :func:`tune_gammas` (``python
benchmarks/handcrafted_baseline.py --tune`` reruns it). The tuned gamma of a cue is used in
all four of its cells (with and without cheirality, both settings), as the paper does for the
fusion rules.

Two settings, scored with the accuracy of Eq. 9 per image pair and averaged over pairs:

* ``"gt"`` (Table I): the ground-truth (visible) boxes are associated; the unique persons of
  Eq. 9 are the ids present in either view. This is the paper's "association only" evaluation
  with a perfect detector.
* ``"det"`` (Table II, ``Accuracy*``): boxes from the detector-noise model
  (:mod:`xvmatch.datasets.visibility_noise`: jitter, misses that grow with occlusion, false
  boxes) are associated. Each detection takes the id of the ground-truth box of its view with
  which it has IoU >= 0.3 (one-to-one, maximum total IoU), else it is a false positive that
  no true pair can include. The unique persons are the ground-truth ids of either view, so the
  accuracy is bounded by the detector's recall, as in the paper.

Per frame and view, the boxes are shuffled with a seeded permutation before any cost is
computed ("ids scrambled"): the association sees boxes, images and cameras only, never an id,
and ids are looked up again only to score.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from dataclasses import asdict, dataclass

import numpy as np

from xvmatch.core.worker_pool import worker_pool
from xvmatch.cues.cost_fusion import ProductFusion, SumFusion, add_cheirality
from xvmatch.cues.handcrafted_costs import PairCosts
from xvmatch.datasets.pair_trials import (
    SETTINGS,
    PairTrial,
    TrialConfig,
    open_dataset,
    scene_trials,
)
from xvmatch.datasets.synthetic_io import SceneRecord, SyntheticDataset
from xvmatch.evaluation.cost_distributions import CostSamples
from xvmatch.inference.linking.assignment import GAMMA_GRID, assign
from xvmatch.metrics.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    count_pair,
    scores_to_dict,
    summarize,
)

__all__ = [
    "GAMMA_GEO",
    "GAMMA_HIST",
    "GAMMA_PRODUCT",
    "GAMMA_SUM",
    "RULES",
    "RULE_NAMES",
    "BaselineConfig",
    "BaselineResult",
    "DetectionStats",
    "Method",
    "TuningResult",
    "associate",
    "evaluate_baseline",
    "format_baseline_table",
    "fused_cost",
    "score_trial",
    "tune_gammas",
]

RULES: tuple[str, ...] = ("geo", "hist", "sum", "product")
"""The cost rules of Tables I-II: geometry only, histogram only, weighted sum, product (Eq. 8)."""
RULE_NAMES: dict[str, str] = {
    "geo": "Geometry only",
    "hist": "Histogram only",
    "sum": "Sum combination",
    "product": "Product combination",
}
GAMMA_SUM: float = 0.25
"""Non-association cost of the sum rule, Section IV-A."""
GAMMA_PRODUCT: float = 0.1
"""Non-association cost of the product rule (Eq. 8), Section IV-A."""
GAMMA_GEO: float = 0.15
"""Non-association cost of "geometry only": tuned on validation seed 2000 (module docstring)."""
GAMMA_HIST: float = 0.95
"""Non-association cost of "histogram only": tuned on validation seed 2000 (module docstring)."""


@dataclass(frozen=True)
class Method:
    """One row of Tables I-II: a cost rule, with or without cheirality, and its gamma.

    Attributes:
        rule: one of :data:`RULES`.
        cheirality: add the cheirality term of Eq. 7.
        gamma: non-association cost of Eq. 2.
    """

    rule: str
    cheirality: bool
    gamma: float

    def __post_init__(self) -> None:
        if self.rule not in RULES:
            raise ValueError(f"Method.rule must be one of {', '.join(RULES)}, got {self.rule!r}")
        if not np.isfinite(self.gamma) or self.gamma <= 0:
            raise ValueError(f"Method.gamma must be a finite cost > 0, got {self.gamma}")

    @property
    def key(self) -> str:
        """Short unique name, e.g. ``"sum"`` or ``"sum+cheirality"``."""
        return f"{self.rule}+cheirality" if self.cheirality else self.rule

    @property
    def name(self) -> str:
        """The paper's name of the rule, e.g. ``"Sum combination"``."""
        return RULE_NAMES[self.rule]


@dataclass(frozen=True)
class BaselineConfig(TrialConfig):
    """Everything that defines a baseline run besides the data: the trials'
    :class:`~xvmatch.datasets.pair_trials.TrialConfig` (cheirality margin and beta, IoU, noise,
    seeds) plus the gammas and the sum rule's weights.

    Attributes:
        gamma_geo: gamma of "geometry only".
        gamma_hist: gamma of "histogram only".
        gamma_sum: gamma of the sum rule (paper: 0.25).
        gamma_product: gamma of the product rule (paper: 0.1).
        weights: ``(w_geo, w_app)`` of the sum rule (paper: 0.5 each).
    """

    gamma_geo: float = GAMMA_GEO
    gamma_hist: float = GAMMA_HIST
    gamma_sum: float = GAMMA_SUM
    gamma_product: float = GAMMA_PRODUCT
    weights: tuple[float, float] = (0.5, 0.5)

    def __post_init__(self) -> None:
        super().__post_init__()
        for rule in RULES:
            g = self.gamma(rule)
            if not np.isfinite(g) or g <= 0:
                raise ValueError(f"gamma_{rule} must be a finite cost > 0, got {g}")
        if len(self.weights) != 2:
            raise ValueError(f"weights must be (w_geo, w_app), got {self.weights}")
        SumFusion({"geo": self.weights[0], "hist": self.weights[1]})  # validates the weights

    def gamma(self, rule: str) -> float:
        """The non-association cost of ``rule``."""
        if rule not in RULES:
            raise ValueError(f"rule must be one of {', '.join(RULES)}, got {rule!r}")
        return float(getattr(self, f"gamma_{rule}"))

    def methods(self) -> tuple[Method, ...]:
        """The 8 rows of Tables I-II: each rule without, then with, cheirality."""
        return tuple(
            Method(rule, cheir, self.gamma(rule)) for rule in RULES for cheir in (False, True)
        )


def fused_cost(
    costs: PairCosts, method: Method, weights: tuple[float, float] = (0.5, 0.5)
) -> np.ndarray:
    """The (M, N) association cost of a method (Section III-C, Eq. 8, Eq. 7).

    ``geo``: ``d'_geo``; ``hist``: ``d'_hist``; ``sum``: ``w_geo d'_geo + w_app d'_app``
    (weights divided by their sum); ``product``: ``d'_geo d'_app`` (Eq. 8); plus the cheirality
    cost (0 or beta) when ``method.cheirality``.

    Args:
        costs: the raw cues of the pair.
        method: the rule and whether to add cheirality.
        weights: ``(w_geo, w_app)`` of the sum rule.

    Returns:
        (M, N) finite costs, in [0, 1] without cheirality.
    """
    norm = costs.normalised()
    if method.rule in ("geo", "hist"):
        fused = norm[method.rule]
    elif method.rule == "sum":
        fused = SumFusion({"geo": weights[0], "hist": weights[1]})(norm)
    else:
        fused = ProductFusion(("geo", "hist"))(norm)
    return add_cheirality(fused, costs.cheirality) if method.cheirality else fused


def associate(
    costs: PairCosts, method: Method, weights: tuple[float, float] = (0.5, 0.5)
) -> np.ndarray:
    """Associate the boxes of one pair with a method (Eqs. 1-2).

    Returns:
        (K, 2) int64 ``(top index, ego index)`` pairs, sorted by top index.
    """
    return assign(fused_cost(costs, method, weights), method.gamma)


def score_trial(
    trial: PairTrial, method: Method, weights: tuple[float, float] = (0.5, 0.5)
) -> FrameCounts:
    """Associate a trial's boxes with ``method`` and count the result (:func:`count_pair`)."""
    pairs = associate(trial.costs, method, weights)
    return count_pair(trial.gt_top_ids, trial.gt_ego_ids, trial.det_top_ids, trial.det_ego_ids,
                      pairs, frame=trial.frame)


@dataclass(frozen=True)
class DetectionStats:
    """How the simulated detector did, matched to ground truth at the IoU threshold.

    Attributes:
        n_gt: ground-truth boxes, per view ``{"top": .., "ego": ..}``.
        n_det: detections per view.
        n_true: detections matched to a ground-truth box, per view.
    """

    n_gt: dict[str, int]
    n_det: dict[str, int]
    n_true: dict[str, int]

    def precision(self, view: str) -> float:
        """Matched detections over detections (0 with no detection)."""
        return self.n_true[view] / self.n_det[view] if self.n_det[view] else 0.0

    def recall(self, view: str) -> float:
        """Matched detections over ground-truth boxes (0 with no ground truth)."""
        return self.n_true[view] / self.n_gt[view] if self.n_gt[view] else 0.0

    @classmethod
    def total(cls, parts: Sequence[DetectionStats]) -> DetectionStats:
        """Sum of several scenes' statistics."""
        def add(name: str) -> dict[str, int]:
            return {v: sum(getattr(p, name)[v] for p in parts) for v in ("top", "ego")}

        return cls(add("n_gt"), add("n_det"), add("n_true"))


@dataclass(frozen=True, eq=False)
class _SceneTrials:
    trials: list[PairTrial]
    samples: CostSamples
    detection: DetectionStats


def _scene_results(
    scene: SceneRecord,
    scene_index: int,
    config: BaselineConfig,
    settings: Sequence[str] = SETTINGS,
) -> _SceneTrials:
    """The trials of every frame of a scene (:func:`~xvmatch.datasets.pair_trials.
    scene_trials`) with the baseline's extras.

    Args:
        scene: the parsed scene.
        scene_index: its index in the dataset (seeds the detector noise and the shuffling).
        config: costs, noise and seeds.
        settings: subset of :data:`SETTINGS`.

    Returns:
        The trials (frame by frame, settings in the given order), the raw true/false costs of
        the ground-truth boxes (Figs. 2-3; empty unless ``"gt"`` is among the settings), and
        the detector statistics (zeros unless ``"det"`` is).
    """
    views = ("top", "ego")
    stats = {k: {v: 0 for v in views} for k in ("n_gt", "n_det", "n_true")}
    samples: list[CostSamples] = []
    trials = scene_trials(scene, scene_index, config, settings)
    for t in trials:
        for key, per_view in stats.items():
            for v in views:
                per_view[v] += getattr(t, key)[v]
        if t.setting == "gt":
            same = t.det_top_ids[:, None] == t.det_ego_ids[None, :]
            samples.append(CostSamples.from_matrices(t.costs.geo, t.costs.hist, same,
                                                     t.costs.hist_valid))
    return _SceneTrials(trials, CostSamples.concatenate(samples), DetectionStats(**stats))


def _scene_task(root: str, name: str, index: int, config: BaselineConfig,
                settings: tuple[str, ...]) -> _SceneTrials:
    scene = SyntheticDataset(root).scene(name)
    return _scene_results(scene, index, config, settings)


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)


def _all_trials(
    data: str | os.PathLike,
    config: BaselineConfig,
    settings: tuple[str, ...],
    workers: int,
    progress: Callable[[int], None] | None,
) -> tuple[SyntheticDataset, list[_SceneTrials]]:
    """Trials of every scene, in scene order, computed by ``workers`` processes."""
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    dataset = open_dataset(data)
    root = os.fspath(dataset.root)
    names = dataset.scene_names
    tasks = [(root, name, i, config, settings) for i, name in enumerate(names)]
    results: list[_SceneTrials | None] = [None] * len(tasks)
    if workers == 1 or len(tasks) <= 1:
        for i, task in enumerate(tasks):
            results[i] = _scene_task(*task)
            if progress is not None:
                progress(len({t.frame for t in results[i].trials}))
    else:
        # "spawn" as in generate_dataset: forked children may inherit OpenCV's thread pool.
        with worker_pool(int(workers), "spawn", _worker_init) as pool:
            futures = {pool.submit(_scene_task, *task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if progress is not None:
                    progress(len({t.frame for t in results[i].trials}))
    return dataset, [r for r in results if r is not None]


@dataclass(frozen=True, eq=False)
class BaselineResult:
    """Scores of the 8 methods in the two settings, with what produced them.

    Attributes:
        data: the dataset folder.
        scenario: its scenario (``"overview"`` is the paper's).
        n_scenes: scenes evaluated.
        n_pairs: image pairs evaluated (per setting).
        config: the configuration used.
        methods: the 8 methods, in table order.
        scores: ``{(method.key, setting): CrossViewScores}``; ``acc9`` is the accuracy of Eq. 9
            averaged over image pairs, in percent.
        detection: the simulated detector's precision and recall at the IoU threshold.
        samples: raw true/false costs of the ground-truth boxes (Figs. 2-3).
    """

    data: str
    scenario: str
    n_scenes: int
    n_pairs: int
    config: BaselineConfig
    methods: tuple[Method, ...]
    scores: dict[tuple[str, str], CrossViewScores]
    detection: DetectionStats
    samples: CostSamples

    def accuracy(self, method_key: str, setting: str) -> float:
        """Eq. 9 accuracy as a fraction in [0, 1] (Table I: ``"gt"``, Table II: ``"det"``)."""
        return self.scores[(method_key, setting)].acc9 / 100.0

    def to_dict(self) -> dict:
        """A JSON-ready record: settings, detector statistics and every score."""
        config = asdict(self.config)
        return {
            "data": self.data,
            "scenario": self.scenario,
            "n_scenes": self.n_scenes,
            "n_pairs": self.n_pairs,
            "config": config,
            "detection": {
                v: {"precision": self.detection.precision(v), "recall": self.detection.recall(v),
                    "n_gt": self.detection.n_gt[v], "n_det": self.detection.n_det[v],
                    "n_true": self.detection.n_true[v]}
                for v in ("top", "ego")
            },
            "methods": [
                {
                    "key": m.key,
                    "name": m.name,
                    "cheirality": m.cheirality,
                    "gamma": m.gamma,
                    "scores": {s: scores_to_dict(self.scores[(m.key, s)]) for s in SETTINGS},
                }
                for m in self.methods
            ],
        }


def evaluate_baseline(
    data: str | os.PathLike,
    config: BaselineConfig | None = None,
    *,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> BaselineResult:
    """Run the 8 methods on every image pair of a synthetic dataset, in both settings.

    Args:
        data: a dataset folder written by ``xvmatch synth`` (holding ``dataset.json``).
        config: gammas, weights, cheirality, noise and seeds (default: :class:`BaselineConfig`).
        workers: processes computing the costs scene by scene; the result does not depend on it.
        progress: called with the number of image pairs of each finished scene.

    Returns:
        The :class:`BaselineResult`.

    Raises:
        ValueError: no dataset at ``data``, or bad ``workers``.
        SchemaError: a malformed dataset file.
    """
    config = BaselineConfig() if config is None else config
    dataset, scenes = _all_trials(data, config, SETTINGS, workers, progress)
    methods = config.methods()
    counts: dict[tuple[str, str], list[FrameCounts]] = {
        (m.key, s): [] for m in methods for s in SETTINGS
    }
    for scene in scenes:
        for trial in scene.trials:
            for m in methods:
                counts[(m.key, trial.setting)].append(score_trial(trial, m, config.weights))
    n_pairs = sum(1 for sc in scenes for t in sc.trials if t.setting == SETTINGS[0])
    return BaselineResult(
        data=os.fspath(dataset.root),
        scenario=dataset.scenario,
        n_scenes=len(scenes),
        n_pairs=n_pairs,
        config=config,
        methods=methods,
        scores={key: summarize(c) for key, c in counts.items()},
        detection=DetectionStats.total([sc.detection for sc in scenes]),
        samples=CostSamples.concatenate([sc.samples for sc in scenes]),
    )


@dataclass(frozen=True)
class TuningResult:
    """Gammas tuned on a validation dataset.

    Attributes:
        gammas: ``{rule: best gamma}``.
        curves: ``{rule: {gamma: mean Eq. 9 accuracy in percent}}`` over the grid.
        setting: the setting tuned on.
    """

    gammas: dict[str, float]
    curves: dict[str, dict[float, float]]
    setting: str


def tune_gammas(
    data: str | os.PathLike,
    config: BaselineConfig | None = None,
    *,
    rules: Sequence[str] = ("geo", "hist"),
    grid: Sequence[float] = GAMMA_GRID,
    setting: str = "gt",
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> TuningResult:
    """Choose the non-association cost of each rule on a validation dataset (Eq. 2).

    For every rule, without cheirality, the mean Eq. 9 accuracy over the dataset's pairs is
    computed for each gamma of ``grid``; the best one wins. When several gammas tie, the middle
    one of them (the lower middle for an even count) is taken, away from the edge of a plateau.
    Never tune on the test scenes.

    Args:
        data: validation dataset folder.
        config: everything but the gammas being tuned.
        rules: the rules to tune.
        grid: candidate gammas (> 0).
        setting: ``"gt"`` (ground-truth boxes) or ``"det"``.
        workers: processes computing the costs.
        progress: called with the number of pairs of each finished scene.

    Returns:
        The :class:`TuningResult`.
    """
    config = BaselineConfig() if config is None else config
    if setting not in SETTINGS:
        raise ValueError(f"setting must be one of {', '.join(SETTINGS)}, got {setting!r}")
    candidates = sorted({float(g) for g in grid})
    if not candidates or candidates[0] <= 0 or not np.isfinite(candidates[-1]):
        raise ValueError(f"grid must hold finite gammas > 0, got {list(grid)}")
    _, scenes = _all_trials(data, config, (setting,), workers, progress)
    trials = [t for sc in scenes for t in sc.trials]
    gammas: dict[str, float] = {}
    curves: dict[str, dict[float, float]] = {}
    for rule in rules:
        curve = {}
        for g in candidates:
            method = Method(rule, False, g)
            curve[g] = summarize([score_trial(t, method, config.weights) for t in trials]).acc9
        curves[rule] = curve
        best = max(curve.values())
        tied = [g for g, acc in curve.items() if acc == best]
        gammas[rule] = tied[(len(tied) - 1) // 2]
    return TuningResult(gammas=gammas, curves=curves, setting=setting)


def format_baseline_table(result: BaselineResult) -> str:
    """The results as Tables I-II of the paper: one row per method, fractions to 0.001.

    Columns: the method, cheirality, gamma, then for each setting the Eq. 9 accuracy (``Acc``
    with ground-truth boxes, ``Acc*`` with detections) and CVIDF1. Footer: the data, the
    detector's precision and recall, and the seeds.

    Returns:
        The table, lines joined by ``\\n`` (no trailing newline).
    """
    header = ["Method", "Cheirality", "gamma", "Acc (GT)", "CVIDF1 (GT)", "Acc* (det)",
              "CVIDF1 (det)"]
    rows = []
    for m in result.methods:
        gt, det = result.scores[(m.key, "gt")], result.scores[(m.key, "det")]
        rows.append([m.name, "Yes" if m.cheirality else "No", f"{m.gamma:g}",
                     f"{gt.acc9 / 100:.3f}", f"{gt.cvidf1 / 100:.3f}",
                     f"{det.acc9 / 100:.3f}", f"{det.cvidf1 / 100:.3f}"])
    widths = [max(len(r[k]) for r in [header, *rows]) for k in range(len(header))]

    def line(cells: list[str]) -> str:
        return "  ".join(c.ljust(w) if k < 2 else c.rjust(w)
                         for k, (c, w) in enumerate(zip(cells, widths, strict=True))).rstrip()

    d = result.detection
    c = result.config
    lines = [
        f"Eq. 9 association accuracy: {result.n_pairs} image pairs, {result.n_scenes} scenes "
        f"({result.scenario}), {result.data}",
        "GT = Table I setting (ground-truth boxes); det = Table II setting (detector noise, "
        f"IoU >= {c.iou_threshold:g} to ground truth)",
        line(header),
        line(["-" * w for w in widths]),
        *(line(r) for r in rows),
        f"detector: top precision {d.precision('top'):.3f} recall {d.recall('top'):.3f}, "
        f"ego precision {d.precision('ego'):.3f} recall {d.recall('ego'):.3f}; "
        f"noise seed {c.noise_seed}, scramble seed {c.scramble_seed}; sum weights "
        f"{c.weights[0]:g}/{c.weights[1]:g}; cheirality margin {c.margin:g} m, "
        f"beta {c.beta:g}",
    ]
    return "\n".join(lines)
