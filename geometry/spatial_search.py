"""Search over the camera location O and orientation theta (CVMHAT paper, Section 3.2.4).

Frame level: every (O, theta) hypothesis is scored with Phi (Eq. 12) and the best one gives the
association. Over a video: the reduced search limits theta to a damped window S_t around the
previous orientation and follows O with the top view's own track ids. The same machinery
estimates a temporal offset between two unsynchronised videos by sliding clips (Fig. 5).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.geometry import kernel_choice
from xvmatch.geometry.spatial_matching import (
    SpatialParams,
    cost_lower_bound,
    match_vector_sets,
)
from xvmatch.geometry.spatial_vectors import (
    TopHypotheses,
    box_centres,
    horizontal_vectors,
    top_geometry,
    top_hypotheses,
)

__all__ = [
    "AUTO_MAX_OFFSET",
    "MIN_AGREEING_CLIPS",
    "SEARCH_MODES",
    "FollowPolicy",
    "FrameAssociation",
    "OffsetEstimate",
    "associate_frame",
    "associate_sequence",
    "best_per_candidate",
    "clip_cost_curves",
    "clip_starts",
    "estimate_offset",
    "hypothesis_vectors",
    "judge_offset",
    "rank_hypotheses",
    "search_window",
]

SEARCH_MODES = ("exhaustive", "reduced", "follow")


@dataclass(frozen=True)
class FrameAssociation:
    """Best hypothesis of one frame.

    Attributes:
        pairs: ``(P, 2)`` indices (top box, horizontal box) of the associated people, sorted.
        camera: index of the top box taken as the camera location O; -1 if none was scored.
        theta: view direction of the horizontal camera in the top image (radians, CCW on screen).
        cost: Phi of Eq. 12 for the best hypothesis (+inf when nothing could be matched).
        scale: the factor mu of the best hypothesis.
    """

    pairs: np.ndarray
    camera: int
    theta: float
    cost: float
    scale: float


_EMPTY = FrameAssociation(np.zeros((0, 2), dtype=np.intp), -1, 0.0, math.inf, 1.0)


def search_window(
    center: float, step_index: int, params: SpatialParams
) -> np.ndarray:
    """Orientations of the reduced search on the ``step_index``-th frame (1-based).

    S_t = 2 pi (r^(t-1) + u) / (1 + u) (Sec. 3.2.4), sampled every dtheta around ``center``;
    the first frame covers the whole circle.
    """
    step = math.radians(params.dtheta_deg)
    full = max(1, round(2.0 * math.pi / step))
    r, u = params.damping_r, params.damping_u
    span = 2.0 * math.pi * (r ** (step_index - 1) + u) / (1.0 + u)
    n = min(full, max(1, math.ceil(span / step - 1e-9)))
    return center + step * (np.arange(n) - n // 2)


def full_circle(params: SpatialParams) -> np.ndarray:
    """Orientations of the exhaustive search: [0, 2 pi) every dtheta."""
    step = math.radians(params.dtheta_deg)
    return step * np.arange(max(1, round(2.0 * math.pi / step)))


def _prepare(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    candidates: Iterable[int] | None,
    thetas: np.ndarray | None,
    params: SpatialParams,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    top_boxes = np.asarray(top_boxes, dtype=float).reshape(-1, 4)
    hor_boxes = np.asarray(hor_boxes, dtype=float).reshape(-1, 4)
    cand = (
        np.arange(top_boxes.shape[0])
        if candidates is None
        else np.asarray(list(candidates), dtype=np.intp)
    )
    thetas = full_circle(params) if thetas is None else np.asarray(thetas, dtype=float).ravel()
    return top_boxes, hor_boxes, cand, thetas


HYPOTHESIS_BLOCK = 1 << 23
"""(hypothesis, person) entries per block of candidate camera locations: a crowd is searched in
blocks of candidates, so that 1,000 people in a frame stay within about 1 GiB (an ordinary
frame, tens of people, is one block)."""


def _candidate_blocks(
    top_boxes: np.ndarray, cand: np.ndarray, thetas: np.ndarray, params: SpatialParams
) -> Iterator[tuple[int, TopHypotheses]]:
    """The hypotheses of consecutive blocks of candidates, with the index of each block's first
    hypothesis among all (candidate-major: b = c T + t)."""
    centres = box_centres(top_boxes)
    step = max(1, HYPOTHESIS_BLOCK // max(1, thetas.shape[0] * centres.shape[0]))
    for lo in range(0, cand.shape[0], step):
        geometry = top_geometry(centres, cand[lo:lo + step], math.radians(params.tau_deg))
        yield lo * thetas.shape[0], top_hypotheses(geometry, thetas,
                                                   math.radians(params.fov_deg))


def _association(found: tuple[int, float, np.ndarray, float, np.ndarray], cand: np.ndarray,
                 thetas: np.ndarray, hor_order: np.ndarray) -> FrameAssociation:
    """The :class:`FrameAssociation` of one scored hypothesis (index b = c T + t, cost, pairs
    mask over the sorted vectors, scale, top person of each entry), in input box order."""
    index, cost, pairs_mask, scale, top_index = found
    rows, cols = np.nonzero(pairs_mask)
    pairs = np.stack([top_index[rows], hor_order[cols]], axis=1)
    pairs = pairs[np.argsort(pairs[:, 0], kind="stable")]
    n_theta = thetas.shape[0]
    return FrameAssociation(pairs=pairs, camera=int(cand[index // n_theta]),
                            theta=float(np.mod(thetas[index % n_theta], 2.0 * math.pi)),
                            cost=cost, scale=scale)


def rank_hypotheses(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_width: float,
    params: SpatialParams | None = None,
    candidates: Iterable[int] | None = None,
    thetas: np.ndarray | None = None,
    k: int = 1,
) -> list[FrameAssociation]:
    """The ``k`` lowest-Phi (O, theta) hypotheses of one frame pair, best first (Sec. 3.2.4).

    Exact (the same branch and bound as :func:`associate_frame`, pruning against the k-th best
    cost); ties keep the lower hypothesis index (candidates, then orientations, in the given
    order). Fewer than ``k`` are returned when fewer have a finite cost.

    Args:
        top_boxes, hor_boxes, hor_width, params, candidates, thetas: as in
            :func:`associate_frame`.
        k: number of hypotheses to return (>= 1).
    """
    if k < 1:
        raise ValueError(f"k must be >= 1, got {k}")
    params = params or SpatialParams()
    top_boxes, hor_boxes, cand, thetas = _prepare(
        top_boxes, hor_boxes, candidates, thetas, params
    )
    if cand.size == 0 or hor_boxes.shape[0] == 0 or top_boxes.shape[0] < 2:
        return []
    hor, hor_order = horizontal_vectors(hor_boxes, hor_width)
    found = []
    for start, hypotheses in _candidate_blocks(top_boxes, cand, thetas, params):
        found += [(start + i, *rest) for i, *rest in _ranked(hypotheses, hor, params, k)]
    found = sorted(found, key=lambda item: (item[1], item[0]))[:k]
    return [_association(f, cand, thetas, hor_order) for f in found]


def associate_frame(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_width: float,
    params: SpatialParams | None = None,
    candidates: Iterable[int] | None = None,
    thetas: np.ndarray | None = None,
) -> FrameAssociation:
    """Associate the people of one top/horizontal frame pair (Sec. 3.2).

    Args:
        top_boxes: ``(M, 4)`` top-view boxes x, y, w, h (pixels).
        hor_boxes: ``(Q, 4)`` horizontal-view boxes.
        hor_width: width W of the horizontal image (pixels), Eq. 9.
        params: association parameters; paper defaults when None.
        candidates: indices of top boxes that may be the camera location O; every box when None
            (the exhaustive search), a single index when O is given.
        thetas: orientations to try (radians), the same for every candidate; the full circle
            every dtheta when None.

    Returns:
        The best :class:`FrameAssociation` (lowest Phi; the first one on ties, candidates in the
        given order and orientations in the given order); an empty one (camera -1, cost +inf)
        when nothing can be matched.
    """
    ranked = rank_hypotheses(top_boxes, hor_boxes, hor_width, params, candidates, thetas, k=1)
    return ranked[0] if ranked else _EMPTY


def best_per_candidate(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_width: float,
    params: SpatialParams | None = None,
    candidates: Iterable[int] | None = None,
    thetas: np.ndarray | None = None,
    keep: int | None = None,
) -> list[FrameAssociation]:
    """The lowest-Phi orientation of every candidate camera location O, in one search.

    The same result as :func:`rank_hypotheses` with ``k=1`` called for each candidate on its
    own (ties keep the lower orientation index; costs equal to rounding), at a fraction of the
    work: one batch of hypotheses for all candidates, pruned by a branch and bound whose
    threshold is each candidate's own best cost so far, and, with ``keep``, the ``keep``-th
    lowest of those (a candidate that cannot enter the ``keep`` best needs no exact answer).

    Args:
        top_boxes, hor_boxes, hor_width, params, candidates, thetas: as in
            :func:`associate_frame`.
        keep: only the ``keep`` lowest-cost candidates are wanted (None: all).

    Returns:
        One :class:`FrameAssociation` per candidate with a finite cost, in candidate order;
        with ``keep``, only the ``keep`` lowest (cost, then candidate order), which are exact.
    """
    params = params or SpatialParams()
    top_boxes, hor_boxes, cand, thetas = _prepare(
        top_boxes, hor_boxes, candidates, thetas, params
    )
    if cand.size == 0 or hor_boxes.shape[0] == 0 or top_boxes.shape[0] < 2:
        return []
    hor, hor_order = horizontal_vectors(hor_boxes, hor_width)
    found = []
    for start, hypotheses in _candidate_blocks(top_boxes, cand, thetas, params):
        found += [(start + i, *rest) for i, *rest in _best_per_group(hypotheses, hor, params,
                                                                      keep)]
    if keep is not None:  # each block's keep best are exact, so the keep best of all are too
        found = sorted(sorted(found, key=lambda b: (b[1], b[0]))[:keep], key=lambda b: b[0])
    return [_association(f, cand, thetas, hor_order) for f in found]


def _best_per_group(
    hypotheses: TopHypotheses,
    hor: np.ndarray,
    params: SpatialParams,
    keep: int | None = None,
    first_chunk: int = 256,
) -> list[tuple[int, float, np.ndarray, float, np.ndarray]]:
    """The lowest-Phi hypothesis of each candidate (group of ``n_theta`` consecutive rows),
    exactly, by best-first branch and bound against each group's own best cost (and the
    ``keep``-th lowest group best, when only the ``keep`` best groups are wanted).

    Returns:
        Per group with a finite cost, in group order (only the ``keep`` lowest with ``keep``):
        (hypothesis index, cost, pairs mask, scale, top person of each entry).
    """
    n = hypotheses.x.shape[0]
    group = np.arange(n) // hypotheses.n_theta
    n_groups = int(group[-1]) + 1 if n else 0
    hor_x = hor[:, 0]
    best_cost = np.full(n_groups, np.inf)
    best: list[tuple[int, float, np.ndarray, float, np.ndarray] | None] = [None] * n_groups

    def score(idx: np.ndarray) -> None:
        vectors = hypotheses.take(idx)
        result = match_vector_sets(vectors.x, vectors.y, vectors.count, hor, params)
        rows = np.flatnonzero(np.isfinite(result.cost))
        if rows.size == 0:
            return
        # The batch's best row of each group (lowest cost, then lowest index), then a merge
        # with the groups' bests so far: a loop over groups, not over rows.
        groups, costs = group[idx[rows]], result.cost[rows]
        order = np.lexsort((idx[rows], costs, groups))
        _, first = np.unique(groups[order], return_index=True)
        for r in rows[order[first]]:
            i, c = int(idx[r]), float(result.cost[r])
            g = group[i]
            held = best[g]
            if c < best_cost[g] or (c == best_cost[g] and held is not None and i < held[0]):
                best_cost[g] = c
                best[g] = (i, c, result.pairs[r], float(result.scale[r]), vectors.index[r])

    def limits(groups: np.ndarray) -> np.ndarray:
        """What a hypothesis of each group must not exceed to matter."""
        if keep is None or keep >= n_groups:
            return best_cost[groups]
        kth = float(np.partition(best_cost, keep - 1)[keep - 1])
        return np.minimum(best_cost[groups], kth)

    loose = cost_lower_bound(hypotheses.x, hypotheses.count, hor_x, params, tight=False)
    # Seed: each group's most promising hypothesis under the loose bound.
    order = np.lexsort((np.arange(n), loose))
    _, first = np.unique(group[order], return_index=True)
    seed = np.sort(order[first][np.isfinite(loose[order[first]])])
    if seed.size == 0:
        return []
    score(seed)
    done = np.zeros(n, dtype=bool)
    done[seed] = True
    rest = np.flatnonzero(~done & (loose <= limits(group)))
    tight = cost_lower_bound(hypotheses.x[rest], hypotheses.count[rest], hor_x, params)
    alive = tight <= limits(group[rest])
    rest, tight = rest[alive], tight[alive]
    order = np.argsort(tight, kind="stable")
    rest, tight = rest[order], tight[order]
    start, chunk = 0, first_chunk
    while start < rest.shape[0] and tight[start] <= limits(group).max():
        sel = slice(start, start + chunk)
        idx = rest[sel][tight[sel] <= limits(group[rest[sel]])]
        start += chunk
        chunk *= 2
        if idx.size:
            score(np.sort(idx))
    found = [b for b in best if b is not None]
    if keep is not None:
        found = sorted(found, key=lambda b: (b[1], b[0]))[:keep]
        found.sort(key=lambda b: b[0])
    return found


def hypothesis_vectors(
    top_boxes: np.ndarray,
    camera: int,
    theta: float,
    params: SpatialParams | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Top-view vectors of every person under one hypothesis (O = ``camera``, ``theta``).

    Returns:
        ``(x, y, in_view, visible)``, each ``(M,)`` in the order of ``top_boxes``: x_top (Eq. 7,
        +inf outside the field of view), the depth y_top = |OP| cos(delta) (pixels; also given
        outside the view), whether the person is in the field of view and not occluded, and
        whether it is not occluded (tau) and not O itself.
    """
    params = params or SpatialParams()
    top_boxes = np.asarray(top_boxes, dtype=float).reshape(-1, 4)
    geometry = top_geometry(box_centres(top_boxes), [camera], math.radians(params.tau_deg))
    hyp = top_hypotheses(geometry, np.array([theta]), math.radians(params.fov_deg))
    x = hyp.x[0]
    y = geometry.dist[0] * np.cos(hyp.delta[0])
    return x, y, np.isfinite(x), geometry.visible[0]


def _ranked(
    hypotheses: TopHypotheses,
    hor: np.ndarray,
    params: SpatialParams,
    k: int,
    first_chunk: int = 256,
) -> list[tuple[int, float, np.ndarray, float, np.ndarray]]:
    """The k lowest-Phi hypotheses by best-first branch and bound, exactly.

    Hypotheses are scored in order of their lower bound (:func:`cost_lower_bound`), in chunks of
    doubling size, until the next bound exceeds the k-th best cost found: the result is the same
    as scoring every hypothesis (lowest Phi, then lowest hypothesis index on ties), at a few
    percent of the work.

    Returns:
        Up to k tuples (hypothesis index, cost, pairs mask (K, Q), scale, top person of each of
        the K entries), best first; only finite costs.
    """
    hor_x = hor[:, 0]
    loose = cost_lower_bound(hypotheses.x, hypotheses.count, hor_x, params, tight=False)
    pool: list[tuple[float, int, np.ndarray, float, np.ndarray]] = []

    def threshold() -> float:
        return pool[-1][0] if len(pool) >= k else math.inf

    def score(idx: np.ndarray) -> None:
        vectors = hypotheses.take(idx)
        result = match_vector_sets(vectors.x, vectors.y, vectors.count, hor, params)
        limit = threshold()
        for r in np.flatnonzero(np.isfinite(result.cost) & (result.cost <= limit)):
            pool.append(
                (
                    float(result.cost[r]),
                    int(idx[r]),
                    result.pairs[r],
                    float(result.scale[r]),
                    vectors.index[r],
                )
            )
        pool.sort(key=lambda item: (item[0], item[1]))
        del pool[k:]

    # Seed the pool with the most promising hypotheses under the loose bound, then bound the
    # survivors tightly and score them best-first in chunks of doubling size.
    seed = np.argsort(loose, kind="stable")[:first_chunk]
    seed = np.sort(seed[np.isfinite(loose[seed])])
    if seed.size == 0:
        return []
    score(seed)
    done = np.zeros(loose.shape[0], dtype=bool)
    done[seed] = True
    rest = np.flatnonzero(~done & (loose <= threshold()))
    tight = cost_lower_bound(hypotheses.x[rest], hypotheses.count[rest], hor_x, params)
    order = np.argsort(tight, kind="stable")
    rest, tight = rest[order], tight[order]
    start, chunk = 0, first_chunk
    while start < rest.shape[0] and tight[start] <= threshold():
        sel = slice(start, start + chunk)
        idx = np.sort(rest[sel][tight[sel] <= threshold()])
        start += chunk
        chunk *= 2
        score(idx)
    return [(i, c, p, s, t) for c, i, p, s, t in pool]


@dataclass(frozen=True)
class FollowPolicy:
    """How the ``follow`` search finds the camera location O without a given camera id.

    One frame's exhaustive search can pick the wrong person as O, and following it would keep
    the mistake, so O is chosen by a vote: the first ``init_frames`` frames and then every
    ``check_every``-th frame run the exhaustive search, and the top-view track id that won most of
    the last ``votes`` checks is followed (the damped theta window restarts when it changes).

    Attributes:
        init_frames: exhaustive checks at the start of the sequence.
        check_every: later, one exhaustive check every this many frames.
        votes: how many recent checks vote.
    """

    init_frames: int = 10
    check_every: int = 30
    votes: int = 10

    def __post_init__(self) -> None:
        if self.init_frames < 1 or self.check_every < 1 or self.votes < 1:
            raise ValueError(
                f"FollowPolicy needs init_frames, check_every and votes >= 1, got {self}"
            )


class _FrameLike:
    """Structural type of a frame record: ``ids (N,)`` and ``boxes (N, 4)``."""

    ids: np.ndarray
    boxes: np.ndarray


def _ids_to_index(ids: np.ndarray, wanted: int) -> list[int]:
    return [int(k) for k in np.flatnonzero(np.asarray(ids) == wanted)]


def associate_sequence(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    hor_width: float,
    params: SpatialParams | None = None,
    search: str = "exhaustive",
    camera_id: int | None = None,
    frames: Iterable[int] | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    follow: FollowPolicy = FollowPolicy(),
) -> dict[int, list[tuple[int, int]]]:
    """Associate every frame of a sequence pair; returns ``{frame: [(top_id, hor_id), ...]}``.

    Ids are only used to report pairs, to locate O when ``camera_id`` is given, and (in the
    ``follow`` mode) to follow O with the top view's own track ids; they are never compared
    across views.

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` (e.g. ``FrameBoxes``).
        hor_width: width of the horizontal image (pixels).
        params: association parameters.
        search: ``exhaustive`` (every O, every theta, each frame on its own), ``reduced``
            (every O, theta within the damped window S_t around the previous orientation) or
            ``follow`` (reduced theta, and O followed by its top-view track id: the id that won
            most of the recent exhaustive checks, see :class:`FollowPolicy`).
        camera_id: top-view id of the camera wearer (O given); frames where it is absent fall
            back to searching every O.
        frames: frames to process (default: the union of both views' frames, ascending).
        progress: optional wrapper around the frame iterator (e.g. a progress bar).
        follow: how the ``follow`` mode finds O when ``camera_id`` is not given.
    """
    if search not in SEARCH_MODES:
        raise ValueError(f"search must be one of {', '.join(SEARCH_MODES)}; got {search!r}")
    params = params or SpatialParams()
    order = sorted(set(top) | set(hor)) if frames is None else sorted(set(frames))
    circle = full_circle(params)
    voting = search == "follow" and camera_id is None
    votes: deque[int] = deque(maxlen=follow.votes)
    followed: int | None = None
    last_theta = 0.0
    step_index = 0
    checks = 0
    out: dict[int, list[tuple[int, int]]] = {}
    # A long run pays for loading the compiled kernels even where its calls are small.
    with kernel_choice.planned(len(order)):
        for frame in progress(order) if progress else order:
            t_rec, h_rec = top.get(frame), hor.get(frame)
            if t_rec is None or h_rec is None or len(t_rec.ids) == 0 or len(h_rec.ids) == 0:
                out[frame] = []
                continue
            step_index += 1
            if voting and (checks < follow.init_frames or step_index % follow.check_every == 0):
                # Exhaustive check: vote for the winning O; follow the most voted top-view id.
                checks += 1
                result = associate_frame(t_rec.boxes, h_rec.boxes, hor_width, params)
                if result.camera >= 0:
                    votes.append(int(t_rec.ids[result.camera]))
                    leader = Counter(votes).most_common(1)[0][0]
                    if leader != followed:
                        followed, step_index = leader, 1
                    if int(t_rec.ids[result.camera]) != followed:
                        own = _ids_to_index(t_rec.ids, followed)
                        if own:
                            result = associate_frame(
                                t_rec.boxes, h_rec.boxes, hor_width, params, own, circle
                            )
            else:
                candidates: list[int] | None = None
                if camera_id is not None:
                    candidates = _ids_to_index(t_rec.ids, camera_id) or None
                elif search == "follow" and followed is not None:
                    candidates = _ids_to_index(t_rec.ids, followed) or None
                thetas = (circle if search == "exhaustive"
                          else search_window(last_theta, step_index, params))
                result = associate_frame(
                    t_rec.boxes, h_rec.boxes, hor_width, params, candidates, thetas
                )
            if result.camera >= 0:
                last_theta = result.theta
                if not voting:
                    followed = int(t_rec.ids[result.camera])
            out[frame] = [(int(t_rec.ids[a]), int(h_rec.ids[b])) for a, b in result.pairs]
    return out


# Defaults of estimate_offset: precision of the estimate in frames (at 30 fps), and the paired t
# statistic the clips must reach before a shift is applied (calibrated on simulated scenes).
OFFSET_TOLERANCE = 5
MIN_OFFSET_EVIDENCE = 2.0
OFFSET_ALPHA = 0.05
MIN_AGREEING_CLIPS = 2
"""Fewest clips whose own minima must agree (within the tolerance) before an offset is applied:
one clip's minimum cannot be told from a noise dip, so a single clip is reported, never applied."""
AUTO_MAX_OFFSET = 60
"""Largest |offset| (frames) that ``associate --offset auto`` and ``fit-geometry`` consider (2 s
at 30 fps; ``estimate_offset`` itself defaults to the paper's 15)."""


@dataclass(frozen=True)
class OffsetEstimate:
    """Result of the sliding-clip synchronisation (Fig. 5).

    Attributes:
        offset: frames to add to a horizontal frame number to get the matching top frame (the
            minimum of the mean curve).
        offsets: ``(N,)`` offsets tried.
        costs: ``(N,)`` mean best Phi of each offset's clip (+inf where nothing matched).
        clip_costs: ``(K, N)`` each clip's own curve (normalised by its median when K > 1;
            rows of +inf for clips that never matched).
        applied: the offset to re-time the videos by: ``offset`` when ``status`` is
            ``"applied"``, else 0 (keep the files' timing).
        status: ``"applied"``; ``"within_tolerance"`` (``|offset| <= tolerance``: as close to the
            files' timing as the estimate can tell); or ``"unsupported"`` (fewer than
            ``min_agree`` clips agree, ``evidence`` or ``chance`` short of the thresholds, or no
            clip could be scored). So one clip, even when it is all that was asked for, never
            gets an offset applied: it is reported for the user to pass on.
        support: fraction of the clips that matched whose own minimum lies within
            ``tolerance`` frames of ``offset`` (1 for a single clip).
        chance: probability that at least that many clips agree by chance, had their minima
            fallen anywhere in the range (binomial tail; 1 for a single clip).
        evidence: paired t statistic of the clips' preference for ``offset`` over 0 (mean over
            clips of cost(0) - cost(offset), over its standard error); 0 when ``offset`` is 0
            or fewer than two clips could be compared.
    """

    offset: int
    offsets: np.ndarray
    costs: np.ndarray
    clip_costs: np.ndarray
    applied: int = 0
    status: str = "applied"
    support: float = 1.0
    chance: float = 1.0
    evidence: float = 0.0


def _paired_evidence(clip_costs: np.ndarray, at: int, zero: int) -> float:
    """t statistic of ``clip_costs[:, zero] - clip_costs[:, at]`` over the clips where both are
    finite (0 with fewer than two; +inf when every clip gains the same positive amount)."""
    d = clip_costs[:, zero] - clip_costs[:, at]
    d = d[np.isfinite(d)]
    if at == zero or d.size < 2:
        return 0.0
    spread, mean = float(np.std(d, ddof=1)), float(d.mean())
    if spread <= 1e-9 * abs(mean) or spread == 0.0:  # every clip gains the same (rounding aside)
        return math.inf if mean > 0 else 0.0
    return mean / (spread / math.sqrt(d.size))


def _clip_cost(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    clip: list[int],
    offset: int,
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None,
) -> float:
    """Mean best Phi of one clip at one offset; +inf unless most of its frames match."""
    values = []
    for f in clip:
        t_rec = top.get(f + offset)
        if t_rec is None or len(t_rec.ids) == 0:
            continue
        cand = (_ids_to_index(t_rec.ids, camera_id) or None) if camera_id is not None else None
        values.append(associate_frame(t_rec.boxes, hor[f].boxes, hor_width, params, cand).cost)
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite and 2 * len(finite) >= len(clip) else math.inf


def _clip_curve(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    clip: list[int],
    offsets: list[int],
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None,
) -> list[float]:
    """:func:`_clip_cost` of one clip at each of ``offsets`` (one task of the process pool)."""
    return [_clip_cost(top, hor, clip, o, hor_width, params, camera_id) for o in offsets]


def _curve_tasks(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    clips: list[list[int]],
    offsets: np.ndarray,
    pieces: int,
) -> list[tuple[int, list[int], tuple]]:
    """Split the (clip, offset) grid into tasks of contiguous offsets, each carrying only the
    frames it reads, so that a task pickles in kilobytes whatever the video's length."""
    tasks = []
    for k, clip in enumerate(clips):
        for chunk in np.array_split(offsets, min(pieces, offsets.size)):
            lo, hi = int(chunk[0]), int(chunk[-1])
            wanted = {f + o for f in clip for o in range(lo, hi + 1)}
            sub_top = {g: top[g] for g in sorted(wanted) if g in top}
            sub_hor = {f: hor[f] for f in clip}
            tasks.append((k, [int(o) for o in chunk], (sub_top, sub_hor, clip)))
    return tasks


def clip_cost_curves(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    clips: list[list[int]],
    offsets: np.ndarray,
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None = None,
    workers: int = 1,
) -> np.ndarray:
    """``(K, N)`` raw cost curves: the mean best Phi of each clip (horizontal frame numbers)
    at each offset (Eq. 12 averaged over the clip, Fig. 5); +inf where most frames found no
    top frame or no match. ``workers`` processes share the (clip, offset) grid; the curves
    are the same for any number of workers, and Ctrl-C stops the workers at once."""
    if int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    offsets = np.asarray(offsets, dtype=int).ravel()
    curves = np.full((len(clips), offsets.size), np.inf)
    if not clips or offsets.size == 0:
        return curves
    if workers == 1:
        for k, clip in enumerate(clips):
            curves[k] = _clip_curve(top, hor, clip, offsets.tolist(), hor_width, params,
                                    camera_id)
        return curves
    from xvmatch.geometry.worker_pool import worker_pool

    # About four tasks per worker, so that uneven tasks (crowded frames) still balance.
    pieces = max(1, -(-4 * int(workers) // len(clips)))
    tasks = _curve_tasks(top, hor, clips, offsets, pieces)
    index = {int(o): i for i, o in enumerate(offsets)}
    # Spawned workers that ignore Ctrl-C; an interrupt stops them at once (worker_pool).
    with worker_pool(min(int(workers), len(tasks))) as pool:
        futures = [
            pool.submit(_clip_curve, sub_top, sub_hor, clip, chunk, hor_width, params, camera_id)
            for _, chunk, (sub_top, sub_hor, clip) in tasks
        ]
        for (k, chunk, _), future in zip(tasks, futures, strict=True):
            curves[k, [index[o] for o in chunk]] = future.result()
    return curves


def clip_starts(
    hor_span: tuple[int, int],
    top_span: tuple[int, int],
    clip_length: int,
    max_offset: int,
    n_clips: int,
) -> list[int]:
    """First horizontal frames of ``n_clips`` clips spread evenly over the part of the video
    where every offset in [-max_offset, max_offset] finds top frames for the whole clip, so
    that all clips score every offset (videos of different lengths or start frames included).
    Where no clip fits that way, the horizontal span less ``max_offset`` at each end is used,
    and where even that is too short, one clip in the middle of the horizontal video."""
    first = max(hor_span[0], top_span[0] + max_offset)
    last = min(hor_span[1], top_span[1] - max_offset) - clip_length + 1
    if last < first:
        first, last = hor_span[0] + max_offset, hor_span[1] - max_offset - clip_length + 1
    if last < first:
        middle = max(hor_span[0], (hor_span[0] + hor_span[1] - clip_length + 1) // 2)
        return [int(middle)]
    return sorted({int(s) for s in np.linspace(first, last, n_clips).round()})


def _check_thresholds(tolerance: int, min_evidence: float, alpha: float, min_agree: int) -> None:
    if tolerance < 0 or not min_evidence >= 0.0 or not 0.0 < alpha <= 1.0 or min_agree < 1:
        raise ValueError(f"need tolerance >= 0, min_evidence >= 0, 0 < alpha <= 1 and "
                         f"min_agree >= 1, got {tolerance}, {min_evidence}, {alpha} and "
                         f"{min_agree}")


def judge_offset(
    clip_costs: np.ndarray,
    offsets: np.ndarray,
    tolerance: int = OFFSET_TOLERANCE,
    min_evidence: float = MIN_OFFSET_EVIDENCE,
    alpha: float = OFFSET_ALPHA,
    min_agree: int = MIN_AGREEING_CLIPS,
) -> OffsetEstimate:
    """The offset that ``(K, N)`` clip cost curves over ``offsets`` point to, and whether to
    apply it (see :func:`estimate_offset`). Rows that are all +inf (clips that never matched)
    are ignored. An offset beyond the tolerance is applied only when at least ``min_agree``
    clips (default :data:`MIN_AGREEING_CLIPS`, 2) have their own minimum within ``tolerance``
    of it, besides the ``evidence`` and ``chance`` tests: with one clip (the paper's single
    clip included) it is ``unsupported``, i.e. reported and not applied."""
    clip_costs = np.asarray(clip_costs, dtype=float)
    offsets = np.asarray(offsets)
    if clip_costs.ndim != 2 or clip_costs.shape[1] != offsets.size or 0 not in offsets:
        raise ValueError(f"need (K, N) curves over N offsets including 0, got "
                         f"{clip_costs.shape} over {offsets.size}")
    _check_thresholds(tolerance, min_evidence, alpha, min_agree)
    used = np.isfinite(clip_costs).any(axis=1)
    n_used = int(used.sum())
    costs = clip_costs[used].mean(axis=0) if n_used else np.full(offsets.shape, np.inf)
    zero = int(np.flatnonzero(offsets == 0)[0])
    best = int(np.argmin(costs)) if np.isfinite(costs).any() else zero
    offset = int(offsets[best])
    common = dict(offset=offset, offsets=offsets, costs=costs, clip_costs=clip_costs)
    clip_best = offsets[np.argmin(clip_costs[used], axis=1)]
    agree = int(np.sum(np.abs(clip_best - offset) <= tolerance))
    p_near = min(1.0, (2 * tolerance + 1) / offsets.size)
    # Binomial tail P(X >= agree), X ~ B(n_used, p_near) (math.comb: scipy.stats costs the CLI
    # half a second of import time).
    chance = sum(
        math.comb(n_used, j) * p_near**j * (1 - p_near) ** (n_used - j)
        for j in range(agree, n_used + 1)
    )
    evidence = _paired_evidence(clip_costs[used], best, zero)
    if n_used and abs(offset) <= tolerance:
        status = "within_tolerance"
    elif agree >= min_agree and evidence >= min_evidence and chance <= alpha:
        status = "applied"
    else:
        status = "unsupported"
    return OffsetEstimate(
        **common,
        applied=offset if status == "applied" else 0,
        status=status,
        support=agree / n_used if n_used else 0.0,
        chance=float(chance),
        evidence=evidence,
    )


def estimate_offset(
    top: Mapping[int, _FrameLike],
    hor: Mapping[int, _FrameLike],
    hor_width: float,
    params: SpatialParams | None = None,
    clip_start: int | None = None,
    clip_length: int = 10,
    max_offset: int = 15,
    camera_id: int | None = None,
    n_clips: int = 9,
    tolerance: int = OFFSET_TOLERANCE,
    min_evidence: float = MIN_OFFSET_EVIDENCE,
    alpha: float = OFFSET_ALPHA,
    workers: int = 1,
    min_agree: int = MIN_AGREEING_CLIPS,
) -> OffsetEstimate:
    """Estimate the temporal offset between the two videos by sliding clips (Sec. 3.2.4, Fig. 5).

    A clip of ``clip_length`` horizontal frames is compared with top clips shifted by every
    offset in [-max_offset, max_offset] (step 1: 2 * max_offset + 1 clips; the paper uses 10
    frames and 30 clips); each offset scores the mean over the clip's frames of the best Phi.
    One clip's cost curve is shallow, so by default ``n_clips`` clips spread over the video are
    used (where every offset finds top frames: :func:`clip_starts`), each curve divided by its
    own median, and the mean curve's minimum wins (``clip_start`` given: that one clip only, as
    in the paper, its minimum reported but never applied).

    The videos are taken to be in sync unless the clips show otherwise: the estimate is applied
    only when it is more than ``tolerance`` frames from 0 (the precision of the estimate: the
    spread of the minima on clean synchronised CVMHAT pairs, and of the errors on simulated
    shifted scenes with detector noise) and the clips back it twice over:
    - they prefer it to 0: the paired t statistic of cost(0) - cost(offset) over the clips is at
      least ``min_evidence`` (this rejects a noise minimum when the truth is 0);
    - they agree on it: at least ``min_agree`` clips (:data:`MIN_AGREEING_CLIPS`) have their
      own minimum within ``tolerance`` frames of it, and as many would agree with probability
      at most ``alpha`` had the minima fallen anywhere in the range (this rejects the lowest of
      many noise dips when the views share no offset at all).
    The defaults were set on simulated scenes with detector noise
    (``benchmarks/offset_calibration.py``): no synchronised scene shifted, most true shifts found.
    ``workers`` processes compute the curves (:func:`clip_cost_curves`); the estimate is the
    same for any number.

    Returns:
        :class:`OffsetEstimate` (see :func:`judge_offset`); ``costs`` is the mean normalised
        curve (raw when one clip is asked for).
    """
    params = params or SpatialParams()
    if clip_length < 1 or max_offset < 0 or n_clips < 1:
        raise ValueError("need clip_length >= 1, max_offset >= 0 and n_clips >= 1")
    _check_thresholds(tolerance, min_evidence, alpha, min_agree)
    if not hor:
        raise ValueError("the horizontal sequence has no frames")
    if not top:
        raise ValueError("the top sequence has no frames")
    starts = [clip_start] if clip_start is not None else clip_starts(
        (min(hor), max(hor)), (min(top), max(top)), clip_length, max_offset, n_clips)
    # One clip asked for (clip_start, or n_clips = 1): the paper's estimate, its raw curve kept;
    # like a lone clip that fits a short video, it is reported but cannot be applied.
    single = clip_start is not None or n_clips == 1
    offsets = np.arange(-max_offset, max_offset + 1)
    clips = [[f for f in range(start, start + clip_length) if f in hor] for start in starts]
    curves = clip_cost_curves(top, hor, clips, offsets, hor_width, params, camera_id, workers)
    clip_costs = np.full(curves.shape, np.inf)
    for k, curve in enumerate(curves):
        finite = curve[np.isfinite(curve)]
        if finite.size:
            clip_costs[k] = curve if single else curve / np.median(finite)
    return judge_offset(clip_costs, offsets, tolerance, min_evidence, alpha, min_agree)
