"""Tests of splitting on evidence (issue 68 item 1, ``inference/views/multicam_evidence.py``)
and of ``xvmatch multicam``'s ``--split-frames auto``, ``--min-score`` and ``--first-frame``:
the shared Viterbi unchanged for its first user, clean tracks kept whole, a tracker's id switch
cut where the other cameras show it, the fallback to fixed pieces where many tracks are cut."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    simulate_multicam_scene,
    write_multicam_scene,
)
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.linking.piecewise_labels import label_path
from xvmatch.inference.views.multicam import MulticamOptions, associate_cameras, relabel
from xvmatch.inference.views.multicam_evidence import partner_path
from xvmatch.inference.views.multicam_run import association_options
from xvmatch.metrics.multicam_metrics import match_to_truth, multicam_scores


@pytest.fixture(scope="module")
def clean():
    """4 cameras, 8 people, 120 frames, ground-truth boxes and scrambled ids."""
    scene = simulate_multicam_scene(MulticamConfig(n_cameras=4, n_people=(8, 8)), 120, 3)
    return scene, {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}


def _swapped(scene, camera: str, at: int):
    """The scene's boxes with one id switch in ``camera`` from frame ``at`` on: the two longest
    tracks seen at ``at``, and at least 40 frames before and after it, swap ids. Returns the
    boxes and the two ids."""
    frames = scene.boxes[camera]
    span: dict[int, list[int]] = {}
    for f, rec in frames.items():
        for t in rec.ids.tolist():
            span.setdefault(t, []).append(f)
    long = [t for t in frames[at].ids.tolist()
            if min(span[t]) <= at - 40 and max(span[t]) >= at + 40]
    a, b = sorted(long, key=lambda t: (-len(span[t]), t))[:2]
    swap = {a: b, b: a}
    boxes = dict(scene.boxes)
    boxes[camera] = {f: FrameBoxes(f, np.array([swap.get(t, t) if f >= at else t
                                                for t in rec.ids.tolist()], np.int64),
                                   rec.boxes) for f, rec in frames.items()}
    return boxes, (a, b)


def test_label_path_default_is_the_consensus_one():
    """The shared Viterbi with ``absent_cost`` unset is the two-view consensus' path (absent
    candidates at ``free_cost``); with ``absent_cost=0`` an absent candidate holds, dearer
    than the free state it is left for it."""
    rng = np.random.default_rng(0)
    obs = rng.integers(0, 4, 60)
    here = rng.random((60, 4)) < 0.7
    np.testing.assert_array_equal(label_path(obs, here, 5.0, 0.5),
                                  label_path(obs, here, 5.0, 0.5, absent_cost=0.5))
    obs = np.array([1] * 10 + [0] * 30)
    here = np.zeros((40, 2), dtype=bool)
    here[:10, 1] = True
    assert set(label_path(obs, here, 3.0, 0.5, absent_cost=0.0).tolist()) == {1}
    assert label_path(obs, here, 3.0, 0.5, absent_cost=1.0)[-1] == 0


def test_partner_path_outvotes_a_lone_link_and_follows_a_switch():
    cols = [np.arange(20 * k, 20 * k + 20) for k in range(8)]
    present = np.ones((3, 160), dtype=bool)
    lone = np.array([0, 0, 0, 1, 0, 0, -1, 0])
    assert partner_path(lone, cols, present, 30.0).tolist() == [0] * 8
    switch = np.array([0, 0, 0, 2, 2, 2, 2, 2])
    assert partner_path(switch, cols, present, 30.0).tolist() == [0, 0, 0, 2, 2, 2, 2, 2]
    gone = present.copy()
    gone[0, 60:] = False  # partner 0 out of view: partner 2 is no evidence against it
    assert partner_path(switch, cols, gone, 30.0).tolist() == [0] * 8


def test_clean_tracks_stay_whole_and_score_at_least_as_the_fixed_pieces(clean):
    scene, cams = clean
    res = associate_cameras(cams, scene.boxes)
    assert res.piece_starts and all(len(s) == 1 for per in res.piece_starts.values()
                                    for s in per.values())
    ours = multicam_scores(relabel(scene.boxes, res), scene.gt)
    fixed = multicam_scores(relabel(scene.boxes, associate_cameras(
        cams, scene.boxes, MulticamOptions(split="fixed"))), scene.gt)
    assert ours["P"] == 1.0 and ours["R"] >= fixed["R"]
    assert ours["idf1"]["IDF1"] >= fixed["idf1"]["IDF1"]
    # Whole tracks: one global id per input track.
    for name, frames in relabel(scene.boxes, res).items():
        owner: dict[int, int] = {}
        for f, rec in frames.items():
            for t, g in zip(scene.boxes[name][f].ids.tolist(), rec.ids.tolist(), strict=True):
                assert owner.setdefault(t, g) == g


def test_an_id_switch_is_cut_where_the_other_cameras_show_it(clean):
    scene, cams = clean
    boxes, (a, b) = _swapped(scene, "cam2", 60)
    res = associate_cameras(cams, boxes, MulticamOptions(evidence_max_cut_share=1.0))
    for t in (a, b):
        starts = res.piece_starts["cam2"][t]
        assert len(starts) == 2 and 40 <= starts[1] <= 80, starts
    n_cut = sum(len(s) > 1 for per in res.piece_starts.values() for s in per.values())
    assert n_cut <= 3  # the two, and at most one partner whose cameras could not tell
    # After the cut each piece carries its own person's global id: the boxes of one true
    # person in cam2 away from the switch share the global id of that person elsewhere.
    rl = relabel(boxes, res)
    truth = match_to_truth(boxes["cam2"], scene.gt["cam2"])
    for f in (30, 90):
        for t, g, p in zip(boxes["cam2"][f].ids.tolist(), rl["cam2"][f].ids.tolist(),
                           truth[f].tolist(), strict=True):
            if t in (a, b):
                others = {int(gg) for name in ("cam1", "cam3", "cam4") if f in rl[name]
                          for gg, pp in zip(rl[name][f].ids.tolist(),
                                            match_to_truth({f: boxes[name][f]},
                                                           scene.gt[name])[f].tolist(),
                                            strict=True) if pp == p}
                assert others <= {g}, (f, t, g, others)
    # Where more tracks are cut than evidence_max_cut_share allows, the fixed pieces are the
    # answer, box for box.
    fallback = associate_cameras(cams, boxes, MulticamOptions(evidence_max_cut_share=0.0))
    fixed = associate_cameras(cams, boxes, MulticamOptions(split="fixed"))
    assert not fallback.piece_starts and fallback.split_frames == 20
    got, want = relabel(boxes, fallback), relabel(boxes, fixed)
    for name in boxes:
        for f in boxes[name]:
            np.testing.assert_array_equal(got[name][f].ids, want[name][f].ids)


def test_association_options_of_the_command_line():
    assert association_options().split == "evidence"
    assert association_options("dtw").split_frames == 0
    fixed = association_options("ours", 20, 2.0)
    assert (fixed.split, fixed.split_frames, fixed.appearance_weight) == ("fixed", 20, 2.0)
    assert association_options("ours", "auto").split_frames == 20
    with pytest.raises(ValueError, match="evidence_max_cut_share"):
        MulticamOptions(evidence_max_cut_share=1.5)


def _rows(path):
    return [r.split(",") for r in path.read_text().splitlines()]


def test_min_score_and_first_frame(tmp_path, capsys):
    scene = simulate_multicam_scene(MulticamConfig(n_cameras=3, n_people=(6, 6)), 40, seed=4)
    root = tmp_path / "scene"
    write_multicam_scene(root, scene)
    names = ("cam1", "cam2", "cam3")
    weak = _rows(root / "boxes" / "cam1.txt")[0][1]  # this track's boxes get a low score
    scored, zero = tmp_path / "scored", tmp_path / "zero"
    scored.mkdir()
    zero.mkdir()
    for n in names:
        rows = _rows(root / "boxes" / f"{n}.txt")
        (scored / f"{n}.txt").write_text("".join(
            ",".join([*r[:6], "0.1" if n == "cam1" and r[1] == weak else "0.9", *r[7:]]) + "\n"
            for r in rows))
        (zero / f"{n}.txt").write_text("".join(
            ",".join([str(int(r[0]) - 1), *r[1:]]) + "\n" for r in rows))
    cams = str(root / "cameras.json")

    def run(folder, out, *extra):
        return main(["multicam", "--boxes", *(f"{n}={folder / (n + '.txt')}" for n in names),
                     "--cameras", cams, "--out", str(tmp_path / out), "--quiet", *extra])

    assert run(scored, "kept", "--min-score", "0.5") == 0
    kept = _rows(tmp_path / "kept" / "cam1.txt")
    n_weak = sum(r[1] == weak for r in _rows(root / "boxes" / "cam1.txt"))
    assert n_weak and len(kept) == len(_rows(root / "boxes" / "cam1.txt")) - n_weak
    capsys.readouterr()
    assert run(zero, "out_zero", "--first-frame", "0") == 0
    assert "note" in capsys.readouterr().err
    for n in names:  # read as frame + 1: the rows of the 1-based files, frames and boxes
        assert [[r[0], *r[2:6]] for r in _rows(tmp_path / "out_zero" / f"{n}.txt")] == \
            [[r[0], *r[2:6]] for r in _rows(root / "boxes" / f"{n}.txt")]
