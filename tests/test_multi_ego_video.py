"""Tests of associate-multi's video mode (inference/views/multi_ego_video.py, --mode)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.views.multi_ego_tracking import pairs_from_ids
from xvmatch.inference.views.multi_ego_video import (
    FORCED_COST,
    top_pairs_along_tracks,
    video_people,
    video_track_ids,
)
from xvmatch.inference.views.multi_view_assignment import cycle_violations
from xvmatch.inference.views.multi_view_costs import FrameProblem
from xvmatch.inference.views.multi_view_people import PeopleOptions, assign_people

FRAMES = list(range(1, 9))


def _views(tracks_per_view):
    """Per view ``{frame: FrameBoxes}`` with row ids ``100 f + n`` and ``{row: track id}``."""
    views, tracks = [], []
    for ids in tracks_per_view:
        view, table = {}, {}
        for f in FRAMES:
            rows = 100 * f + np.arange(len(ids), dtype=np.int64)
            view[f] = FrameBoxes(f, rows, np.tile([10.0, 10.0, 5.0, 10.0], (len(ids), 1)))
            table.update(zip(rows.tolist(), ids, strict=True))
        views.append(view)
        tracks.append(table)
    return views, tracks


def _problems(top_hor, hor_hor, wrong=()):
    """Every frame: top-hor costs ``top_hor[k]`` (swapped rows on the frames of ``wrong``),
    hor1-hor2 costs ``hor_hor``, gamma 0."""
    out = {}
    for f in FRAMES:
        c1 = np.array(top_hor[0], float)
        c1 = c1[:, ::-1] if f in wrong else c1
        costs = {(0, 1): c1, (0, 2): np.array(top_hor[1], float),
                 (1, 2): np.array(hor_hor, float)}
        out[f] = FrameProblem(tuple([c1.shape[0], c1.shape[1], costs[(0, 2)].shape[1]]), costs,
                              dict.fromkeys(costs, 0.0))
    return out


def _frame_pairs(views, person, f, a, b):
    """The pairs of views a and b on frame f, as (row, row)."""
    ra, rb = views[a][f].ids.tolist(), views[b][f].ids.tolist()
    return {(x, y) for x in ra for y in rb if person[a][x] == person[b][y]}


def _consistent(views, person):
    for f in FRAMES:
        ids = [np.array([person[v][r] for r in views[v][f].ids.tolist()]) for v in range(3)]
        assert all(np.unique(i).size == i.size for i in ids)
        assert not cycle_violations(pairs_from_ids(ids), [i.size for i in ids])


def test_a_frame_mistake_is_outvoted_along_the_tracks_and_ids_carry():
    # top tracks 7, 8; hor1 tracks 3, 4; hor2 tracks 5, 6 (the same two people in that
    # order); frames 3 and 6 swap the top-hor1 evidence
    views, tracks = _views([[7, 8], [3, 4], [5, 6]])
    good = [[-3.0, 1.0], [1.0, -3.0]]
    problems = _problems([good, good], [[0.0, 0.0], [0.0, 0.0]], wrong=(3, 6))
    frame = assign_people(views, problems, FRAMES, PeopleOptions())
    assert _frame_pairs(views, frame.person, 3, 0, 1) == {(300, 301), (301, 300)}
    video = video_people(views, problems, FRAMES, tracks, PeopleOptions())
    for f in FRAMES:
        for k in (1, 2):
            assert _frame_pairs(views, video.person, f, 0, k) == {(100 * f, 100 * f),
                                                                  (100 * f + 1, 100 * f + 1)}
        assert _frame_pairs(views, video.person, f, 1, 2) == {(100 * f, 100 * f),
                                                              (100 * f + 1, 100 * f + 1)}
    _consistent(views, video.person)
    # ids carry over frames along the tracks: two people, each one id throughout
    assert video.n_people == 2 and video.n_fallback == 0
    assert {video.person[0][100 * f] for f in FRAMES} == {1}
    assert {video.person[2][100 * f + 1] for f in FRAMES} == {2}


def test_handheld_pairs_follow_the_top_pairs_not_their_own_costs():
    # the hor1-hor2 costs pair them crosswise, strongly; the top view pairs them straight on
    # every frame: each frame stays one set of people, hor-hor through the top view
    views, tracks = _views([[7, 8], [3, 4], [5, 6]])
    good = [[-3.0, 1.0], [1.0, -3.0]]
    problems = _problems([good, good], [[2.0, -4.0], [-4.0, 2.0]])
    for solver in ("mip", "greedy"):
        options = PeopleOptions(solver=solver)
        video = video_people(views, problems, FRAMES, tracks, options)
        _consistent(views, video.person)
        first = assign_people(views, problems, FRAMES, options).person
        kept = [top_pairs_along_tracks(views, first, FRAMES, tracks, k) for k in (1, 2)]
        for f in FRAMES:  # the top-hor pairs are the consensus's, the hor-hor pairs through them
            made = [_frame_pairs(views, video.person, f, 0, k) for k in (1, 2)]
            assert made == [set(kept[0][f]), set(kept[1][f])]
            via = {(h1, h2) for t, h1 in made[0] for s, h2 in made[1] if s == t}
            assert _frame_pairs(views, video.person, f, 1, 2) == via


def test_handheld_people_the_top_view_lacks_pair_on_their_own_costs():
    # hor1 row 1 (track 9) and hor2 row 1 (track 9) are no top person's: their own strong
    # evidence pairs them; the top-held person stays paired through the top view
    views, tracks = _views([[7], [3, 9], [5, 9]])
    problems = _problems([[[-3.0, 1.0]], [[-3.0, 1.0]]], [[0.0, 1.0], [1.0, -4.0]])
    video = video_people(views, problems, FRAMES, tracks, PeopleOptions())
    _consistent(views, video.person)
    for f in FRAMES:
        assert _frame_pairs(views, video.person, f, 1, 2) == {(100 * f, 100 * f),
                                                              (100 * f + 1, 100 * f + 1)}
        assert _frame_pairs(views, video.person, f, 0, 2) == {(100 * f, 100 * f)}


def test_forced_cost_is_far_below_any_evidence():
    assert FORCED_COST <= -100


def test_video_track_ids_reads_the_mode():
    views, _ = _views([[7, 8], [3, 4]])
    file_ids = [np.zeros(900, np.int64), np.zeros(900, np.int64)]
    for v, ids in enumerate([[7, 8], [3, 4]]):
        for f in FRAMES:
            file_ids[v][100 * f + np.arange(2)] = ids
    names = ["top.txt", "hor.txt"]
    assert video_track_ids(views, file_ids, "frame", names) is None
    auto = video_track_ids(views, file_ids, "auto", names)
    assert auto is not None and auto[0][100] == 7 and auto[1][801] == 4
    assert video_track_ids(views, file_ids, "video", names) == auto
    fresh = [np.arange(900, dtype=np.int64), file_ids[1]]  # a new id on every box: no tracks
    assert video_track_ids(views, fresh, "auto", names) is None
    assert video_track_ids(views, fresh, "video", names) is not None  # asked for: taken
    twice = [file_ids[0], np.full(900, -1, np.int64)]  # a detector's -1 on every row
    assert video_track_ids(views, twice, "auto", names) is None
    with pytest.raises(ValueError, match=r"--mode video: hor\.txt: frame 1 holds an id twice"):
        video_track_ids(views, twice, "video", names)
