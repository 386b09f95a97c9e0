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
non-association cost gamma (:func:`xvmatch.inference.assignment.assign`).

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

import multiprocessing
import os
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.datasets.synthetic_io import MANIFEST, PairRecord, SceneRecord, SyntheticDataset
from xvmatch.datasets.visibility_noise import VisibilityNoise, apply_visibility_noise
from xvmatch.evaluation.cost_distributions import CostSamples
from xvmatch.evaluation.cross_view_metrics import (
    CrossViewScores,
    FrameCounts,
    scores_to_dict,
    summarize,
)
from xvmatch.geometry.array_checks import as_boxes
from xvmatch.geometry.camera import Camera
from xvmatch.geometry.color_histogram import box_histograms, chi2_brd_distance
from xvmatch.geometry.cost_fusion import (
    ProductFusion,
    SumFusion,
    add_cheirality,
    normalise_distance,
)
from xvmatch.geometry.ray_priors import (
    DEFAULT_BETA,
    METRIC_MARGIN,
    box_rays,
    cheirality_cost,
    ray_distances,
)
from xvmatch.inference.assignment import assign

__all__ = [
    "FALSE_POSITIVE",
    "GAMMA_GEO",
    "GAMMA_GRID",
    "GAMMA_HIST",
    "GAMMA_PRODUCT",
    "GAMMA_SUM",
    "RULES",
    "RULE_NAMES",
    "SETTINGS",
    "SETTING_NAMES",
    "BaselineConfig",
    "BaselineResult",
    "DetectionStats",
    "FrameSample",
    "Method",
    "PairCosts",
    "PairTrial",
    "TuningResult",
    "associate",
    "box_iou",
    "count_pair",
    "evaluate_baseline",
    "format_baseline_table",
    "fused_cost",
    "match_to_ground_truth",
    "noise_seed_of",
    "open_dataset",
    "pair_costs",
    "scene_samples",
    "scene_trials",
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

SETTINGS: tuple[str, ...] = ("gt", "det")
"""``"gt"``: ground-truth boxes (Table I); ``"det"``: detector-noise boxes (Table II)."""

SETTING_NAMES: dict[str, str] = {
    "gt": "Table I: ground-truth boxes",
    "det": "Table II: detections",
}

FALSE_POSITIVE: int = -1
"""Id given to a detection that overlaps no ground-truth box enough (IoU < threshold)."""

GAMMA_SUM: float = 0.25
"""Non-association cost of the sum rule, Section IV-A."""
GAMMA_PRODUCT: float = 0.1
"""Non-association cost of the product rule (Eq. 8), Section IV-A."""
GAMMA_GEO: float = 0.15
"""Non-association cost of "geometry only": tuned on validation seed 2000 (module docstring)."""
GAMMA_HIST: float = 0.95
"""Non-association cost of "histogram only": tuned on validation seed 2000 (module docstring)."""
GAMMA_GRID: tuple[float, ...] = tuple(round(0.05 * k, 2) for k in range(1, 21))
"""Candidate gammas of :func:`tune_gammas`: 0.05, 0.10, ..., 1.0 (normalised costs are < 1, so
gamma = 1 accepts every pair the Hungarian solution wants)."""


# --------------------------------------------------------------------------------------------
# Methods and configuration


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
class BaselineConfig:
    """Everything that defines a baseline run besides the data.

    Attributes:
        gamma_geo: gamma of "geometry only".
        gamma_hist: gamma of "histogram only".
        gamma_sum: gamma of the sum rule (paper: 0.25).
        gamma_product: gamma of the product rule (paper: 0.1).
        weights: ``(w_geo, w_app)`` of the sum rule (paper: 0.5 each).
        margin: depth margin of Eq. 7 in metres (0.5 with a metric scale, 0 without).
        beta: cost added to pairs that violate Eq. 7 (``>> 1``).
        iou_threshold: IoU for a detection to count as a ground-truth box (paper: 0.3).
        noise: the detector-noise model of the ``"det"`` setting.
        noise_seed: seed of the detector noise; scene i uses ``SeedSequence([seed, i])``.
        scramble_seed: seed of the per-frame, per-view shuffling of the boxes.
    """

    gamma_geo: float = GAMMA_GEO
    gamma_hist: float = GAMMA_HIST
    gamma_sum: float = GAMMA_SUM
    gamma_product: float = GAMMA_PRODUCT
    weights: tuple[float, float] = (0.5, 0.5)
    margin: float = METRIC_MARGIN
    beta: float = DEFAULT_BETA
    iou_threshold: float = 0.3
    noise: VisibilityNoise = field(default_factory=VisibilityNoise)
    noise_seed: int = 0
    scramble_seed: int = 0

    def __post_init__(self) -> None:
        for rule in RULES:
            g = self.gamma(rule)
            if not np.isfinite(g) or g <= 0:
                raise ValueError(f"gamma_{rule} must be a finite cost > 0, got {g}")
        if len(self.weights) != 2:
            raise ValueError(f"weights must be (w_geo, w_app), got {self.weights}")
        if not 0 < self.iou_threshold <= 1:
            raise ValueError(f"iou_threshold must be in (0, 1], got {self.iou_threshold}")
        if not np.isfinite(self.margin) or self.margin < 0:
            raise ValueError(f"margin must be a finite depth >= 0, got {self.margin}")
        if not np.isfinite(self.beta) or self.beta <= 1:
            raise ValueError(f"beta must be a finite cost > 1, got {self.beta}")
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


# --------------------------------------------------------------------------------------------
# Costs and association of one image pair


@dataclass(frozen=True, eq=False)
class PairCosts:
    """Raw cues between the M top-view boxes (rows) and N egocentric boxes (columns).

    Attributes:
        geo: (M, N) ray distances of Eq. 6 between the top-centre rays, world units (metres).
        hist: (M, N) chi-square BRD distances of Eq. 3 between the HSV histograms.
        hist_valid: (M, N) bool, False where either crop is empty (box outside its image).
        cheirality: (M, N) cost of Eq. 7: 0 where the constraint holds, ``beta`` elsewhere.
    """

    geo: np.ndarray
    hist: np.ndarray
    hist_valid: np.ndarray
    cheirality: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(M, N)."""
        return self.geo.shape  # type: ignore[return-value]

    def normalised(self) -> dict[str, np.ndarray]:
        """``{"geo": tanh(d_geo), "hist": tanh(d_hist)}`` (Section III-C), each (M, N) in [0, 1].

        Pairs without appearance evidence (``hist_valid`` False) get ``d'_hist = 1``.
        """
        return {
            "geo": normalise_distance(self.geo),
            "hist": np.where(self.hist_valid, normalise_distance(self.hist), 1.0),
        }


def _check_image(image: np.ndarray, camera: Camera, name: str) -> None:
    shape = np.shape(image)
    if len(shape) != 3 or shape[2] != 3:
        raise ValueError(f"{name} must be an (H, W, 3) BGR image, got shape {shape}")
    if (shape[1], shape[0]) != camera.image_size:
        raise ValueError(
            f"{name} is {shape[1]}x{shape[0]} but its camera is "
            f"{camera.width}x{camera.height}; pass the image the camera was calibrated for"
        )


def pair_costs(
    top_camera: Camera,
    ego_camera: Camera,
    top_image: np.ndarray,
    ego_image: np.ndarray,
    top_boxes: np.ndarray,
    ego_boxes: np.ndarray,
    *,
    margin: float = METRIC_MARGIN,
    beta: float = DEFAULT_BETA,
) -> PairCosts:
    """Compute the raw cues of one image pair (Eqs. 3, 6 and 7).

    Args:
        top_camera: calibrated top/overview camera.
        ego_camera: calibrated egocentric camera.
        top_image: (H, W, 3) uint8 BGR top image, of ``top_camera``'s size.
        ego_image: (H', W', 3) uint8 BGR egocentric image, of ``ego_camera``'s size.
        top_boxes: (M, 4) ``(x, y, w, h)`` boxes in the top image (may run past its border).
        ego_boxes: (N, 4) boxes in the egocentric image.
        margin: depth margin of Eq. 7.
        beta: cost of violating Eq. 7.

    Returns:
        The :class:`PairCosts`; every matrix is finite (never NaN), also for empty crops,
        coincident camera centres or parallel rays.

    Raises:
        TypeError: a camera that is not a :class:`~xvmatch.geometry.camera.Camera`.
        ValueError: malformed boxes or images, an image that does not match its camera.
    """
    for cam, name in ((top_camera, "top_camera"), (ego_camera, "ego_camera")):
        if not isinstance(cam, Camera):
            raise TypeError(f"{name} must be a xvmatch.geometry.camera.Camera, got {type(cam)}")
    top_boxes = as_boxes(top_boxes, "top_boxes")
    ego_boxes = as_boxes(ego_boxes, "ego_boxes")
    _check_image(top_image, top_camera, "top_image")
    _check_image(ego_image, ego_camera, "ego_image")
    top_hist = box_histograms(top_image, top_boxes)
    ego_hist = box_histograms(ego_image, ego_boxes)
    rays_top = box_rays(top_camera, top_boxes)
    rays_ego = box_rays(ego_camera, ego_boxes)
    return PairCosts(
        geo=ray_distances(rays_top, rays_ego),
        hist=chi2_brd_distance(top_hist.histograms, ego_hist.histograms),
        hist_valid=top_hist.valid[:, None] & ego_hist.valid[None, :],
        cheirality=cheirality_cost(rays_top, rays_ego, margin=margin, beta=beta),
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


# --------------------------------------------------------------------------------------------
# Ground-truth matching and counting


def box_iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over union of ``(x, y, w, h)`` boxes.

    Args:
        boxes_a: (M, 4) boxes.
        boxes_b: (N, 4) boxes.

    Returns:
        (M, N) IoU in [0, 1]; 0 where the union is empty (two zero-area boxes).
    """
    a = as_boxes(boxes_a, "boxes_a")
    b = as_boxes(boxes_b, "boxes_b")
    ax1, ay1 = a[:, 0] + a[:, 2], a[:, 1] + a[:, 3]
    bx1, by1 = b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
    iw = np.minimum(ax1[:, None], bx1[None, :]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(ay1[:, None], by1[None, :]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)


def match_to_ground_truth(
    det_boxes: np.ndarray,
    gt_boxes: np.ndarray,
    gt_ids: np.ndarray,
    iou_threshold: float = 0.3,
) -> np.ndarray:
    """The ground-truth id each detection stands for (Section IV-B: IoU >= 0.3).

    Detections and ground-truth boxes of one view are matched one to one, maximising the total
    IoU over the pairs with ``IoU >= iou_threshold`` (Hungarian algorithm); a detection left
    without a partner, e.g. a second detection on an already matched person, is a false
    positive.

    Args:
        det_boxes: (D, 4) detections.
        gt_boxes: (G, 4) ground-truth boxes.
        gt_ids: (G,) their ids (distinct, >= 0).
        iou_threshold: smallest IoU of a match, in (0, 1].

    Returns:
        (D,) int64 ids; :data:`FALSE_POSITIVE` (-1) for false positives.

    Raises:
        ValueError: bad boxes, ids not matching the boxes, repeated or negative ids, or a
            threshold outside (0, 1].
    """
    if not 0 < iou_threshold <= 1:
        raise ValueError(f"iou_threshold must be in (0, 1], got {iou_threshold}")
    ids = np.asarray(gt_ids).reshape(-1).astype(np.int64)
    iou = box_iou(det_boxes, gt_boxes)
    if ids.shape[0] != iou.shape[1]:
        raise ValueError(f"gt_ids has {ids.shape[0]} ids for {iou.shape[1]} gt_boxes")
    if ids.size and (np.unique(ids).size != ids.size or ids.min() < 0):
        raise ValueError(f"gt_ids must be distinct and >= 0, got {sorted(ids.tolist())}")
    out = np.full(iou.shape[0], FALSE_POSITIVE, np.int64)
    if iou.size == 0:
        return out
    eligible = iou >= iou_threshold
    rows, cols = linear_sum_assignment(np.where(eligible, iou, 0.0), maximize=True)
    keep = eligible[rows, cols]
    out[rows[keep]] = ids[cols[keep]]
    return out


def _true_ids(ids: np.ndarray, gt: set[int], name: str, frame: int) -> np.ndarray:
    arr = np.asarray(ids).reshape(-1).astype(np.int64)
    real = arr[arr != FALSE_POSITIVE]
    if np.unique(real).size != real.size:
        raise ValueError(f"frame {frame}: {name} stand for one ground-truth id twice: "
                         f"{sorted(real.tolist())}")
    unknown = sorted(set(real.tolist()) - gt)
    if unknown:
        raise ValueError(f"frame {frame}: {name} name ids absent from the view's ground truth: "
                         f"{unknown}")
    return arr


def count_pair(
    gt_top_ids: np.ndarray,
    gt_ego_ids: np.ndarray,
    det_top_ids: np.ndarray,
    det_ego_ids: np.ndarray,
    pairs: np.ndarray,
    *,
    frame: int = 0,
) -> FrameCounts:
    """Count one image pair against the ground truth, detections allowed (Eq. 9, Accuracy*).

    ``U`` (the unique persons of Eq. 9) are the ground-truth ids of either view and ``G`` those
    of both. A predicted pair is a true positive when both of its boxes stand for the same
    ground-truth id; a wrong pair is a mismatch when its egocentric box stands for an id of
    ``G``, otherwise a false positive. A miss is an id of ``G`` whose egocentric box is
    undetected or in no pair. A true negative is an id seen in one view only (in the ground
    truth) whose box there was detected and left unmatched. With the ground-truth boxes as
    detections this equals :func:`xvmatch.evaluation.cross_view_metrics.count_frame`.

    Args:
        gt_top_ids: (G1,) ground-truth ids of the top view.
        gt_ego_ids: (G2,) ground-truth ids of the egocentric view.
        det_top_ids: (M,) id each associated top box stands for (:data:`FALSE_POSITIVE` for a
            false positive), in the order of the association's rows.
        det_ego_ids: (N,) the same for the egocentric boxes (columns).
        pairs: (K, 2) ``(row, column)`` pairs of the association.
        frame: frame number, recorded and used in error messages.

    Returns:
        The :class:`~xvmatch.evaluation.cross_view_metrics.FrameCounts`.

    Raises:
        ValueError: repeated ground-truth ids, a detection standing for an id twice or for an id
            the view does not have, or pairs out of range or not one-to-one.
    """
    gt_top = [int(v) for v in np.asarray(gt_top_ids).reshape(-1)]
    gt_ego = [int(v) for v in np.asarray(gt_ego_ids).reshape(-1)]
    top_set, ego_set = set(gt_top), set(gt_ego)
    if len(top_set) != len(gt_top) or len(ego_set) != len(gt_ego):
        raise ValueError(f"frame {frame}: a ground-truth id is listed twice in a view")
    det_top = _true_ids(det_top_ids, top_set, "det_top_ids", frame)
    det_ego = _true_ids(det_ego_ids, ego_set, "det_ego_ids", frame)
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    if p.size and ((p < 0).any() or (p[:, 0] >= det_top.size).any()
                   or (p[:, 1] >= det_ego.size).any()):
        raise ValueError(f"frame {frame}: pairs out of range for {det_top.size} x {det_ego.size}")
    if np.unique(p[:, 0]).size != len(p) or np.unique(p[:, 1]).size != len(p):
        raise ValueError(f"frame {frame}: pairs must be one-to-one, got {p.tolist()}")
    shared = top_set & ego_set
    a, b = det_top[p[:, 0]], det_ego[p[:, 1]]
    correct = (a == b) & (a != FALSE_POSITIVE)
    tp = int(correct.sum())
    mismatch = int(sum(1 for ok, h in zip(correct, b, strict=True) if not ok and int(h) in shared))
    paired_ego = {int(h) for h in b if h != FALSE_POSITIVE}
    paired_top = {int(t) for t in a if t != FALSE_POSITIVE}
    detected_top = {int(t) for t in det_top if t != FALSE_POSITIVE}
    detected_ego = {int(h) for h in det_ego if h != FALSE_POSITIVE}
    tn = len(((top_set - ego_set) & detected_top) - paired_top) + len(
        ((ego_set - top_set) & detected_ego) - paired_ego
    )
    return FrameCounts(
        frame=int(frame),
        n_pred=len(p),
        n_gt=len(shared),
        tp=tp,
        fp=len(p) - tp - mismatch,
        mismatch=mismatch,
        miss=len(shared - paired_ego),
        n_union=len(top_set | ego_set),
        tn=tn,
    )


# --------------------------------------------------------------------------------------------
# Trials: one image pair in one setting, ready to associate and score


@dataclass(frozen=True, eq=False)
class PairTrial:
    """One image pair in one setting, its boxes shuffled, ready to associate and score.

    Attributes:
        scene: scene name.
        frame: 1-based frame number.
        setting: ``"gt"`` or ``"det"``.
        costs: the raw cues between the shuffled boxes.
        gt_top_ids: ground-truth ids of the top view.
        gt_ego_ids: ground-truth ids of the egocentric view.
        det_top_ids: (M,) id each shuffled top box stands for (-1: false positive).
        det_ego_ids: (N,) id each shuffled egocentric box stands for.
    """

    scene: str
    frame: int
    setting: str
    costs: PairCosts
    gt_top_ids: np.ndarray
    gt_ego_ids: np.ndarray
    det_top_ids: np.ndarray
    det_ego_ids: np.ndarray


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


def noise_seed_of(noise_seed: int, scene_index: int) -> int:
    """Seed of the detector noise of one scene, independent across scenes."""
    state = np.random.SeedSequence([int(noise_seed), int(scene_index)]).generate_state(1)
    return int(state[0])


@dataclass(frozen=True, eq=False)
class FrameSample:
    """The boxes of one frame pair in one setting, as every synthetic evaluation sees them.

    Attributes:
        pair: the frame pair (images and cameras).
        setting: ``"gt"`` or ``"det"``.
        images, cameras: per view (``"top"``, ``"ego"``).
        gt_ids: per view, the ground-truth ids of the frame.
        boxes: per view, the boxes in a seeded random order (ground truth or detections).
        stands_for: per view, the ground-truth id each box stands for
            (:data:`FALSE_POSITIVE` for a false detection); evaluation only.
        n_gt, n_det, n_true: per view, ground-truth boxes, detections and true detections
            (zeros in the ``"gt"`` setting).
    """

    pair: PairRecord
    setting: str
    images: dict[str, np.ndarray]
    cameras: dict[str, Camera]
    gt_ids: dict[str, np.ndarray]
    boxes: dict[str, np.ndarray]
    stands_for: dict[str, np.ndarray]
    n_gt: dict[str, int]
    n_det: dict[str, int]
    n_true: dict[str, int]


def scene_samples(
    scene: SceneRecord,
    scene_index: int,
    config: BaselineConfig,
    settings: Sequence[str] = SETTINGS,
) -> Iterator[FrameSample]:
    """Every frame pair of a scene in each requested setting (:data:`SETTINGS` order), boxes
    shuffled per view with a seed of (``config.scramble_seed``, scene, frame, setting) and
    detections drawn with :func:`noise_seed_of` (``config.noise_seed``, ``scene_index``)."""
    unknown = [s for s in settings if s not in SETTINGS]
    if unknown:
        raise ValueError(f"settings must be among {', '.join(SETTINGS)}, got {unknown}")
    views = ("top", "ego")
    gt_boxes = {v: scene.boxes(v) for v in views}
    det_boxes = {}
    if "det" in settings:
        seed = noise_seed_of(config.noise_seed, scene_index)
        for v in views:
            camera = getattr(scene.pairs[0], v).camera
            det_boxes[v] = apply_visibility_noise(
                gt_boxes[v], scene.visibility(v), camera.image_size, config.noise, seed, v
            )
    for pair in scene.pairs:
        images = {v: getattr(pair, v).load_image() for v in views}
        cameras = {v: getattr(pair, v).camera for v in views}
        gt_ids = {v: gt_boxes[v][pair.frame].ids for v in views}
        for s_index, setting in enumerate(SETTINGS):
            if setting not in settings:
                continue
            rng = np.random.default_rng(
                [int(config.scramble_seed), int(scene_index), pair.frame, s_index]
            )
            boxes, stands_for = {}, {}
            counts = {k: {v: 0 for v in views} for k in ("n_gt", "n_det", "n_true")}
            for v in views:
                gt = gt_boxes[v][pair.frame]
                if setting == "gt":
                    b, ids = gt.boxes, gt.ids
                else:
                    b = det_boxes[v][pair.frame].boxes
                    ids = match_to_ground_truth(b, gt.boxes, gt.ids, config.iou_threshold)
                    counts["n_gt"][v] = len(gt)
                    counts["n_det"][v] = len(b)
                    counts["n_true"][v] = int((ids != FALSE_POSITIVE).sum())
                order = rng.permutation(len(ids))
                boxes[v], stands_for[v] = b[order], ids[order]
            yield FrameSample(pair, setting, images, cameras, gt_ids, boxes, stands_for,
                              **counts)


def scene_trials(
    scene: SceneRecord,
    scene_index: int,
    config: BaselineConfig,
    settings: Sequence[str] = SETTINGS,
) -> tuple[list[PairTrial], CostSamples, DetectionStats]:
    """Build the trials of every frame of a scene, in the requested settings.

    Args:
        scene: the parsed scene.
        scene_index: its index in the dataset (seeds the detector noise and the shuffling).
        config: costs, noise and seeds.
        settings: subset of :data:`SETTINGS`.

    Returns:
        (trials, samples, detection): the trials (frame by frame, settings in the given order),
        the raw true/false costs of the ground-truth boxes (Figs. 2-3; empty unless ``"gt"`` is
        among the settings), and the detector statistics (zeros unless ``"det"`` is).
    """
    views = ("top", "ego")
    stats = {k: {v: 0 for v in views} for k in ("n_gt", "n_det", "n_true")}
    trials: list[PairTrial] = []
    samples: list[CostSamples] = []
    for fs in scene_samples(scene, scene_index, config, settings):
        for key, per_view in stats.items():
            for v in views:
                per_view[v] += getattr(fs, key)[v]
        costs = pair_costs(fs.cameras["top"], fs.cameras["ego"], fs.images["top"],
                           fs.images["ego"], fs.boxes["top"], fs.boxes["ego"],
                           margin=config.margin, beta=config.beta)
        if fs.setting == "gt":
            same = fs.stands_for["top"][:, None] == fs.stands_for["ego"][None, :]
            samples.append(CostSamples.from_matrices(costs.geo, costs.hist, same,
                                                     costs.hist_valid))
        trials.append(PairTrial(fs.pair.scene, fs.pair.frame, fs.setting, costs,
                                fs.gt_ids["top"], fs.gt_ids["ego"], fs.stands_for["top"],
                                fs.stands_for["ego"]))
    return trials, CostSamples.concatenate(samples), DetectionStats(**stats)


def _scene_task(root: str, name: str, index: int, config: BaselineConfig,
                settings: tuple[str, ...]) -> _SceneTrials:
    scene = SyntheticDataset(root).scene(name)
    trials, samples, detection = scene_trials(scene, index, config, settings)
    return _SceneTrials(trials, samples, detection)


def _worker_init() -> None:
    import cv2

    cv2.setNumThreads(1)


def open_dataset(data: str | os.PathLike) -> SyntheticDataset:
    """Open a synthetic dataset folder, with an actionable error when it is not one.

    Raises:
        ValueError: no ``dataset.json`` in ``data``.
        SchemaError: a malformed manifest.
    """
    root = Path(data)
    if not (root / MANIFEST).is_file():
        raise ValueError(
            f"{os.fspath(root)}: no {MANIFEST}; generate a dataset first, e.g. "
            "xvmatch synth --out DIR --scenario overview --scenes 20 --frames 5 --seed 1000"
        )
    return SyntheticDataset(root)


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
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(max_workers=int(workers), mp_context=context,
                                 initializer=_worker_init) as pool:
            futures = {pool.submit(_scene_task, *task): i for i, task in enumerate(tasks)}
            for future in as_completed(futures):
                i = futures[future]
                results[i] = future.result()
                if progress is not None:
                    progress(len({t.frame for t in results[i].trials}))
    return dataset, [r for r in results if r is not None]


# --------------------------------------------------------------------------------------------
# Evaluation, tuning and the table


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
