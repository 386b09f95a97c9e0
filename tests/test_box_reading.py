"""Box files as MOT tools write them (issue 69, item 10): a header line, frames counted from 0
(``--first-frame 0``) and the detector's score column (``--min-score``), read once in
:mod:`xvmatch.formats.mot_boxes` and offered by the commands through
:func:`xvmatch.commands._options.read_boxes`."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.formats.detection_rows import read_detection_rows
from xvmatch.formats.mot_boxes import BoxFileError, BoxFileNote, read_mot_boxes

HEADER = "frame,id,bb_left,bb_top,bb_width,bb_height,conf,x,y,z"


def _write(path, lines: list[str]):
    path.write_text("".join(f"{ln}\n" for ln in lines))
    return path


def _notes(call):
    """``(result, [note texts])`` of ``call()``; any other warning fails the test."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = call()
    assert all(issubclass(w.category, BoxFileNote) for w in caught), caught
    return result, [str(w.message) for w in caught]


def _same(a, b) -> None:
    assert list(a) == list(b)
    for f in a:
        np.testing.assert_array_equal(a[f].ids, b[f].ids)
        np.testing.assert_array_equal(a[f].boxes, b[f].boxes)


def test_header_line_is_skipped_with_a_note_and_line_numbers_kept(tmp_path) -> None:
    plain = _write(tmp_path / "plain.txt", ["1,1,10,20,30,40", "2,1,11,20,30,40"])
    headed = _write(tmp_path / "headed.txt", ["frame,id,x,y,w,h", "1,1,10,20,30,40",
                                              "2,1,11,20,30,40"])
    frames, notes = _notes(lambda: read_mot_boxes(headed))
    _same(frames, read_mot_boxes(plain))
    assert notes == [f"{headed}:1: header line skipped ('frame,id,x,y,w,h')"]
    bad = _write(tmp_path / "bad.txt", [HEADER, "1,1,10,20,30,40,0.9,-1,-1,-1",
                                        "2,1,abc,20,30,40,0.9,-1,-1,-1"])
    with pytest.raises(BoxFileError, match=rf"^{bad}:3: x is not a number: 'abc'$"):
        _notes(lambda: read_mot_boxes(bad))


@pytest.mark.parametrize("first", ["1,one,10,20,30,40", "frame,1,10,20,30,40", "a,b,c,d,e"])
def test_a_first_line_that_is_no_header_is_still_an_error(tmp_path, first) -> None:
    # Not column names in each of the first six fields: bad data, named at its line.
    path = _write(tmp_path / "b.txt", [first, "1,1,10,20,30,40"])
    with pytest.raises(BoxFileError, match=rf"^{path}:1: "):
        read_mot_boxes(path)


def test_frames_from_zero(tmp_path) -> None:
    one = _write(tmp_path / "one.txt", ["1,1,10,20,30,40", "2,1,11,20,30,40", "3,2,5,5,9,9"])
    zero = _write(tmp_path / "zero.txt", ["0,1,10,20,30,40", "1,1,11,20,30,40", "2,2,5,5,9,9"])
    with pytest.raises(BoxFileError, match=rf"^{zero}:1: frame must be >= 1 .*--first-frame 0"):
        read_mot_boxes(zero)
    frames, notes = _notes(lambda: read_mot_boxes(zero, first_frame=0))
    _same(frames, read_mot_boxes(one))
    assert notes == [f"{zero}: frames counted from 0 (--first-frame 0): frame f is read as f + 1"
                     ", and what xvmatch writes counts from 1"]
    negative = _write(tmp_path / "neg.txt", ["-1,1,10,20,30,40"])
    with pytest.raises(BoxFileError, match=rf"^{negative}:1: frame must be >= 0"):
        read_mot_boxes(negative, first_frame=0)
    with pytest.raises(ValueError, match="first_frame must be 0 or 1"):
        read_mot_boxes(one, first_frame=2)


def test_min_score_drops_the_weak_boxes_with_a_count(tmp_path) -> None:
    dets = _write(tmp_path / "dets.txt", ["1,-1,10,20,30,40,0.9,-1,-1,-1",
                                          "1,-1,50,20,30,40,0.3,-1,-1,-1",
                                          "2,-1,11,20,30,40,0.5,-1,-1,-1",
                                          "2,-1,90,20,30,40,0.49,-1,-1,-1"])
    frames, notes = _notes(lambda: read_detection_rows(dets, min_score=0.5))
    assert {f: r.boxes[:, 0].tolist() for f, r in frames.frames.items()} == {1: [10.0],
                                                                            2: [11.0]}
    assert notes == [f"{dets}: --min-score 0.5 dropped 2 of 4 boxes (score in field 7)"]
    # The kept rows keep their text and row numbers (track writes them back).
    assert [frames.lines[r] for r in np.concatenate([r.ids for r in frames.frames.values()])
            ] == ["1,-1,10,20,30,40,0.9,-1,-1,-1", "2,-1,11,20,30,40,0.5,-1,-1,-1"]
    # Without --min-score every box is kept, scores ignored.
    assert sum(len(r) for r in read_detection_rows(dets).frames.values()) == 4


def test_min_score_reads_the_column_a_header_names(tmp_path) -> None:
    path = _write(tmp_path / "h.txt", ["frame,id,x,y,w,h,class,score",
                                       "1,1,10,20,30,40,0.1,0.8", "1,2,50,20,30,40,0.9,0.2"])
    frames, notes = _notes(lambda: read_mot_boxes(path, min_score=0.5))
    assert frames[1].ids.tolist() == [1]  # field 8 (score), not field 7 (class)
    assert notes[-1] == f"{path}: --min-score 0.5 dropped 1 of 2 boxes (score in field 8)"


def test_min_score_without_scores_is_a_clear_error(tmp_path) -> None:
    six = _write(tmp_path / "six.txt", ["", "1,1,10,20,30,40"])
    with pytest.raises(BoxFileError, match=rf"^{six}:2: --min-score needs the detector's score "
                       r"in field 7 .* the line has 6 fields: the file has no score column"):
        read_mot_boxes(six, min_score=0.5)
    unset = _write(tmp_path / "unset.txt", ["1,1,10,20,30,40,-1,-1,-1,-1"])
    with pytest.raises(BoxFileError, match=rf"^{unset}: field 7 is -1 on every row"):
        read_mot_boxes(unset, min_score=0.5)
    weak = _write(tmp_path / "weak.txt", ["1,1,10,20,30,40,0.1", "2,1,10,20,30,40,0.2"])
    with pytest.raises(BoxFileError, match=rf"^{weak}: --min-score 0.5 drops every box "
                       r"\(scores 0.1..0.2 in field 7\)"):
        read_mot_boxes(weak, min_score=0.5)
    short = _write(tmp_path / "short.txt", ["1,1,10,20,30,40,0.9", "2,1,10,20,30,40"])
    with pytest.raises(BoxFileError, match=rf"^{short}:2: expected at least 7"):
        read_mot_boxes(short, min_score=0.5)


def test_duplicates_are_named_at_their_line_after_drops(tmp_path) -> None:
    path = _write(tmp_path / "d.txt", [HEADER, "1,1,10,20,30,40,0.1,-1,-1,-1",
                                       "1,1,12,20,30,40,0.9,-1,-1,-1",
                                       "1,1,14,20,30,40,0.8,-1,-1,-1"])
    with pytest.raises(BoxFileError, match=rf"^{path}:4: duplicate id 1 in frame 1 \(first on "
                       r"line 3\)"):
        _notes(lambda: read_mot_boxes(path, min_score=0.5))


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    """A simulated pair; the horizontal file with a score column, plus weak false boxes in a
    header-led, 0-based copy (what a detector with a low threshold writes)."""
    folder = tmp_path_factory.mktemp("reading")
    top, hor = write_box_scene(simulate_box_scene(SceneConfig(n_people=(5, 7)), n_frames=12,
                                                  seed=5), folder, "s")
    rows = [ln.split(",") for ln in hor.read_text().splitlines()]
    scored = [",".join([r[0], r[1], *r[2:6], "0.9", "-1", "-1", "-1"]) for r in rows]
    clean = _write(folder / "clean.txt", scored)
    noisy = [HEADER]
    for k, r in enumerate(rows):
        noisy.append(",".join([str(int(r[0]) - 1), r[1], *r[2:6], "0.9", "-1", "-1", "-1"]))
        if k % 3 == 0:  # a weak false box beside a real one, id far from any person's
            x = str((float(r[2]) + 400) % 2200)
            noisy.append(",".join([str(int(r[0]) - 1), str(900 + k), x, *r[3:6], "0.2", "-1",
                                   "-1", "-1"]))
    return folder, str(top), str(clean), str(_write(folder / "noisy0.txt", noisy))


def _zero_based(source: str, target, score: str | None = None) -> str:
    """``source`` rewritten counting frames from 0 (and with ``score`` in field 7)."""
    out = []
    for line in open(source).read().splitlines():
        f = line.split(",")
        out.append(",".join([str(int(f[0]) - 1), *f[1:6], *([score] if score else f[6:7]),
                             *f[7:]]))
    return str(_write(target, out))


def test_associate_with_min_score_and_first_frame(scene, capsys) -> None:
    folder, top, clean, noisy = scene
    # Frame by frame: the weak false boxes' effect on each frame is what is checked (video mode's
    # consensus along the tracks would mend it).
    args = ["--image-size", "2688x1512", "--quiet", "--mode", "frame"]
    assert main(["associate", "--top", top, "--hor", clean, "--out", str(folder / "a.csv"),
                 *args]) == 0
    capsys.readouterr()
    # --first-frame applies to both files, --min-score too: the top one needs scores.
    assert main(["associate", "--top", top, "--hor", noisy, "--out", str(folder / "b.csv"),
                 "--min-score", "0.5", "--first-frame", "0", *args]) == 2
    assert capsys.readouterr().err == (
        f"xvmatch: error: {top}: field 7 is -1 on every row (MOT's 'no score'): the file holds "
        "no detector scores; drop --min-score\n")
    top0 = _zero_based(top, folder / "top0.txt", "0.8")
    assert main(["associate", "--top", top0, "--hor", noisy, "--out", str(folder / "b.csv"),
                 "--min-score", "0.5", "--first-frame", "0", *args]) == 0
    err = capsys.readouterr().err
    assert f"xvmatch: note: {noisy}:1: header line skipped" in err
    n = len(open(clean).read().splitlines())
    weak = (n + 2) // 3  # one weak false box after every third real one
    assert f"xvmatch: note: {noisy}: --min-score 0.5 dropped {weak} of {n + weak} boxes" in err
    assert f"xvmatch: note: {top0}: --min-score 0.5 dropped 0 of " in err
    assert (folder / "a.csv").read_text() == (folder / "b.csv").read_text()
    # Without --min-score the weak false boxes stay, and change the pairs.
    assert main(["associate", "--top", top0, "--hor", noisy, "--out", str(folder / "c.csv"),
                 "--first-frame", "0", *args]) == 0
    assert (folder / "c.csv").read_text() != (folder / "a.csv").read_text()


def test_evaluate_reads_frames_from_zero(scene, capsys) -> None:
    folder, top, clean, _ = scene
    pred = folder / "e.csv"
    assert main(["associate", "--top", top, "--hor", clean, "--out", str(pred),
                 "--image-size", "2688x1512", "--quiet"]) == 0
    assert main(["evaluate", "--pred", str(pred), "--top", top, "--hor", clean]) == 0
    table = capsys.readouterr().out
    top0 = _zero_based(top, folder / "et0.txt")
    hor0 = _zero_based(clean, folder / "eh0.txt")
    assert main(["evaluate", "--pred", str(pred), "--top", top0, "--hor", hor0]) == 2
    assert capsys.readouterr().err == (
        f"xvmatch: error: {top0}:1: frame must be >= 1 (frames are 1-based, as in MOTChallenge;"
        " a file that counts from 0 needs --first-frame 0), got '0'\n")
    assert main(["evaluate", "--pred", str(pred), "--top", top0, "--hor", hor0,
                 "--first-frame", "0"]) == 0
    assert capsys.readouterr().out == table
