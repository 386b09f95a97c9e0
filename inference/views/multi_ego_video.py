"""Video mode of ``xvmatch associate-multi``: each frame's people kept consistent along every
view's own track ids, cycle-consistently.

``associate --mode video`` keeps one pair of views consistent over time with the views' track ids
(:func:`~xvmatch.inference.linking.pair_consensus.tracklet_consensus`: a Viterbi per top-view
track over its partner). With one top view and several horizontal ones:

1. every frame is solved as in frame mode (or with ``--tracks``)
   (:func:`~xvmatch.inference.views.multi_view_people.assign_people`): the frame's people, read
   as top-horizontal pairs of track ids per horizontal view;
2. per horizontal view ``k``, the pairs of (top, ``k``) made consistent along the two views'
   tracks, each horizontal view on its own (:func:`top_pairs_along_tracks`);
3. every frame solved again with those pairs as its only top-horizontal pairs (every other
   top-horizontal pair forbidden): the cycle constraints then pair two horizontal people who
   share a top person, and never two of whom one has a top person and the other another or
   none; horizontal people the top view does not hold are paired on their own costs
   (:func:`video_people`; read off without a solver where no such pair gains,
   :func:`_direct`). So the answer is one set of people on every frame, as in frame mode, and
   its top-horizontal pairs are those of the consensus;
4. person ids carried from frame to frame along the tracks
   (:func:`~xvmatch.inference.views.multi_ego_tracking.carry_ids`): a person keeps the id of
   its top-view track (:data:`TOP_VOTE`), else the id whose boxes lay on the same tracks in
   the most views the last time they were seen.

Within-view ids are read as track ids (never compared across views): use only on videos whose
ids persist (:func:`video_track_ids`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from xvmatch.inference.linking.pair_consensus import tracklet_consensus
from xvmatch.inference.views.multi_view_costs import FrameProblem

__all__ = ["AUTO_VIDEO", "FORCED_COST", "top_pairs_along_tracks", "video_people",
           "video_track_ids"]

AUTO_VIDEO = ("--mode video: each view's ids persist from frame to frame (track ids), so the "
              "pairs were kept consistent along them; --mode frame solves each frame alone")
"""The note of ``associate-multi --mode auto`` taking video mode, said with the summary."""

FORCED_COST = -1e3
"""Cost of a top-horizontal pair the consensus keeps in the second solve: far below any
evidence (a few nats), so that the program always makes it."""

TOP_VOTE = 1e3
"""A top-view track's vote for its earlier person id (each other view's track: 1): the ids
follow the top view's tracks, the horizontal views' tracks deciding among what is left."""

TrackIds = Sequence[Mapping[int, int]]
"""Per view (top first), ``{row id: track id}``: the view's own id of each box."""


def video_track_ids(views: Sequence[Mapping], file_ids: Sequence[np.ndarray], mode: str,
                    names: Sequence[str]) -> list[dict[int, int]] | None:
    """``--mode``: each view's ``{row id: track id}`` for video mode, or None for frame mode.

    Args:
        views: per view (top first) ``{frame: record}`` whose ``ids`` are row numbers.
        file_ids: per view, ``(R,)`` the id column of every row.
        mode: ``auto`` (video when every view's ids persist from frame to frame,
            :func:`~xvmatch.cues.box_motion.is_video`, and no id repeats within a frame),
            ``frame`` or ``video``.
        names: the box files (messages).

    Raises:
        ValueError: ``video`` where an id repeats within a frame of a view (a detector's ids,
            not a tracker's).
    """
    if mode == "frame":
        return None
    from xvmatch.cues.box_motion import is_video
    from xvmatch.formats.mot_boxes import FrameBoxes

    tracked = []
    for v, (view, ids) in enumerate(zip(views, file_ids, strict=True)):
        ids = np.asarray(ids, dtype=np.int64)
        for f, record in sorted(view.items()):
            own = ids[np.asarray(record.ids, dtype=np.int64)]
            if len(np.unique(own)) < len(own):
                if mode == "auto":
                    return None
                raise ValueError(f"--mode video: {names[v]}: frame {f} holds an id twice; video "
                                 "mode reads each view's ids as track ids (one box per id and "
                                 "frame); use --mode frame")
        tracked.append({f: FrameBoxes(f, ids[np.asarray(r.ids, np.int64)], r.boxes)
                        for f, r in view.items()})
    if mode == "auto" and not is_video(*tracked):
        return None
    return [dict(zip(np.arange(len(ids)).tolist(), np.asarray(ids).tolist(), strict=True))
            for ids in file_ids]


def _rows(record) -> list[int]:
    return [] if record is None else np.asarray(record.ids, dtype=np.int64).tolist()


def top_pairs_along_tracks(views: Sequence[Mapping], person: Sequence[Mapping[int, int]],
                           frames: Sequence[int], tracks: TrackIds, k: int,
                           keep_free: bool = True) -> dict[int, list[tuple[int, int]]]:
    """The (top, ``k``) pairs of a frame-by-frame answer made consistent along the tracks.

    Args:
        views: per view (top first) ``{frame: record}`` whose ``ids`` are row ids.
        person: per view ``{row id: person id}`` (:class:`~xvmatch.inference.views.
            multi_view_people.ViewPeople`'s ``person``): two boxes of a frame with one id are
            one person.
        frames: the frames.
        tracks: per view ``{row id: track id}``.
        k: the horizontal view (1-based).
        keep_free: a top track no partner holds keeps its frames' own pairs
            (:func:`~xvmatch.inference.linking.pair_consensus.tracklet_consensus`).

    Returns:
        ``{frame: [(top row, row of view k), ...]}`` for every frame of ``frames``.
    """
    pairs, present, back = {}, {}, {}
    for f in frames:
        t_rows, h_rows = _rows(views[0].get(f)), _rows(views[k].get(f))
        back[f] = ({tracks[0][r]: r for r in t_rows}, {tracks[k][r]: r for r in h_rows})
        present[f] = (np.array([tracks[0][r] for r in t_rows], dtype=np.int64),
                      np.array([tracks[k][r] for r in h_rows], dtype=np.int64))
        of_person = {person[k][r]: r for r in h_rows if r in person[k]}
        pairs[f] = [(tracks[0][r], tracks[k][of_person[person[0][r]]]) for r in t_rows
                    if person[0].get(r) in of_person]
    kept = tracklet_consensus(pairs, present, keep_free=keep_free)
    return {f: [(back[f][0][t], back[f][1][h]) for t, h in kept[f]] for f in frames}


def _forced(problem: FrameProblem, rows: Sequence[list[int]],
            kept: Mapping[int, Sequence[tuple[int, int]]]) -> FrameProblem:
    """The frame's problem with ``kept`` (``{k: [(top row, row of k)]}``) its only top-horizontal
    pairs: :data:`FORCED_COST` for those, +inf for every other."""
    costs = dict(problem.costs)
    for k, pairs in kept.items():
        c = np.full((problem.sizes[0], problem.sizes[k]), np.inf)
        at_top = {r: i for i, r in enumerate(rows[0])}
        at_hor = {r: j for j, r in enumerate(rows[k])}
        for t, h in pairs:
            c[at_top[t], at_hor[h]] = FORCED_COST
        costs[(0, k)] = c
    return FrameProblem(problem.sizes, costs, problem.gamma)


def _direct(problem: FrameProblem, rows: Sequence[list[int]],
            kept: Mapping[int, Sequence[tuple[int, int]]]) -> tuple[np.ndarray, ...] | None:
    """The optimum of :func:`_forced`'s program read off without solving it, or None where it
    needs solving: every kept pair made, two horizontal boxes one person when they share a top
    person, every other box alone. That is the optimum when no two horizontal boxes without a
    top person gain by a pair (cost >= gamma: boxes only, or the oblique path) and no pair
    through a top person is forbidden. Clusters are numbered as
    :func:`~xvmatch.inference.views.multi_view_assignment.global_ids` numbers them."""
    cluster = [np.arange(problem.sizes[0], dtype=np.int64),
               *(np.full(problem.sizes[k], -1, dtype=np.int64) for k in kept)]
    for k, pairs in kept.items():
        at_top = {r: i for i, r in enumerate(rows[0])}
        at_hor = {r: j for j, r in enumerate(rows[k])}
        for t, h in pairs:
            cluster[k][at_hor[h]] = at_top[t]
    for (a, b), c in problem.costs.items():
        if a == 0:
            continue
        gain = np.asarray(c, dtype=float) - problem.gamma[(a, b)]
        free_a, free_b = cluster[a] < 0, cluster[b] < 0
        same = (cluster[a][:, None] == cluster[b][None, :]) & ~free_a[:, None]
        if (gain[np.ix_(free_a, free_b)] < 0).any() or not np.isfinite(gain[same]).all():
            return None
    start = problem.sizes[0]
    for v in range(1, len(cluster)):
        free = np.flatnonzero(cluster[v] < 0)
        cluster[v][free] = start + np.arange(free.size)
        start += free.size
    return tuple(cluster)


def video_people(views: Sequence[Mapping], problems: Mapping[int, FrameProblem],
                 frames: Sequence[int], tracks: TrackIds, options, keep_free: bool = True):
    """Person ids for every box of ``views``, the top-horizontal pairs of each horizontal view
    kept consistent along the tracks (module docstring).

    Args:
        views: per view (top first) ``{frame: record}`` whose ``ids`` are row ids (unique).
        problems: ``{frame: FrameProblem}`` of every frame of ``frames``.
        frames: the frames to solve.
        tracks: per view ``{row id: track id}``: the view's own ids, persisting over time.
        options: :class:`~xvmatch.inference.views.multi_view_people.PeopleOptions` (the first
            solve's ``solver``, ``tracks`` and ``clip_length``; the second solve's ``solver``
            and ``time_limit``).
        keep_free: as :func:`top_pairs_along_tracks`.

    Returns:
        :class:`~xvmatch.inference.views.multi_view_people.ViewPeople`; ``n_fallback`` counts
        the programs of either solve that used the best consistent answer found (at most one a
        frame is counted: the command says "N of M frames").
    """
    from xvmatch.inference.views.multi_ego_tracking import carry_ids
    from xvmatch.inference.views.multi_view_people import ViewPeople, assign_people, solve_frame

    first = assign_people(views, problems, frames, options)
    n_views = len(views)
    kept = {k: top_pairs_along_tracks(views, first.person, frames, tracks, k, keep_free)
            for k in range(1, n_views)}
    person: list[dict[int, int]] = [{} for _ in views]
    owner: dict[tuple[int, int], int] = {}
    next_id, n_fallback = 1, first.n_fallback
    for f in frames:
        rows = [_rows(v.get(f)) for v in views]
        here = {k: kept[k][f] for k in kept}
        clusters = _direct(problems[f], rows, here)
        if clusters is None:
            sol, fell_back = solve_frame(_forced(problems[f], rows, here), options)
            n_fallback += fell_back
            clusters = sol.person
        chains = [np.array([tracks[v][r] for r in rows[v]], dtype=np.int64)
                  for v in range(n_views)]
        ids, next_id = carry_ids(clusters, chains, owner, next_id, TOP_VOTE)
        for v in range(n_views):
            person[v].update(zip(rows[v], ids[clusters[v]].tolist(), strict=True))
    return ViewPeople(person, next_id - 1, min(n_fallback, len(frames)))
