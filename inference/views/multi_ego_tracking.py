"""People followed over time in one top view and several egocentric views, cycle-consistently.

The frame-by-frame program of :mod:`xvmatch.inference.views.multi_view_assignment` decides every
frame alone and its person ids do not carry over frames. Here (issue 33, item 2) tracklets, as in
the two-view tracker (:mod:`xvmatch.inference.tracks.tracking`), carry evidence and ids over time:

1. every view is cut into the same clips and its boxes linked into tracklets
   (:func:`xvmatch.inference.linking.tracklets.view_tracklets`, CVMHAT Sec. 4.1): the top view by
   IoU (>= 0.5), the egocentric views by motion (``motion`` = 0.3, a gate in box heights): a
   head-worn camera's shake moves all its boxes alike, often by more than a box width, so a
   box is linked to the tracklet nearest once that common shift is removed
   (:func:`xvmatch.cues.box_motion.motion_link_costs`). On the benchmark's tuning scenes
   (ground-truth boxes) the egocentric tracklets held 1.8 boxes on average by IoU (>= 0.7,
   ``motion=None``, the links before) and 5.9 by motion, with no more wrong links (98.6% and
   99.6% of the links right). A tracklet continues one
   of the previous clip when that one's last box and its first are linked the same way
   (:func:`view_chains`). A motion link now and then joins two people (a person leaves the
   view as another enters near the same place); such a tracklet's mean evidence (step 2) can
   then overrule the frames of its minority person. So, for the smoothing only, an egocentric
   tracklet is cut where the top-view tracklet it matches confidently (frame cost below
   ``-partner_change`` = -2 nats) switches to another for at least two boxes
   (:func:`split_at_partner_changes`); the pieces keep their tracklet's chain;
2. per clip and view pair, two tracklets' evidence is the mean, over the frames both are
   present in, of the frames' costs ``c - gamma`` (those of ``associate-multi``: minus the
   evidence, in nats, that two boxes are one person; :func:`tracklet_costs`); every box pair
   of a frame then costs ``w c + (1 - w)`` its tracklets' mean (:func:`smoothed_problems`,
   ``w = frame_weight`` = 0.6), so one frame's mistake of the matcher is outvoted by the
   tracklets' other frames while a tracklet that wrongly holds two people cannot overrule a
   frame alone;
3. every frame is solved by the joint program over all views with the cycle constraints
   (:func:`~xvmatch.inference.views.multi_view_assignment.solve_multi_view`) on those costs:
   every person has at most one box per view, and the matches are cycle-consistent;
4. a frame's people take the ids of earlier ones (:func:`carry_ids`): a person continues the
   id whose boxes, in the latest frame they were seen, lay on the same tracklet chains, in the
   most views (one-to-one, Hungarian); any other opens a new id.

Ids are unique per frame and a person has at most one box per view, so the matches read off
the ids are cycle-consistent on every frame. Nothing here is random; the result does not depend
on worker counts.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.box_overlap import box_iou
from xvmatch.inference.linking.tracklets import (
    Tracklet,
    motion_assignment,
    split_clips,
    view_tracklets,
)
from xvmatch.inference.tracks.track_mip import MIP_TIME_LIMIT
from xvmatch.inference.views.multi_view_assignment import (
    consistent_hungarian,
    solve_multi_view,
    view_pairs,
)
from xvmatch.inference.views.multi_view_costs import FrameProblem

__all__ = [
    "MultiViewTracks",
    "carry_ids",
    "pairs_from_ids",
    "smoothed_problems",
    "split_at_partner_changes",
    "track_multi_view",
    "tracklet_costs",
    "view_chains",
]


@dataclass(frozen=True, eq=False)
class MultiViewTracks:
    """Person ids carried over frames in every view.

    Attributes:
        person: per view, ``{frame: (n,) int64}`` the person id (1, 2, ...) of each box of the
            frame's record, in record order; the same id in two views of a frame, or in two
            frames, is the same person.
        statuses: per frame solved, the status of its joint program (``optimal``,
            ``fallback`` or ``greedy``; see
            :data:`~xvmatch.inference.views.multi_view_assignment.STATUSES`).
        n_people: person ids used (the largest id).
        max_triangles: the most broken triangles one frame's program added (the budget:
            :data:`~xvmatch.inference.views.multi_view_assignment.MIP_MAX_TRIANGLES`).
    """

    person: tuple[dict[int, np.ndarray], ...]
    statuses: tuple[str, ...]
    n_people: int
    max_triangles: int = 0


def _positions(record: FrameBoxes | None) -> dict[int, int]:
    """``{row id: position in the record}`` of one frame's record."""
    if record is None:
        return {}
    return {int(r): k for k, r in enumerate(np.asarray(record.ids).tolist())}


def tracklet_costs(
    tracklets: Sequence[Sequence[Tracklet]],
    problems: Mapping[int, FrameProblem],
    views: Sequence[Mapping[int, FrameBoxes]],
) -> dict[tuple[int, int], tuple[np.ndarray, np.ndarray]]:
    """Cross-view evidence of the tracklets of one clip, for every view pair ``a < b``.

    Args:
        tracklets: per view, the clip's tracklets.
        problems: ``{frame: FrameProblem}`` (sizes, ``{(a, b): (n_a, n_b)}`` costs in record
            order, gammas), as :func:`~xvmatch.inference.views.multi_view_costs.multi_view_costs`
            builds them.
        views: per view, ``{frame: FrameBoxes}``; a tracklet's ``rows`` are the records' ids.

    Returns:
        ``{(a, b): (total, shared)}``, both ``(len(tracklets[a]), len(tracklets[b]))``: the sum
        of ``c - gamma`` of the two tracklets' boxes over the frames both are present in, and
        the number of those frames.
    """
    n_views = len(tracklets)
    present = [_presence(tracklets[v], views[v]) for v in range(n_views)]
    out = {}
    for a, b in view_pairs(n_views):
        total = np.zeros((len(tracklets[a]), len(tracklets[b])))
        shared = np.zeros_like(total)
        for f in sorted(set(present[a]) & set(present[b])):
            (ta, pa), (tb, pb) = present[a][f], present[b][f]
            total[np.ix_(ta, tb)] += _evidence(problems[f], (a, b), pa, pb)
            shared[np.ix_(ta, tb)] += 1.0
        out[(a, b)] = (total, shared)
    return out


def _evidence(problem: FrameProblem, ab: tuple[int, int], rows: np.ndarray, cols: np.ndarray
              ) -> np.ndarray:
    """``c - gamma`` of view pair ``ab`` for the boxes at record positions ``rows`` x ``cols``."""
    return np.asarray(problem.costs[ab], dtype=float)[np.ix_(rows, cols)] - float(problem.gamma[ab])


def _presence(tracklets: Sequence[Tracklet], frames: Mapping[int, FrameBoxes]
              ) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``{frame: (tracklet indices, box positions in the frame's record)}`` of one view."""
    found: dict[int, tuple[list[int], list[int]]] = {}
    where: dict[int, dict[int, int]] = {}
    for k, tr in enumerate(tracklets):
        for f, row in zip(tr.frames.tolist(), tr.rows.tolist(), strict=True):
            if f not in where:
                where[f] = _positions(frames.get(f))
            entry = found.setdefault(f, ([], []))
            entry[0].append(k)
            entry[1].append(where[f][int(row)])
    return {f: (np.array(t, dtype=np.int64), np.array(p, dtype=np.int64))
            for f, (t, p) in found.items()}


def smoothed_problems(
    tracklets: Sequence[Sequence[Tracklet]],
    problems: Mapping[int, FrameProblem],
    views: Sequence[Mapping[int, FrameBoxes]],
    frame_weight: float = 0.6,
) -> dict[int, FrameProblem]:
    """The frames of one clip with every box pair's cost ``c - gamma`` replaced by
    ``frame_weight (c - gamma) + (1 - frame_weight) m``, ``m`` the mean of ``c - gamma`` of the
    two boxes' tracklets over the frames they share (:func:`tracklet_costs`); gamma 0.

    Returns:
        ``{frame: FrameProblem}`` of every frame of the clip with a box.
    """
    n_views = len(tracklets)
    present = [_presence(tracklets[v], views[v]) for v in range(n_views)]
    pair = tracklet_costs(tracklets, problems, views)
    mean = {ab: total / np.maximum(shared, 1.0) for ab, (total, shared) in pair.items()}
    out = {}
    for f in sorted(set().union(*present)):
        problem = problems[f]
        owner = []  # per view, the tracklet of each box of the frame, record order
        for v in range(n_views):
            o = np.full(int(problem.sizes[v]), -1, dtype=np.int64)
            if f in present[v]:
                o[present[v][f][1]] = present[v][f][0]
            owner.append(o)
        costs = {}
        for ab in pair:
            own = np.asarray(problem.costs[ab], dtype=float) - float(problem.gamma[ab])
            smooth = mean[ab][np.ix_(owner[ab[0]], owner[ab[1]])]
            forbidden = np.isposinf(own) | np.isposinf(smooth)
            mixed = frame_weight * np.where(forbidden, 0.0, own) + (1.0 - frame_weight) * (
                np.where(forbidden, 0.0, smooth))
            costs[ab] = np.where(forbidden, np.inf, mixed)
        out[f] = FrameProblem(tuple(problem.sizes), costs, dict.fromkeys(costs, 0.0))
    return out


def split_at_partner_changes(
    top: Sequence[Tracklet],
    ego: Sequence[Tracklet],
    problems: Mapping[int, FrameProblem],
    top_frames: Mapping[int, FrameBoxes],
    ego_frames: Mapping[int, FrameBoxes],
    view: int,
    confident: float = 2.0,
    persist: int = 2,
) -> tuple[list[Tracklet], np.ndarray]:
    """Cut the egocentric tracklets of one clip where the top-view tracklet they match changes:
    a motion link that joined two people shows as a switch of the confident top-view partner.

    A box's partner is the top-view tracklet of the top box whose frame cost with it,
    ``c - gamma`` of the pair ``(0, view)``, is smallest, if that is below ``-confident``
    (nats; otherwise none). Runs of consecutive boxes with one partner (boxes without one
    skipped) count when they hold at least ``persist`` boxes; a tracklet is cut before the first
    box of every counted run whose partner differs from the previous counted run's (boxes
    without a partner in between stay with the earlier piece). So a shorter run, a single
    frame's confident mistake of the matcher, cuts nothing.

    Args:
        top, ego: the clip's tracklets of the top view (0) and of egocentric view ``view``.
        problems: ``{frame: FrameProblem}``, the frames' costs.
        top_frames, ego_frames: ``{frame: FrameBoxes}`` of the two views.
        view: the egocentric view's index.
        confident: evidence (nats) a partner needs.
        persist: boxes with the new partner a cut needs.

    Returns:
        ``(pieces, parent)``: the tracklets after the cuts, each tracklet's pieces in frame
        order, and ``(len(pieces),)`` int64 the index in ``ego`` each piece comes from.

    Raises:
        ValueError: ``persist`` below 1.
    """
    if persist < 1:
        raise ValueError(f"persist: a cut needs >= 1 box with the new partner, got {persist}")
    partner = [np.full(len(tr), -1, dtype=np.int64) for tr in ego]
    on_top = _presence(top, top_frames)
    for f, (owner, pos) in _presence(ego, ego_frames).items():
        if f not in on_top:
            continue
        t_owner, t_pos = on_top[f]
        c = _evidence(problems[f], (0, view), t_pos, pos)
        best = np.argmin(c, axis=0)
        sure = c[best, np.arange(pos.size)] < -confident
        for k, b, ok in zip(owner.tolist(), best.tolist(), sure.tolist(), strict=True):
            if ok:
                partner[k][np.searchsorted(ego[k].frames, f)] = t_owner[b]
    pieces: list[Tracklet] = []
    parent: list[int] = []
    for k, (tr, p) in enumerate(zip(ego, partner, strict=True)):
        known = np.flatnonzero(p >= 0)
        q = p[known]
        runs = np.flatnonzero(np.r_[True, q[1:] != q[:-1]]) if q.size else np.zeros(0, int)
        held = runs[np.diff(np.r_[runs, q.size]) >= persist]  # runs of >= persist boxes
        cuts = known[held[1:][q[held[1:]] != q[held[:-1]]]]
        for s, e in zip(np.r_[0, cuts].tolist(), np.r_[cuts, len(tr)].tolist(), strict=True):
            pieces.append(Tracklet(tr.clip, tr.frames[s:e], tr.rows[s:e], tr.boxes[s:e]))
            parent.append(k)
    return pieces, np.array(parent, dtype=np.int64)


def _continuations(earlier: Sequence[Tracklet], later: Sequence[Tracklet], min_iou: float,
                   max_gap: int, motion: float | None = None) -> np.ndarray:
    """For each later tracklet, the earlier one it continues (or -1): IoU of the earlier's last
    box and the later's first >= ``min_iou`` (with ``motion``: their motion cost,
    :func:`~xvmatch.cues.box_motion.motion_link_costs`, <= ``motion``), at most ``max_gap``
    frames missing between them, one-to-one by Hungarian on IoU (on the cost); a shorter gap
    wins a tie."""
    out = np.full(len(later), -1, dtype=np.int64)
    if not earlier or not later:
        return out
    last = np.array([t.boxes[-1] for t in earlier])
    first = np.array([t.boxes[0] for t in later])
    gap = (np.array([t.frames[0] for t in later])[None, :]
           - np.array([t.frames[-1] for t in earlier])[:, None] - 1).astype(float)
    near = (gap >= 0) & (gap <= max_gap)
    if motion is None:
        iou = box_iou(last, first)
        ok = (iou >= min_iou) & near
        r, c = linear_sum_assignment(-np.where(ok, iou - 1e-3 * gap, -1.0))
    else:
        r, c, ok = motion_assignment(last, first, motion, gap, near)
    keep = ok[r, c]
    out[c[keep]] = r[keep]
    return out


def view_chains(tracks: Sequence[Sequence[Tracklet]], min_iou: float = 0.5,
                max_gap: int = 3, motion: float | None = None) -> list[np.ndarray]:
    """Per clip, the chain of each tracklet of one view: a tracklet that continues one of the
    previous clip (:func:`_continuations`, by IoU or with a ``motion`` gate) takes its chain,
    any other opens one (0, 1, ...)."""
    chains: list[np.ndarray] = []
    n = 0
    for t, clip in enumerate(tracks):
        ids = np.full(len(clip), -1, dtype=np.int64)
        if t:
            before = _continuations(tracks[t - 1], clip, min_iou, max_gap, motion)
            ids[before >= 0] = chains[t - 1][before[before >= 0]]
        fresh = np.flatnonzero(ids < 0)
        ids[fresh] = n + np.arange(fresh.size)
        n += int(fresh.size)
        chains.append(ids)
    return chains


def carry_ids(clusters: Sequence[np.ndarray], chains: Sequence[np.ndarray],
              owner: dict[tuple[int, int], int], next_id: int,
              top_weight: float = 1.01) -> tuple[np.ndarray, int]:
    """Person ids of one frame's clusters, carried from earlier frames.

    Args:
        clusters: per view, the cluster of each box of the frame (``(n,)`` int64, as
            :attr:`~xvmatch.inference.views.multi_view_assignment.MultiViewSolution.person`).
        chains: per view, the chain (:func:`view_chains`) of each box.
        owner: ``{(view, chain): person id}`` of the latest frame each chain was seen in;
            updated in place.
        next_id: the first unused person id.
        top_weight: a top-view chain's vote (another view's is 1): 1.01 breaks ties; a weight
            above the number of other views makes the top view's chains decide (video mode).

    Returns:
        ``(ids, next_id)``: the person id of each cluster and the next unused id. A cluster
        continues the person whose chains it holds in the most views (the top view, 0,
        breaking ties), one-to-one (Hungarian); any other opens a new id.
    """
    m = 1 + max((int(x.max()) for x in clusters if x.size), default=-1)
    votes: dict[tuple[int, int], float] = {}
    for v, (cl, ch) in enumerate(zip(clusters, chains, strict=True)):
        for q, c in zip(cl.tolist(), ch.tolist(), strict=True):
            g = owner.get((v, int(c)))
            if g is not None:
                votes[(g, q)] = votes.get((g, q), 0.0) + (top_weight if v == 0 else 1.0)
    ids = np.zeros(m, dtype=np.int64)
    if votes:
        people = sorted({g for g, _ in votes})
        index = {g: k for k, g in enumerate(people)}
        w = np.zeros((len(people), m))
        for (g, q), x in votes.items():
            w[index[g], q] = x
        r, c = linear_sum_assignment(-w)
        keep = w[r, c] > 0
        ids[c[keep]] = np.array(people, dtype=np.int64)[r[keep]]
    fresh = np.flatnonzero(ids == 0)
    ids[fresh] = next_id + np.arange(fresh.size)
    for v, (cl, ch) in enumerate(zip(clusters, chains, strict=True)):
        for q, c in zip(cl.tolist(), ch.tolist(), strict=True):
            owner[(v, int(c))] = int(ids[q])
    return ids, next_id + int(fresh.size)


def pairs_from_ids(ids: Sequence[np.ndarray]) -> dict[tuple[int, int], np.ndarray]:
    """The matches of one frame read off person ids: ``{(a, b): (K, 2) rows}`` of every view
    pair, boxes with equal ids paired (each view's ids assumed unique within the frame)."""
    out = {}
    for a, b in view_pairs(len(ids)):
        ia, ib = np.asarray(ids[a]), np.asarray(ids[b])
        i, j = np.nonzero(ia[:, None] == ib[None, :])
        out[(a, b)] = np.stack([i, j], axis=1).astype(np.int64).reshape(-1, 2)
    return out


def _check_track_options(n_views: int, clip_length: int, solver: str, frame_weight: float,
                         motion: float | None, partner_change: float | None) -> None:
    """Refuse fewer than 2 views, a bad ``clip_length``, ``solver``, ``frame_weight``,
    ``motion`` or ``partner_change`` (:func:`track_multi_view`)."""
    if n_views < 2:
        raise ValueError(f"views: give the top view and >= 1 other, got {n_views}")
    if int(clip_length) < 1 or solver not in ("mip", "greedy") or not 0 <= frame_weight <= 1:
        raise ValueError(f"clip_length must be >= 1, solver 'mip' or 'greedy' and "
                         f"frame_weight in [0, 1], got {clip_length}, {solver!r}, "
                         f"{frame_weight}")
    if motion is not None and not motion > 0:
        raise ValueError(f"motion: the link gate must be > 0 box heights (or None for IoU "
                         f"links), got {motion}")
    if partner_change is not None and not partner_change >= 0:
        raise ValueError(f"partner_change: the evidence a top-view partner needs must be >= 0 "
                         f"nats (or None: never cut), got {partner_change}")


def _view_tracks(views: Sequence[Mapping[int, FrameBoxes]], problems: Mapping[int, FrameProblem],
                 clips: list, iou: list[float], gate: list[float | None], max_gap: int,
                 partner_change: float | None) -> tuple[list, list]:
    """Per view and clip, the tracklets and the chain of each across clips; the egocentric
    tracklets cut where their top-view partner changes (for the smoothing; the pieces keep
    their chains)."""
    n_views = len(views)
    tracks = [view_tracklets(views[v], clips, iou[v], max_gap, gate[v]) for v in range(n_views)]
    chains = [view_chains(tracks[v], iou[v], max_gap, gate[v]) for v in range(n_views)]
    if partner_change is not None:  # cut for the smoothing; the pieces keep their chains
        for v, t in ((v, t) for v in range(1, n_views) for t in range(len(clips))):
            tracks[v][t], parent = split_at_partner_changes(
                tracks[0][t], tracks[v][t], problems, views[0], views[v], v, partner_change)
            chains[v][t] = chains[v][t][parent]
    return tracks, chains


def _box_chains(sizes: Sequence[int], f: int, present: list, chains: list, t: int
                ) -> list[np.ndarray]:
    """Per view, the chain of each box of frame f in clip t (-1: a box in no tracklet)."""
    box_chains = []
    for v in range(len(present)):
        ch = np.full(int(sizes[v]), -1, dtype=np.int64)
        if f in present[v]:
            ch[present[v][f][1]] = chains[v][t][present[v][f][0]]
        box_chains.append(ch)
    return box_chains


def track_multi_view(
    views: Sequence[Mapping[int, FrameBoxes]],
    problems: Mapping[int, FrameProblem],
    clip_length: int = 10,
    min_iou: float = 0.7,
    max_gap: int = 3,
    top_min_iou: float = 0.5,
    solver: str = "mip",
    time_limit: float = MIP_TIME_LIMIT,
    frame_weight: float = 0.6,
    motion: float | None = 0.3,
    partner_change: float | None = 2.0,
) -> MultiViewTracks:
    """Follow the people of V views over time with cycle-consistent ids (module docstring).

    Args:
        views: per view (0 the top view), ``{frame: FrameBoxes}``; the records' ``ids`` must
            be unique within a frame (they name the rows; they are never compared across views).
        problems: ``{frame: FrameProblem}`` of every frame (as
            :func:`~xvmatch.inference.views.multi_view_costs.multi_view_costs` builds them).
        clip_length: frames per clip (10, CVMHAT's).
        min_iou, max_gap: the tracklet rule of the egocentric views, inside a clip and across
            clips (``min_iou`` only with ``motion`` None).
        top_min_iou: ``min_iou`` of the top view (0), always linked by IoU.
        solver: ``mip`` (the joint program per frame) or ``greedy`` (pairwise Hungarian made
            consistent).
        time_limit: wall-time guard per frame for the MIP, past which its fallback is used
            (:func:`~xvmatch.inference.views.multi_view_assignment.solve_multi_view`).
        frame_weight: the share of a frame's own cost in the costs (:func:`smoothed_problems`).
        motion: the egocentric views' links by motion, with this gate in box heights
            (:func:`~xvmatch.cues.box_motion.motion_link_costs`); None: by IoU >= ``min_iou``
            (the links before issue 33's motion step).
        partner_change: the egocentric tracklets are cut, for the smoothing only, where the
            top-view tracklet they match with at least this evidence (nats) changes
            (:func:`split_at_partner_changes`; the pieces keep their tracklet's chain, so ids
            carry as before); None: never cut.

    Returns:
        The :class:`MultiViewTracks`.

    Raises:
        ValueError: fewer than 2 views, a bad ``clip_length``, ``solver``, ``frame_weight``,
            ``motion`` or ``partner_change``.
    """
    _check_track_options(len(views), clip_length, solver, frame_weight, motion, partner_change)
    n_views = len(views)
    clips = split_clips(sorted(problems), int(clip_length))
    iou = [top_min_iou, *[min_iou] * (n_views - 1)]
    gate = [None, *[motion] * (n_views - 1)]
    tracks, chains = _view_tracks(views, problems, clips, iou, gate, max_gap, partner_change)
    person: tuple[dict[int, np.ndarray], ...] = tuple(
        {f: np.zeros(len(rec), dtype=np.int64) for f, rec in views[v].items()}
        for v in range(n_views))
    statuses: list[str] = []
    triangles = 0
    owner: dict[tuple[int, int], int] = {}
    next_id = 1
    for t in range(len(clips)):
        clip = [tracks[v][t] for v in range(n_views)]
        present = [_presence(clip[v], views[v]) for v in range(n_views)]
        for f, problem in smoothed_problems(clip, problems, views, frame_weight).items():
            if solver == "mip":
                sol = solve_multi_view(problem.sizes, problem.costs, problem.gamma, time_limit)
            else:
                sol = consistent_hungarian(problem.sizes, problem.costs, problem.gamma)
            statuses.append(sol.status)
            triangles = max(triangles, sol.triangles)
            box_chains = _box_chains(problem.sizes, f, present, chains, t)
            ids, next_id = carry_ids(sol.person, box_chains, owner, next_id)
            for v in range(n_views):
                if f in person[v]:
                    person[v][f][:] = ids[sol.person[v]]
    return MultiViewTracks(person, tuple(statuses), next_id - 1, triangles)
