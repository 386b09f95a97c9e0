"""Complementary-view tracking from boxes: the whole CVMHAT pipeline (paper, Algorithm 1).

1. Frame-level cross-view association of every frame (Sec. 3.2, the exhaustive search of
   :func:`xvmatch.cues.spatial_search.associate_frame`; O given when the wearer is known),
   or the learned matcher's box-only association (:func:`learned_frame_evidence`: its cost
   matrices and its non-association cost give the cross-view weights,
   :func:`~xvmatch.inference.tracks.track_costs.learned_similarity`).
2. Single-view tracklets in clips of ``clip_length`` frames (:mod:`.tracklets`); with images,
   the horizontal view's link by IoU and colour, and each tracklet gets its appearance
   (:mod:`.track_appearance`: colour histograms, and the network descriptor with a bundle).
3. For each pair of adjacent clips, the edge weights (:mod:`.track_costs`; with images, Eqs. 17
   and 18 mix in the appearance terms) and the four-cluster MIP (:mod:`.track_mip`), or the
   spectral-clustering baseline (:mod:`.track_spectral`).
4. Stitching into long cross-view trajectories (:mod:`.track_stitching`).

Input records are ``{frame: FrameBoxes}`` whose ``ids`` are detection row numbers (unique over
the view), so that the result can name each input row; no id is ever compared across views.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from xvmatch.core.worker_pool import worker_pool
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.cues.spatial_search import associate_frame
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.assignment import FrameCosts, assign
from xvmatch.inference.linking.tracklets import (
    Tracklet,
    clip_tracklets,
    split_clips,
    view_tracklets,
)
from xvmatch.inference.matching.appearance_check import AppearanceCheck, check_tracklet_appearance
from xvmatch.inference.matching.learned_association import (
    FrameCameraSource,
    FrameImages,
    LearnedMatcher,
    associate_sequence_learned,
)
from xvmatch.inference.tracks.track_appearance import (
    CostOfDescriptors,
    Embedder,
    PairEmbedder,
    TrackletAppearance,
    clip_appearance,
    colour_similarity,
    descriptor_similarity,
    frame_histograms,
)
from xvmatch.inference.tracks.track_costs import (
    LEARNED_RULES,
    TrackWeights,
    combine_cross_view,
    combine_over_time,
    learned_similarity,
    motion_similarity,
    spatial_similarity,
)
from xvmatch.inference.tracks.track_mip import MIP_TIME_LIMIT, ClusterSolution, solve_four_clusters
from xvmatch.inference.tracks.track_spectral import spectral_solution
from xvmatch.inference.tracks.track_stitching import stitch_windows

__all__ = [
    "SOLVERS",
    "TIME_APPEARANCE",
    "LearnedEvidence",
    "TrackConfig",
    "TrackImages",
    "TrackResult",
    "associate_frames",
    "learned_frame_evidence",
    "track_pair",
]

SOLVERS = ("mip", "spectral")
TIME_APPEARANCE = ("colour", "network")
"""Over-time appearance terms (Eq. 18): the paper's colour histograms (Eq. 14) or the network."""

Progress = Callable[[Iterable, int, str], Iterable]
"""``progress(iterable, total, description)``: wraps an iterable, e.g. in a progress bar."""


@dataclass(frozen=True)
class TrackConfig:
    """Settings of :func:`track_pair` (paper defaults, Sec. 4.1).

    Attributes:
        clip_length: frames per clip (10).
        min_iou: IoU a box needs with the previous frame's box to extend its tracklet (0.5).
        max_gap: frames a tracklet may miss inside a clip and still be extended (3).
        weights: the edge-weight parameters (``c0``, ``w1``, ``w2``, ``sigma``).
        solver: ``mip`` (Eqs. 1-4 with HiGHS) or ``spectral`` (the Sec. 4.1 baseline).
        time_limit: wall-time guard per window for the MIP before its fallback
            (:data:`~xvmatch.inference.tracks.track_mip.MIP_TIME_LIMIT`; the MIP's budget of work,
            the same on every CPU, is its loop and node limits).
        seed: seed of the spectral baseline's k-means.
        min_colour: with images, the colour-histogram similarity a horizontal box needs with
            the previous box to extend its tracklet (0.3, Sec. 4.1).
        time_appearance: with images, the over-time appearance term of Eq. 18: ``network``
            (the appearance network's descriptors, when there is one; else colour) or
            ``colour`` (the paper's Eq. 14, histogram intersection of median colour
            histograms). On rendered videos the network was ahead with the bundle of its
            first measurement, and is level with the shipped one (docs/tracking.md).
        learned_rule: with the learned matcher's evidence (:class:`LearnedEvidence`), how each
            frame's costs count in the cross-view weight
            (:func:`~xvmatch.inference.tracks.track_costs.frame_evidence`); chosen on the even
            CVMHAT dev pairs (docs/tracking.md).
        learned_share: with the learned evidence, its share of the cross-view spatial term; the
            rest is Eq. 13 on the handcrafted frame association (``frame_pairs``, computed when
            not given). 1 (default): the learned evidence alone; 0.5 was behind on the even
            dev pairs (docs/tracking.md).
    """

    clip_length: int = 10
    min_iou: float = 0.5
    max_gap: int = 3
    weights: TrackWeights = field(default_factory=TrackWeights)
    solver: str = "mip"
    time_limit: float = MIP_TIME_LIMIT
    seed: int = 0
    min_colour: float = 0.3
    time_appearance: str = "network"
    learned_rule: str = LEARNED_RULES[0]
    learned_share: float = 1.0

    def __post_init__(self) -> None:
        if self.clip_length < 1:
            raise ValueError(f"clip_length must be >= 1, got {self.clip_length}")
        if not 0.0 < self.min_iou <= 1.0:
            raise ValueError(f"min_iou must be in (0, 1], got {self.min_iou}")
        if self.max_gap < 0:
            raise ValueError(f"max_gap must be >= 0 frames, got {self.max_gap}")
        if self.solver not in SOLVERS:
            raise ValueError(f"solver must be one of {', '.join(SOLVERS)}, got {self.solver!r}")
        if not self.time_limit > 0:
            raise ValueError(f"time_limit must be > 0 seconds, got {self.time_limit}")
        if not 0.0 <= self.min_colour <= 1.0:
            raise ValueError(f"min_colour must be in [0, 1], got {self.min_colour}")
        if self.time_appearance not in TIME_APPEARANCE:
            raise ValueError(f"time_appearance must be one of {', '.join(TIME_APPEARANCE)}, "
                             f"got {self.time_appearance!r}")
        if not 0.0 <= self.learned_share <= 1.0:
            raise ValueError(f"learned_share must be in [0, 1], got {self.learned_share}")
        if self.learned_rule not in LEARNED_RULES:
            raise ValueError(f"learned_rule must be one of {', '.join(LEARNED_RULES)}, "
                             f"got {self.learned_rule!r}")


@dataclass(frozen=True)
class TrackImages:
    """The images of both views, and the appearance network if any.

    Attributes:
        top, hor: image sources, ``get(frame)`` per frame that has boxes.
        embed: ``embed(image, boxes) -> (K, D)`` unit descriptors (the deployed appearance
            network, cut as the runtime cuts crops), or None: colour terms only, and the
            cross-view weight stays the spatial term alone.
        cross_cost: the cross-view appearance cost of raw top and horizontal descriptors
            (a site bundle's adapted cost, ``LearnedMatcher.appearance_cost``), or None:
            ``|a - b| / 2``. The over-time terms compare descriptors of one view, whose
            camera is the same, and stay ``|a - b| / 2``.
        cross_embed: when ``cross_cost`` takes other vectors than ``embed``'s (a site bundle
            adapted on the network's features): the descriptors and those vectors from one
            network run (``embed(image, boxes) -> (descriptors, vectors)``), or None.
    """

    top: FrameImages
    hor: FrameImages
    embed: Embedder | None = None
    cross_cost: CostOfDescriptors | None = None
    cross_embed: PairEmbedder | None = None


@dataclass(frozen=True, eq=False)
class LearnedEvidence:
    """The learned matcher's box-only frame association, the evidence of the cross-view weights.

    Attributes:
        costs: ``{frame: FrameCosts}`` of every frame with boxes in both views.
        gamma: the matcher's non-association cost (its dustbin).
    """

    costs: dict[int, FrameCosts]
    gamma: float

    @property
    def frame_pairs(self) -> dict[int, list[tuple[int, int]]]:
        """``{frame: [(top row, horizontal row)]}``: the matcher's assignment on each frame."""
        out = {}
        for f, c in self.costs.items():
            a, b = np.nonzero(c.paired)
            out[f] = [(int(c.top_rows[i]), int(c.hor_rows[j]))
                      for i, j in zip(a.tolist(), b.tolist(), strict=True)]
        return out


def learned_frame_evidence(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    hor_size: tuple[float, float],
    matcher: LearnedMatcher | list[LearnedMatcher],
    camera_rows: Iterable[int] | None = None,
    workers: int = 1,
    progress: Progress | None = None,
    mirror: bool = False,
    cameras: FrameCameraSource | None = None,
) -> LearnedEvidence:
    """The learned matcher's association of every frame both views have, from the boxes alone
    (and the cameras, when given).

    Each frame's cost matrix (:func:`~xvmatch.inference.matching.learned_association.
    associate_sequence_learned`, no image cue even when the bundle has one; the camera cues
    and the rectified geometry only with ``cameras``) and its assignment with the matcher's
    non-association cost (geometric-priors Eqs. 1-2).

    Args:
        top, hor: ``{frame: FrameBoxes}``, ``ids`` = detection rows, unique within a view.
        hor_size: ``(W, H)`` of the horizontal images, pixels.
        matcher: an opened bundle, or several (an ensemble: costs averaged).
        camera_rows: top rows of the camera wearer (O given on frames that have one).
        workers: processes computing the geometry features (the result does not depend on it).
        progress: optional progress wrapper.
        mirror: also score the scene mirrored left-right and average the costs.
        cameras: the calibrated cameras of each frame (``get(frame)``), or None; the matchers
            must take camera cues.

    Returns:
        The :class:`LearnedEvidence`; the ids never reach the matcher.
    """
    models = [matcher] if isinstance(matcher, LearnedMatcher) else list(matcher)
    frames = sorted(f for f in set(top) & set(hor) if len(top[f]) and len(hor[f]))
    cams = set(int(r) for r in camera_rows) if camera_rows is not None else set()
    view = top
    camera_id = None
    if cams:  # the matcher finds O by one id: give the wearer's rows a common id of their own
        camera_id = min(int(top[f].ids.min()) for f in frames) - 1 if frames else -1
        view = {f: FrameBoxes(f, np.where(np.isin(top[f].ids, list(cams)), camera_id,
                                          top[f].ids), top[f].boxes) for f in frames}
    wrap = None
    if progress is not None:
        def wrap(items):
            return progress(items, len(frames), "associate")
    costs: dict[int, np.ndarray] = {}
    gamma = float(models[0].gamma)
    associate_sequence_learned(view, hor, float(hor_size[0]), models, camera_id=camera_id,
                               gamma=gamma, progress=wrap, hor_height=float(hor_size[1]),
                               frames=frames, mirror=mirror, costs_out=costs,
                               workers=workers, cameras=cameras)
    out = {}
    for f in frames:
        cost = costs[f]
        paired = np.zeros(cost.shape, dtype=bool)
        pairs = assign(cost, gamma)
        paired[pairs[:, 0], pairs[:, 1]] = True
        out[f] = FrameCosts(top[f].ids.copy(), hor[f].ids.copy(), cost, paired)
    return LearnedEvidence(out, gamma)


@dataclass(frozen=True)
class TrackResult:
    """Tracks of both views.

    Attributes:
        top_rows: ``{top row: track id}``; rows absent were dropped.
        hor_rows: ``{horizontal row: track id}``; the same id in both views is one person.
        frame_pairs: ``{frame: [(top row, horizontal row), ...]}`` of the frame association.
        n_windows: windows solved.
        n_fallback: windows where the MIP spent its budget or time limit or failed (the best
            loop-free answer found used).
        max_loops: the most loop constraints one window's MIP added
            (:data:`~xvmatch.inference.tracks.track_mip.MIP_MAX_LOOPS` is the budget).
    """

    top_rows: dict[int, int]
    hor_rows: dict[int, int]
    frame_pairs: dict[int, list[tuple[int, int]]]
    n_windows: int
    n_fallback: int
    max_loops: int = 0


def _associate_chunk(
    args: tuple[list[tuple[int, FrameBoxes, FrameBoxes, np.ndarray | None]], float, SpatialParams],
) -> list[tuple[int, list[tuple[int, int]]]]:
    """Associate a chunk of frames (one task of the process pool); pairs as detection rows."""
    items, hor_width, params = args
    out = []
    for frame, t, h, cand in items:
        res = associate_frame(t.boxes, h.boxes, hor_width, params, cand)
        out.append((frame, [(int(t.ids[a]), int(h.ids[b])) for a, b in res.pairs]))
    return out


def associate_frames(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    hor_width: float,
    params: SpatialParams | None = None,
    camera_rows: Iterable[int] | None = None,
    workers: int = 1,
    progress: Progress | None = None,
) -> dict[int, list[tuple[int, int]]]:
    """Frame-level association (Sec. 3.2) of every frame both views have, as row pairs.

    ``camera_rows`` are the top rows of the camera wearer (O given on frames that have one,
    searched elsewhere). The result does not depend on ``workers``.
    """
    params = params or SpatialParams()
    cams = set(int(r) for r in camera_rows) if camera_rows is not None else set()
    items = []
    for f in sorted(set(top) & set(hor)):
        t, h = top[f], hor[f]
        if len(t) == 0 or len(h) == 0:
            continue
        cand = np.flatnonzero(np.isin(t.ids, list(cams))) if cams else np.zeros(0, np.intp)
        items.append((f, t, h, cand if cand.size else None))
    chunk = 25
    chunks = [(items[k:k + chunk], hor_width, params) for k in range(0, len(items), chunk)]
    out: dict[int, list[tuple[int, int]]] = {}
    if workers > 1 and len(chunks) > 1:
        # Forked (the platform default, as before) workers that ignore Ctrl-C; an interrupt
        # stops them at once instead of waiting for the queued chunks (worker_pool).
        with worker_pool(workers, start_method=None) as pool:
            results = pool.map(_associate_chunk, chunks)
            done = progress(results, len(chunks), "associate") if progress else results
            for res in done:
                out.update(res)
    else:
        done = progress(chunks, len(chunks), "associate") if progress else chunks
        for c in done:
            out.update(_associate_chunk(c))
    return out


def _window_weights(
    top_t: list[Tracklet], top_u: list[Tracklet], hor_u: list[Tracklet], hor_t: list[Tracklet],
    frame_pairs: Mapping[int, list[tuple[int, int]]], weights: TrackWeights,
    app: tuple[TrackletAppearance, ...] | None = None, time_appearance: str = "network",
    learned: LearnedEvidence | None = None, learned_rule: str = LEARNED_RULES[0],
    learned_share: float = 1.0, cross_cost: CostOfDescriptors | None = None,
    cross_appearance: bool = True,
) -> list[np.ndarray]:
    """The four weight matrices of a window (clusters 0..3 = top t, top t+1, hor t+1, hor t);
    ``app``: the appearance of the same four tracklet lists, or None (boxes only); ``learned``:
    the learned matcher's evidence for the cross-view spatial term, or None (Eq. 13 on
    ``frame_pairs``); ``cross_cost``: the cross-view appearance cost (None: ``|a - b| / 2``);
    ``cross_appearance``: False leaves the network out of the cross-view weights (Eq. 17 on its
    spatial term alone), the over-time terms keep it."""
    a_time = a_cross = (None, None)
    if app is not None:
        a_tt, a_tu, a_hu, a_ht = app
        network = a_tt.descriptors is not None
        over = (descriptor_similarity if network and time_appearance == "network"
                else colour_similarity)
        a_time = (over(a_tt, a_tu), over(a_ht, a_hu))
        if network and cross_appearance:
            a_cross = (descriptor_similarity(a_tu, a_hu, cross_cost, cross=True),
                       descriptor_similarity(a_tt, a_ht, cross_cost, cross=True))
    def cross(top: list[Tracklet], hor: list[Tracklet]) -> np.ndarray:
        if learned is None:
            return spatial_similarity(top, hor, frame_pairs)
        out = learned_similarity(top, hor, learned.costs, learned.gamma, learned_rule)
        if learned_share < 1:
            out = learned_share * out + (1 - learned_share) * spatial_similarity(
                top, hor, frame_pairs)
        return out

    c0 = combine_over_time(motion_similarity(top_t, top_u, weights.sigma), a_time[0], weights)
    c1 = combine_cross_view(cross(top_u, hor_u), a_cross[0], weights)
    c2 = combine_over_time(motion_similarity(hor_t, hor_u, weights.sigma), a_time[1],
                           weights).T
    c3 = combine_cross_view(cross(top_t, hor_t), a_cross[1], weights).T
    return [c0, c1, c2, c3]


def _tracklets_with_images(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    clips: list[np.ndarray],
    config: TrackConfig,
    images: TrackImages,
    progress: Progress | None,
) -> tuple[list[list[Tracklet]], list[list[Tracklet]], list[tuple[TrackletAppearance, ...]]]:
    """Tracklets and their appearance, clip by clip (each clip's images read once, then
    dropped): top by IoU, horizontal by IoU and colour (Sec. 4.1). When no colour term is used
    in the top view (a network gives the over-time term), only the top frames that hold a
    tracklet's middle box are read, and no top-view histogram is computed."""
    top_colour = images.embed is None or config.time_appearance == "colour"
    top_tr, hor_tr, app = [], [], []
    steps = list(enumerate(clips))
    for k, c in progress(steps, len(steps), "images") if progress else steps:
        out = []
        for frames, source, is_hor in ((top, images.top, False), (hor, images.hor, True)):
            boxed = [f for f in c.tolist() if f in frames and len(frames[f])]
            if is_hor or top_colour:
                imgs = {f: source.get(f) for f in boxed}
                hist = frame_histograms(frames, imgs)
                tracklets = clip_tracklets(frames, c, k, config.min_iou, config.max_gap,
                                           hist if is_hor else None, config.min_colour)
            else:
                hist = None
                tracklets = clip_tracklets(frames, c, k, config.min_iou, config.max_gap)
                middle = sorted({int(t.frames[len(t) // 2]) for t in tracklets})
                imgs = {f: source.get(f) for f in middle}
            out.append((tracklets, clip_appearance(tracklets, frames, hist, imgs,
                                                   images.embed, images.cross_embed)))
        top_tr.append(out[0][0])
        hor_tr.append(out[1][0])
        app.append((out[0][1], out[1][1]))
    return top_tr, hor_tr, app


def _check_has_boxes(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes]) -> None:
    """Refuse a view without any box."""
    for name, view in (("top", top), ("horizontal", hor)):
        if not any(len(rec) for rec in view.values()):
            raise ValueError(f"the {name} view has no boxes: nothing to track")


def _clip_tracklets(
    top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes], clips: list[np.ndarray],
    config: TrackConfig, images: TrackImages | None, progress: Progress | None,
) -> tuple[list, list, list[tuple[TrackletAppearance, ...]] | None]:
    """Each clip's tracklets of both views and, with images, their appearance (else None)."""
    if images is None:
        return (view_tracklets(top, clips, config.min_iou, config.max_gap),
                view_tracklets(hor, clips, config.min_iou, config.max_gap), None)
    return _tracklets_with_images(top, hor, clips, config, images, progress)


def _judged_cross_appearance(
    top_tr: list, hor_tr: list, app: list[tuple[TrackletAppearance, ...]], images: TrackImages,
    learned: LearnedEvidence, checked: list[AppearanceCheck] | None,
) -> bool:
    """Whether the cross-view appearance cue passes its check on the clips' own box-only
    pseudo-matched tracklets (the check goes to ``checked`` when given)."""
    result = check_tracklet_appearance(
        [(top_tr[k], hor_tr[k],
          1.0 - descriptor_similarity(app[k][0], app[k][1], images.cross_cost, cross=True))
         for k in range(len(app))], learned.costs, learned.gamma)
    if checked is not None:
        checked.append(result)
    return result.trusted


def _add_empty_clip(top_tr: list, hor_tr: list,
                    app: list[tuple[TrackletAppearance, ...]] | None,
                    images: TrackImages | None) -> None:
    """Append an empty clip (no tracklets, and their empty appearance), so that a single
    clip makes one window."""
    top_tr.append([])
    hor_tr.append([])
    if app is not None:
        app.append(tuple(clip_appearance([], {}, {}, {}, images.embed, images.cross_embed)
                         for _ in range(2)))


def _solve_windows(
    top_tr: list, hor_tr: list, app: list[tuple[TrackletAppearance, ...]] | None,
    frame_pairs: Mapping[int, list[tuple[int, int]]], config: TrackConfig,
    learned: LearnedEvidence | None, images: TrackImages | None, cross_appearance: bool,
    n_windows: int, progress: Progress | None,
) -> list[ClusterSolution]:
    """The four-cluster solution of each of the ``n_windows`` windows of two consecutive
    clips."""
    solutions: list[ClusterSolution] = []
    steps = range(n_windows)
    for t in progress(steps, n_windows, "track") if progress else steps:
        window_app = None if app is None else (app[t][0], app[t + 1][0], app[t + 1][1],
                                               app[t][1])
        w = _window_weights(top_tr[t], top_tr[t + 1], hor_tr[t + 1], hor_tr[t], frame_pairs,
                            config.weights, window_app, config.time_appearance, learned,
                            config.learned_rule, config.learned_share,
                            None if images is None else images.cross_cost, cross_appearance)
        if config.solver == "mip":
            solutions.append(solve_four_clusters(w, config.weights.c0, config.time_limit))
        else:
            solutions.append(spectral_solution(w, config.weights.c0, config.seed + t))
    return solutions


def track_pair(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    hor_width: float,
    params: SpatialParams | None = None,
    config: TrackConfig | None = None,
    camera_rows: Iterable[int] | None = None,
    workers: int = 1,
    progress: Progress | None = None,
    frame_pairs: Mapping[int, list[tuple[int, int]]] | None = None,
    images: TrackImages | None = None,
    learned: LearnedEvidence | None = None,
    appearance_check: bool = False,
    checked: list[AppearanceCheck] | None = None,
) -> TrackResult:
    """Track the people of a top/horizontal sequence pair with one id across views (Alg. 1).

    Args:
        top, hor: ``{frame: FrameBoxes}``, ``ids`` = detection rows, unique within a view.
        hor_width: width of the horizontal image (pixels).
        params: spatial-distribution parameters of the frame association.
        config: tracking settings.
        camera_rows: top rows of the camera wearer, when known.
        workers: processes for the frame association.
        progress: optional progress wrapper.
        frame_pairs: a frame association computed earlier (skips step 1).
        images: the images of both views (and the appearance network): the appearance terms
            of Sec. 3.3.2, 3.4.1 and 4.1; without them the weights come from the boxes alone.
        learned: the learned matcher's evidence (:func:`learned_frame_evidence`): the spatial
            term of the cross-view weights comes from its costs (``config.learned_rule``) and
            the frame association is its assignment (step 1 skipped; ``frame_pairs``,
            ``params`` and ``camera_rows`` unused, unless ``config.learned_share < 1`` mixes
            in the handcrafted Eq. 13). None: the handcrafted Eq. 13.
        appearance_check: with the network's images, ``learned`` and a cross-view appearance
            term (``config.weights.w1`` < 1), judge that cue on the clips' own box-only
            pseudo-matched tracklets
            (:func:`~xvmatch.inference.matching.appearance_check.check_tracklet_appearance`) and,
            when it fails, leave it out of the cross-view weights (the over-time terms keep it).
        checked: if given, receives that :class:`~xvmatch.inference.matching.appearance_check.
            AppearanceCheck` (nothing when there was nothing to judge).

    Only the frames present are visited (:func:`split_clips`), so a gap of any length between
    frames costs nothing.

    Raises:
        ValueError: a view without any box.
    """
    config = config or TrackConfig()
    _check_has_boxes(top, hor)
    if learned is not None and config.learned_share >= 1:
        frame_pairs = learned.frame_pairs
    elif frame_pairs is None:
        frame_pairs = associate_frames(top, hor, hor_width, params, camera_rows, workers,
                                       progress)
    clips = split_clips(sorted(set(top) | set(hor)), config.clip_length)
    top_tr, hor_tr, app = _clip_tracklets(top, hor, clips, config, images, progress)
    cross_appearance = True
    if (appearance_check and app is not None and images.embed is not None
            and learned is not None and config.weights.w1 < 1):  # w1 1: no cue to judge
        cross_appearance = _judged_cross_appearance(top_tr, hor_tr, app, images, learned,
                                                    checked)
    if len(clips) == 1:
        _add_empty_clip(top_tr, hor_tr, app, images)
    n_windows = max(1, len(clips) - 1)
    solutions = _solve_windows(top_tr, hor_tr, app, frame_pairs, config, learned, images,
                               cross_appearance, n_windows, progress)
    if len(clips) == 1:
        top_tr, hor_tr = top_tr[:1], hor_tr[:1]
    stitched = stitch_windows(top_tr, hor_tr, [s.edges for s in solutions])
    return TrackResult(
        top_rows=stitched.top_rows,
        hor_rows=stitched.hor_rows,
        frame_pairs=dict(frame_pairs),
        n_windows=n_windows,
        n_fallback=sum(s.status == "fallback" for s in solutions),
        max_loops=max((s.loops for s in solutions), default=0),
    )
