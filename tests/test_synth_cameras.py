"""``xvmatch synth --cameras N``: one scene of static cameras in the files ``multicam`` reads."""

from __future__ import annotations

from pathlib import Path

import pytest

from xvmatch.cli import main
from xvmatch.formats.mot_boxes import read_mot_boxes


def _exit_code(args: list[str]) -> int:
    """The exit code of a command, whether argparse (SystemExit) or the command refused it."""
    try:
        return main(args)
    except SystemExit as stop:
        return int(stop.code)


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != ".xvmatch-output.json"}


def test_box_only_scene_is_seeded_and_complete(tmp_path):
    args = ["synth", "--cameras", "3", "--boxes-only", "--frames", "30", "--seed", "4",
            "--quiet"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a = _files(tmp_path / "a")
    assert a == _files(tmp_path / "b")
    assert {"cameras.json", "ground_gt.csv", "boxes/cam1.txt", "gt/cam3.txt"} <= set(a)
    assert not any(name.startswith("images/") for name in a)
    # Rerun in its own folder with noise and fewer cameras: no stale camera, gt/ clean.
    assert main(["synth", "--cameras", "2", "--boxes-only", "--tracker-noise", "--frames", "30",
                 "--seed", "4", "--quiet", "--out", str(tmp_path / "a")]) == 0
    again = _files(tmp_path / "a")
    assert "boxes/cam3.txt" not in again and "gt/cam3.txt" not in again
    noisy = read_mot_boxes(tmp_path / "a" / "boxes" / "cam1.txt")
    clean = read_mot_boxes(tmp_path / "a" / "gt" / "cam1.txt")
    assert sum(len(r) for r in noisy.values()) != sum(len(r) for r in clean.values())


def test_rendered_scene_has_images_of_every_camera(tmp_path):
    out = tmp_path / "r"
    assert main(["synth", "--cameras", "2", "--frames", "2", "--size", "128x72", "--people",
                 "3:3", "--quiet", "--out", str(out)]) == 0
    for cam in ("cam1", "cam2"):
        assert sorted(p.name for p in (out / "images" / cam).iterdir()) == [
            "frame_000001.jpg", "frame_000002.jpg"]
        assert (out / "boxes" / f"{cam}.txt").is_file()


@pytest.mark.parametrize("extra, message", [
    (["--boxes-only"], "--boxes-only needs --cameras"),
    (["--cameras", "3", "--size", "640x480"], "16:9"),
    (["--cameras", "3", "--scenes", "2"], "--scenes does not apply to --cameras"),
    (["--cameras", "3", "--scenario", "drone"], "--scenario does not apply"),
    (["--cameras", "9"], "--cameras"),
])
def test_bad_options_are_one_line_and_write_nothing(tmp_path, capsys, extra, message):
    out = tmp_path / "o"
    assert _exit_code(["synth", "--quiet", "--out", str(out), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_a_folder_of_someone_else_is_not_replaced(tmp_path, capsys):
    out = tmp_path / "mine"
    out.mkdir()
    (out / "notes.txt").write_text("keep me\n")
    assert _exit_code(["synth", "--cameras", "2", "--boxes-only", "--quiet", "--out",
                       str(out)]) == 2
    assert "not made by synth --cameras" in capsys.readouterr().err
    assert (out / "notes.txt").read_text() == "keep me\n"
    assert sorted(p.name for p in out.iterdir()) == ["notes.txt"]
