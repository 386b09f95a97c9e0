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


def test_the_forced_program_read_off_is_its_optimum():
    # random frames of 1 top + 2 or 3 horizontal views: where _direct answers, its people are
    # those of the forced program solved by HiGHS; where a pair of horizontal boxes without a
    # top person gains, it leaves the frame to the solver
    from xvmatch.inference.views.multi_ego_video import _direct, _forced
    from xvmatch.inference.views.multi_view_assignment import global_ids, solve_multi_view

    rng = np.random.default_rng(7)
    answered = 0
    for trial in range(40):
        n_views = 3 + trial % 2
        sizes = tuple(int(x) for x in rng.integers(0, 5, n_views))
        rows = [list(range(100 * v, 100 * v + sizes[v])) for v in range(n_views)]
        costs = {}
        for a in range(n_views):
            for b in range(a + 1, n_views):
                low = -1.0 if trial % 3 == 0 and a else 0.05
                costs[(a, b)] = rng.uniform(low, 2.0, (sizes[a], sizes[b]))
        problem = FrameProblem(sizes, costs, dict.fromkeys(costs, 0.0))
        kept = {}
        for k in range(1, n_views):
            top, hor = rng.permutation(sizes[0]), rng.permutation(sizes[k])
            m = int(rng.integers(0, min(sizes[0], sizes[k]) + 1))
            kept[k] = [(rows[0][t], rows[k][h]) for t, h in zip(top[:m], hor[:m], strict=True)]
        direct = _direct(problem, rows, kept)
        forced = _forced(problem, rows, kept)
        solved = solve_multi_view(forced.sizes, forced.costs, forced.gamma)
        assert solved.status == "optimal"
        if direct is None:
            continue
        answered += 1
        for mine, theirs in zip(direct, solved.person, strict=True):
            np.testing.assert_array_equal(mine, theirs)
        assert all(np.array_equal(x, y) for x, y in zip(
            global_ids(pairs_from_ids(direct), sizes), direct, strict=True))
    assert 15 <= answered < 40


@pytest.mark.slow
def test_the_oblique_path_in_video_mode():
    # benchmarks/oblique_multi_view.py's scene 1 (12 s, every 3rd frame), ids scrambled per view:
    # video mode keeps every frame one set of people and pairs at least as well as each frame
    import sys
    from itertools import combinations
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from oblique_association import _scrambled
    from oblique_multi_view import by_row, f1, people_pairs, row_tracks, score

    from xvmatch.datasets.oblique_scenes import ObliqueSceneConfig, make_oblique_scene
    from xvmatch.inference.matching.ground_association import top_calibration
    from xvmatch.inference.views.multi_ground import MultiGroundOptions, run_multi_ground

    config = ObliqueSceneConfig(n_hor=2)
    scene = make_oblique_scene(config, 120, np.random.default_rng([0, 1]))
    rng = np.random.default_rng([0, 1, 1])
    raw = [scene.top, *(scene.hor[f"hor{k}"] for k in (1, 2))]
    frames = [f for f in sorted(set().union(*raw)) if (f - 1) % 3 == 0]
    views, backs = zip(*(_scrambled({f: v[f] for f in frames if f in v}, rng) for v in raw),
                       strict=True)
    views = list(views)
    truth = {(a, b): {f: {(int(i), int(j)) for i in views[a][f].ids for j in views[b][f].ids
                          if backs[a][int(i)] == backs[b][int(j)]}
                      for f in frames if f in views[a] and f in views[b]}
             for a, b in combinations(range(3), 2)}
    calib = top_calibration(views[0], scene.top_cameras[0].image_size)
    options = MultiGroundOptions(tuple(tuple(scene.hor_cameras[f"hor{k}"][0].image_size)
                                       for k in (1, 2)), fps=config.fps)
    got = {}
    for name, tracks in (("frame", None), ("video", row_tracks(views))):
        run = run_multi_ground([by_row(v) for v in views], [0, 0], calib, options,
                               PeopleOptions(), tracks)
        pairs = people_pairs(run.people.person, views, frames)
        got[name] = f1(score(pairs, truth, lambda ab: True))
        rows = [by_row(v) for v in views]
        for f in frames:
            ids = [np.array([run.people.person[v][r] for r in rows[v][f].ids.tolist()])
                   if f in rows[v] else np.zeros(0, np.int64) for v in range(3)]
            assert not cycle_violations(pairs_from_ids(ids), [i.size for i in ids])
    assert got["video"] >= got["frame"] > 0.5
