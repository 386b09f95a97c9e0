"""Hostile box files through the commands (issue 28): real line numbers, empty files, a box
far outside any image; each is one line naming the file (and line), exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from xvmatch.cli import main


def _error_line(capsys) -> str:
    """The single stderr line of a failed command."""
    err = capsys.readouterr().err
    lines = err.splitlines()
    assert len(lines) == 1 and lines[0].startswith("xvmatch: error: "), err
    return lines[0]


def _commands(top: Path, hor: Path, out: Path) -> dict[str, list[str]]:
    """Every command that reads a top and a horizontal box file, writing under ``out``."""
    return {
        "associate": ["associate", "--top", str(top), "--hor", str(hor), "--out",
                      str(out / "pred.csv"), "--quiet"],
        "associate-model": ["associate", "--top", str(top), "--hor", str(hor), "--model",
                            "default", "--out", str(out / "pred.csv"), "--quiet"],
        "offset": ["offset", "--top", str(top), "--hor", str(hor), "--max-offset", "1"],
        "track": ["track", "--top", str(top), "--hor", str(hor), "--out", str(out / "tracks"),
                  "--quiet"],
        "associate-multi": ["associate-multi", "--top", str(top), "--hor", str(hor), "--out",
                            str(out / "multi"), "--quiet"],
    }


COMMANDS = list(_commands(Path(), Path(), Path()))


def _with_bad_top(scene_files, tmp_path: Path, bad: str) -> tuple[Path, int]:
    """The scene's top file with blank lines and ``bad`` inserted; returns it and bad's line."""
    lines = Path(scene_files[0]).read_text().splitlines()
    text = ["", lines[0], "", "", *lines[1:4], bad, *lines[4:]]
    path = tmp_path / "top.txt"
    path.write_text("\n".join(text) + "\n")
    return path, text.index(bad) + 1


@pytest.mark.parametrize("command", COMMANDS)
def test_a_bad_line_is_named_by_its_real_number(scene_files, tmp_path, capsys, command):
    # Blank lines before it count (track and associate-multi once skipped them first).
    top, line = _with_bad_top(scene_files, tmp_path, "2,99,10,20,0,40")
    out = tmp_path / "out"
    out.mkdir()
    assert main(_commands(top, scene_files[1], out)[command]) == 2
    assert f"{top}:{line}: box size w must be > 0" in _error_line(capsys)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("command", COMMANDS)
def test_a_box_far_outside_any_image_is_refused_at_its_line(scene_files, tmp_path, capsys,
                                                             command):
    # One top box at x = 1e22 once took the learned association of a frame from 11 pairs to 0,
    # silently (see MAX_PIXELS).
    top, line = _with_bad_top(scene_files, tmp_path, "2,99,1e22,20,30,40")
    out = tmp_path / "out"
    out.mkdir()
    assert main(_commands(top, scene_files[1], out)[command]) == 2
    assert f"{top}:{line}: x = 1e22 is far outside any image" in _error_line(capsys)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("text", ["", "\n\n \n"], ids=["empty", "blank-lines"])
@pytest.mark.parametrize("command", COMMANDS)
def test_a_box_file_without_boxes_is_one_line(scene_files, tmp_path, capsys, command, text):
    empty = tmp_path / "empty.txt"
    empty.write_text(text)
    out = tmp_path / "out"
    out.mkdir()
    for top, hor in ((empty, scene_files[1]), (scene_files[0], empty)):
        assert main(_commands(top, hor, out)[command]) == 2
        assert f"{empty}: no boxes" in _error_line(capsys)
    assert list(out.iterdir()) == []


# Frames and ids are integers read exactly (issue 65): 2**53 + 1 once read as 2**53 and was
# matched with that frame.

BEYOND = 2**53 + 1


@pytest.mark.parametrize(("bad", "field"), [
    (f"{BEYOND},99,10,20,30,40", "frame"),
    (f"2,{BEYOND},10,20,30,40", "id"),
    (f"2,-{BEYOND},10,20,30,40", "id"),
    ("2,9.007199254740993e15,10,20,30,40", "id"),
])
@pytest.mark.parametrize("command", COMMANDS)
def test_a_frame_or_id_beyond_2_53_is_refused_at_its_line(scene_files, tmp_path, capsys,
                                                          command, bad, field):
    top, line = _with_bad_top(scene_files, tmp_path, bad)
    out = tmp_path / "out"
    out.mkdir()
    assert main(_commands(top, scene_files[1], out)[command]) == 2
    message = _error_line(capsys)
    assert f"{top}:{line}: {field} " in message and "beyond 2**53" in message, message
    assert list(out.iterdir()) == []


def test_frames_and_ids_of_2_53_are_read_exactly(tmp_path):
    from xvmatch.formats.mot_boxes import read_mot_boxes, read_predictions

    boxes = tmp_path / "boxes.txt"
    boxes.write_text(f"{2**53},1,10,20,30,40\n{2**53 - 1},{-(2**53)},10,20,30,40\n"
                     f"1,{2**53}.0,10,20,30,40\n")
    frames = read_mot_boxes(boxes)
    assert sorted(frames) == [1, 2**53 - 1, 2**53]
    assert frames[2**53 - 1].ids.tolist() == [-(2**53)]
    assert frames[1].ids.tolist() == [2**53]
    pred = tmp_path / "pred.csv"
    pred.write_text(f"frame,top_id,hor_id\n{2**53},1,2\n")
    assert read_predictions(pred) == {2**53: [(1, 2)]}
    pred.write_text(f"frame,top_id,hor_id\n{BEYOND},1,2\n")
    with pytest.raises(ValueError, match=f"pred.csv:2: frame {BEYOND} is beyond 2\\*\\*53"):
        read_predictions(pred)


# Views with no frame in common (issue 65): once "wrote 0 pairs over 40 frames" and exit 0.


def _late(path: Path, folder: Path, shift: int) -> Path:
    """``path``'s boxes ``shift`` frames later, written in ``folder``."""
    from xvmatch.formats.mot_boxes import read_mot_boxes, shift_frames, write_mot_boxes

    late = folder / f"late_{Path(path).name}"
    write_mot_boxes(late, shift_frames(read_mot_boxes(path), -shift))
    return late


PAIRING = [c for c in COMMANDS if c != "offset"]


@pytest.mark.parametrize("command", PAIRING)
def test_views_without_a_common_frame_are_refused(scene_files, tmp_path, capsys, command):
    hor = _late(scene_files[1], tmp_path, 100)  # frames 101..103 against 1..3
    out = tmp_path / "out"
    out.mkdir()
    assert main(_commands(scene_files[0], hor, out)[command]) == 2
    line = _error_line(capsys)
    assert (f"nothing to match: {scene_files[0]} and {hor} share no frame with boxes in both "
            "views (top frames 1..3, horizontal frames 101..103)") in line, line
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("command", PAIRING)
def test_an_offset_that_leaves_no_common_frame_is_named(scene_files, tmp_path, capsys,
                                                        command):
    out = tmp_path / "out"
    out.mkdir()
    argv = [*_commands(scene_files[0], scene_files[1], out)[command], "--offset", "50"]
    assert main(argv) == 2
    assert ("share no frame with boxes in both views after --offset 50 (top frame = "
            "horizontal frame +50)") in _error_line(capsys)
    assert list(out.iterdir()) == []


@pytest.mark.parametrize("command", ["associate", "track", "associate-multi"])
def test_an_offset_that_lines_the_views_up_runs(scene_files, tmp_path, capsys, command):
    hor = _late(scene_files[1], tmp_path, 100)
    out = tmp_path / "out"
    out.mkdir()
    argv = [*_commands(scene_files[0], hor, out)[command], "--offset", "-100"]
    assert main(argv) == 0, capsys.readouterr().err


def test_associate_multi_names_the_view_without_a_common_frame(scene_files, tmp_path, capsys):
    late = _late(scene_files[1], tmp_path, 100)
    out = tmp_path / "multi"
    argv = ["associate-multi", "--top", str(scene_files[0]), "--hor", str(scene_files[1]),
            str(late), "--out", str(out), "--quiet"]
    assert main(argv) == 2
    assert f"{scene_files[0]} and {late} share no frame" in _error_line(capsys)
    assert not out.exists()


def test_evaluate_and_adapt_refuse_views_without_a_common_frame(scene_files, tmp_path, capsys):
    hor = _late(scene_files[1], tmp_path, 100)
    pred = tmp_path / "pred.csv"
    pred.write_text("frame,top_id,hor_id\n")
    assert main(["evaluate", "--pred", str(pred), "--top", str(scene_files[0]), "--hor",
                 str(hor)]) == 2
    assert (f"nothing to score: {scene_files[0]} and {hor} share no frame"
            in _error_line(capsys))
    out = tmp_path / "site"
    assert main(["adapt", "--top", str(scene_files[0]), "--hor", str(hor), "--top-images",
                 str(tmp_path / "top"), "--hor-images", str(tmp_path / "hor"), "--out",
                 str(out), "--quiet"]) == 2
    assert (f"nothing to adapt on: {scene_files[0]} and {hor} share no frame"
            in _error_line(capsys))
    assert not out.exists()
