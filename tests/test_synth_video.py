"""``xvmatch synth --video`` (a smooth clip), ``synth --egos K`` (several egocentric views) and
the MOT box files ``synth`` writes beside its JSON: what ``track``, ``associate``,
``associate-multi`` and ``evaluate`` read, and the commands ``synth`` prints (issue 69, items 2
and 5)."""

from __future__ import annotations

import shlex
from pathlib import Path

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.synthetic_io import MOT_FOLDER, SyntheticDataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import (
    render_tracking_video,
    tracking_frames,
    write_tracking_frames,
    write_tracking_video,
)
from xvmatch.formats.mot_boxes import FrameBoxes, read_mot_boxes

SIZE = (192, 108)
VIDEO = ["synth", "--video", "--frames", "20", "--size", "192x108", "--seed", "0"]


def _files(root: Path) -> dict[str, bytes]:
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != ".xvmatch-output.json"}


def _steps(frames: dict[int, FrameBoxes]) -> np.ndarray:
    """How far each person's box centre moves from one frame to the next, in pixels."""
    out, prev = [], {}
    for f in sorted(frames):
        b = frames[f]
        cur = {int(i): (x + w / 2, y + h / 2) for i, (x, y, w, h) in zip(b.ids, b.boxes,
                                                                         strict=True)}
        out += [np.hypot(cur[i][0] - prev[i][0], cur[i][1] - prev[i][1]) for i in cur
                if i in prev]
        prev = cur
    return np.array(out)


def _printed(text: str) -> list[list[str]]:
    """The arguments of the xvmatch commands ``synth`` printed, one list a line."""
    lines = [shlex.split(line) for line in text.splitlines() if line.startswith("  ")]
    return [words[next(k for k, w in enumerate(words)
                       if w in ("track", "associate", "evaluate")):] for words in lines]


@pytest.mark.slow
def test_video_is_smooth_and_seeded(tmp_path):
    """Consecutive frames: boxes move a few pixels (well under 1% of the width at the median),
    where the walk model's per-frame gaze (no head smoothing) jumps several percent."""
    assert main([*VIDEO, "--quiet", "--out", str(tmp_path / "a")]) == 0
    a = _files(tmp_path / "a")
    assert {"top.txt", "hor.txt", "top/000001.png", "hor/000020.png",
            "cameras/000020.json"} <= set(a)
    hor = read_mot_boxes(tmp_path / "a" / "hor.txt")
    top = read_mot_boxes(tmp_path / "a" / "top.txt")
    assert sorted(top) == list(range(1, 21))
    steps, width = _steps(hor), SIZE[0]
    assert len(steps) > 50
    assert np.median(steps) < 0.01 * width and np.percentile(steps, 95) < 0.03 * width
    assert np.percentile(_steps(top), 95) < 0.01 * width
    jumpy = {fr.frame: fr.hor for fr in tracking_frames(
        0, 20, SynthConfig(n_people=(3, 14), top_size=SIZE, ego_size=SIZE, fps=25.0),
        head_smoothing=0.0)}
    assert np.median(_steps(jumpy)) > 0.02 * width
    # the same seed gives the same bytes; a shorter rerun leaves no stale frame
    assert main([*VIDEO, "--quiet", "--out", str(tmp_path / "b")]) == 0
    assert _files(tmp_path / "b") == a
    assert main([*VIDEO[:3], "5", *VIDEO[4:], "--quiet", "--out", str(tmp_path / "a")]) == 0
    assert sorted(p.name for p in (tmp_path / "a" / "hor").iterdir())[-1] == "000005.png"
    assert sorted(read_mot_boxes(tmp_path / "a" / "top.txt")) == [1, 2, 3, 4, 5]


def test_frames_written_as_they_come_match_the_whole_video(tmp_path):
    """``write_tracking_frames`` (synth --video, one frame at a time) writes the bytes of
    ``write_tracking_video(render_tracking_video(...))``."""
    config = SynthConfig(n_people=(3, 5), top_size=(96, 54), ego_size=(96, 54), fps=25.0)
    write_tracking_video(render_tracking_video(5, 3, config), tmp_path / "whole")
    write_tracking_frames(tracking_frames(5, 3, config), tmp_path / "streamed")
    assert _files(tmp_path / "streamed") == _files(tmp_path / "whole")


def test_pairs_write_mot_files_that_round_trip(tmp_path, capsys):
    """``synth``'s ``mot/SCENE/top.txt`` and ``hor.txt`` hold the scene's labelled boxes."""
    out = tmp_path / "ds"
    assert main(["synth", "--out", str(out), "--scenes", "2", "--frames", "3", "--size",
                 "192x108", "--seed", "1"]) == 0
    dataset = SyntheticDataset(out)
    for name in dataset.scene_names:
        scene = dataset.scene(name)
        for view, file in (("top", "top.txt"), ("ego", "hor.txt")):
            want, got = scene.boxes(view), read_mot_boxes(out / MOT_FOLDER / name / file)
            assert sorted(got) == sorted(f for f in want if len(want[f]))
            for f, rows in got.items():
                np.testing.assert_array_equal(rows.ids, want[f].ids)
                np.testing.assert_allclose(rows.boxes, want[f].boxes, atol=1e-3)
        assert len(list((out / MOT_FOLDER / name / "cameras").iterdir())) == 3
    assert "mot/s00000/top.txt" in capsys.readouterr().err
    # a rerun replaces the dataset, mot/ included
    assert main(["synth", "--out", str(out), "--scenes", "1", "--frames", "2", "--size",
                 "192x108", "--quiet"]) == 0
    assert sorted(p.name for p in (out / MOT_FOLDER).iterdir()) == ["s00000"]


@pytest.mark.slow
def test_handcrafted_associate_and_evaluate_run_on_mot_files(tmp_path, capsys):
    """The box-only ``associate`` and ``evaluate`` read ``synth``'s MOT files as they are."""
    out = tmp_path / "ds"
    assert main(["synth", "--out", str(out), "--scenes", "1", "--frames", "3", "--size",
                 "192x108", "--seed", "1", "--quiet"]) == 0
    scene = out / MOT_FOLDER / "s00000"
    boxes = ["--top", str(scene / "top.txt"), "--hor", str(scene / "hor.txt")]
    pred = tmp_path / "pred.csv"
    assert main(["associate", *boxes, "--image-size", "192x108", "--out", str(pred)]) == 0
    assert main(["evaluate", "--pred", str(pred), *boxes]) == 0
    assert "CVIDF1" in capsys.readouterr().out


@pytest.mark.slow
def test_printed_commands_run(tmp_path, capsys, monkeypatch):
    """Every command ``synth`` and ``synth --video`` print runs as printed (``--model default``
    on the pairs' images and cameras; ``track`` on the clip)."""
    monkeypatch.chdir(tmp_path)
    assert main(["synth", "--out", "ds", "--scenes", "1", "--frames", "2", "--size",
                 "192x108"]) == 0
    assert main([*VIDEO[:3], "12", *VIDEO[4:], "--people", "3:5", "--out", "clip"]) == 0
    commands = _printed(capsys.readouterr().err)
    assert [c[0] for c in commands] == ["associate", "evaluate", "track", "evaluate",
                                        "associate", "evaluate"]
    for command in commands:
        assert main(command) == 0, command
    assert (tmp_path / "pred.csv").is_file() and (tmp_path / "clip" / "tracks").is_dir()


def test_egos_scene_is_seeded_and_complete(tmp_path):
    """``synth --egos 2``: a top and two egocentric views, each a MOT file (ground-truth ids: a
    person seen in two views has the same id), an image folder and, per egocentric view, a
    camera folder; the same seed gives the same bytes."""
    args = ["synth", "--egos", "2", "--frames", "2", "--size", "96x54", "--seed", "3",
            "--quiet"]
    assert main([*args, "--out", str(tmp_path / "a")]) == 0
    assert main([*args, "--out", str(tmp_path / "b")]) == 0
    a = _files(tmp_path / "a")
    assert a == _files(tmp_path / "b")
    assert {"top.txt", "hor1.txt", "hor2.txt", "images/top/000002.jpg", "images/hor2/000001.jpg",
            "cameras/hor1/000002.json", "cameras/hor2/000001.json"} <= set(a)
    assert not any(name.startswith("cameras/top") for name in a)
    top = read_mot_boxes(tmp_path / "a" / "top.txt")
    for view in ("hor1.txt", "hor2.txt"):
        hor = read_mot_boxes(tmp_path / "a" / view)
        assert sorted(hor) == [1, 2]
        assert set(hor[1].ids.tolist()) <= set(top[1].ids.tolist())


@pytest.mark.slow
def test_printed_associate_multi_and_evaluate_run(tmp_path, capsys):
    assert main(["synth", "--egos", "2", "--frames", "1", "--size", "96x54", "--out",
                 str(tmp_path / "me")]) == 0
    associate, evaluate = [shlex.split(line) for line in capsys.readouterr().err.splitlines()
                           if line.startswith("  ")]
    assert main(associate[associate.index("associate-multi"):]) == 0
    assert (tmp_path / "me" / "multi" / "hor2.txt").is_file()
    # Its output scored against the scene's ids, every pair of views (issue 69, item 5).
    capsys.readouterr()
    assert main(evaluate[evaluate.index("evaluate"):]) == 0
    assert "hor1 - hor2" in capsys.readouterr().out


@pytest.mark.parametrize("extra, message", [
    (["--cameras", "3"], "--video and --cameras are different modes"),
    (["--egos", "2"], "--video and --egos are different modes"),
    (["--scenes", "2"], "--scenes does not apply to --video"),
    (["--workers", "2"], "--workers does not apply to --video"),
    (["--boxes-only"], "--boxes-only needs --cameras"),
])
def test_video_refuses_what_does_not_apply(tmp_path, capsys, extra, message):
    assert main(["synth", "--video", "--out", str(tmp_path / "v"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "v").exists()


@pytest.mark.parametrize("extra, message", [
    (["--scenario", "overview"], "--scenario does not apply to --egos"),
    (["--scenes", "2"], "--scenes does not apply to --egos"),
    (["--people", "2:5"], "--egos 2 needs at least 3 people"),
])
def test_egos_refuses_what_does_not_apply(tmp_path, capsys, extra, message):
    assert main(["synth", "--egos", "2", "--out", str(tmp_path / "e"), *extra]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "e").exists()
