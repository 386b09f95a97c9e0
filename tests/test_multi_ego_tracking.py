"""Tests of associate-multi over time (inference/views/multi_ego_tracking.py, --tracks)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.cues.box_motion import common_shift, motion_link_costs
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.linking.tracklets import clip_tracklets, split_clips, view_tracklets
from xvmatch.inference.views.multi_ego_tracking import (
    carry_ids,
    pairs_from_ids,
    smoothed_problems,
    split_at_partner_changes,
    track_multi_view,
    view_chains,
)
from xvmatch.inference.views.multi_view_assignment import cycle_violations, view_pairs
from xvmatch.inference.views.multi_view_costs import FrameProblem


def _scene(seed: int, n_views: int = 3, n_people: int = 4, n_frames: int = 12,
           flip: int | None = None, noise: float = 0.0, shake: float = 0.0):
    """People walking slowly (boxes far apart, so IoU tracklets are exact), every view sees all
    of them in a shuffled order each frame; costs -2 for the same person, +2 otherwise (plus
    ``noise``), and on frame ``flip`` persons 0 and 1 of the later view of every pair swapped,
    at -0.5 / +0.5 (a matcher's hesitant one-frame mistake); ``shake``: every box of a view but
    the top one moved by the same offset, drawn per frame and view (normal, ``shake`` pixels: a
    head-worn camera's shake). Returns views, problems and the true person of each box."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 50, size=(n_views, n_people, 2)) + 150.0 * np.arange(n_people)[:, None]
    step = rng.uniform(-1, 1, size=(n_views, n_people, 2))
    jolt = np.random.default_rng([seed, 1]).normal(0.0, shake, size=(n_frames + 1, n_views, 2))
    jolt[:, 0] = 0.0
    views = [dict() for _ in range(n_views)]
    truth = [dict() for _ in range(n_views)]
    for f in range(1, n_frames + 1):
        for v in range(n_views):
            order = rng.permutation(n_people)
            xy = start[v, order] + f * step[v, order] + jolt[f, v]
            boxes = np.c_[xy, np.full((n_people, 2), 40.0)]
            views[v][f] = FrameBoxes(f, np.arange(n_people, dtype=np.int64) + 100 * f, boxes)
            truth[v][f] = order
    problems = {}
    for f in range(1, n_frames + 1):
        costs = {}
        for a, b in view_pairs(n_views):
            ta, tb = truth[a][f].copy(), truth[b][f].copy()
            if f == flip:
                tb = np.where(tb == 0, 1, np.where(tb == 1, 0, tb))
            c = np.where(ta[:, None] == tb[None, :], -2.0, 2.0) * (0.25 if f == flip else 1.0)
            costs[(a, b)] = c + noise * rng.standard_normal(c.shape)
        problems[f] = FrameProblem(tuple([n_people] * n_views), costs,
                                   dict.fromkeys(costs, 0.0))
    return views, problems, truth


def test_ids_carry_over_frames_and_agree_across_views():
    views, problems, truth = _scene(0, flip=5)
    tracks = track_multi_view(views, problems, clip_length=5)
    assert set(tracks.statuses) == {"optimal"}
    assert tracks.n_people == 4  # one id per person over all 12 frames and 3 views
    for v in range(3):
        for f in views[v]:
            for person, pid in zip(truth[v][f].tolist(), tracks.person[v][f].tolist(),
                                   strict=True):
                assert pid == tracks.person[0][1][truth[0][1].tolist().index(person)]


def test_tracklets_outvote_one_frame_mistake_that_the_frame_program_makes():
    from xvmatch.inference.views.multi_view_assignment import solve_multi_view

    views, problems, truth = _scene(1, flip=3)
    alone = solve_multi_view(problems[3].sizes, problems[3].costs, 0.0)
    wrong = [(t[p[:, 0]] != truth[b][3][p[:, 1]]).sum()
             for (a, b), p in alone.pairs.items() for t in [truth[a][3]]]
    assert sum(wrong) > 0  # frame 3 alone follows the swapped costs
    tracks = track_multi_view(views, problems, clip_length=12)
    ids = [tracks.person[v][3] for v in range(3)]
    for (a, b), p in pairs_from_ids(ids).items():
        assert np.array_equal(truth[a][3][p[:, 0]], truth[b][3][p[:, 1]])
        assert len(p) == 4


@pytest.mark.parametrize("seed", range(6))
def test_no_frame_has_a_broken_triangle_or_an_id_twice_in_a_view(seed):
    rng = np.random.default_rng(seed)
    views, problems, _ = _scene(seed, n_views=4, n_people=int(rng.integers(2, 5)),
                                n_frames=9, noise=3.0)
    for f in list(views[2])[::3]:  # missing detections: drop a box now and then
        keep = np.arange(len(views[2][f])) != 0
        views[2][f] = FrameBoxes(f, views[2][f].ids[keep], views[2][f].boxes[keep])
        p = problems[f]
        costs = {ab: (c[:, keep] if ab[1] == 2 else c[keep] if ab[0] == 2 else c)
                 for ab, c in p.costs.items()}
        sizes = tuple(n - (v == 2) for v, n in enumerate(p.sizes))
        problems[f] = FrameProblem(sizes, costs, p.gamma)
    for solver in ("mip", "greedy"):
        tracks = track_multi_view(views, problems, clip_length=4, solver=solver)
        for f in problems:
            ids = [tracks.person[v][f] for v in range(4)]
            assert all(i.size == len(views[v][f]) and (i > 0).all() for v, i in enumerate(ids))
            assert all(np.unique(i).size == i.size for i in ids)
            assert not cycle_violations(pairs_from_ids(ids), [i.size for i in ids])


def test_deterministic_and_checked():
    views, problems, _ = _scene(3, noise=2.0)
    a = track_multi_view(views, problems)
    b = track_multi_view(views, problems)
    for pa, pb in zip(a.person, b.person, strict=True):
        assert all(np.array_equal(pa[f], pb[f]) for f in pa)
    with pytest.raises(ValueError, match="frame_weight"):
        track_multi_view(views, problems, frame_weight=2.0)
    with pytest.raises(ValueError, match="top view"):
        track_multi_view(views[:1], problems)


def test_smoothed_costs_are_the_tracklets_mean_mixed_with_the_frame():
    views, problems, truth = _scene(4, n_views=2, n_people=2, n_frames=4, flip=2)
    clips = split_clips(sorted(problems), 4)
    tracks = [view_tracklets(views[v], clips)[0] for v in range(2)]
    assert [len(t) for t in tracks] == [2, 2]
    smooth = smoothed_problems(tracks, problems, views, frame_weight=0.5)
    c = smooth[2].costs[(0, 1)]
    same = truth[0][2][:, None] == truth[1][2][None, :]
    # mean over 4 frames: (3 * -2 + 0.5) / 4 for the same person; mixed with the flipped 0.5
    assert np.allclose(c[same], 0.5 * 0.5 + 0.5 * -5.5 / 4)
    assert np.allclose(c[~same], 0.5 * -0.5 + 0.5 * 5.5 / 4)


def test_chains_and_carry_ids():
    views, problems, _ = _scene(5, n_views=2, n_people=3, n_frames=8)
    clips = split_clips(sorted(problems), 4)
    chains = view_chains(view_tracklets(views[0], clips))
    assert [c.tolist() for c in map(np.sort, chains)] == [[0, 1, 2], [0, 1, 2]]
    owner: dict[tuple[int, int], int] = {}
    ids, nxt = carry_ids([np.array([0, 1]), np.array([1, 0])],
                         [np.array([7, 8]), np.array([3, 4])], owner, 1)
    assert ids.tolist() == [1, 2] and nxt == 3
    # next frame: view 1's chains now lie in swapped clusters; the top view breaks the tie
    ids, nxt = carry_ids([np.array([0, 1]), np.array([0, 1])],
                         [np.array([8, 7]), np.array([3, 4])], owner, nxt)
    assert ids.tolist() == [2, 1] and nxt == 3
    ids, nxt = carry_ids([np.array([0])], [np.array([9])], owner, nxt)
    assert ids.tolist() == [3] and nxt == 4


def test_common_shift_is_the_camera_motion_and_links_across_a_jump():
    people = np.array([[0.0, 0, 40, 100], [100, 10, 40, 100], [260, 0, 30, 75]])
    jump = np.array([70.0, -12.0, 0.0, 0.0])  # the camera turns: 70 px, wider than a box
    moved = people[[2, 0, 1]] + jump
    moved[1, 0] += 2.0  # and one walker's own step
    cost = motion_link_costs(people, moved)
    assert cost.shape == (3, 3)
    assert np.argmin(cost, axis=1).tolist() == [1, 2, 0]
    assert np.allclose(np.diag(cost[:, [1, 2, 0]]), [2.0 / 100, 0, 0])
    # one person alone: the shift explains any jump, but not a change of size; a pair whose
    # heights differ by more than the radius (log 1.5 > 0.3) proposes no shift at all
    assert motion_link_costs(people[:1], people[:1] + 4 * jump)[0, 0] == 0.0
    other = people[2:] * [1, 1, 1, 1.6]  # 120 px high, 100 before
    assert np.isclose(motion_link_costs(people[:1], other)[0, 0], np.log(1.2))
    assert motion_link_costs(people[:1], people[2:] * [1, 1, 1, 2])[0, 0] > 2.0
    d = np.zeros((2, 2, 2))
    assert np.array_equal(common_shift(d, np.ones((2, 2)), np.zeros((2, 2), bool), 0.3),
                          [0.0, 0.0])
    masked = motion_link_costs(people[:2], moved[:2], valid=np.eye(2, dtype=bool))
    assert np.isinf(masked[0, 1]) and np.isinf(masked[1, 0])
    with pytest.raises(ValueError, match="valid must be"):
        motion_link_costs(people, moved, valid=np.ones((2, 3), bool))


def test_like_sized_boxes_decide_the_shift():
    # one tall track; next frame a short box 100 px to the right and a tall one 300 px: the
    # smaller shift would win a tie of one vote each, but the short box cannot vote (its height
    # differs by log 2 > 0.3), so the shift is 300 px and the tall box links at cost 0 (with
    # a shift of 100 px the costs would be log 2 and 200 / 120)
    last = np.array([[0.0, 0, 40, 120]])
    now = np.array([[100.0, 30, 20, 60], [300, 0, 40, 120]])
    cost = motion_link_costs(last, now)
    assert cost[0, 1] == 0.0 and cost[0, 0] > 2.0


def test_motion_links_a_shaking_view_that_iou_cuts():
    views, _, truth = _scene(6, n_views=2, n_people=4, n_frames=10, shake=30.0)
    clip = np.arange(1, 11)
    by_iou = clip_tracklets(views[1], clip, 0, min_iou=0.7)
    by_motion = clip_tracklets(views[1], clip, 0, motion=0.3)
    assert len(by_iou) > 10  # the shake (about a box width) breaks the overlap
    assert len(by_motion) == 4 and all(len(t) == 10 for t in by_motion)
    for t in by_motion:  # each holds one person
        rows = {f: views[1][f].ids.tolist().index(r) for f, r in zip(t.frames, t.rows, strict=True)}
        assert len({int(truth[1][f][k]) for f, k in rows.items()}) == 1
    with pytest.raises(ValueError, match="not both"):
        clip_tracklets(views[1], clip, 0, histograms={}, motion=0.3)


def test_motion_tracklets_outvote_a_mistake_in_shaking_views():
    # every egocentric view shakes by about a box width per frame: by IoU its tracklets are
    # single boxes, which carry no other frame's evidence, so frame 3's swap stays; by motion
    # they span the clip and outvote it
    views, problems, truth = _scene(7, n_views=3, n_people=4, n_frames=8, flip=3, shake=30.0)

    def wrong(tracks):
        ids = [tracks.person[v][3] for v in range(3)]
        return sum(int((truth[a][3][p[:, 0]] != truth[b][3][p[:, 1]]).sum())
                   for (a, b), p in pairs_from_ids(ids).items())

    assert wrong(track_multi_view(views, problems, clip_length=8, motion=None)) > 0
    tracks = track_multi_view(views, problems, clip_length=8)
    assert wrong(tracks) == 0 and tracks.n_people == 4
    with pytest.raises(ValueError, match="motion"):
        track_multi_view(views, problems, motion=0.0)


def _handover(c_right: float, c_other: float):
    """A top view with persons A and B on 10 frames, and an egocentric view that sees A alone
    on frames 1-7, then B alone on frames 8-10 where A stood: one box per frame, so the common
    shift explains the jump and the motion links join the two people into one tracklet. Costs
    top-ego: A -3 and B +3 on frames 1-7; on frames 8-10 ``c_right`` for B and ``c_other`` for
    A. Returns views, problems and the ego box's true top row per frame."""
    top = {f: FrameBoxes(f, np.array([0, 1]), np.array([[100.0, 100, 10, 10],
                                                        [300, 100, 10, 10]]))
           for f in range(1, 11)}
    ego = {f: FrameBoxes(f, np.array([0]), np.array([[100.0 if f < 8 else 300.0, 50, 40, 100]]))
           for f in range(1, 11)}
    problems = {}
    for f in range(1, 11):
        c = np.array([[-3.0], [3.0]]) if f < 8 else np.array([[c_other], [c_right]])
        problems[f] = FrameProblem((2, 1), {(0, 1): c}, {(0, 1): 0.0})
    return [top, ego], problems, [0] * 7 + [1] * 3


def test_split_at_partner_changes_cuts_where_the_confident_top_partner_switches():
    views, problems, _ = _handover(-2.2, -0.9)
    clips = split_clips(sorted(problems), 10)
    top, ego = (view_tracklets(views[v], clips, motion=None if v == 0 else 0.3)[0]
                for v in range(2))
    assert len(top) == 2 and len(ego) == 1 and len(ego[0]) == 10  # the wrong link is made
    pieces, parent = split_at_partner_changes(top, ego, problems, views[0], views[1], 1)
    assert [p.frames.tolist() for p in pieces] == [list(range(1, 8)), [8, 9, 10]]
    assert parent.tolist() == [0, 0]
    # evidence below the bar (-1.5 > -2 nats) names no partner: no cut
    weak = _handover(-1.5, -0.9)[1]
    assert len(split_at_partner_changes(top, ego, weak, views[0], views[1], 1)[0]) == 1
    # one frame's confident switch is a matcher's mistake, not a wrong link: no cut
    blip = dict(problems)
    for f in (9, 10):
        blip[f] = problems[1]
    assert len(split_at_partner_changes(top, ego, blip, views[0], views[1], 1)[0]) == 1
    assert len(split_at_partner_changes(top, ego, blip, views[0], views[1], 1,
                                        persist=1)[0]) == 3
    with pytest.raises(ValueError, match="persist"):
        split_at_partner_changes(top, ego, problems, views[0], views[1], 1, persist=0)


def test_cut_tracklets_stop_a_wrong_link_from_overruling_the_frames():
    # frames 8-10 alone say B (-2.2 against -0.9); the joined tracklet's mean says A strongly
    # enough to overrule them (0.6 * -0.9 + 0.4 * -2.37 < 0.6 * -2.2 + 0.4 * 1.44); once cut,
    # the frames' own evidence decides, and the ids still carry (the piece keeps its chain)
    views, problems, truth = _handover(-2.2, -0.9)

    def partner(tracks):
        return [int(np.flatnonzero(tracks.person[0][f] == tracks.person[1][f][0])[0])
                if tracks.person[1][f][0] in tracks.person[0][f] else -1 for f in range(1, 11)]

    assert partner(track_multi_view(views, problems, partner_change=None)) == [0] * 10
    tracks = track_multi_view(views, problems)
    assert partner(tracks) == truth and tracks.n_people == 2
    with pytest.raises(ValueError, match="partner_change"):
        track_multi_view(views, problems, partner_change=-1.0)


@pytest.fixture(scope="module")
def video(tmp_path_factory):
    """Four rendered frames, a top view and two egocentric views, laid out as user data."""
    from xvmatch.datasets.multi_ego_scenes import (
        multi_ego_config,
        render_multi_ego,
        write_multi_ego_inputs,
    )

    config = multi_ego_config(2, n_people=(5, 6))  # 640x360, as the benchmark's
    frames = render_multi_ego([5, 1], n_ego=2, n_frames=4, config=config)
    return write_multi_ego_inputs(frames, tmp_path_factory.mktemp("multi_ego_video"), seed=1)


def _rows(path):
    rows = [line.split(",") for line in path.read_text().splitlines()]
    return [(int(r[0]), int(r[1]), ",".join(r[2:])) for r in rows]


def test_cli_tracks_carries_ids_and_ignores_workers(video, tmp_path):
    from xvmatch.cli import main

    top, *hor = video.boxes
    outs = []
    for workers in (1, 2):
        out = tmp_path / f"w{workers}"
        assert main(["associate-multi", "--top", str(top), "--hor", *map(str, hor), "--out",
                     str(out), "--quiet", "--image-size", "640x360", "--tracks",
                     "--workers", str(workers)]) == 0
        outs.append([_rows(out / p.name) for p in video.boxes])
    assert outs[0] == outs[1]
    truth = [_rows(p) for p in video.boxes]
    pred = outs[0]
    for t, p in zip(truth, pred, strict=True):
        assert [(f, rest) for f, _, rest in t] == [(f, rest) for f, _, rest in p]  # rows kept
    frames = sorted({f for f, _, _ in truth[0]})
    assert len(frames) == 4
    for f in frames:  # on every frame a person id names at most one box per view
        ids = [np.array([pid for g, pid, _ in p if g == f]) for p in pred]
        assert all(np.unique(i).size == i.size for i in ids)
        assert not cycle_violations(pairs_from_ids(ids), [i.size for i in ids])
    # the top view's people keep their ids over the four frames (ids carry over frames)
    kept = {}
    for (_, gt, _), (_, pid, _) in zip(truth[0], pred[0], strict=True):
        kept.setdefault(gt, set()).add(pid)
    assert sum(len(s) == 1 for s in kept.values()) >= 0.8 * len(kept)
    people = {pid for p in pred for _, pid, _ in p}
    per_frame = sum(len({pid for p in pred for g, pid, _ in p if g == f}) for f in frames)
    assert len(people) < 0.6 * per_frame  # frame by frame, every frame's people are new ids
