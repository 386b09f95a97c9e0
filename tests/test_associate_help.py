"""``xvmatch associate --help`` grouped, the common options first, each help short; and the
notes of the checks said in plain words (issue 69, item 8)."""

from __future__ import annotations

import math
import re

import pytest

from xvmatch.cli import main
from xvmatch.geometry.top_camera_refinement import TopCameraRefinement
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.camera_check import CameraCheck

COMMON = ["--top", "--hor", "--out", "--model", "--top-images", "--hor-images", "--cameras",
          "--image-size", "--offset", "--max-offset", "--mode", "--draw"]
"""The options most runs need, in the first group (``--max-offset`` comes with ``--offset``)."""

GROUPS = {
    "the handcrafted search (without --model)": ["--camera-id", "--search", "--rho", "--lam",
                                                 "--tau", "--dtheta", "--fov"],
    "learned matcher (--model)": ["--gamma", "--mirror", "--appearance-check"],
    "calibrated cameras (--cameras)": ["--refine-top-camera", "--write-cameras",
                                       "--camera-check"],
    "an oblique top view (without --cameras)": ["--top-view", "--top-image-size", "--hor-hfov",
                                                "--fps"],
    "box files from a detector": ["--duplicates", "--min-score", "--first-frame"],
    "output and run time": ["--costs", "--threads", "--precision", "--draw-video",
                            "--draw-every", "--no-labels", "--draw-truth", "--workers",
                            "--quiet"],
}
"""The groups after the first, in the order printed, with their options."""

LONG_HELP: set[str] = set()
"""Options allowed more than two lines (none: ``--offset``'s, written in
``xvmatch/commands/offset.py``, is given two lines by ``short_offset_help``)."""


def _help(capsys, monkeypatch, command: str = "associate") -> str:
    """``xvmatch COMMAND --help`` at 100 columns."""
    monkeypatch.setenv("COLUMNS", "100")
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    return capsys.readouterr().out


def _sections(text: str) -> dict[str, list[str]]:
    """``{section title: the flags it lists, in order}`` of a help text."""
    sections: dict[str, list[str]] = {}
    title = None
    for line in text.splitlines():
        if line and not line.startswith(" ") and line.endswith(":"):
            title = line[:-1]
            sections[title] = []
        elif title is not None and (m := re.match(r"  (--[a-z0-9-]+)", line)):
            sections[title].append(m.group(1))
    return sections


def test_associate_help_lists_the_common_options_first_then_one_group_per_topic(
        capsys, monkeypatch) -> None:
    text = _help(capsys, monkeypatch)
    sections = _sections(text)
    assert list(sections) == ["options", *GROUPS, "example"]
    assert sections["options"] == COMMON
    for title, flags in GROUPS.items():
        assert sections[title] == flags, title
    assert text.startswith("usage: xvmatch associate --top TOP --hor HOR --out OUT")
    assert len(text.splitlines()) <= 100  # 136 before the groups, 98 after


def test_associate_help_gives_each_option_two_lines_at_most(capsys, monkeypatch) -> None:
    text = _help(capsys, monkeypatch)
    lines: dict[str, int] = {}
    flag = None
    for line in text.split("\n\nexample:")[0].splitlines():
        if m := re.match(r"  (--[a-z0-9-]+)( \S+)?( {2,}\S.*)?$", line):
            flag = m.group(1)
            lines[flag] = 1 if m.group(3) else 0  # help on the option's own line, or below
        elif flag is not None and line.startswith(" " * 24):
            lines[flag] += 1
        else:
            flag = None
    assert set(lines) >= set(COMMON) | {f for flags in GROUPS.values() for f in flags}
    long = {f: n for f, n in lines.items() if n > 2 and f not in LONG_HELP}
    assert not long, long


@pytest.mark.parametrize("command", ["track", "associate-multi", "adapt", "evaluate", "offset"])
def test_the_commands_sharing_the_option_adders_still_list_them(command, capsys,
                                                                monkeypatch) -> None:
    # the adders now take groups; a command that passes none keeps every option in its help
    text = _help(capsys, monkeypatch, command)
    flags = {f for section in _sections(text).values() for f in section}
    shared = {"--top", "--duplicates"} if command in ("evaluate", "offset") else set()
    if command in ("track", "associate-multi", "adapt"):
        shared |= {"--refine-top-camera", "--camera-check", "--top-images", "--hor-images"}
    assert shared <= flags, shared - flags


def test_the_checks_that_could_not_judge_say_so_in_plain_words() -> None:
    few_images = AppearanceCheck(judged=False, trusted=True, auc=math.nan, error=math.nan,
                                 positives=1, negatives=0, bursts=2)
    assert few_images.message() == (
        "appearance check: the boxes alone are sure of only 1 pair over consecutive frames, "
        "30 needed to judge the images (a longer video gives more); the images were used "
        "without this check")
    few_cameras = CameraCheck(judged=False, trusted=True, kept=0, positives=1, bursts=2)
    said = few_cameras.message()
    assert said.startswith("camera check: the boxes alone are sure of only 1 pair over")
    assert said.endswith("; the cameras were used without this check")
    many = CameraCheck(judged=False, trusted=True, kept=0, positives=3, bursts=2, min_pairs=5)
    assert "only 3 pairs over consecutive frames, 5 needed" in many.message()
    for message in (few_images.message(), said, many.message()):
        assert "box-only matcher" not in message and "as they are" not in message


def test_the_top_cameras_refinement_says_how_many_of_the_frames_it_fitted() -> None:
    fit = TopCameraRefinement(camera=None, rotation_deg=(0.0, 0.5, 0.0), angle_deg=0.5,
                              frames=30, loss_before=0.676, loss_after=0.171)
    assert fit.describe(60) == (
        "turned the top camera 0.50 degrees so the people of both views line up, fitted on 30 "
        "of the 60 frames with people in both views, evenly spread (misfit 0.676 -> 0.171)")
    assert fit.fitted_on(30) == "30 frames with people in both views"
    assert fit.fitted_on() == "30 frames with people in both views"
