"""Temporal offset between two unsynchronised videos by sliding clips (CVMHAT paper, Sec. 3.2.4,
Fig. 5): the mean best Phi of short horizontal clips against the top video at every offset, the
minimum of the averaged curve, and whether enough clips back it before it is applied.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import numpy as np

from xvmatch.core.worker_pool import worker_pool
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.cues.spatial_search import (
    FrameLike,
    TopSearch,
    best_cost,
    ids_to_index,
    top_search,
)

__all__ = [
    "AUTO_MAX_OFFSET",
    "CLIPS",
    "CLIP_LENGTH",
    "MIN_AGREEING_CLIPS",
    "MIN_OFFSET_EVIDENCE",
    "OFFSET_ALPHA",
    "OFFSET_STEP",
    "OFFSET_TOLERANCE",
    "REFINED_MINIMA",
    "OffsetEstimate",
    "clip_cost_curves",
    "clip_start_range",
    "clip_starts",
    "coarse_offsets",
    "estimate_offset",
    "judge_offset",
    "search_offsets",
]


# Defaults of estimate_offset: precision of the estimate in frames (at 30 fps), and the paired t
# statistic the clips must reach before a shift is applied (calibrated on simulated scenes).
OFFSET_TOLERANCE = 5
MIN_OFFSET_EVIDENCE = 2.0
OFFSET_ALPHA = 0.05
MIN_AGREEING_CLIPS = 2
"""Fewest clips whose own minima must agree (within the tolerance) before an offset is applied:
one clip's minimum cannot be told from a noise dip, so a single clip is reported, never applied."""
OFFSET_STEP = 4
"""Spacing (frames) of the first, coarse pass of :func:`estimate_offset`; the frames around 0
and around its :data:`REFINED_MINIMA` lowest minima are then tried one by one: about 45
offsets instead of 121 at the default range, with as many shifts found and none wrongly
applied on the CVMHAT pairs and the simulated scenes (``benchmarks/offset_calibration.py
--step``)."""
REFINED_MINIMA = 2
"""Local minima of the coarse curve refined (besides 0): curves of detector boxes are rough,
and the coarse pass's lowest point is not always next to the full grid's."""
CLIPS = 9
"""Clips spread over the video that :func:`estimate_offset` averages by default."""
CLIP_LENGTH = 10
"""Frames per clip (the paper's 10)."""
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
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    clip: list[int],
    offset: int,
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None,
    searches: OrderedDict[int, TopSearch] | None = None,
) -> float:
    """Mean best Phi of one clip at one offset; +inf unless most of its frames match.
    ``searches``: the top frames' hypotheses already built (:func:`top_search`), by top frame,
    the most recently used last; the frames built here join it, and it keeps the last
    2 * ``len(clip)`` (the next offsets of a clip read mostly the same top frames)."""
    searches = OrderedDict() if searches is None else searches
    values = []
    for f in clip:
        t_rec = top.get(f + offset)
        if t_rec is None or len(t_rec.ids) == 0:
            continue
        if f + offset in searches:
            searches.move_to_end(f + offset)
        else:
            cand = ((ids_to_index(t_rec.ids, camera_id) or None) if camera_id is not None
                    else None)
            searches[f + offset] = top_search(t_rec.boxes, params, cand)
            while len(searches) > 2 * len(clip):
                searches.popitem(last=False)
        values.append(best_cost(searches[f + offset], hor[f].boxes, hor_width, params))
    finite = [v for v in values if math.isfinite(v)]
    return float(np.mean(finite)) if finite and 2 * len(finite) >= len(clip) else math.inf


def _clip_curve(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    clip: list[int],
    offsets: list[int],
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None,
) -> list[float]:
    """:func:`_clip_cost` of one clip at each of ``offsets`` (one task of the process pool),
    each top frame's hypotheses built once while consecutive offsets read it (the same costs
    as :func:`~xvmatch.cues.spatial_search.associate_frame`'s, at about half the time)."""
    searches: OrderedDict[int, TopSearch] = OrderedDict()
    return [_clip_cost(top, hor, clip, o, hor_width, params, camera_id, searches)
            for o in offsets]


def _curve_tasks(
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
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
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    clips: list[list[int]],
    offsets: np.ndarray,
    hor_width: float,
    params: SpatialParams,
    camera_id: int | None = None,
    workers: int = 1,
    progress: Callable[[int], None] | None = None,
) -> np.ndarray:
    """``(K, N)`` raw cost curves: the mean best Phi of each clip (horizontal frame numbers)
    at each offset (Eq. 12 averaged over the clip, Fig. 5); +inf where most frames found no
    top frame or no match. ``workers`` processes share the (clip, offset) grid; the curves
    are the same for any number of workers, and Ctrl-C stops the workers at once.
    ``progress(n)``: told each time ``n`` more (clip, offset) costs are known (a progress bar;
    the costs do not depend on it)."""
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
            if progress is not None:
                progress(offsets.size)
        return curves

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
            if progress is not None:
                progress(len(chunk))
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


def clip_start_range(hor_span: tuple[int, int], clip_length: int) -> tuple[int, int]:
    """First and last horizontal frame a single clip of ``clip_length`` frames may start at
    (``estimate_offset(clip_start=...)``): the whole clip inside the horizontal video's span
    ``(first frame, last frame)``; a video shorter than the clip has the one start at its first
    frame (the clip then holds the whole video)."""
    first, last = int(hor_span[0]), int(hor_span[1])
    return first, max(first, last - int(clip_length) + 1)


def coarse_offsets(max_offset: int, step: int) -> np.ndarray:
    """Every ``step``-th offset from 0 out to -``max_offset`` and +``max_offset``, both ends
    included (the first pass of :func:`estimate_offset`)."""
    half = np.arange(0, max_offset + 1, step)
    if half[-1] != max_offset:
        half = np.append(half, max_offset)
    return np.concatenate([-half[:0:-1], half])


def _normalised(curves: np.ndarray, scale_from: np.ndarray, single: bool) -> np.ndarray:
    """Each clip's curve divided by the median of its finite ``scale_from`` values (rows that
    never matched stay +inf; ``single``: the raw curve, as in the paper)."""
    out = np.full(curves.shape, np.inf)
    for k, (curve, ref) in enumerate(zip(curves, scale_from, strict=True)):
        finite = ref[np.isfinite(ref)]
        if finite.size:
            out[k] = curve if single else curve / np.median(finite)
    return out


def _lowest_minima(curve: np.ndarray, k: int) -> np.ndarray:
    """Indices of the ``k`` lowest finite local minima of ``curve`` (no higher than either
    neighbour), lowest first (ties: lower index first)."""
    lower = np.concatenate([[np.inf], curve[:-1]])
    upper = np.concatenate([curve[1:], [np.inf]])
    minima = np.flatnonzero(np.isfinite(curve) & (curve <= lower) & (curve <= upper))
    return minima[np.argsort(curve[minima], kind="stable")][:k]


def search_offsets(
    curves_at: Callable[[np.ndarray], np.ndarray],
    max_offset: int,
    step: int | None = None,
    single: bool = False,
    tolerance: int = OFFSET_TOLERANCE,
    min_evidence: float = MIN_OFFSET_EVIDENCE,
    alpha: float = OFFSET_ALPHA,
    min_agree: int = MIN_AGREEING_CLIPS,
) -> OffsetEstimate:
    """Judge the offsets in [-max_offset, max_offset] coarse to fine (see
    :func:`estimate_offset`): ``curves_at(offsets)`` gives the ``(K, len(offsets))`` raw clip
    costs at those offsets. It is asked for the coarse grid (:func:`coarse_offsets`), then
    for every offset within ``step`` - 1 of 0 and of the :data:`REFINED_MINIMA` lowest local
    minima of the coarse mean curve. ``single``: one clip, its raw curve kept. ``step`` None:
    :data:`OFFSET_STEP`, or 2 * ``tolerance`` + 1 where that is smaller."""
    _check_thresholds(tolerance, min_evidence, alpha, min_agree)
    step = min(OFFSET_STEP, 2 * tolerance + 1) if step is None else step
    if not 1 <= step <= 2 * tolerance + 1:
        raise ValueError(f"need 1 <= step <= 2 * tolerance + 1 = {2 * tolerance + 1}, so that "
                         f"every offset has a coarse one within the tolerance; got {step}")
    coarse = coarse_offsets(max_offset, step)
    raw = curves_at(coarse)
    curves = _normalised(raw, raw, single)
    if step == 1:
        return judge_offset(curves, coarse, tolerance, min_evidence, alpha, min_agree)
    votes = coarse[np.argmin(curves, axis=1)]  # clips that never matched are ignored
    used = np.isfinite(curves).any(axis=1)
    mean = curves[used].mean(axis=0) if used.any() else np.full(coarse.shape, np.inf)
    centres = [0, *coarse[_lowest_minima(mean, REFINED_MINIMA)].tolist()]
    near = np.unique(np.concatenate([np.arange(c - step + 1, c + step) for c in centres]))
    fine = np.setdiff1d(near[np.abs(near) <= max_offset], coarse)
    offsets = np.concatenate([coarse, fine])
    order = np.argsort(offsets, kind="stable")
    curves = _normalised(np.concatenate([raw, curves_at(fine)], axis=1), raw, single)
    return judge_offset(curves[:, order], offsets[order], tolerance, min_evidence, alpha,
                        min_agree, votes=votes)


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
    votes: np.ndarray | None = None,
) -> OffsetEstimate:
    """The offset that ``(K, N)`` clip cost curves over ``offsets`` point to, and whether to
    apply it (see :func:`estimate_offset`). Rows that are all +inf (clips that never matched)
    are ignored. An offset beyond the tolerance is applied only when at least ``min_agree``
    clips (default :data:`MIN_AGREEING_CLIPS`, 2) have their own minimum within ``tolerance``
    of it, besides the ``evidence`` and ``chance`` tests: with one clip (the paper's single
    clip included) it is ``unsupported``, i.e. reported and not applied.

    ``votes``: ``(K,)`` each clip's own minimum as found on an evenly spaced grid, when
    ``offsets`` is not one (a coarse grid refined around 0 and the mean's lowest minima, whose
    extra offsets would draw the clips' minima there); default each row's minimum over
    ``offsets``. The chance of agreement takes minima spread over the whole range of
    ``offsets``, whatever its spacing."""
    clip_costs = np.asarray(clip_costs, dtype=float)
    offsets = np.asarray(offsets)
    if clip_costs.ndim != 2 or clip_costs.shape[1] != offsets.size or 0 not in offsets:
        raise ValueError(f"need (K, N) curves over N offsets including 0, got "
                         f"{clip_costs.shape} over {offsets.size}")
    if votes is not None and np.shape(votes) != (clip_costs.shape[0],):
        raise ValueError(f"need one vote per clip, got {np.shape(votes)} for "
                         f"{clip_costs.shape[0]} clips")
    _check_thresholds(tolerance, min_evidence, alpha, min_agree)
    used = np.isfinite(clip_costs).any(axis=1)
    n_used = int(used.sum())
    costs = clip_costs[used].mean(axis=0) if n_used else np.full(offsets.shape, np.inf)
    zero = int(np.flatnonzero(offsets == 0)[0])
    best = int(np.argmin(costs)) if np.isfinite(costs).any() else zero
    offset = int(offsets[best])
    common = dict(offset=offset, offsets=offsets, costs=costs, clip_costs=clip_costs)
    clip_best = (offsets[np.argmin(clip_costs[used], axis=1)] if votes is None
                 else np.asarray(votes)[used])
    agree = int(np.sum(np.abs(clip_best - offset) <= tolerance))
    p_near = min(1.0, (2 * tolerance + 1) / (int(offsets.max()) - int(offsets.min()) + 1))
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
    top: Mapping[int, FrameLike],
    hor: Mapping[int, FrameLike],
    hor_width: float,
    params: SpatialParams | None = None,
    clip_start: int | None = None,
    clip_length: int = CLIP_LENGTH,
    max_offset: int = 15,
    camera_id: int | None = None,
    n_clips: int = CLIPS,
    tolerance: int = OFFSET_TOLERANCE,
    min_evidence: float = MIN_OFFSET_EVIDENCE,
    alpha: float = OFFSET_ALPHA,
    workers: int = 1,
    min_agree: int = MIN_AGREEING_CLIPS,
    step: int | None = None,
    progress: Callable[[int, int], None] | None = None,
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

    Coarse to fine (``step`` > 1; default :data:`OFFSET_STEP`, at most 2 * ``tolerance`` + 1
    so that every offset has a coarse one within the tolerance): the clips are first compared
    at every ``step``-th offset (:func:`coarse_offsets`), then at each offset within
    ``step`` - 1 of 0 and of the lowest minima of that mean curve (:func:`search_offsets`);
    each clip's own minimum, which must agree, is taken on the coarse grid, and each curve is
    divided by the median of its coarse part. ``step`` = 1 tries every offset, as the paper
    does.

    ``progress(done, total)``: told as the (clip, offset) costs are computed, ``total`` the
    costs asked for so far (it grows when the fine pass is known), so that a long search can
    show a progress bar; the estimate does not depend on it.

    Returns:
        :class:`OffsetEstimate` (see :func:`judge_offset`); ``costs`` is the mean normalised
        curve (raw when one clip is asked for).

    Raises:
        ValueError: bad clip settings or thresholds, an empty view, or a ``clip_start`` whose
            clip is not inside the horizontal video (:func:`clip_start_range`).
    """
    params = params or SpatialParams()
    if clip_length < 1 or max_offset < 0 or n_clips < 1:
        raise ValueError("need clip_length >= 1, max_offset >= 0 and n_clips >= 1")
    _check_thresholds(tolerance, min_evidence, alpha, min_agree)
    if not hor:
        raise ValueError("the horizontal sequence has no frames")
    if not top:
        raise ValueError("the top sequence has no frames")
    if clip_start is not None:
        low, high = clip_start_range((min(hor), max(hor)), clip_length)
        if not low <= clip_start <= high:
            raise ValueError(f"clip_start {clip_start} is outside the horizontal video (frames "
                             f"{min(hor)}..{max(hor)}): a clip of {clip_length} frames starts "
                             f"in {low}..{high}")
    starts = [clip_start] if clip_start is not None else clip_starts(
        (min(hor), max(hor)), (min(top), max(top)), clip_length, max_offset, n_clips)
    # One clip asked for (clip_start, or n_clips = 1): the paper's estimate, its raw curve kept;
    # like a lone clip that fits a short video, it is reported but cannot be applied.
    single = clip_start is not None or n_clips == 1
    clips = [[f for f in range(start, start + clip_length) if f in hor] for start in starts]
    counts = [0, 0]  # costs computed, costs asked for

    def curves_at(offsets: np.ndarray) -> np.ndarray:
        told = None
        if progress is not None:
            counts[1] += len(clips) * int(np.size(offsets))

            def told(n: int) -> None:
                counts[0] += n
                progress(counts[0], counts[1])
        return clip_cost_curves(top, hor, clips, offsets, hor_width, params, camera_id,
                                workers, told)

    return search_offsets(curves_at, max_offset, step, single, tolerance, min_evidence, alpha,
                          min_agree)
