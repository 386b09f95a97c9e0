"""``evaluate --pred A=a.csv B=b.csv``: several methods scored side by side in one table, each
with its own recorded offset (issue 69, item 10)."""

from __future__ import annotations

import json
import shutil

import pytest

from xvmatch.cli import main
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import read_mot_boxes, shift_frames, write_mot_boxes


@pytest.fixture(scope="module")
def methods(tmp_path_factory):
    """A pair whose horizontal view starts 4 frames late, and two prediction CSVs: ``sync``
    made with ``--offset -4`` (recorded beside it), ``plain`` made without."""
    folder = tmp_path_factory.mktemp("methods")
    scene = simulate_box_scene(SceneConfig(n_people=(6, 8)), n_frames=24, seed=8)
    top, hor = write_box_scene(scene, folder, "s")
    late = folder / "late.txt"
    write_mot_boxes(late, shift_frames(read_mot_boxes(hor), 4))
    # Frame by frame, so that the run without the offset is worse (video mode's consensus along
    # the tracks mends much of a small shift).
    common = ["--top", str(top), "--hor", str(late), "--quiet", "--image-size", "2688x1512",
              "--mode", "frame"]
    assert main(["associate", *common, "--offset", "-4", "--out", str(folder / "sync.csv")]) == 0
    assert main(["associate", *common, "--out", str(folder / "plain.csv")]) == 0
    assert (folder / "sync.csv.offset.json").is_file()
    assert not (folder / "plain.csv.offset.json").exists()
    return folder, str(top), str(late)


def _rows(out: str) -> dict[str, list[str]]:
    header, *body = out.strip().splitlines()
    assert header.split()[0] == "name"
    return {line.split()[0]: line.split()[1:] for line in body}


def test_one_row_per_method_each_with_its_recorded_offset(methods, capsys) -> None:
    folder, top, late = methods
    sync, plain = folder / "sync.csv", folder / "plain.csv"
    alone = {}
    for name, path in (("sync", sync), ("plain", plain)):
        assert main(["evaluate", "--pred", str(path), "--top", top, "--hor", late,
                     "--name", name]) == 0
        alone.update(_rows(capsys.readouterr().out))
    assert main(["evaluate", "--pred", f"sync={sync}", f"plain={plain}", "--top", top,
                 "--hor", late]) == 0
    captured = capsys.readouterr()
    table = _rows(captured.out)
    assert list(table) == ["sync", "plain"]  # the order given
    assert table == alone
    assert float(table["sync"][3]) > float(table["plain"][3])  # CVIDF1: the offset helps
    assert captured.err.count("applying the offset -4") == 1  # sync's record only
    # --pred repeated is the same, and a plain FILE is named by its path.
    assert main(["evaluate", "--pred", f"sync={sync}", "--pred", str(plain), "--top", top,
                 "--hor", late]) == 0
    assert list(_rows(capsys.readouterr().out)) == ["sync", str(plain)]


def test_offset_given_applies_to_every_row(methods, capsys) -> None:
    folder, top, late = methods
    sync, plain = folder / "sync.csv", folder / "plain.csv"
    assert main(["evaluate", "--pred", f"a={sync}", f"b={plain}", "--top", top, "--hor", late,
                 "--offset", "0"]) == 0
    table = _rows(capsys.readouterr().out)
    assert main(["evaluate", "--pred", str(plain), "--top", top, "--hor", late, "--name",
                 "b"]) == 0
    assert table["b"] == _rows(capsys.readouterr().out)["b"]
    assert float(table["a"][3]) < 100.0  # sync's pairs scored on the wrong frames


def test_json_names_each_method(methods, capsys) -> None:
    folder, top, late = methods
    argv = ["evaluate", "--top", top, "--hor", late, "--json", "--pred"]
    assert main([*argv, f"x={folder / 'sync.csv'}", f"y={folder / 'plain.csv'}"]) == 0
    both = json.loads(capsys.readouterr().out)
    assert list(both) == ["x", "y"]
    assert main([*argv, str(folder / "sync.csv")]) == 0
    assert both["x"] == json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("extra, message", [
    (["--pred", "a=A", "a=B"], "--pred a=B: the row name a is given twice"),
    (["--pred", "a=A", "b=B", "--name", "n"], "--name labels one prediction CSV (2 given)"),
    (["--tracks", "T", "--first-frame", "0"], "--first-frame 0 scores prediction CSVs only"),
])
def test_bad_method_lists(methods, capsys, extra, message) -> None:
    _, top, late = methods
    assert main(["evaluate", "--top", top, "--hor", late, *extra]) == 2
    assert capsys.readouterr().err.startswith(f"xvmatch: error: {message}")


def test_a_path_with_an_equals_sign_is_a_file(methods, capsys) -> None:
    folder, top, late = methods
    odd = folder / "sub=dir"
    odd.mkdir(exist_ok=True)
    shutil.copy(folder / "plain.csv", odd / "p.csv")
    assert main(["evaluate", "--pred", str(odd / "p.csv"), "--top", top, "--hor", late]) == 0
    assert list(_rows(capsys.readouterr().out)) == [str(odd / "p.csv")]
