"""Tests of associate-multi over time (inference/multi_ego_tracking.py, --tracks)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.datasets.mot_boxes import FrameBoxes
from xvmatch.inference.multi_ego_tracking import (
    carry_ids,
    pairs_from_ids,
    smoothed_problems,
    track_multi_view,
    view_chains,
)
from xvmatch.inference.multi_view_assignment import cycle_violations, view_pairs
from xvmatch.inference.multi_view_costs import FrameProblem
from xvmatch.inference.tracklets import split_clips, view_tracklets


def _scene(seed: int, n_views: int = 3, n_people: int = 4, n_frames: int = 12,
           flip: int | None = None, noise: float = 0.0):
    """People walking slowly (boxes far apart, so IoU tracklets are exact), every view sees all
    of them in a shuffled order each frame; costs -2 for the same person, +2 otherwise (plus
    ``noise``), and on frame ``flip`` persons 0 and 1 of the later view of every pair swapped,
    at -0.5 / +0.5 (a matcher's hesitant one-frame mistake). Returns views, problems and the
    true person of each box."""
    rng = np.random.default_rng(seed)
    start = rng.uniform(0, 50, size=(n_views, n_people, 2)) + 150.0 * np.arange(n_people)[:, None]
    step = rng.uniform(-1, 1, size=(n_views, n_people, 2))
    views = [dict() for _ in range(n_views)]
    truth = [dict() for _ in range(n_views)]
    for f in range(1, n_frames + 1):
        for v in range(n_views):
            order = rng.permutation(n_people)
            xy = start[v, order] + f * step[v, order]
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
    from xvmatch.inference.multi_view_assignment import solve_multi_view

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
