"""Tests of the MOT box / prediction file reader and writer (xvmatch.formats.mot_boxes)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.formats.detection_rows import read_detection_rows
from xvmatch.formats.mot_boxes import (
    MAX_PIXELS,
    PREDICTION_HEADER,
    BoxFileError,
    FrameBoxes,
    align_views,
    read_mot_boxes,
    read_predictions,
    shift_frames,
    write_mot_boxes,
    write_predictions,
)

GOOD_LINE = "1,1,10,20,30,40,-1,-1,-1,-1"


def _write(tmp_path: Path, text: str, name: str = "boxes.txt") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _expect_error(path: Path, line: int | None, match: str, reader=read_mot_boxes) -> None:
    """The reader raises a one-line BoxFileError "<path>:<line>: ..." that mentions ``match``."""
    with pytest.raises(BoxFileError, match=match) as info:
        reader(path)
    message = str(info.value)
    where = f"{path}:{line}: " if line is not None else f"{path}: "
    assert message.startswith(where), message
    assert "\n" not in message
    assert info.value.line == line
    assert info.value.path == str(path)


# --------------------------------------------------------------------------------------------
# Reading box files


def test_read_groups_by_frame_sorted_and_keeps_file_order(tmp_path):
    path = _write(
        tmp_path,
        "2,7,1.5,2,3,4,-1,-1,-1,-1\n"
        "1,3,10,20,30,40\n"  # only the 6 required fields
        "\n"  # blank lines are skipped
        "2,5,-4,0,1,1,-1,-1,-1,-1\n"
        "1.0,4.0,0,0,2,2,-1,-1,-1,-1\n",  # integer-valued floats are integers
    )
    frames = read_mot_boxes(path)
    assert list(frames) == [1, 2]
    assert frames[2].frame == 2
    np.testing.assert_array_equal(frames[2].ids, [7, 5])
    np.testing.assert_array_equal(frames[1].ids, [3, 4])
    np.testing.assert_array_equal(frames[2].boxes, [[1.5, 2, 3, 4], [-4, 0, 1, 1]])
    assert frames[1].ids.dtype == np.int64
    assert frames[1].boxes.dtype == np.float64
    assert frames[1].boxes.shape == (2, 4)


@pytest.mark.parametrize("text", ["", "\n\n", "  \n\t\n"])
def test_a_file_without_boxes_is_refused(tmp_path, text):
    path = _write(tmp_path, text)
    _expect_error(path, None, "no boxes")
    _expect_error(path, None, "no boxes", reader=read_detection_rows)
    assert read_mot_boxes(path, allow_empty=True) == {}


# Every character str.splitlines breaks at besides "\n": each would shift the line numbers.
OTHER_BREAKS = ["\v", "\x0c", "\x1c", "\x1d", "\x1e", "\x85", "\u2028", "\u2029", "\r"]


@pytest.mark.parametrize("char", OTHER_BREAKS, ids=[f"U+{ord(c):04X}" for c in OTHER_BREAKS])
@pytest.mark.parametrize("reader", [read_mot_boxes, read_detection_rows])
def test_another_line_break_character_is_refused_at_its_line(tmp_path, char, reader):
    # Line 3 holds the character between two fields, line 4 a bad value: the error is at 3.
    text = f"{GOOD_LINE}\n\n1,2,10,20,{char}30,40\n1,3,abc,0,1,1\n"
    _expect_error(_write(tmp_path, text), 3, f"U\\+{ord(char):04X}", reader=reader)


@pytest.mark.parametrize("char", OTHER_BREAKS, ids=[f"U+{ord(c):04X}" for c in OTHER_BREAKS])
def test_another_line_break_character_in_predictions_is_refused(tmp_path, char):
    path = _write(tmp_path, f"{PREDICTION_HEADER}\n1,2,3\n1,{char}4,5\n")
    _expect_error(path, 3, f"U\\+{ord(char):04X}", reader=read_predictions)


@pytest.mark.parametrize("reader", [read_mot_boxes, read_detection_rows])
def test_line_numbers_count_blank_lines_and_crlf_ends(tmp_path, reader):
    path = tmp_path / "boxes.txt"
    path.write_bytes(f"{GOOD_LINE}\r\n\r\n\n1,2,0,0,1,1\r\n1,3,0,0,1,0\r\n".encode())
    _expect_error(path, 5, "box size h must be > 0", reader=reader)
    path.write_bytes(f"{GOOD_LINE}\r\n\r\n1,2,0,0,1,1\r\n".encode())
    frames = reader(path) if reader is read_mot_boxes else reader(path).frames
    np.testing.assert_array_equal(frames[1].boxes[1], [0, 0, 1, 1])


def test_detection_rows_name_the_real_line_of_a_repeated_bad_row(tmp_path):
    # Blank lines before the bad row used to be skipped before counting (reported as line 2).
    path = _write(tmp_path, f"\n\n{GOOD_LINE}\n\n1,1,0,0,-1,5\n")
    _expect_error(path, 5, "box size w must be > 0", reader=read_detection_rows)
    rows = read_detection_rows(_write(tmp_path, f"\n{GOOD_LINE}\n\n1,-1,0,0,2,2\n", "ok.txt"))
    assert rows.lines == (GOOD_LINE, "1,-1,0,0,2,2")
    np.testing.assert_array_equal(rows.frames[1].ids, [0, 1])


def test_missing_file(tmp_path):
    _expect_error(tmp_path / "nope.txt", None, "no such file")


@pytest.mark.parametrize(
    ("bad_line", "match"),
    [
        ("1,1,abc,20,30,40", "x is not a number: 'abc'"),
        ("1,1,,20,30,40", "x is not a number"),
        ("1,1,10,20,30", "at least 6 comma-separated fields"),
        ("1", "at least 6"),
        ("5.5,1,10,20,30,40", "frame must be an integer"),
        ("0,1,10,20,30,40", "frame must be >= 1"),
        ("-3,1,10,20,30,40", "frame must be >= 1"),
        ("1,2.5,10,20,30,40", "id must be an integer"),
        ("1,2,10,20,0,40", "w must be > 0"),
        ("1,2,10,20,30,-1", "h must be > 0"),
        ("1,2,nan,20,30,40", "x must be finite"),
        ("1,2,10,inf,30,40", "y must be finite"),
        ("1,2,10,20,30,1_0", "h is not a number"),
        ("1,2,1e22,20,30,40", "x = 1e22 is far outside any image"),
        ("1,2,10,-1000001,30,40", "|y| must be at most 1000000 pixels"),
        ("1,2,10,20,2e6,40", "w = 2e6 is far outside any image"),
        ("1,1,11,21,31,41", "duplicate id 1 in frame 1 \\(first on line 1\\)"),
    ],
)
def test_malformed_box_line_names_file_and_line(tmp_path, bad_line, match):
    # Line 1 is good, line 2 blank, line 3 good: the bad line is line 4.
    text = f"{GOOD_LINE}\n\n2,1,10,20,30,40\n{bad_line}\n3,1,10,20,30,40\n"
    _expect_error(_write(tmp_path, text), 4, match)


def test_coordinates_up_to_max_pixels_are_read(tmp_path):
    path = _write(tmp_path, f"1,1,{-MAX_PIXELS:g},{MAX_PIXELS:g},{MAX_PIXELS:g},0.5\n")
    np.testing.assert_array_equal(read_mot_boxes(path)[1].boxes, [[-1e6, 1e6, 1e6, 0.5]])


def test_not_utf8_is_refused_at_its_line(tmp_path):
    path = tmp_path / "boxes.txt"
    path.write_bytes(b"1,1,10,20,30,40\n\xff\xfe\n")
    _expect_error(path, 2, "not UTF-8")


def test_duplicates_first_keeps_first_box_and_warns(tmp_path):
    path = _write(tmp_path, f"{GOOD_LINE}\n1,2,0,0,1,1\n1,1,99,99,9,9\n")
    with pytest.warns(UserWarning, match=f"{path}:3: duplicate id 1 in frame 1") as record:
        frames = read_mot_boxes(path, duplicates="first")
    assert len(record) == 1
    np.testing.assert_array_equal(frames[1].ids, [1, 2])
    np.testing.assert_array_equal(frames[1].boxes[0], [10, 20, 30, 40])
    with pytest.raises(ValueError, match="duplicates must be"):
        read_mot_boxes(path, duplicates="last")


def test_read_large_file_groups_every_frame(tmp_path):
    """A 13,200-line file parses on the vectorised path into 1200 frames of 11 boxes."""
    rng = np.random.default_rng(0)
    lines = [
        f"{t},{i},{x:.0f},{y:.0f},{w:.0f},{h:.0f},-1,-1,-1,-1"
        for i in range(11)
        for t in range(1, 1201)
        for x, y, w, h in [rng.uniform(1, 2000, size=4)]
    ]
    path = _write(tmp_path, "\n".join(lines) + "\n")
    frames = read_mot_boxes(path)
    assert len(frames) == 1200
    assert all(len(f) == 11 for f in frames.values())
    np.testing.assert_array_equal(frames[7].ids, np.arange(11))


# --------------------------------------------------------------------------------------------
# Writing box files


def test_box_round_trip_is_exact(tmp_path):
    rng = np.random.default_rng(1)
    min_size = np.array([0, 0, 60, 60])
    frames = {
        t: FrameBoxes(t, rng.permutation(9)[:n], rng.uniform(-50, 2700, (n, 4)) + min_size)
        for t, n in [(3, 4), (1, 2), (10, 5)]
    }
    frames[1] = FrameBoxes(1, [0, 8], [[1986, 144, 96, 85], [0.1, 1e-3, 1e6, 2.5]])
    path = tmp_path / "out.txt"
    write_mot_boxes(path, frames)
    back = read_mot_boxes(path)
    assert list(back) == [1, 3, 10]
    for t, rec in frames.items():
        np.testing.assert_array_equal(back[t].ids, rec.ids)
        np.testing.assert_array_equal(back[t].boxes, rec.boxes)
    assert path.read_text().splitlines()[0] == "1,0,1986,144,96,85,-1,-1,-1,-1"


def test_write_rejects_bad_records(tmp_path):
    path = tmp_path / "out.txt"
    with pytest.raises(ValueError, match="frame key 2"):
        write_mot_boxes(path, {2: FrameBoxes(1, [1], [[0, 0, 1, 1]])})
    with pytest.raises(ValueError, match="w/h <= 0"):
        write_mot_boxes(path, {1: FrameBoxes(1, [1], [[0, 0, 0, 1]])})
    with pytest.raises(ValueError, match="repeats an id"):
        write_mot_boxes(path, {1: FrameBoxes(1, [1, 1], [[0, 0, 1, 1], [0, 0, 1, 1]])})
    assert not path.exists()


def test_frame_boxes_checks_shapes():
    with pytest.raises(ValueError, match=r"boxes \(N, 4\)"):
        FrameBoxes(1, [1, 2], [[0, 0, 1, 1]])
    with pytest.raises(ValueError, match="ids must be integers"):
        FrameBoxes(1, [1.5], [[0, 0, 1, 1]])
    assert FrameBoxes(1, np.array([2.0]), [[0, 0, 1, 1]]).ids.dtype == np.int64
    empty = FrameBoxes(1, [], [])
    assert len(empty) == 0 and empty.boxes.shape == (0, 4)


# --------------------------------------------------------------------------------------------
# Prediction files


def test_predictions_round_trip(tmp_path):
    pairs = {12: [(3, 3), (1, 4)], 2: [(0, 1)], 5: []}
    path = tmp_path / "pred.csv"
    write_predictions(path, pairs)
    text = path.read_text()
    assert text.splitlines() == [PREDICTION_HEADER, "2,0,1", "12,3,3", "12,1,4"]
    assert read_predictions(path) == {2: [(0, 1)], 12: [(3, 3), (1, 4)]}


def test_predictions_header_only_is_empty(tmp_path):
    path = _write(tmp_path, PREDICTION_HEADER + "\n", "pred.csv")
    assert read_predictions(path) == {}


@pytest.mark.parametrize(
    ("text", "line", "match"),
    [
        ("", 1, "missing header"),
        ("frame,hor_id,top_id\n1,1,1\n", 1, "wrong header"),
        ("1,2,3\n", 1, "wrong header"),
        (f"{PREDICTION_HEADER}\n1,1,1\n1,1,2\n", 3, "duplicate top_id 1 in frame 1"),
        (f"{PREDICTION_HEADER}\n1,1,1\n\n1,2,1\n", 4, "duplicate hor_id 1 in frame 1"),
        (f"{PREDICTION_HEADER}\n1,1,1\n2,1.5,1\n", 3, "top_id must be an integer"),
        (f"{PREDICTION_HEADER}\n1,1,1,0.9\n", 2, "exactly 3 comma-separated fields"),
        (f"{PREDICTION_HEADER}\n1,1\n", 2, "exactly 3"),
        (f"{PREDICTION_HEADER}\n0,1,1\n", 2, "frame must be >= 1"),
        (f"{PREDICTION_HEADER}\n1,a,1\n", 2, "top_id is not a number"),
    ],
)
def test_malformed_predictions_name_file_and_line(tmp_path, text, line, match):
    path = _write(tmp_path, text, "pred.csv")
    _expect_error(path, line, match, reader=read_predictions)


def test_predictions_repeated_ids_in_other_frames_are_fine(tmp_path):
    path = _write(tmp_path, f"{PREDICTION_HEADER}\n1,1,2\n2,1,2\n1.0,2,1\n", "pred.csv")
    assert read_predictions(path) == {1: [(1, 2), (2, 1)], 2: [(1, 2)]}


def test_write_predictions_rejects_non_one_to_one(tmp_path):
    path = tmp_path / "pred.csv"
    with pytest.raises(ValueError, match="at most once"):
        write_predictions(path, {1: [(1, 2), (1, 3)]})
    assert not path.exists()


# --------------------------------------------------------------------------------------------
# Atomic writes


def test_atomic_write_leaves_no_temp_file(tmp_path):
    path = tmp_path / "a.txt"
    atomic_write_text(path, "one\n")
    atomic_write_text(path, "two\n")
    write_mot_boxes(tmp_path / "b.txt", {1: FrameBoxes(1, [1], [[0, 0, 1, 1]])})
    write_predictions(tmp_path / "c.csv", {1: [(1, 1)]})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt", "b.txt", "c.csv"]
    assert path.read_text() == "two\n"


def test_atomic_write_failure_keeps_old_file_and_cleans_up(tmp_path, monkeypatch):
    path = tmp_path / "a.txt"
    path.write_text("old\n")

    def broken_replace(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken_replace)
    with pytest.raises(OSError, match="disk full"):
        atomic_write_text(path, "new\n")
    assert path.read_text() == "old\n"
    assert [p.name for p in tmp_path.iterdir()] == ["a.txt"]


def test_atomic_write_keeps_permissions(tmp_path):
    path = tmp_path / "a.txt"
    path.write_text("old\n")
    path.chmod(0o640)
    atomic_write_text(path, "new\n")
    assert path.stat().st_mode & 0o777 == 0o640


def test_shift_frames_retimes_a_view():
    frames = {f: FrameBoxes(f, np.array([f]), np.array([[f, 0.0, 1.0, 2.0]])) for f in (1, 2, 5)}
    ahead = shift_frames(frames, 1)  # frame f of the result shows input frame f + 1
    assert sorted(ahead) == [1, 4]  # input frame 1 would land on frame 0: dropped
    assert ahead[1].frame == 1 and ahead[1].ids.tolist() == [2]
    assert ahead[4].boxes[0, 0] == 5.0
    behind = shift_frames(frames, -3)
    assert sorted(behind) == [4, 5, 8] and behind[8].ids.tolist() == [5]
    assert shift_frames(frames, 0).keys() == frames.keys()


@settings(max_examples=60, deadline=None)
@given(top=st.sets(st.integers(1, 50), min_size=1, max_size=8),
       hor=st.sets(st.integers(1, 50), min_size=1, max_size=8),
       offset=st.integers(-60, 60))
def test_align_views_lines_up_the_offset_and_drops_no_frame(top, hor, offset):
    def view(frames):
        return {f: FrameBoxes(f, np.array([f]), np.array([[f, 0.0, 1.0, 2.0]])) for f in frames}

    a_top, a_hor = align_views(view(top), view(hor), offset)
    # every box kept, still tagged with its input frame (its id here), frame numbers >= 1
    assert sorted(int(r.ids[0]) for r in a_top.values()) == sorted(top)
    assert sorted(int(r.ids[0]) for r in a_hor.values()) == sorted(hor)
    assert min(a_top) >= 1 and min(a_hor) >= 1
    assert all(r.frame == f for v in (a_top, a_hor) for f, r in v.items())
    # top frame t + offset and horizontal frame t share a number: one view moved, one not
    shift_top = {int(r.ids[0]): f for f, r in a_top.items()}
    shift_hor = {int(r.ids[0]): f for f, r in a_hor.items()}
    d_top = {f - t for t, f in shift_top.items()}
    d_hor = {f - t for t, f in shift_hor.items()}
    assert len(d_top) == 1 and len(d_hor) == 1 and 0 in d_top | d_hor
    assert d_hor.pop() - d_top.pop() == offset
