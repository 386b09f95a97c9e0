"""Hostile box files through the commands (issue 28): real line numbers, empty files, a box
far outside any image; each is one line naming the file (and line), exit 2, nothing written."""

from __future__ import annotations

from pathlib import Path

import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import simulate_box_scene, write_box_scene


@pytest.fixture(scope="module")
def scene_files(tmp_path_factory) -> tuple[Path, Path]:
    """A 3-frame simulated scene written as ``s_top.txt`` / ``s_hor.txt``."""
    folder = tmp_path_factory.mktemp("scene")
    return write_box_scene(simulate_box_scene(n_frames=3, seed=1), folder, "s")


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
