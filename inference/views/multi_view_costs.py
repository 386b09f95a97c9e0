"""Cost matrices of every view pair of one top view and K egocentric views, frame by frame.

View 0 is the top view, views 1..K the egocentric (horizontal) ones. Every cost is minus the
evidence, in nats, that the two boxes are one person, with non-association cost 0, so that the
joint program of :mod:`xvmatch.inference.views.multi_view_assignment` adds evidence of different
origins in one unit (a log-odds), and pairwise Hungarian on the same matrices takes the pairs
each matcher takes alone.

- Top-ego pairs come from an existing per-pair matcher: the learned matcher of a bundle
  (:func:`~xvmatch.inference.matching.learned_association.associate_sequence_learned`: boxes, and
  images and cameras when given), its cost ``1 - P`` turned into minus the log-odds relative to
  its gamma (:func:`log_odds_cost`); or the handcrafted spatial-distribution search (CVMHAT
  Sec. 3.2), whose best hypotheses vote for pairs (:func:`spatial_vote_cost`), calibrated into
  log-odds by a logistic fit (:data:`SPATIAL_VOTE`).
- Ego-ego pairs are two horizontal views: people are seen from the side in both, at similar
  scales, so appearance is the natural cue, while the box layouts of two views facing different
  ways share nothing the spatial features could use. The cue is the appearance distance of the
  bundle's network (:func:`~xvmatch.cues.matcher_inputs.appearance_cost`) as a
  log-likelihood ratio (:data:`EGO_APPEARANCE`). Without images the ego-ego costs are 0: no
  evidence either way, and the joint program links two egocentric views through the top view.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.cues.matcher_inputs import appearance_cost
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.cues.spatial_search import best_per_candidate, rank_hypotheses
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.learned_association import (
    FrameCameraSource,
    FrameImages,
    LearnedMatcher,
    associate_sequence_learned,
)
from xvmatch.inference.views.multi_view_assignment import view_pairs

__all__ = [
    "EGO_APPEARANCE",
    "LOGIT_CLIP",
    "SPATIAL_VOTE",
    "FrameProblem",
    "LogisticCalibration",
    "log_odds_cost",
    "multi_view_costs",
    "spatial_vote_cost",
    "with_wearer_tag",
]

LOGIT_CLIP = 0.01
"""Probabilities are clipped to [0.01, 0.99] before their log-odds are taken (a matcher's
certainty is capped at about 4.6 nats, so no single pair overrules every other)."""


def log_odds_cost(cost: np.ndarray, gamma: float = 0.5) -> np.ndarray:
    """``logit(c) - logit(gamma)`` of costs ``c = 1 - P`` in [0, 1]: minus the log-odds of a
    match (relative to the matcher's own threshold), in the units the joint program adds up;
    with non-association cost 0 a pair is matched alone when ``c < gamma``, as the matcher's
    own pairwise decision."""
    c = np.clip(np.asarray(cost, dtype=float), LOGIT_CLIP, 1.0 - LOGIT_CLIP)
    g = float(np.clip(gamma, LOGIT_CLIP, 1.0 - LOGIT_CLIP))
    return (np.log(c) - np.log1p(-c)) - (np.log(g) - np.log1p(-g))


@dataclass(frozen=True)
class LogisticCalibration:
    """Evidence ``slope (threshold - d)`` (nats) that two boxes are one person, from a cost or
    distance ``d`` that grows as they differ; the joint program takes minus it as the cost.

    Attributes:
        threshold: the ``d`` with no evidence either way.
        slope: how fast the evidence falls with ``d`` (> 0).
    """

    threshold: float
    slope: float

    def __post_init__(self) -> None:
        if not (np.isfinite(self.threshold) and np.isfinite(self.slope) and self.slope > 0):
            raise ValueError(f"LogisticCalibration needs a finite threshold and a slope > 0, "
                             f"got {self.threshold}, {self.slope}")

    def cost(self, distance: np.ndarray) -> np.ndarray:
        """Minus the evidence of each ``d``: the joint program's cost (gamma 0)."""
        return self.slope * (np.asarray(distance, dtype=float) - self.threshold)


EGO_APPEARANCE = LogisticCalibration(threshold=0.240, slope=18.8)
"""Ego-ego pairs: the log-likelihood ratio of the shipped appearance network's distance, i.e.
the log-odds of a logistic fit less the log prior odds of the fit's pairs (the prior of an
ego-ego match is already counted by the top-ego matches it closes a triangle with). Fitted on
30 rendered 1 top + 3 ego scenes (ground-truth boxes, seeds disjoint from the evaluation's) by
``python benchmarks/multi_ego_eval.py --calibrate`` (docs/multi_egocentric.md)."""

SPATIAL_VOTE = LogisticCalibration(threshold=0.598, slope=9.8)
"""Top-ego pairs of the handcrafted search: the log-odds of a logistic fit of
:func:`spatial_vote_cost` (O searched), on the same scenes by the same command."""


@dataclass(frozen=True, eq=False)
class FrameProblem:
    """The joint program of one frame.

    Attributes:
        sizes: boxes per view, top first.
        costs: ``{(a, b): (n_a, n_b) costs}`` for every ``a < b``.
        gamma: ``{(a, b): non-association cost}``.
    """

    sizes: tuple[int, ...]
    costs: dict[tuple[int, int], np.ndarray]
    gamma: dict[tuple[int, int], float]


def spatial_vote_cost(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_width: float,
    params: SpatialParams | None = None,
    camera: int | None = None,
    keep: int = 5,
    temperature: float = 0.01,
) -> np.ndarray:
    """``(M, N)`` cost of the spatial-distribution search (Sec. 3.2): one minus the weighted
    share of its best hypotheses that pair the two boxes.

    The hypotheses are the best orientation of each of the ``keep`` best camera locations O
    (or, with O given, the ``keep`` best orientations), weighted by
    ``exp(-(Phi - Phi_min) / temperature)`` (Phi of Eq. 12).
    """
    return _spatial_votes(top_boxes, hor_boxes, hor_width, params, camera, keep, temperature)[0]


def _spatial_votes(top_boxes: np.ndarray, hor_boxes: np.ndarray, hor_width: float,
                   params: SpatialParams | None, camera: int | None, keep: int = 5,
                   temperature: float = 0.01) -> tuple[np.ndarray, int | None]:
    """:func:`spatial_vote_cost`, and the top box its best hypothesis puts the camera at (None:
    no hypothesis)."""
    m, n = len(top_boxes), len(hor_boxes)
    out = np.ones((m, n))
    if camera is None:
        found = best_per_candidate(top_boxes, hor_boxes, hor_width, params, keep=keep)
    else:
        found = rank_hypotheses(top_boxes, hor_boxes, hor_width, params, [camera], k=keep)
    if not found:
        return out, None
    phi = np.array([h.cost for h in found])
    weight = np.exp(-(phi - phi.min()) / temperature)
    weight /= weight.sum()
    for h, w in zip(found, weight, strict=True):
        p = np.asarray(h.pairs, dtype=np.int64).reshape(-1, 2)
        out[p[:, 0], p[:, 1]] -= w
    return np.clip(out, 0.0, 1.0), int(found[int(np.argmin(phi))].camera)


def _view_boxes(views: Sequence[Mapping[int, object]], v: int, f: int) -> np.ndarray:
    """The ``(n, 4)`` boxes of view v in frame f (none where the frame has no record)."""
    rec = views[v].get(f)
    return np.zeros((0, 4)) if rec is None else np.asarray(rec.boxes, float).reshape(-1, 4)


def _check_views(views: Sequence[Mapping[int, object]], hor_sizes: Sequence[tuple[float, float]],
                 images: Sequence[FrameImages] | None, appearance: LearnedMatcher | None) -> None:
    """Refuse fewer than two views, a size missing, images of some views only, or ego-ego
    appearance without images."""
    n_views = len(views)
    if n_views < 2 or len(hor_sizes) != n_views - 1:
        raise ValueError(f"need a top view, >= 1 egocentric view and one size per egocentric "
                         f"view, got {n_views} views and {len(hor_sizes)} sizes")
    if images is not None and len(images) != n_views:
        raise ValueError(f"give images for all {n_views} views or none")
    if appearance is not None and images is None:
        raise ValueError("ego-ego appearance costs need the images of every view")


def _spatial_top_ego(views: Sequence[Mapping[int, object]], k: int, frames: Iterable[int],
                     width: float, params: SpatialParams | None, rows: Mapping[int, int],
                     searched: dict[int, int] | None = None) -> dict[int, np.ndarray]:
    """``{frame: top x view-k vote costs}`` of the spatial search (all 1 where a view has no
    box); ``searched`` filled with ``{frame: O's row in the top record}`` of each frame's best
    hypothesis."""
    out = {}
    for f in frames:
        t, h = _view_boxes(views, 0, f), _view_boxes(views, k, f)
        if not (len(t) and len(h)):
            out[f] = np.ones((len(t), len(h)))
            continue
        out[f], best = _spatial_votes(t, h, width, params, rows.get(f))
        if searched is not None and best is not None:
            searched[f] = best
    return out


def _learned_top_ego(views: Sequence[Mapping[int, object]], k: int, frames: list[int],
                     size: tuple[float, float], matcher: LearnedMatcher,
                     rows: Mapping[int, int], options: dict,
                     searched: dict[int, int] | None = None
                     ) -> tuple[dict[int, np.ndarray], list[AppearanceCheck]]:
    """The learned matcher's top x view-k cost matrices, ``{frame: costs}`` of the frames
    with boxes in both views, and the appearance check of the pass (if judged); ``searched``
    filled with ``{frame: O's row in the top record}`` of its features' search.

    ``options`` are the keyword arguments passed on to
    :func:`~xvmatch.inference.matching.learned_association.associate_sequence_learned`.
    """
    found: dict[int, np.ndarray] = {}
    judged: list[AppearanceCheck] = []
    top_rows = {f: with_wearer_tag(views[0][f], rows.get(f)) for f in frames if f in views[0]}
    associate_sequence_learned(
        top_rows, {f: views[k][f] for f in frames if f in views[k]}, size[0], matcher,
        camera_id=-1 if rows else None, hor_height=size[1], frames=frames, costs_out=found,
        checked=judged, searched=searched, **options,
    )
    return found, judged


def _frame_problem(views: Sequence[Mapping[int, object]], f: int, sizes: tuple[int, ...],
                   top_ego: Mapping[int, np.ndarray], matcher: LearnedMatcher | None,
                   appearance: LearnedMatcher | None, images: Sequence[FrameImages] | None,
                   calibration: LogisticCalibration, vote_calibration: LogisticCalibration
                   ) -> FrameProblem:
    """Frame f's problem: top-ego costs from ``top_ego`` (``{view: costs}``), ego-ego ones
    from the appearance (0 without it), every gamma 0."""
    n_views = len(views)
    desc = {}
    if appearance is not None:
        for v in range(1, n_views):
            b = _view_boxes(views, v, f)
            desc[v] = appearance.descriptors(images[v].get(f), b) if len(b) else None
    costs, gammas = {}, {}
    for a, b in view_pairs(n_views):
        gammas[(a, b)] = 0.0
        if a == 0 and matcher is None:
            costs[(a, b)] = vote_calibration.cost(top_ego[b])
        elif a == 0:
            costs[(a, b)] = log_odds_cost(top_ego[b], matcher.gamma)
        elif appearance is not None and desc[a] is not None and desc[b] is not None:
            costs[(a, b)] = calibration.cost(appearance_cost(desc[a], desc[b]))
        else:
            costs[(a, b)] = np.zeros((sizes[a], sizes[b]))
    return FrameProblem(sizes, costs, gammas)


def multi_view_costs(
    views: Sequence[Mapping[int, object]],
    hor_sizes: Sequence[tuple[float, float]],
    frames: Iterable[int],
    matcher: LearnedMatcher | None = None,
    appearance: LearnedMatcher | None = None,
    images: Sequence[FrameImages] | None = None,
    cameras: Sequence[FrameCameraSource | None] | None = None,
    camera_rows: Sequence[Mapping[int, int] | None] | None = None,
    params: SpatialParams | None = None,
    calibration: LogisticCalibration = EGO_APPEARANCE,
    vote_calibration: LogisticCalibration = SPATIAL_VOTE,
    workers: int = 1,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    appearance_check: bool = False,
    checked: dict[int, AppearanceCheck] | None = None,
    searched: dict[int, dict[int, int]] | None = None,
) -> dict[int, FrameProblem]:
    """The :class:`FrameProblem` of every frame.

    Args:
        views: per view, top first, ``{frame: record}`` with ``ids`` and ``boxes``.
        hor_sizes: (width, height) of each egocentric view's images.
        frames: the frames to build.
        matcher: the learned top-ego matcher; None runs the spatial search.
        appearance: the bundle whose appearance network scores ego-ego pairs (needs
            ``images``); None leaves them uninformative (cost 0).
        images: per view (top first) an image source, or None.
        cameras: per egocentric view, its ``top``/``ego`` camera source or None (learned only).
        camera_rows: per egocentric view, ``{frame: top-view row of its wearer}`` or None.
        params: the spatial search's parameters (handcrafted top-ego costs).
        calibration: the ego-ego appearance calibration.
        vote_calibration: the calibration of the handcrafted top-ego vote costs.
        workers: processes for the learned matcher's geometry features.
        progress: wraps the frame iterator of each top-ego pass.
        appearance_check: with images, judge each top-ego pass's appearance cue on its own
            box-only pseudo-matches, that pass falling back to the boxes when it fails
            (:mod:`xvmatch.inference.matching.appearance_check`; the ego-ego costs are not judged).
        checked: if given, receives ``{egocentric view (1-based): AppearanceCheck}`` of the
            passes judged.
        searched: if given, receives ``{egocentric view (1-based): {frame: row of the top
            record}}``: where each frame's best hypothesis of the search puts that view's camera
            (:mod:`~xvmatch.inference.matching.search_camera`), for the views whose wearer is
            not given.
    """
    frames = sorted({int(f) for f in frames})
    n_views = len(views)
    _check_views(views, hor_sizes, images, appearance)
    sizes = {f: tuple(len(_view_boxes(views, v, f)) for v in range(n_views)) for f in frames}
    top_ego: dict[int, dict[int, np.ndarray]] = {f: {} for f in frames}
    for k in range(1, n_views):
        rows = (camera_rows[k - 1] if camera_rows is not None else None) or {}
        if searched is not None and not rows:
            searched[k] = {}
        if matcher is None:
            spatial = _spatial_top_ego(views, k, progress(frames) if progress else frames,
                                       hor_sizes[k - 1][0], params, rows,
                                       None if searched is None else searched.get(k))
            for f, cost in spatial.items():
                top_ego[f][k] = cost
            continue
        found, judged = _learned_top_ego(
            views, k, frames, hor_sizes[k - 1], matcher, rows, dict(
                workers=workers, progress=progress,
                top_images=images[0] if images is not None else None,
                hor_images=images[k] if images is not None else None,
                cameras=cameras[k - 1] if cameras is not None else None,
                appearance_check=appearance_check), None if searched is None else searched.get(k))
        if checked is not None and judged:
            checked[k] = judged[0]
        for f in frames:
            top_ego[f][k] = found.get(f, np.ones(sizes[f][:1] + sizes[f][k:k + 1]))
    return {f: _frame_problem(views, f, sizes[f], top_ego[f], matcher, appearance, images,
                              calibration, vote_calibration)
            for f in frames}


@dataclass(frozen=True, eq=False)
class _Tagged:
    """A top-view record whose ids are -1 at the wearer's row and the row number elsewhere,
    so that ``camera_id=-1`` names the wearer to the learned matcher."""

    ids: np.ndarray
    boxes: np.ndarray

    def __len__(self) -> int:
        return int(self.ids.shape[0])


def with_wearer_tag(record, wearer_row: int | None):
    """``record`` with ids that name only the wearer: -1 at position ``wearer_row`` (None: no
    wearer), the position elsewhere (:class:`_Tagged`), for ``camera_id=-1``."""
    n = len(record.boxes)
    ids = np.arange(n, dtype=np.int64)
    if wearer_row is not None:
        ids[int(wearer_row)] = -1
    return _Tagged(ids, np.asarray(record.boxes, float).reshape(-1, 4))
