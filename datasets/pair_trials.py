"""Trials of synthetic image pairs: what every synthetic evaluation and training set is made of.

A trial is one image pair (``xvmatch synth``) in one setting, ready to associate and score:

* ``"gt"`` (Table I of the geometric-priors paper): the ground-truth (visible) boxes;
* ``"det"`` (Table II): boxes from the detector-noise model (:mod:`xvmatch.datasets.
  visibility_noise`: jitter, misses that grow with occlusion, false boxes). Each detection takes
  the id of the ground-truth box of its view with which it has IoU >= 0.3 (one-to-one, maximum
  total IoU), else it is a false positive that no true pair can include.

Per frame and view, the boxes are shuffled with a seeded permutation before any cost is
computed ("ids scrambled"): a method sees boxes, images and cameras only, never an id; ids are
looked up again only to score (:func:`xvmatch.metrics.cross_view_metrics.count_pair`) and to
build training labels. Each trial carries the handcrafted cues between its boxes
(:func:`~xvmatch.cues.handcrafted_costs.pair_costs`) and, when a coster is given, learned
appearance costs. The handcrafted baseline, the learned-matcher evaluation and the fusion and
matcher training all draw their trials here.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.cues.handcrafted_costs import PairCosts, pair_costs
from xvmatch.datasets.synthetic_io import MANIFEST, PairRecord, SceneRecord, SyntheticDataset
from xvmatch.datasets.visibility_noise import VisibilityNoise, apply_visibility_noise
from xvmatch.formats.mot_boxes import FALSE_POSITIVE
from xvmatch.geometry.box_overlap import box_iou
from xvmatch.geometry.camera import Camera
from xvmatch.geometry.ray_priors import DEFAULT_BETA, METRIC_MARGIN

__all__ = [
    "CUES",
    "FALSE_POSITIVE",
    "SETTINGS",
    "SETTING_NAMES",
    "FrameSample",
    "PairTrial",
    "TrialConfig",
    "dataset_trials",
    "match_to_ground_truth",
    "noise_seed_of",
    "open_dataset",
    "scene_samples",
    "scene_trials",
]

SETTINGS: tuple[str, ...] = ("gt", "det")
"""``"gt"``: ground-truth boxes (Table I); ``"det"``: detector-noise boxes (Table II)."""

SETTING_NAMES: dict[str, str] = {
    "gt": "Table I: ground-truth boxes",
    "det": "Table II: detections",
}

CUES: tuple[str, ...] = ("app", "geo", "cheir", "hist")
"""Names of the normalised cues of a trial (:meth:`PairTrial.cues`): learned appearance,
tanh of the ray distance (Eq. 6), cheirality failure (Eq. 7) and tanh of the histogram distance
(Eq. 3)."""


@dataclass(frozen=True)
class TrialConfig:
    """How the trials of a dataset are drawn: detector noise, seeds, ground-truth matching and
    the cheirality cue's constants.

    Attributes:
        margin: depth margin of Eq. 7 in metres (0.5 with a metric scale, 0 without).
        beta: cost added to pairs that violate Eq. 7 (``>> 1``).
        iou_threshold: IoU for a detection to count as a ground-truth box (paper: 0.3).
        noise: the detector-noise model of the ``"det"`` setting.
        noise_seed: seed of the detector noise; scene i uses ``SeedSequence([seed, i])``.
        scramble_seed: seed of the per-frame, per-view shuffling of the boxes.
    """

    margin: float = METRIC_MARGIN
    beta: float = DEFAULT_BETA
    iou_threshold: float = 0.3
    noise: VisibilityNoise = field(default_factory=VisibilityNoise)
    noise_seed: int = 0
    scramble_seed: int = 0

    def __post_init__(self) -> None:
        if not 0 < self.iou_threshold <= 1:
            raise ValueError(f"iou_threshold must be in (0, 1], got {self.iou_threshold}")
        if not np.isfinite(self.margin) or self.margin < 0:
            raise ValueError(f"margin must be a finite depth >= 0, got {self.margin}")
        if not np.isfinite(self.beta) or self.beta <= 1:
            raise ValueError(f"beta must be a finite cost > 1, got {self.beta}")


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
    config: TrialConfig,
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


@dataclass(frozen=True, eq=False)
class PairTrial:
    """One image pair in one setting, its boxes shuffled, ready to associate and score.

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
        n_gt, n_det, n_true: per view, ground-truth boxes, detections and true detections
            (zeros in the ``"gt"`` setting).
        cameras: the frame's calibrated cameras per view (``"top"``, ``"ego"``).
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
    n_gt: dict[str, int] = field(default_factory=dict)
    n_det: dict[str, int] = field(default_factory=dict)
    n_true: dict[str, int] = field(default_factory=dict)
    cameras: dict[str, Camera] = field(default_factory=dict)

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



def scene_trials(
    scene: SceneRecord,
    scene_index: int,
    config: TrialConfig,
    settings: Sequence[str] = SETTINGS,
    coster: Callable[..., np.ndarray] | None = None,
) -> list[PairTrial]:
    """The trials of every frame of a scene: boxes of :func:`scene_samples`, their handcrafted
    cues (:func:`~xvmatch.cues.handcrafted_costs.pair_costs`) and optional learned
    appearance costs.

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
    trials: list[PairTrial] = []
    for fs in scene_samples(scene, scene_index, config, settings):
        costs = pair_costs(fs.cameras["top"], fs.cameras["ego"], fs.images["top"],
                           fs.images["ego"], fs.boxes["top"], fs.boxes["ego"],
                           margin=config.margin, beta=config.beta)
        app = None
        if coster is not None:
            app = coster(fs.images["top"], fs.boxes["top"], fs.images["ego"], fs.boxes["ego"])
        trials.append(PairTrial(fs.pair.scene, fs.pair.frame, fs.setting, fs.boxes["top"],
                                fs.boxes["ego"], costs, app, fs.gt_ids["top"], fs.gt_ids["ego"],
                                fs.stands_for["top"], fs.stands_for["ego"], fs.n_gt, fs.n_det,
                                fs.n_true, fs.cameras))
    return trials


def dataset_trials(
    data: str | os.PathLike,
    config: TrialConfig | None = None,
    settings: Sequence[str] = SETTINGS,
    coster: Callable[..., np.ndarray] | None = None,
    progress: Callable[[int], None] | None = None,
) -> list[PairTrial]:
    """:func:`scene_trials` of every scene of a dataset folder, in scene order.

    Args:
        data: dataset folder written by ``xvmatch synth``.
        config: seeds and noise (default :class:`TrialConfig`).
        settings: subset of :data:`SETTINGS`.
        coster: optional learned appearance costs.
        progress: called with the number of pairs of each finished scene.
    """
    config = TrialConfig() if config is None else config
    dataset = open_dataset(data)
    out: list[PairTrial] = []
    for index, name in enumerate(dataset.scene_names):
        scene = dataset.scene(name)
        out += scene_trials(scene, index, config, settings, coster)
        if progress is not None:
            progress(len(scene.pairs))
    return out


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
