"""Search over the camera location O and orientation theta (CVMHAT paper, Section 3.2.4).

Frame level: every (O, theta) hypothesis is scored with Phi (Eq. 12) and the best one gives the
association. Over a video: the reduced search limits theta to a damped window S_t around the
previous orientation and follows O with the top view's own track ids. The temporal offset
between two unsynchronised videos (Fig. 5) is estimated with this search in
:mod:`xvmatch.cues.offset_estimation`.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.core import kernel_choice
from xvmatch.cues.spatial_matching import (
    SpatialParams,
    cached_penalty_table,
    cost_lower_bound,
    match_vector_sets,
)
from xvmatch.cues.spatial_vectors import (
    TopGeometry,
    TopHypotheses,
    box_centres,
    horizontal_vectors,
    top_geometry,
    top_hypotheses,
)

__all__ = [
    "SEARCH_MODES",
    "FollowPolicy",
    "FrameAssociation",
    "TopSearch",
    "associate_frame",
    "associate_sequence",
    "best_cost",
    "best_per_candidate",
    "hypothesis_vectors",
    "rank_hypotheses",
    "search_window",
    "top_search",
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
    top_boxes: np.ndarray, cand: np.ndarray, thetas: np.ndarray, params: SpatialParams,
    geometries: list[TopGeometry] | None = None,
) -> Iterator[tuple[int, TopHypotheses]]:
    """The hypotheses of consecutive blocks of candidates, with the index of each block's first
    hypothesis among all (candidate-major: b = c T + t); each block's geometry is appended to
    ``geometries`` when given."""
    centres = box_centres(top_boxes)
    step = max(1, HYPOTHESIS_BLOCK // max(1, thetas.shape[0] * centres.shape[0]))
    for lo in range(0, cand.shape[0], step):
        geometry = top_geometry(centres, cand[lo:lo + step], math.radians(params.tau_deg))
        if geometries is not None:
            geometries.append(geometry)
        yield lo * thetas.shape[0], top_hypotheses(geometry, thetas,
                                                   math.radians(params.fov_deg))


def _association(found: tuple, cand: np.ndarray, thetas: np.ndarray,
                 hor_order: np.ndarray) -> FrameAssociation:
    """The :class:`FrameAssociation` of one scored hypothesis (index b = c T + t, cost, pairs
    mask over the sorted vectors, scale, top person of each entry; or, from the compiled
    :func:`_best_per_group`, index, cost, the top person kept with each sorted horizontal
    column or -1, scale), in input box order. Each person is kept at most once, so the pairs
    sorted by person are the same from either form."""
    if len(found) == 4:
        index, cost, kept, scale = found
        cols = np.flatnonzero(kept >= 0)
        first = kept[cols].astype(np.intp)
    else:
        index, cost, pairs_mask, scale, top_index = found
        rows, cols = np.nonzero(pairs_mask)
        first = top_index[rows]
    order = np.argsort(first, kind="stable")
    pairs = np.empty((cols.shape[0], 2), dtype=np.result_type(first, hor_order))
    pairs[:, 0], pairs[:, 1] = first[order], hor_order[cols[order]]
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


@dataclass(frozen=True)
class TopSearch:
    """One top frame's hypotheses, computed once to be matched with several horizontal frames
    (:func:`best_cost`): the offset search pairs each top frame with up to a clip's length of
    horizontal frames, and the hypotheses are most of a frame pair's work.

    Attributes:
        n_top: M, the top frame's boxes.
        n_cand: candidate camera locations.
        blocks: the hypotheses of each block of candidates with the index of its first
            hypothesis (as :func:`rank_hypotheses` builds them); empty when nothing can match.
    """

    n_top: int
    n_cand: int
    blocks: tuple[tuple[int, TopHypotheses], ...]


def top_search(top_boxes: np.ndarray, params: SpatialParams | None = None,
               candidates: Iterable[int] | None = None) -> TopSearch:
    """The :class:`TopSearch` of one top frame (``top_boxes``, ``params``, ``candidates`` as in
    :func:`associate_frame`; the full circle of orientations)."""
    params = params or SpatialParams()
    top_boxes, _, cand, thetas = _prepare(top_boxes, np.zeros((0, 4)), candidates, None, params)
    if cand.size == 0 or top_boxes.shape[0] < 2:
        return TopSearch(top_boxes.shape[0], cand.size, ())
    return TopSearch(top_boxes.shape[0], cand.size,
                     tuple(_candidate_blocks(top_boxes, cand, thetas, params)))


def best_cost(search: TopSearch, hor_boxes: np.ndarray, hor_width: float,
              params: SpatialParams | None = None) -> float:
    """The lowest Phi of a top frame (its :class:`TopSearch`) against one horizontal frame:
    exactly ``associate_frame(top_boxes, hor_boxes, hor_width, params, candidates).cost``
    (the same branch and bound on the same hypotheses), +inf when nothing can be matched."""
    params = params or SpatialParams()
    hor_boxes = np.asarray(hor_boxes, dtype=float).reshape(-1, 4)
    if search.n_cand == 0 or hor_boxes.shape[0] == 0 or search.n_top < 2:
        return math.inf
    hor, _ = horizontal_vectors(hor_boxes, hor_width)
    costs = [cost for _, hypotheses in search.blocks
             for _, cost, *_ in _ranked(hypotheses, hor, params, 1)]
    return min(costs, default=math.inf)


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
    return _best_per_candidate(top_boxes, hor_boxes, hor_width, params, candidates, thetas,
                               keep)[0]


def _best_per_candidate(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_width: float,
    params: SpatialParams | None = None,
    candidates: Iterable[int] | None = None,
    thetas: np.ndarray | None = None,
    keep: int | None = None,
) -> tuple[list[FrameAssociation], TopGeometry | None]:
    """:func:`best_per_candidate`, and the :class:`TopGeometry` of its candidates (a row per
    candidate, in the given order; None when nothing was searched), which the learned matcher's
    features read again (:mod:`xvmatch.cues.spatial_features`)."""
    params = params or SpatialParams()
    top_boxes, hor_boxes, cand, thetas = _prepare(
        top_boxes, hor_boxes, candidates, thetas, params
    )
    if cand.size == 0 or hor_boxes.shape[0] == 0 or top_boxes.shape[0] < 2:
        return [], None
    hor, hor_order = horizontal_vectors(hor_boxes, hor_width)
    found = []
    geometries: list[TopGeometry] = []
    for start, hypotheses in _candidate_blocks(top_boxes, cand, thetas, params, geometries):
        found += [(start + i, *rest) for i, *rest in _best_per_group(hypotheses, hor, params,
                                                                      keep)]
    if keep is not None:  # each block's keep best are exact, so the keep best of all are too
        found = sorted(sorted(found, key=lambda b: (b[1], b[0]))[:keep], key=lambda b: b[0])
    geometry = geometries[0] if len(geometries) == 1 else TopGeometry(
        *(np.concatenate([getattr(g, k) for g in geometries]) for k in ("phi", "dist",
                                                                         "visible")))
    return [_association(f, cand, thetas, hor_order) for f in found], geometry


def _best_per_group(
    hypotheses: TopHypotheses,
    hor: np.ndarray,
    params: SpatialParams,
    keep: int | None = None,
    first_chunk: int = 256,
) -> list[tuple]:
    """The lowest-Phi hypothesis of each candidate (group of ``n_theta`` consecutive rows),
    exactly, by best-first branch and bound against each group's own best cost (and the
    ``keep``-th lowest group best, when only the ``keep`` best groups are wanted).

    Where the kernels are loaded (:mod:`~xvmatch.core.kernel_choice`), each batch is sorted,
    matched and merged in one compiled call (:class:`_CompiledBatches`) on the y of Eq. 5
    taken once per block (numpy's cos of every entry in view, elementwise as
    :meth:`~xvmatch.cues.spatial_vectors.TopHypotheses.take` takes it): the same batches, the
    same arithmetic, so the same bits as the numpy form (tested).

    Returns:
        Per group with a finite cost, in group order (only the ``keep`` lowest with ``keep``):
        (hypothesis index, cost, pairs mask, scale, top person of each entry) in numpy, and
        (hypothesis index, cost, top person kept with each sorted horizontal column or -1,
        scale) from the kernels; :func:`_association` reads either.
    """
    n = hypotheses.x.shape[0]
    group = np.arange(n) // hypotheses.n_theta
    n_groups = int(group[-1]) + 1 if n else 0
    hor_x = hor[:, 0]
    best_cost = np.full(n_groups, np.inf)
    best_index = np.full(n_groups, n)  # each group's best hypothesis so far (n: none)
    best: list[tuple | None] = [None] * n_groups
    kernels = kernel_choice.kernels()
    if kernels is not None:
        compiled = _CompiledBatches(kernels, hypotheses, hor, params, best_cost, best_index,
                                    best)
        score = compiled.score
    else:
        def score(idx: np.ndarray) -> None:
            vectors = hypotheses.take(idx)
            result = match_vector_sets(vectors.x, vectors.y, vectors.count, hor, params)
            rows = np.flatnonzero(np.isfinite(result.cost))
            if rows.size == 0:
                return
            # The batch's best row of each group (lowest cost, then lowest index), then a
            # merge with the groups' bests so far (lower cost, or the same and a lower index):
            # in numpy over the batch's groups, a loop over the groups it improves only.
            groups, costs = group[idx[rows]], result.cost[rows]
            order = np.lexsort((idx[rows], costs, groups))
            ordered = groups[order]  # ascending: each group's first entry is its best row
            first = np.flatnonzero(np.concatenate(([True], ordered[1:] != ordered[:-1])))
            win = rows[order[first]]
            g, c, i = group[idx[win]], result.cost[win], idx[win]
            held = best_cost[g]
            better = (c < held) | ((c == held) & (i < best_index[g]))
            for k in np.flatnonzero(better):
                r, gk = win[k], g[k]
                best_cost[gk], best_index[gk] = c[k], i[k]
                best[gk] = (int(i[k]), float(c[k]), result.pairs[r], float(result.scale[r]),
                            vectors.index[r])

    def limits() -> np.ndarray:
        """``(n_groups,)``: what a hypothesis of each group must not exceed to matter (per
        group, indexed by the callers: every group has rows, so its max is the rows' max)."""
        if keep is None or keep >= n_groups:
            return best_cost
        kth = float(np.partition(best_cost, keep - 1)[keep - 1])
        return np.minimum(best_cost, kth)

    loose = cost_lower_bound(hypotheses.x, hypotheses.count, hor_x, params, tight=False)
    # Seed: each group's most promising hypothesis under the loose bound.
    seed = _group_seeds(loose, hypotheses.n_theta)
    if seed.size == 0:
        return []
    score(seed)
    done = np.zeros(n, dtype=bool)
    done[seed] = True
    rest = np.flatnonzero(~done & (loose <= limits()[group]))
    tight = cost_lower_bound(hypotheses.x[rest], hypotheses.count[rest], hor_x, params)
    alive = tight <= limits()[group[rest]]
    rest, tight = rest[alive], tight[alive]
    order = np.argsort(tight, kind="stable")
    rest, tight = rest[order], tight[order]
    start, chunk = 0, first_chunk
    while start < rest.shape[0] and tight[start] <= limits().max():
        sel = slice(start, start + chunk)
        idx = rest[sel][tight[sel] <= limits()[group[rest[sel]]]]
        start += chunk
        chunk *= 2
        if idx.size:
            score(np.sort(idx))
    found = [b for b in best if b is not None]
    if keep is not None:
        found = sorted(found, key=lambda b: (b[1], b[0]))[:keep]
        found.sort(key=lambda b: b[0])
    return found


class _CompiledBatches:
    """The compiled form of :func:`_best_per_group`'s batches (``search_kernels.score_groups``)
    on one block of hypotheses: the y of Eq. 5 of every entry in view, taken once; each
    batch's new group bests stored in ``best`` as (index, cost, the top person kept with each
    sorted horizontal column or -1, scale)."""

    def __init__(self, kernels, hypotheses: TopHypotheses, hor: np.ndarray,
                 params: SpatialParams, best_cost: np.ndarray, best_index: np.ndarray,
                 best: list) -> None:
        x = np.ascontiguousarray(hypotheses.x, dtype=np.float64)
        n_rows = x.shape[0]
        row_start = np.empty(n_rows + 1, dtype=np.int64)
        n_seen = int(hypotheses.count.sum())
        delta, dist = np.empty(n_seen), np.empty(n_seen)
        kernels.packed_depths(x, np.ascontiguousarray(hypotheses.delta, dtype=np.float64),
                              np.ascontiguousarray(hypotheses.dist, dtype=np.float64),
                              hypotheses.n_theta, row_start, delta, dist)
        # numpy's cos in both forms, of the entries in view (elementwise: the same bits)
        self.y = dist * np.cos(delta)
        self.kernels, self.x, self.row_start = kernels, x, row_start
        self.count = np.ascontiguousarray(hypotheses.count, dtype=np.int64)
        self.n_theta = hypotheses.n_theta
        self.hor_x = np.ascontiguousarray(hor[:, 0], dtype=np.float64)
        self.hor_y = np.ascontiguousarray(hor[:, 1], dtype=np.float64)
        self.params, self.best_cost, self.best_index, self.best = (params, best_cost,
                                                                    best_index, best)
        self.group_row = np.full(best_cost.shape[0], -1, dtype=np.int64)

    def score(self, idx: np.ndarray) -> None:
        """Score the hypotheses ``idx`` (ascending) as one batch and merge the group bests."""
        rows = np.ascontiguousarray(idx, dtype=np.int64)
        n_cols = self.hor_x.shape[0]
        width = int(self.count[rows].max()) if rows.size else 0
        # the batch's table of rho^(L / kappa), as match_vector_sets takes it
        coef = cached_penalty_table(float(self.params.rho), max(width, n_cols))
        cost, scale = np.empty(rows.shape[0]), np.empty(rows.shape[0])
        kept = np.empty((rows.shape[0], n_cols), dtype=np.int64)
        improved = np.empty(rows.shape[0], dtype=np.int64)
        n_improved = self.kernels.score_groups(
            self.x, self.count, self.row_start, self.y, rows, self.n_theta, width, self.hor_x,
            self.hor_y, coef, float(self.params.lam), float(self.params.scale_threshold),
            self.best_cost, self.best_index, self.group_row, cost, scale, kept, improved)
        for r in improved[:n_improved]:
            index = int(rows[r])
            self.best[index // self.n_theta] = (index, float(cost[r]), kept[r],
                                                float(scale[r]))


def _group_seeds(loose: np.ndarray, n_theta: int) -> np.ndarray:
    """Each group's (``n_theta`` consecutive rows) row of lowest ``loose``, the lowest index on
    ties, ascending, where finite: the seeds of :func:`_best_per_group`.

    The definition is a sort by (bound, index) and each group's first row in it; ``argmin`` per
    group gives the same rows where no bound is NaN (a sort puts NaN last, ``argmin`` first),
    at a tenth of the cost.
    """
    n = loose.shape[0]
    n_groups = -(-n // n_theta)
    if n == n_groups * n_theta and not np.isnan(loose).any():
        seed = np.arange(n_groups) * n_theta + loose.reshape(n_groups, n_theta).argmin(axis=1)
    else:
        order = np.lexsort((np.arange(n), loose))
        _, first = np.unique(order // n_theta, return_index=True)
        seed = np.sort(order[first])
    return seed[np.isfinite(loose[seed])]


def _lowest_finite(values: np.ndarray, n: int) -> np.ndarray:
    """Ascending indices of the ``n`` lowest finite ``values``, the lower index on ties: the
    finite ones among ``np.argsort(values, kind="stable")[:n]`` (the seeds of :func:`_ranked`),
    by a partition instead of a sort of every hypothesis."""
    finite = np.flatnonzero(np.isfinite(values))
    if finite.size <= n:
        return finite
    kept = values[finite]
    kth = np.partition(kept, n - 1)[n - 1]
    below = kept < kth
    below[np.flatnonzero(kept == kth)[:n - int(below.sum())]] = True
    return finite[below]


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
        rows = np.flatnonzero(np.isfinite(result.cost) & (result.cost <= threshold()))
        if rows.size > k:  # only the batch's k best can enter the pool's k best
            rows = rows[np.lexsort((idx[rows], result.cost[rows]))[:k]]
        for r in rows:
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
    seed = _lowest_finite(loose, first_chunk)
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


class FrameLike:
    """Structural type of a frame record: ``ids (N,)`` and ``boxes (N, 4)``."""

    ids: np.ndarray
    boxes: np.ndarray


def ids_to_index(ids: np.ndarray, wanted: int) -> list[int]:
    """Rows of a frame whose id is ``wanted`` (the camera wearer's top-view box, when given)."""
    return [int(k) for k in np.flatnonzero(np.asarray(ids) == wanted)]


def associate_sequence(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    hor_width: float,
    params: SpatialParams | None = None,
    search: str = "exhaustive",
    camera_id: int | None = None,
    frames: Iterable[int] | None = None,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
    follow: FollowPolicy = FollowPolicy(),
    cameras: dict[int, int] | None = None,
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
        cameras: where given, filled with ``{frame: O's row in the frame's top record}`` for
            each frame whose search found one (:mod:`~xvmatch.inference.matching.search_camera`).
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
                    own = ids_to_index(t_rec.ids, followed)
                    if own:
                        result = associate_frame(
                            t_rec.boxes, h_rec.boxes, hor_width, params, own, circle
                        )
        else:
            candidates: list[int] | None = None
            if camera_id is not None:
                candidates = ids_to_index(t_rec.ids, camera_id) or None
            elif search == "follow" and followed is not None:
                candidates = ids_to_index(t_rec.ids, followed) or None
            thetas = (circle if search == "exhaustive"
                      else search_window(last_theta, step_index, params))
            result = associate_frame(
                t_rec.boxes, h_rec.boxes, hor_width, params, candidates, thetas
            )
        if result.camera >= 0:
            last_theta = result.theta
            if not voting:
                followed = int(t_rec.ids[result.camera])
            if cameras is not None:
                cameras[frame] = int(result.camera)
        out[frame] = [(int(t_rec.ids[a]), int(h_rec.ids[b])) for a, b in result.pairs]
    return out
