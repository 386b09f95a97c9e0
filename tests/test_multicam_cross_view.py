"""N-view cross-view scores (``xvmatch evaluate --multicam`` and ``--pred NAME=FILE``, issue 68):
the worked example of docs/multicam.md by hand, degenerate cases, parity with the two-view
metrics, a perfect prediction, a swap of two people's ids in one view, and the command."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.metrics.cross_view_metrics import summarize
from xvmatch.metrics.multicam_cross_view import (
    cross_view_scores,
    format_cross_view,
    pair_counts,
    view_tracking_scores,
)
from xvmatch.metrics.multicam_metrics import multicam_scores
from xvmatch.metrics.track_metrics import track_pair_counts


def _boxes(frame: int, people: list[int], ids: list[int] | None = None) -> FrameBoxes:
    """Person ``p``'s box is at x = 100 p in every view (the views' boxes never overlap
    another person's); ``ids`` are the ids written on them (default the people)."""
    ids = people if ids is None else ids
    boxes = np.array([[100.0 * p, 50.0, 40.0, 80.0] for p in people]).reshape(-1, 4)
    return FrameBoxes(frame, np.array(ids, dtype=np.int64), boxes)


def _example():
    """The worked example of docs/multicam.md: views A, B, C; people 1, 2, 3; frames 1, 2.

    Frame 1: A sees 1, 2; B sees 1, 2, 3; C sees 2, 3; every global id right.
    Frame 2: A sees 1, 2; B sees 1, 3; C sees 2, 3. The tracker missed person 3 in B, and in C
    it swapped the ids of persons 2 and 3.
    """
    gt = {
        "A": {1: _boxes(1, [1, 2]), 2: _boxes(2, [1, 2])},
        "B": {1: _boxes(1, [1, 2, 3]), 2: _boxes(2, [1, 3])},
        "C": {1: _boxes(1, [2, 3]), 2: _boxes(2, [2, 3])},
    }
    pred = {
        "A": {1: _boxes(1, [1, 2]), 2: _boxes(2, [1, 2])},
        "B": {1: _boxes(1, [1, 2, 3]), 2: _boxes(2, [1])},
        "C": {1: _boxes(1, [2, 3]), 2: _boxes(2, [2, 3], ids=[3, 2])},
    }
    return pred, gt


def test_worked_example_by_hand():
    pred, gt = _example()
    s = cross_view_scores(pred, gt)
    by_pair = {tuple(p["views"]): p for p in s["pairs"]}
    # A-B: frame 1 pairs ids 1, 2 (both right, G = {1, 2}); frame 2 pairs id 1 (right, G = {1}).
    ab = by_pair[("A", "B")]
    assert (ab["cvidp"], ab["cvidr"], ab["cvidf1"], ab["cvma"]) == (100.0, 100.0, 100.0, 100.0)
    # A-C: frame 1 pairs id 2, right (G = {2}); frame 2 pairs id 2: A's person 2 with C's
    # person 3, who is not in G = {2}: a false positive, and person 2 of C is unpaired: a miss.
    ac = by_pair[("A", "C")]
    assert (ac["tp"], ac["fp"], ac["mismatch"], ac["miss"], ac["n_gt"]) == (1, 1, 0, 1, 2)
    assert ac["cvidp"] == pytest.approx(50.0) and ac["cvidr"] == pytest.approx(50.0)
    assert ac["cvidf1"] == pytest.approx(50.0) and ac["cvma"] == pytest.approx(0.0)
    # B-C: frame 1 pairs ids 2, 3, right (G = {2, 3}); frame 2: B has id 1 only, C ids 3, 2: no
    # pair, G = {3}: one miss. CVIDP over frame 1 only.
    bc = by_pair[("B", "C")]
    assert bc["cvidp"] == pytest.approx(100.0) and bc["cvidr"] == pytest.approx(50.0)
    assert bc["cvidf1"] == pytest.approx(200 / 3) and bc["cvma"] == pytest.approx(200 / 3)
    # All 6 frame pairs: CVIDP 4/5 (5 with a pair), CVIDR 4/6, CVMA 1 - 3/8.
    pooled = s["pooled"]
    assert pooled["n_frames"] == 6
    assert pooled["cvidp"] == pytest.approx(80.0)
    assert pooled["cvidr"] == pytest.approx(200 / 3)
    assert pooled["cvidf1"] == pytest.approx(800 / 11)
    assert pooled["cvma"] == pytest.approx(62.5)
    mean = s["pair_mean"]
    assert mean["cvidp"] == pytest.approx(250 / 3) and mean["cvidr"] == pytest.approx(200 / 3)
    assert mean["cvidf1"] == pytest.approx(650 / 9) and mean["cvma"] == pytest.approx(500 / 9)


def test_worked_example_global_idf1():
    """12 predicted and 13 true boxes; id 1 is person 1 on 4 boxes, id 2 person 2 on 4, id 3
    person 3 on 2: IDTP 10, IDF1 = 20 / 25."""
    pred, gt = _example()
    idf1 = multicam_scores(pred, gt)["idf1"]
    assert idf1["IDP"] == pytest.approx(10 / 12) and idf1["IDR"] == pytest.approx(10 / 13)
    assert idf1["IDF1"] == pytest.approx(0.8)


def test_perfect_prediction_scores_100_everywhere():
    _pred, gt = _example()
    s = cross_view_scores(gt, gt)
    for p in [*s["pairs"], s["pooled"]]:
        assert (p["cvidp"], p["cvidr"], p["cvidf1"], p["cvma"]) == (100.0, 100.0, 100.0, 100.0)
    assert all(v == 100.0 for v in s["pair_mean"].values())
    assert multicam_scores(gt, gt)["idf1"]["IDF1"] == 1.0
    tracking = view_tracking_scores(gt, gt)
    if tracking is not None:
        for v in tracking.values():
            assert v["mota"] == pytest.approx(100.0) and v["idf1"] == pytest.approx(100.0)
            assert v["hota"] == pytest.approx(100.0)


def test_swapping_two_people_in_one_view_lowers_the_right_scores():
    """Persons 2 and 3 swap global ids in C on every frame: the pairs with C and the global IDF1
    fall; A-B and each view's own tracking scores (ids within one view) do not change."""
    _pred, gt = _example()
    swapped = dict(gt)
    swapped["C"] = {f: _boxes(f, [2, 3], ids=[3, 2]) for f in (1, 2)}
    s = cross_view_scores(swapped, gt)
    by_pair = {tuple(p["views"]): p for p in s["pairs"]}
    assert by_pair[("A", "B")]["cvidf1"] == 100.0 and by_pair[("A", "B")]["cvma"] == 100.0
    for key in (("A", "C"), ("B", "C")):
        assert by_pair[key]["cvidf1"] < 100.0 and by_pair[key]["cvma"] < 100.0
    assert s["pooled"]["cvidf1"] < 100.0
    assert multicam_scores(swapped, gt)["idf1"]["IDF1"] < 1.0
    tracking = view_tracking_scores(swapped, gt)
    if tracking is not None:
        assert tracking["C"]["idf1"] == pytest.approx(100.0)
        assert tracking["C"]["mota"] == pytest.approx(100.0)


def test_two_views_equal_the_two_view_metrics():
    pred, gt = _example()
    for a, b in (("A", "B"), ("A", "C"), ("B", "C")):
        two = {a: pred[a], b: pred[b]}
        mine = cross_view_scores(two, {a: gt[a], b: gt[b]})
        theirs = summarize(track_pair_counts(pred[a], pred[b], gt[a], gt[b]))
        assert mine["pooled"] == pytest.approx(
            {k: getattr(theirs, k) for k in mine["pooled"]})
        assert mine["pairs"][0]["cvma"] == pytest.approx(theirs.cvma)


def test_empty_and_degenerate_cases_never_divide_by_zero():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        empty = cross_view_scores({"A": {}, "B": {}}, {"A": {}, "B": {}})
        assert empty["pooled"]["n_frames"] == 0
        assert all(empty["pooled"][k] == 0.0 for k in ("cvidp", "cvidr", "cvidf1", "cvma"))
        # Nothing predicted: precision 0, recall 0, CVMA 0 (every shared person missed).
        _pred, gt = _example()
        nothing = cross_view_scores({k: {} for k in gt}, gt)["pooled"]
        assert (nothing["cvidp"], nothing["cvidr"], nothing["cvma"]) == (0.0, 0.0, 0.0)
        # No person seen by two views: recall and CVMA undefined, reported 0; a pair is an fp.
        lone = {"A": {1: _boxes(1, [1])}, "B": {1: _boxes(1, [2])}}
        guess = {"A": {1: _boxes(1, [1], ids=[7])}, "B": {1: _boxes(1, [2], ids=[7])}}
        s = cross_view_scores(guess, lone)["pooled"]
        assert (s["cvidp"], s["cvidr"], s["cvma"], s["fp"]) == (0.0, 0.0, 0.0, 1)
        # One view: no pair at all.
        one = cross_view_scores({"A": gt["A"]}, {"A": gt["A"]})
        assert one["pairs"] == [] and one["pair_mean"]["cvidf1"] == 0.0


def test_predictions_on_frames_without_truth_are_false_positives():
    gt = {"A": {1: _boxes(1, [1])}, "B": {1: _boxes(1, [1])}}
    pred = {"A": {1: _boxes(1, [1]), 5: _boxes(5, [1])}, "B": {1: _boxes(1, [1]),
                                                             5: _boxes(5, [1])}}
    counts = pair_counts(pred["A"], pred["B"], gt["A"], gt["B"])
    assert [c.frame for c in counts] == [1, 5] and counts[1].fp == 1


def test_views_must_agree():
    _pred, gt = _example()
    with pytest.raises(ValueError, match="differ"):
        cross_view_scores({"A": {}, "B": {}}, gt)


def test_format_names_every_pair():
    pred, gt = _example()
    text = format_cross_view(cross_view_scores(pred, gt), None)
    assert "A - C" in text and "all frame pairs" in text and "TrackEval" in text


# --- the command ---------------------------------------------------------------------------


@pytest.fixture()
def example_files(tmp_path):
    pred, gt = _example()
    out = {}
    for kind, views in (("pred", pred), ("gt", gt)):
        for name, frames in views.items():
            path = tmp_path / f"{kind}_{name}.txt"
            write_mot_boxes(path, frames)
            out.setdefault(kind, []).append(f"{name}={path}")
    return out


def test_command_with_pred_files(example_files, capsys):
    argv = ["evaluate", "--pred", *example_files["pred"], "--gt", *example_files["gt"],
            "--json"]
    assert main(argv) == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["cross_view"]["pooled"]["cvma"] == pytest.approx(62.5)
    assert scores["idf1"]["IDF1"] == pytest.approx(0.8)
    assert main(argv[:-1]) == 0
    text = capsys.readouterr().out
    assert "all frame pairs" in text and "global IDF1 0.800" in text


def test_command_with_a_multicam_folder(example_files, tmp_path, capsys):
    folder = tmp_path / "mc"
    folder.mkdir()
    for item in example_files["pred"]:
        name, _, path = item.partition("=")
        (folder / f"{name}.txt").write_text(open(path).read())
    assert main(["evaluate", "--multicam", str(folder), "--gt", *example_files["gt"],
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["cross_view"]["pooled"]["cvidp"] == 80.0


def test_command_bad_input_is_one_line(example_files, tmp_path, capsys):
    bad = tmp_path / "bad.txt"
    bad.write_text("1,1,0,0,10,10,1,-1,-1,-1\n2,x,0,0,10,10,1,-1,-1,-1\n")
    pred = [f"A={bad}", *example_files["pred"][1:]]
    assert main(["evaluate", "--pred", *pred, "--gt", *example_files["gt"]]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and f"{bad}:2" in err


def test_command_cameras_must_match(example_files, capsys):
    assert main(["evaluate", "--pred", *example_files["pred"][:2], "--gt",
                 *example_files["gt"]]) == 2
    assert "same cameras" in capsys.readouterr().err
    # Without --gt, several CSVs are methods scored side by side (test_evaluate_methods.py):
    # the missing --top file is named.
    assert main(["evaluate", "--pred", "a.csv", "b.csv", "--top", "t", "--hor", "h"]) == 2
    assert capsys.readouterr().err == "xvmatch: error: t: no such file\n"


def test_worked_example_per_view_tracking():
    """TrackEval's per-view figures of the example: B misses 1 of its 5 boxes (MOTA 4/5, IDF1
    8/9); C swaps two ids at frame 2 (2 switches over 4 boxes, MOTA 1/2, IDF1 2/4)."""
    pytest.importorskip("trackeval")
    pred, gt = _example()
    t = view_tracking_scores(pred, gt)
    assert t["A"]["mota"] == pytest.approx(100.0) and t["A"]["idf1"] == pytest.approx(100.0)
    assert t["B"]["mota"] == pytest.approx(80.0) and t["B"]["idf1"] == pytest.approx(800 / 9)
    assert t["C"]["mota"] == pytest.approx(50.0) and t["C"]["idf1"] == pytest.approx(50.0)
    assert t["C"]["idsw"] == 2


def test_without_trackeval_the_cross_view_scores_stand_alone(example_files, monkeypatch,
                                                              capsys):
    import xvmatch.metrics.track_metrics as track_metrics

    def missing():
        raise ValueError("per-view tracking metrics need the TrackEval package")

    monkeypatch.setattr(track_metrics, "_trackeval", missing)
    pred, gt = _example()
    assert view_tracking_scores(pred, gt) is None
    assert main(["evaluate", "--pred", *example_files["pred"], "--gt",
                 *example_files["gt"]]) == 0
    out = capsys.readouterr().out
    assert "need TrackEval" in out and "all frame pairs" in out
