"""Complementary-view tracking: tracklets, edge weights, the four-cluster MIP, stitching."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.box_overlap import box_iou
from xvmatch.inference.linking.tracklets import (
    Tracklet,
    box_track_ids,
    clip_tracklets,
    split_clips,
)
from xvmatch.inference.tracks.track_costs import (
    TrackWeights,
    combine_cross_view,
    combine_over_time,
    motion_similarity,
    spatial_similarity,
)
from xvmatch.inference.tracks.track_mip import (
    greedy_solution,
    loop_violations,
    objective,
    repair_loops,
    solve_four_clusters,
)
from xvmatch.inference.tracks.track_spectral import spectral_groups, spectral_solution
from xvmatch.inference.tracks.track_stitching import stitch_windows
from xvmatch.inference.tracks.tracking import TrackConfig, track_pair


def _tracklet(clip: int, frames, rows, centres, size=(10.0, 10.0)) -> Tracklet:
    c = np.asarray(centres, dtype=float).reshape(-1, 2)
    boxes = np.c_[c - 0.5 * np.asarray(size), np.tile(size, (len(c), 1))]
    return Tracklet(clip, np.asarray(frames), np.asarray(rows), boxes)


# --- tracklets -------------------------------------------------------------------------------


def test_box_iou_reference_values():
    a = np.array([[0, 0, 10, 10]])
    b = np.array([[0, 0, 10, 10], [5, 0, 10, 10], [20, 20, 5, 5]])
    # Half overlap: intersection 50, union 150 -> 1/3.
    assert box_iou(a, b) == pytest.approx(np.array([[1.0, 1 / 3, 0.0]]))


def test_split_clips_holds_the_frames_present_and_one_clip_per_gap():
    clips = split_clips([3, 25, 7, 7], 10)
    # Clips start every 10 frames from frame 3: 3..12, 13..22 (empty), 23..32.
    assert [c.tolist() for c in clips] == [[3, 7], [], [25]]
    clips = split_clips([1, 2, 11, 12, 50, 10**9], 10)
    assert [c.tolist() for c in clips] == [[1, 2], [11, 12], [], [50], [], [10**9]]
    assert split_clips([], 10) == []
    with pytest.raises(ValueError, match="clip length"):
        split_clips([1], 0)


def test_track_over_a_gap_of_a_billion_frames_visits_only_the_frames_present():
    # One person, seen at frames 1-3 and 10**9 + 1-3 in both views: stepping through the
    # frames between (as the tracker once did) would take minutes and run out of memory.
    scene = simulate_box_scene(SceneConfig(n_people=(3, 3)), n_frames=3, seed=0)
    late = 10**9  # frames 10**9 + 1 to 10**9 + 3, all in one clip
    top = {**scene.top, **{f + late: FrameBoxes(f + late, r.ids + 100, r.boxes)
                           for f, r in scene.top.items()}}
    hor = {**scene.hor, **{f + late: FrameBoxes(f + late, r.ids + 100, r.boxes)
                           for f, r in scene.hor.items()}}
    rows = {}
    for name, view in (("top", top), ("hor", hor)):  # ids become unique row numbers
        n = 0
        rows[name] = {}
        for f, r in sorted(view.items()):
            rows[name][f] = FrameBoxes(f, np.arange(n, n + len(r)), r.boxes)
            n += len(r)
    result = track_pair(rows["top"], rows["hor"], 1920.0)
    assert result.n_windows == 2  # clips: frames 1-3, one empty clip, the late frames
    assert len(result.top_rows) == sum(len(r) for r in top.values())
    assert {f for f in result.frame_pairs} == set(top)


def test_track_without_boxes_is_one_line():
    scene = simulate_box_scene(SceneConfig(n_people=(2, 2)), n_frames=2, seed=0)
    for top, hor, name in ((scene.top, {}, "horizontal"), ({}, scene.hor, "top")):
        with pytest.raises(ValueError, match=f"the {name} view has no boxes"):
            track_pair(top, hor, 1920.0)


def test_clip_tracklets_links_by_iou_over_short_gaps():
    def rec(f, ids, xs):
        return FrameBoxes(f, np.array(ids), np.array([[x, 0, 10, 10] for x in xs], float))

    # Two people moving 1 px per frame, listed in a different order on frame 2; frame 4 missing.
    frames = {1: rec(1, [0, 1], [0, 100]), 2: rec(2, [2, 3], [101, 1]), 3: rec(3, [4, 5], [2, 102]),
              5: rec(5, [6], [4])}
    tracklets = clip_tracklets(frames, np.arange(1, 6), clip=0, max_gap=0)
    rows = sorted(t.rows.tolist() for t in tracklets)
    assert rows == [[0, 3, 4], [1, 2, 5], [6]]
    # A one-frame miss is bridged when the gap is allowed (IoU of x=2 and x=4 boxes: 8/12).
    tracklets = clip_tracklets(frames, np.arange(1, 6), clip=0, max_gap=1)
    assert sorted(t.rows.tolist() for t in tracklets) == [[0, 3, 4, 6], [1, 2, 5]]


def test_box_track_ids_follow_people_by_their_boxes_not_their_ids():
    def rec(f, ids, xs):
        return FrameBoxes(f, np.array(ids), np.array([[x, 0, 10, 20] for x in xs], float))

    # Two people 4 px a frame apart (IoU 0.43: linked at 0.3, not at the paper's 0.5), their
    # ids new on every frame and the same on frame 21 for both (the ids are not read).
    # A gap counts the frames with boxes (every 10th frame of a video), not frame numbers.
    frames = {1: rec(1, [7, 8], [0, 100]), 11: rec(11, [1, 2], [104, 4]),
              21: rec(21, [5, 5], [8, 108]), 31: rec(31, [3], [200]), 41: rec(41, [0], [10])}
    assert box_track_ids(frames).tolist() == [0, 1, 1, 0, 0, 1, 2, 0]
    # The frame of 31 a missed one: linked over one frame with boxes, not over none.
    assert box_track_ids(frames, max_gap=0).tolist() == [0, 1, 1, 0, 0, 1, 2, 3]
    assert box_track_ids(frames, min_iou=0.5).tolist() == [0, 1, 2, 3, 4, 5, 6, 4]
    assert box_track_ids({}).tolist() == []


# --- edge weights ----------------------------------------------------------------------------


def test_spatial_similarity_is_eq13_fraction():
    top = [_tracklet(0, [1, 2, 3, 4], [0, 1, 2, 3], [[0, 0]] * 4)]
    hor = [_tracklet(0, [2, 3], [10, 11], [[0, 0]] * 2),
           _tracklet(0, [1, 2], [12, 13], [[0, 0]] * 2)]
    pairs = {1: [(0, 12)], 2: [(1, 10)], 3: [(2, 11)], 4: []}
    # Paired on 2 of the longer tracklet's 4 frames, and on 1 of 4.
    assert spatial_similarity(top, hor, pairs) == pytest.approx(np.array([[2 / 4, 1 / 4]]))


def test_motion_similarity_constant_velocity():
    earlier = [_tracklet(0, [1, 2, 3], [0, 1, 2], [[0, 0], [1, 0], [2, 0]])]
    on_line = _tracklet(1, [4, 5], [3, 4], [[3, 0], [4, 0]])
    off_line = _tracklet(1, [4, 5], [5, 6], [[3, 4], [4, 4]])
    sim = motion_similarity(earlier, [on_line, off_line], sigma=0.5)
    # Forward and backward deviations: 0 on the line; 4 + 4 pixels off it, in units of the
    # 10-pixel box height: 0.4 + 0.4.
    assert sim == pytest.approx(np.array([[1.0, np.exp(-0.5 * 0.8)]]))
    overlapping = _tracklet(1, [3], [7], [[2, 0]])
    assert motion_similarity(earlier, [overlapping])[0, 0] == 0.0
    # Each deviation is measured in units of the box it is measured at: the forward one at
    # the later tracklet's (20 px), the backward one at the earlier tracklet's (10 px).
    big = _tracklet(1, [4, 5], [8, 9], [[3, 4], [4, 4]], size=(20.0, 20.0))
    assert motion_similarity(earlier, [big], sigma=0.5)[0, 0] == pytest.approx(
        np.exp(-0.5 * (4 / 20 + 4 / 10)))


@settings(max_examples=30, deadline=None)
@given(st.floats(0.25, 4.0), st.integers(0, 2**16))
def test_motion_similarity_is_resolution_free(scale, seed):
    rng = np.random.default_rng(seed)

    def random_tracklet(clip, start):
        c = rng.uniform(0, 500, 2) + np.cumsum(rng.normal(0, 3, (5, 2)), axis=0)
        return _tracklet(clip, np.arange(start, start + 5), np.arange(5), c,
                         size=tuple(rng.uniform(10, 200, 2)))

    def scaled(t):
        return Tracklet(t.clip, t.frames, t.rows, t.boxes * scale)

    earlier = [random_tracklet(0, 1) for _ in range(3)]
    later = [random_tracklet(1, 7) for _ in range(4)]
    np.testing.assert_allclose(
        motion_similarity([scaled(t) for t in earlier], [scaled(t) for t in later]),
        motion_similarity(earlier, later), rtol=1e-9, atol=1e-12)


def test_combinations_eq17_eq18():
    w = TrackWeights()
    assert combine_cross_view(np.array([1.0]), np.array([0.0]), w) == pytest.approx([0.3])
    assert combine_over_time(np.array([1.0]), np.array([0.0]), w) == pytest.approx([0.4])
    assert combine_cross_view(np.array([0.7]), None, w) == pytest.approx([0.7])
    with pytest.raises(ValueError, match="c0"):
        TrackWeights(c0=2.0)


# --- the four-cluster MIP --------------------------------------------------------------------


def _check_constraints(edges, sizes):
    for i, e in enumerate(edges):
        assert e.shape == (sizes[i], sizes[(i + 1) % 4])
        assert set(np.unique(e).tolist()) <= {0, 1}
        assert (e.sum(axis=0) <= 1).all() and (e.sum(axis=1) <= 1).all()  # Eq. 2
    assert loop_violations(edges) == []  # Eq. 3


def _brute_force(weights, c0):
    """Best Eq. 1 value over every assignment (tiny problems only)."""
    shapes = [w.shape for w in weights]
    cells = [(i, a, b) for i, s in enumerate(shapes) for a in range(s[0]) for b in range(s[1])]
    best = -np.inf
    for bits in itertools.product((0, 1), repeat=len(cells)):
        edges = [np.zeros(s, dtype=np.int8) for s in shapes]
        for on, (i, a, b) in zip(bits, cells, strict=True):
            edges[i][a, b] = on
        if any((e.sum(0) > 1).any() or (e.sum(1) > 1).any() for e in edges):
            continue
        if loop_violations(edges):
            continue
        best = max(best, objective(weights, edges, c0))
    return best


def test_mip_two_people_forms_two_loops():
    eye = np.eye(2)
    weights = [eye * 0.9, eye[::-1] * 0.8, eye[::-1] * 0.9, eye * 0.8]
    sol = solve_four_clusters(weights)
    assert sol.status == "optimal"
    for e, w in zip(sol.edges, weights, strict=True):
        assert np.array_equal(e, (w > 0).astype(np.int8))
    assert sol.dummies.tolist() == [0, 0, 0, 0]  # K = 2, every cluster has 4 real edge ends


def test_mip_loop_forces_a_weak_closing_edge():
    # Three strong edges and a weak fourth: the loop (Eq. 3) is worth more than any open path.
    w = [np.array([[0.9]]), np.array([[0.9]]), np.array([[0.9]]), np.array([[0.1]])]
    sol = solve_four_clusters(w)
    assert [int(e[0, 0]) for e in sol.edges] == [1, 1, 1, 1]
    assert objective(w, sol.edges, 0.2) == pytest.approx(2.8)
    assert _brute_force(w, 0.2) == pytest.approx(2.8)


def test_mip_rejects_bad_shapes():
    with pytest.raises(ValueError, match="chained"):
        solve_four_clusters([np.zeros((2, 2)), np.zeros((3, 2)), np.zeros((2, 2)),
                             np.zeros((2, 2))])
    ok = [np.zeros((1, 1))] * 4
    for bad in ({"time_limit": 0.0}, {"max_rounds": 0}, {"max_loops": -1}):
        with pytest.raises(ValueError, match="max_loops >= 0"):
            solve_four_clusters(ok, **bad)


@st.composite
def _problems(draw, max_size=3):
    sizes = [draw(st.integers(0, max_size)) for _ in range(4)]
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    return [rng.random((sizes[i], sizes[(i + 1) % 4])) ** 2 for i in range(4)]


@settings(max_examples=40, deadline=None)
@given(_problems())
def test_mip_solutions_satisfy_the_constraints(weights):
    sizes = [w.shape[0] for w in weights]
    sol = solve_four_clusters(weights)
    _check_constraints(sol.edges, sizes)
    assert sol.status == "optimal"
    k = max(sizes)
    for i in range(4):  # Eq. 4
        ends = sol.edges[(i - 1) % 4].sum() + sol.edges[i].sum() + sol.dummies[i]
        assert ends == 2 * k and sol.dummies[i] >= 0
    greedy = greedy_solution(weights)
    _check_constraints(greedy.edges, sizes)
    assert objective(weights, sol.edges, 0.2) >= objective(weights, greedy.edges, 0.2) - 1e-9


@settings(max_examples=15, deadline=None)
@given(_problems(max_size=2))
def test_mip_is_optimal_on_tiny_problems(weights):
    if sum(w.size for w in weights) > 12:
        return
    sol = solve_four_clusters(weights)
    assert objective(weights, sol.edges, 0.2) == pytest.approx(_brute_force(weights, 0.2))


@settings(max_examples=30, deadline=None)
@given(_problems(max_size=4), st.integers(1, 3))
def test_a_spent_round_budget_answers_the_best_loop_free_answer_seen(weights, rounds):
    """Out of rounds, the answer still keeps Eqs. 2-4 and is worth at least the greedy one."""
    sizes = [w.shape[0] for w in weights]
    sol = solve_four_clusters(weights, max_rounds=rounds)
    assert sol.status in ("optimal", "fallback") and sol.rounds <= rounds
    _check_constraints(sol.edges, sizes)
    assert (sol.dummies == 2 * max(sizes) - np.array(
        [sol.edges[(i - 1) % 4].sum() + sol.edges[i].sum() for i in range(4)])).all()
    greedy = objective(weights, greedy_solution(weights).edges, 0.2)
    assert objective(weights, sol.edges, 0.2) >= greedy - 1e-9


def test_a_spent_round_budget_keeps_the_programs_answer_not_the_greedy_one():
    # One program leaves broken loops here; cutting them keeps it optimal (10.9306), where the
    # greedy answer is worth 10.633: the fallback used to be the greedy one.
    rng = np.random.default_rng(3)
    n = [5, 5, 4, 4]
    weights = [rng.random((n[i], n[(i + 1) % 4])) ** 4 for i in range(4)]
    once = solve_four_clusters(weights, max_rounds=1)
    full = solve_four_clusters(weights)
    assert once.status == "fallback" and full.status == "optimal"
    assert full.loops == 3  # the loops the first program broke
    spent = solve_four_clusters(weights, time_limit=600.0, max_loops=0)  # work, not time
    assert spent.status == "fallback" and spent.rounds == 1 and spent.loops == 0
    assert all((a == b).all() for a, b in zip(spent.edges, once.edges, strict=True))
    assert objective(weights, once.edges, 0.2) == pytest.approx(objective(weights, full.edges, 0.2))
    assert objective(weights, once.edges, 0.2) > objective(
        weights, greedy_solution(weights).edges, 0.2) + 0.1


def test_a_loop_budget_too_small_for_a_round_fills_it_with_the_loops_worth_most():
    # the first program breaks 4 loops; a budget of 1 adds the one whose edges are worth most
    # and solves a last program, whose repaired answer is the optimum here (12.9952); stopping
    # at once, as before, left the first program's repaired answer (12.938)
    rng = np.random.default_rng(0)
    weights = [rng.random((5, 5)) ** 3 for _ in range(4)]
    full = solve_four_clusters(weights)
    assert (full.status, full.loops) == ("optimal", 4)
    none = solve_four_clusters(weights, time_limit=600.0, max_loops=0)
    one = solve_four_clusters(weights, time_limit=600.0, max_loops=1)
    assert (none.rounds, none.loops) == (1, 0) and (one.status, one.rounds, one.loops) == (
        "fallback", 2, 1)
    assert objective(weights, one.edges, 0.2) == pytest.approx(objective(weights, full.edges, 0.2))
    assert objective(weights, one.edges, 0.2) > objective(weights, none.edges, 0.2) + 0.05


@settings(max_examples=60, deadline=None)
@given(_problems(max_size=4), st.integers(0, 2**32 - 1), st.sampled_from([0.0, 0.2, 0.5]))
def test_repair_loops_only_cuts_or_closes_broken_loops(weights, seed, c0):
    rng = np.random.default_rng(seed)
    edges = []
    for w in weights:  # any answer of Eq. 2: a random partial matching per edge set
        e = np.zeros(w.shape, dtype=np.int8)
        k = min(w.shape)
        if k:
            r, c = rng.permutation(w.shape[0])[:k], rng.permutation(w.shape[1])[:k]
            keep = rng.random(k) < 0.8
            e[r[keep], c[keep]] = 1
        edges.append(e)
    before = [e.copy() for e in edges]
    broken = loop_violations(edges)
    on_broken = {(i, a, b) for j, *abcd in broken
                 for i, a, b in ((j, abcd[0], abcd[1]), ((j + 1) % 4, abcd[1], abcd[2]),
                                 ((j + 2) % 4, abcd[2], abcd[3]))}
    closing = {((j + 3) % 4, d, a) for j, a, _, _, d in broken}
    fixed = repair_loops(weights, edges, c0)
    _check_constraints(fixed, [w.shape[0] for w in weights])  # Eqs. 2 and 3
    assert all((e == b).all() for e, b in zip(edges, before, strict=True))  # input untouched
    for i, (f, e) in enumerate(zip(fixed, edges, strict=True)):
        assert {(i, a, b) for a, b in zip(*np.nonzero((e == 1) & (f == 0)), strict=True)} \
            <= on_broken
        assert {(i, a, b) for a, b in zip(*np.nonzero((e == 0) & (f == 1)), strict=True)} \
            <= closing
    if not broken:
        assert all((f == e).all() for f, e in zip(fixed, edges, strict=True))


def test_repair_loops_closes_a_loop_worth_closing_and_cuts_one_that_is_not():
    one = np.ones((1, 1))
    path = [np.ones((1, 1), np.int8), np.ones((1, 1), np.int8), np.ones((1, 1), np.int8),
            np.zeros((1, 1), np.int8)]
    closed = repair_loops([one * 0.9, one * 0.9, one * 0.9, one * 0.5], path, 0.2)
    assert [int(e[0, 0]) for e in closed] == [1, 1, 1, 1]  # 0.5 - 0.4 > 0.4 - 0.9
    cut = repair_loops([one * 0.9, one * 0.3, one * 0.9, one * -1.0], path, 0.2)
    assert [int(e[0, 0]) for e in cut] == [1, 0, 1, 0]  # the weakest edge goes


def test_the_mip_budget_is_work_not_time():
    """A window over its node budget falls back on any CPU, however much time is left; within
    it the answer does not depend on the time limit."""
    rng = np.random.default_rng(3)
    n = [4, 3, 4, 3]
    weights = [rng.random((n[i], n[(i + 1) % 4])) for i in range(4)]
    assert solve_four_clusters(weights, time_limit=600.0, node_limit=0).status == "fallback"
    fast = solve_four_clusters(weights)
    slow = solve_four_clusters(weights, time_limit=600.0)
    assert fast.status == slow.status == "optimal"
    assert all((a == b).all() for a, b in zip(fast.edges, slow.edges, strict=True))


# --- spectral baseline -----------------------------------------------------------------------


def test_spectral_groups_separates_blocks():
    w = np.kron(np.eye(3), np.ones((2, 2))) - np.eye(6)
    groups = spectral_groups(w, 3, seed=0)
    assert len(set(groups.tolist())) == 3
    assert all(groups[2 * k] == groups[2 * k + 1] for k in range(3))


def test_spectral_solution_two_people():
    eye = np.eye(2)
    weights = [eye * 0.9, eye[::-1] * 0.8, eye[::-1] * 0.9, eye * 0.8]
    sol = spectral_solution(weights, seed=1)
    for e, w in zip(sol.edges, weights, strict=True):
        assert np.array_equal(e, (w > 0).astype(np.int8))


# --- stitching -------------------------------------------------------------------------------


def test_stitching_follows_algorithm_1():
    top = [[_tracklet(0, [1], [0], [[0, 0]]), _tracklet(0, [1], [1], [[50, 0]])],
           [_tracklet(1, [2], [2], [[0, 0]]), _tracklet(1, [2], [3], [[50, 0]])]]
    hor = [[_tracklet(0, [1], [0], [[0, 0]])], [_tracklet(1, [2], [1], [[0, 0]])]]
    e0 = np.eye(2, dtype=np.int8)  # top over time
    e1 = np.array([[0], [1]], dtype=np.int8)  # clip 1: hor joins the second top tracklet
    e2 = np.array([[1]], dtype=np.int8)  # hor over time
    e3 = np.array([[1, 0]], dtype=np.int8)  # clip 0: hor joins the first top tracklet
    out = stitch_windows(top, hor, [(e0, e1, e2, e3)])
    assert out.top_clip_ids[0].tolist() == out.top_clip_ids[1].tolist() == [1, 2]
    assert out.hor_clip_ids[0].tolist() == [1]
    assert out.hor_clip_ids[1].tolist() == [2]  # the cross-view edge wins over the over-time one
    # Without the clip-1 cross-view edge, the horizontal tracklet keeps id 1, unless the top
    # tracklet holding id 1 is in clip 1 (then pairing them would contradict the window).
    out = stitch_windows(top, hor, [(e0, np.zeros((2, 1), np.int8), e2, e3)])
    assert out.hor_clip_ids[1].tolist() == [3]
    out = stitch_windows(top, hor, [(np.zeros((2, 2), np.int8), np.zeros((2, 1), np.int8), e2,
                                     e3)])
    assert out.hor_clip_ids[1].tolist() == [1]
    assert out.top_rows == {0: 1, 1: 2, 2: 3, 3: 4}


# --- the pipeline ----------------------------------------------------------------------------


def _scrambled(frames, seed):
    """Records whose ids are row numbers, in a shuffled order per frame (ids are detections)."""
    rng = np.random.default_rng(seed)
    out, truth, row = {}, {}, 0
    for f in sorted(frames):
        rec = frames[f]
        order = rng.permutation(len(rec))
        ids = np.arange(row, row + len(rec))
        truth.update(zip(ids.tolist(), rec.ids[order].tolist(), strict=True))
        out[f] = FrameBoxes(f, ids, rec.boxes[order])
        row += len(rec)
    return out, truth


@pytest.mark.parametrize("solver", ["mip", "spectral"])
def test_track_pair_on_a_synthetic_scene(solver):
    # A calm head (the default turns it up to ~140 px a frame, beyond IoU linking).
    scene = simulate_box_scene(SceneConfig(head_turn_std_deg=2.0), n_frames=40, seed=5)
    top, top_truth = _scrambled(scene.top, 1)
    hor, hor_truth = _scrambled(scene.hor, 2)
    res = track_pair(top, hor, float(scene.config.hor_size[0]), config=TrackConfig(solver=solver))
    assert set(res.top_rows) == set(top_truth) and set(res.hor_rows) == set(hor_truth)
    for frames, rows in ((top, res.top_rows), (hor, res.hor_rows)):
        for rec in frames.values():  # one box per track id and frame in each view
            ids = [rows[r] for r in rec.ids.tolist()]
            assert len(set(ids)) == len(ids)
    # Top-view tracks are pure: each track id stands for one person (the MIP; the spectral
    # baseline, without the loop constraints, may merge two people's ids).
    owners: dict[int, set[int]] = {}
    for r, k in res.top_rows.items():
        owners.setdefault(k, set()).add(top_truth[r])
    pure = sum(len(v) == 1 for v in owners.values())
    assert pure == len(owners) if solver == "mip" else pure >= 0.8 * len(owners)
    # Cross-view pairs (same track id in one frame) are mostly right.
    good = bad = 0
    for f in set(top) & set(hor):
        by_id = {res.top_rows[r]: top_truth[r] for r in top[f].ids.tolist()}
        for r in hor[f].ids.tolist():
            person = by_id.get(res.hor_rows[r])
            if person is not None:
                good += person == hor_truth[r]
                bad += person != hor_truth[r]
    assert good > 4 * bad and good > 0, (good, bad)


def test_tracklet_scores_table10_toy():
    from xvmatch.metrics.track_metrics import tracklet_scores

    def t(clip, rows):
        return Tracklet(clip, np.arange(len(rows)), np.array(rows), np.zeros((len(rows), 4)))

    person = {0: 1, 1: 1, 2: 1, 3: 2, 4: 2, 5: None, 6: 1}
    # Clip 0: person 1 whole (right), person 2 cut in two (both wrong), a false box (wrong).
    # Clip 1: person 1 whole (right). 2 right of 5 made; 2 right of 3 person-clips.
    scores = tracklet_scores([[t(0, [0, 1, 2]), t(0, [3]), t(0, [4]), t(0, [5])],
                              [t(1, [6])]], person)
    assert (scores.n_right, scores.n_tracklets, scores.n_person_clips) == (2, 5, 3)
    assert scores.precision == pytest.approx(100 * 2 / 5)
    assert scores.recall == pytest.approx(100 * 2 / 3)
    assert scores.f1 == pytest.approx(100 * 2 * (2 / 5) * (2 / 3) / (2 / 5 + 2 / 3))
