"""Tests of the command-line interface (xvmatch.cli), run in-process on simulated box files."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from xvmatch.cli import EXAMPLES, main
from xvmatch.cues.spatial_search import associate_sequence
from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene, write_box_scene
from xvmatch.formats.mot_boxes import (
    PREDICTION_HEADER,
    FrameBoxes,
    read_mot_boxes,
    read_predictions,
    shift_frames,
    write_mot_boxes,
    write_predictions,
)
from xvmatch.inference.linking.pair_consensus import consistent_pairs
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

WIDTH = 2688
COMMANDS = ("associate", "evaluate", "noise", "offset", "demo")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """A 30-frame simulated scene written as ``sim_top.txt`` / ``sim_hor.txt``."""
    folder = tmp_path_factory.mktemp("scene")
    scene = simulate_box_scene(n_frames=30, seed=1)
    top, hor = write_box_scene(scene, folder, "sim")
    return top, hor


def _error_line(capsys) -> str:
    """The single stderr line of a failed command (and nothing on stdout)."""
    out, err = capsys.readouterr()
    lines = err.splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("xvmatch: error: ")
    assert out == ""
    return lines[0]


# --------------------------------------------------------------------------------------------
# associate


@pytest.mark.parametrize(
    ("extra", "kwargs"),
    [
        (["--mode", "frame"], {}),
        ([], {"video": True}),  # auto: the files' ids are track ids, so video
        (["--camera-id", "0"], {"camera_id": 0, "video": True}),
        (["--mode", "video"], {"video": True}),
        (["--mode", "video", "--search", "follow"], {"search": "follow"}),
        (["--mode", "video", "--search", "reduced"], {"search": "reduced"}),
    ],
)
def test_associate_writes_the_pairs_of_associate_sequence(files, tmp_path, capsys, extra, kwargs):
    top, hor = files
    out = tmp_path / "pred.csv"
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(out), "--quiet"]
    assert main(argv + extra) == 0
    assert capsys.readouterr().err == ""
    assert out.read_text().splitlines()[0] == PREDICTION_HEADER == "frame,top_id,hor_id"
    top_boxes, hor_boxes = read_mot_boxes(top), read_mot_boxes(hor)
    video = kwargs.pop("video", False) or "search" in kwargs
    expected = associate_sequence(top_boxes, hor_boxes, WIDTH, **kwargs)
    if video:  # the pairs kept consistent along each view's tracks
        expected = consistent_pairs(expected, top_boxes, hor_boxes,
                                    sorted(set(top_boxes) | set(hor_boxes)))
    assert read_predictions(out) == {f: p for f, p in expected.items() if p}
    assert sum(len(p) for p in expected.values()) > 30  # not an empty prediction


def test_associate_reports_a_summary_unless_quiet(files, tmp_path, capsys):
    top, hor = files
    out = tmp_path / "pred.csv"
    assert main(["associate", "--top", str(top), "--hor", str(hor), "--out", str(out)]) == 0
    err = capsys.readouterr().err
    assert f"over 30 frames to {out}" in err


def test_associate_parameters_reach_the_search(files, tmp_path):
    # A 10-degree field of view sees almost nobody: far fewer pairs than the default 90.
    top, hor = files
    default, narrow = tmp_path / "a.csv", tmp_path / "b.csv"
    base = ["associate", "--top", str(top), "--hor", str(hor), "--quiet", "--camera-id", "0"]
    assert main([*base, "--out", str(default)]) == 0
    assert main([*base, "--out", str(narrow), "--fov", "10"]) == 0
    n_default = sum(map(len, read_predictions(default).values()))
    n_narrow = sum(map(len, read_predictions(narrow).values()))
    assert n_narrow < n_default / 2


def test_frame_mode_rejects_a_video_search(files, tmp_path, capsys):
    top, hor = files
    out = tmp_path / "pred.csv"
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(out), "--quiet"]
    assert main([*argv, "--mode", "frame", "--search", "follow"]) == 2
    assert "--mode video" in _error_line(capsys)
    assert not out.exists()


def test_auto_mode_is_frame_without_track_ids(files, tmp_path, capsys):
    # Ids that change every frame (detections numbered per frame, no tracker) are no video:
    # auto solves each frame on its own, and a video search is refused with the reason.
    top, hor = files
    renumbered = tmp_path / "hor_rows.txt"
    write_mot_boxes(renumbered, {f: FrameBoxes(f, np.arange(len(r.ids)) + 1000 * f, r.boxes)
                                 for f, r in read_mot_boxes(hor).items()})
    out = tmp_path / "pred.csv"
    argv = ["associate", "--top", str(top), "--hor", str(renumbered), "--out", str(out)]
    assert main([*argv, "--quiet", "--search", "follow"]) == 2
    assert "auto found no track ids" in _error_line(capsys)
    assert main(argv) == 0
    assert "--mode video" not in capsys.readouterr().err
    frame = tmp_path / "frame.csv"
    assert main([*argv[:-1], str(frame), "--mode", "frame", "--quiet"]) == 0
    assert out.read_text() == frame.read_text()


def test_video_mode_keeps_the_learned_pairs_consistent_along_tracks(tmp_path):
    # The learned matcher solves each frame; in video mode (auto, here) its pairs are then made
    # consistent along each view's tracks, as the library's consensus makes them (a scene whose
    # frames it does not all get right: the consensus changes some).
    top, hor = write_box_scene(simulate_box_scene(n_frames=30, seed=2), tmp_path, "s2")
    base = ["associate", "--top", str(top), "--hor", str(hor), "--model", "default", "--quiet"]
    frame, video = tmp_path / "frame.csv", tmp_path / "video.csv"
    assert main([*base, "--mode", "frame", "--out", str(frame)]) == 0
    assert main([*base, "--out", str(video)]) == 0
    top_boxes, hor_boxes = read_mot_boxes(top), read_mot_boxes(hor)
    expected = consistent_pairs(read_predictions(frame), top_boxes, hor_boxes,
                                sorted(set(top_boxes) | set(hor_boxes)))
    assert read_predictions(video) == {f: p for f, p in expected.items() if p}
    assert read_predictions(video) != read_predictions(frame)


def test_auto_mode_says_it_took_video(files, tmp_path, capsys):
    top, hor = files
    out = tmp_path / "pred.csv"
    assert main(["associate", "--top", str(top), "--hor", str(hor), "--out", str(out)]) == 0
    assert "note: --mode video: each view's ids persist" in capsys.readouterr().err


def test_bad_spatial_parameter_is_one_line(files, tmp_path, capsys):
    top, hor = files
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(tmp_path / "p.csv")]
    assert main([*argv, "--rho", "0.5"]) == 2
    assert "rho=0.5" in _error_line(capsys)


# --------------------------------------------------------------------------------------------
# Malformed input files: exit 2, one line naming the file and the line


def _write_lines(path, lines):
    path.write_text("".join(line + "\n" for line in lines))
    return path


GOOD = "1,1,10,20,30,40,-1,-1,-1,-1"


@pytest.mark.parametrize(
    ("lines", "bad_line", "what"),
    [
        ([GOOD, "1,2,10,20,30,40", "2,1,abc,20,30,40"], 3, "x is not a number: 'abc'"),
        ([GOOD, "2,1,10,20,-5,40"], 2, "w must be > 0"),
        ([GOOD, GOOD, GOOD, "2,1,10,20,30"], 4, "expected at least 6"),
        (["1.5,1,10,20,30,40"], 1, "frame must be an integer"),
    ],
)
@pytest.mark.parametrize("view", ["top", "hor"])
def test_malformed_box_file(files, tmp_path, capsys, lines, bad_line, what, view):
    top, hor = files
    bad = _write_lines(tmp_path / "bad.txt", lines)
    argv = ["associate", "--quiet", "--out", str(tmp_path / "p.csv")]
    argv += (
        ["--top", str(bad), "--hor", str(hor)]
        if view == "top"
        else ["--top", str(top), "--hor", str(bad)]
    )
    assert main(argv) == 2
    line = _error_line(capsys)
    assert f"{bad}:{bad_line}: " in line
    assert what in line


def test_missing_box_file(files, tmp_path, capsys):
    _, hor = files
    missing = tmp_path / "nowhere_top.txt"
    argv = ["associate", "--top", str(missing), "--hor", str(hor), "--out", str(tmp_path / "p")]
    assert main(argv) == 2
    assert _error_line(capsys) == f"xvmatch: error: {missing}: no such file"


@pytest.mark.parametrize("command", ["evaluate", "offset"])
def test_malformed_box_file_in_other_commands(files, tmp_path, capsys, command):
    top, _ = files
    bad = _write_lines(tmp_path / "bad_hor.txt", [GOOD, "3,1,10,20,30,nan"])
    argv = [command, "--top", str(top), "--hor", str(bad)]
    if command == "evaluate":
        pred = tmp_path / "pred.csv"
        write_predictions(pred, {})
        argv += ["--pred", str(pred)]
    assert main(argv) == 2
    assert f"{bad}:2: " in _error_line(capsys)


def test_noise_malformed_input(tmp_path, capsys):
    bad = _write_lines(tmp_path / "boxes.txt", [GOOD, "1,2,10,20,30,40", "1,3,10,x,30,40"])
    argv = ["noise", "--boxes", str(bad), "--view", "top", "--out", str(tmp_path / "o.txt")]
    assert main(argv) == 2
    assert f"{bad}:3: y is not a number" in _error_line(capsys)
    assert not (tmp_path / "o.txt").exists()


@pytest.mark.parametrize(
    ("lines", "bad_line", "what"),
    [
        (["frame,top,hor", "1,1,1"], 1, "wrong header"),
        ([PREDICTION_HEADER, "1,1,1", "2,one,1"], 3, "top_id is not a number"),
        ([PREDICTION_HEADER, "1,1,1", "1,2,1"], 3, "duplicate hor_id 1 in frame 1"),
    ],
)
def test_malformed_prediction_file(files, tmp_path, capsys, lines, bad_line, what):
    top, hor = files
    pred = _write_lines(tmp_path / "pred.csv", lines)
    assert main(["evaluate", "--top", str(top), "--hor", str(hor), "--pred", str(pred)]) == 2
    line = _error_line(capsys)
    assert f"{pred}:{bad_line}: " in line and what in line


def test_prediction_naming_an_absent_id(files, tmp_path, capsys):
    top, hor = files
    pred = _write_lines(tmp_path / "pred.csv", [PREDICTION_HEADER, "2,1,424242"])
    assert main(["evaluate", "--top", str(top), "--hor", str(hor), "--pred", str(pred)]) == 2
    line = _error_line(capsys)
    assert str(pred) in line and "424242" in line


# --------------------------------------------------------------------------------------------
# evaluate


@pytest.fixture(scope="module")
def prediction(files, tmp_path_factory):
    top, hor = files
    top_boxes, hor_boxes = read_mot_boxes(top), read_mot_boxes(hor)
    pred = associate_sequence(top_boxes, hor_boxes, WIDTH)
    path = tmp_path_factory.mktemp("pred") / "pred.csv"
    write_predictions(path, pred)
    return path, summarize(count_sequence(pred, top_boxes, hor_boxes))


def test_evaluate_prints_a_table(files, prediction, capsys):
    top, hor = files
    path, scores = prediction
    assert (
        main(
            [
                "evaluate",
                "--top",
                str(top),
                "--hor",
                str(hor),
                "--pred",
                str(path),
                "--name",
                "my-run",
            ]
        )
        == 0
    )
    header, row = capsys.readouterr().out.splitlines()
    assert header.split() == ["name", "frames", "CVIDP", "CVIDR", "CVIDF1", "CVMA", "ACC9"]
    cells = row.split()
    assert cells[0] == "my-run" and cells[1] == "30"
    assert float(cells[4]) == pytest.approx(scores.cvidf1, abs=0.051)
    assert float(cells[5]) == pytest.approx(scores.cvma, abs=0.051)


def test_evaluate_json(files, prediction, capsys):
    top, hor = files
    path, scores = prediction
    argv = ["evaluate", "--top", str(top), "--hor", str(hor), "--pred", str(path), "--json"]
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["cvidf1"] == pytest.approx(scores.cvidf1, rel=1e-12)
    assert data["cvma"] == pytest.approx(scores.cvma, rel=1e-12)
    assert data["n_frames"] == 30 and isinstance(data["tp"], int)


# --------------------------------------------------------------------------------------------
# noise


def test_noise_is_deterministic_for_a_seed(files, tmp_path):
    top, _ = files

    def run(seed: int, name: str) -> bytes:
        out = tmp_path / name
        argv = [
            "noise",
            "--boxes",
            str(top),
            "--view",
            "top",
            "--seed",
            str(seed),
            "--keep-id",
            "0",
            "--out",
            str(out),
        ]
        assert main(argv) == 0
        return out.read_bytes()

    first, again, other = run(3, "a.txt"), run(3, "b.txt"), run(4, "c.txt")
    assert first == again
    assert first != other
    original, noisy = read_mot_boxes(top), read_mot_boxes(tmp_path / "a.txt")
    assert original.keys() == noisy.keys()
    assert all(0 in noisy[f].ids for f in original if 0 in original[f].ids)  # --keep-id 0
    assert not np.array_equal(original[1].boxes[:1], noisy[1].boxes[:1])  # jittered


def test_noise_zero_levels_copy_the_boxes(files, tmp_path):
    _, hor = files
    out = tmp_path / "same.txt"
    argv = [
        "noise",
        "--boxes",
        str(hor),
        "--view",
        "hor",
        "--jitter",
        "0",
        "--miss",
        "0",
        "--false",
        "0",
        "--out",
        str(out),
    ]
    assert main(argv) == 0
    a, b = read_mot_boxes(hor), read_mot_boxes(out)
    assert a.keys() == b.keys()
    assert all(
        np.array_equal(a[f].ids, b[f].ids) and np.array_equal(a[f].boxes, b[f].boxes) for f in a
    )


# --------------------------------------------------------------------------------------------
# offset and demo


def test_offset_json(files, capsys):
    top, hor = files
    argv = [
        "offset",
        "--top",
        str(top),
        "--hor",
        str(hor),
        "--camera-id",
        "0",
        "--max-offset",
        "2",
        "--clip-start",
        "5",
        "--clip-length",
        "4",
        "--json",
    ]
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["offsets"] == [-2, -1, 0, 1, 2]
    assert len(data["costs"]) == 5 and all(c is None or c > 0 for c in data["costs"])
    assert data["offset"] in data["offsets"]
    # One clip: nothing to compare it with, so it is reported but never applied (issue 28,
    # item 6: an offset needs MIN_AGREEING_CLIPS clips that agree).
    assert data["status"] in ("unsupported", "within_tolerance") and data["applied"] == 0

    assert main(argv[:-1]) == 0
    assert capsys.readouterr().out.startswith(f"offset {data['offset']:+d} frames")


@pytest.mark.slow
def test_offset_from_one_asked_clip_says_why_it_is_not_applied(tmp_path, capsys):
    # A single clip the user asked for cannot be checked: it is reported, never applied, and
    # the warning says why (not that the videos are too short). The idealised walk of
    # test_offset_recovers_a_shift_end_to_end, renumbered by 8 frames (beyond the tolerance).
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=60, seed=3)
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    write_mot_boxes(top, scene.top)
    write_mot_boxes(hor, {f + 8: FrameBoxes(f + 8, r.ids, r.boxes) for f, r in scene.hor.items()})
    argv = ["offset", "--top", str(top), "--hor", str(hor), "--camera-id", "0",
            "--max-offset", "10", "--clips", "1", "--image-size", "2688x1512"]
    assert main([*argv, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["offset"] == -8 and data["status"] == "unsupported" and data["applied"] == 0
    assert main(argv) == 0
    err = capsys.readouterr().err
    assert "one clip (--clips 1 or --clip-start) cannot back an offset" in err
    assert "videos this short" not in err


@pytest.mark.slow
def test_offset_recovers_a_shift_end_to_end(tmp_path, capsys):
    # An idealised walk (equal heights, level camera, 5 fps: see test_spatial_search) whose
    # horizontal frames are renumbered f -> f + 4: horizontal frame g shows top frame g - 4.
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=60, seed=3)
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    write_mot_boxes(top, scene.top)
    write_mot_boxes(hor, {f + 4: FrameBoxes(f + 4, r.ids, r.boxes) for f, r in scene.hor.items()})
    argv = [
        "offset",
        "--top",
        str(top),
        "--hor",
        str(hor),
        "--camera-id",
        "0",
        "--max-offset",
        "6",
        "--clips",
        "3",
        "--json",
    ]
    assert main([*argv, "--step", "1"]) == 0  # every offset, as the paper
    full = json.loads(capsys.readouterr().out)
    assert full["offset"] == -4
    assert full["offsets"] == list(range(-6, 7))
    # 4 frames is within the estimate's precision: reported, not applied by --offset auto.
    assert full["status"] == "within_tolerance" and full["applied"] == 0
    assert full["evidence"] > 0 and 0 < full["support"] <= 1
    # The default, coarse to fine: the same estimate from fewer offsets.
    assert main(argv) == 0
    data = json.loads(capsys.readouterr().out)
    assert (data["offset"], data["status"], data["applied"]) == (-4, "within_tolerance", 0)
    assert set(data["offsets"]) < set(full["offsets"])
    assert main(argv[:-1]) == 0
    assert "note: -4 is within the estimate's precision" in capsys.readouterr().err


@pytest.mark.slow
def test_associate_with_an_offset_re_times_the_top_view(tmp_path, capsys):
    # The idealised walk of test_offset_recovers_a_shift_end_to_end, horizontal frames
    # renumbered by 8 (beyond the 5-frame tolerance of --offset auto): horizontal frame g shows
    # top frame g - 8, so the offset is -8 and pairs are written under the horizontal frames.
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=60, seed=3)
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    write_mot_boxes(top, scene.top)
    shifted_hor = {f + 8: FrameBoxes(f + 8, r.ids, r.boxes) for f, r in scene.hor.items()}
    write_mot_boxes(hor, shifted_hor)
    base = ["associate", "--top", str(top), "--hor", str(hor), "--camera-id", "0",
            "--mode", "frame"]
    scores = {}
    for tag, extra in [("none", []), ("given", ["--offset", "-8"]),
                       ("auto", ["--offset", "auto", "--max-offset", "10", "--workers", "2"])]:
        out = tmp_path / f"{tag}.csv"
        assert main([*base, "--out", str(out), "--quiet", *extra]) == 0
        pred = read_predictions(out)
        truth_top = shift_frames(scene.top, -8)  # the top view on the horizontal timeline
        scores[tag] = summarize(count_sequence(pred, truth_top, shifted_hor)).cvidf1
        if tag == "given":
            expected = associate_sequence(truth_top, shifted_hor, WIDTH, camera_id=0)
            assert pred == {f: p for f, p in expected.items() if p}
        if tag == "auto":
            assert pred == read_predictions(tmp_path / "given.csv")
    assert scores["given"] > scores["none"] + 10, scores
    capsys.readouterr()
    argv = ["evaluate", "--pred", str(tmp_path / "given.csv"), "--top", str(top), "--hor",
            str(hor), "--offset", "-8", "--json"]
    assert main(argv) == 0
    assert json.loads(capsys.readouterr().out)["cvidf1"] == pytest.approx(scores["given"])
    out = tmp_path / "loud.csv"
    assert main([*base, "--out", str(out), "--offset", "auto", "--max-offset", "10"]) == 0
    assert "estimated offset -8 frames" in capsys.readouterr().err


@pytest.mark.slow
def test_associate_keeps_the_timing_when_the_offset_is_unreliable(tmp_path, capsys):
    # Top and horizontal views of two different scenes: the clips' minima disagree.
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    write_mot_boxes(top, simulate_box_scene(config, n_frames=80, seed=3).top)
    write_mot_boxes(hor, simulate_box_scene(config, n_frames=80, seed=4).hor)
    base = ["associate", "--top", str(top), "--hor", str(hor)]
    auto, plain = tmp_path / "auto.csv", tmp_path / "plain.csv"
    auto_args = ["--out", str(auto), "--quiet", "--offset", "auto", "--max-offset", "15"]
    assert main([*base, *auto_args]) == 0
    assert "not applied" in capsys.readouterr().err  # a warning, even with --quiet
    assert main([*base, "--out", str(plain), "--quiet"]) == 0
    assert read_predictions(auto) == read_predictions(plain)


@pytest.mark.parametrize("extra", [["--mirror"], ["--gamma", "0.4"]])
def test_model_options_need_a_model(files, tmp_path, capsys, extra):
    top, hor = files
    out = tmp_path / "pred.csv"
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(out), "--quiet"]
    assert main([*argv, *extra]) == 2
    assert "add --model" in _error_line(capsys)
    assert not out.exists()


def test_associate_rejects_a_bad_offset(files, tmp_path, capsys):
    top, hor = files
    argv = ["associate", "--top", str(top), "--hor", str(hor), "--out", str(tmp_path / "p.csv")]
    with pytest.raises(SystemExit):
        main([*argv, "--offset", "soon"])
    assert "expected an integer number of frames or 'auto'" in capsys.readouterr().err


@pytest.mark.slow
def test_offset_on_videos_too_short_for_the_range_says_so(tmp_path, capsys):
    # The idealised walk, 35 frames, horizontal frames renumbered by 8: with the default +-60
    # one clip fits, its minimum is -8, and one clip cannot back it.
    config = SceneConfig(fps=5.0, height_range=(1.7, 1.7), hor_wobble_deg=0.0)
    scene = simulate_box_scene(config, n_frames=35, seed=3)
    top, hor = tmp_path / "top.txt", tmp_path / "hor.txt"
    write_mot_boxes(top, scene.top)
    write_mot_boxes(hor, {f + 8: FrameBoxes(f + 8, r.ids, r.boxes) for f, r in scene.hor.items()})
    argv = ["offset", "--top", str(top), "--hor", str(hor), "--camera-id", "0"]
    assert main(argv) == 0
    out, err = capsys.readouterr()
    assert out.startswith("offset -8 frames") and "1 of 1 clips agree" in out
    assert "only 1 clip fits videos this short for --max-offset 60" in err
    assert main([*argv, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["status"] == "unsupported" and data["applied"] == 0


def test_offset_bad_clip_settings_are_one_line(files, capsys):
    top, hor = files
    argv = ["offset", "--top", str(top), "--hor", str(hor), "--clip-length", "0"]
    assert main(argv) == 2
    assert "clip_length >= 1" in _error_line(capsys)


@pytest.mark.slow
def test_demo_prints_the_table_and_writes_the_picture(tmp_path, capsys, tiny_models):
    out = tmp_path / "demo"
    argv = ["demo", "--out", str(out), "--scenes", "1", "--frames", "2",
            "--model", str(tiny_models["full_bundle"])]
    assert main(argv) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("Eq. 9 accuracy (%) on 2 rendered pairs per scenario")
    rows = [line for line in lines if line.startswith(("handcrafted:", "learned (ONNX):"))]
    assert len(rows) == 8 + 3
    for row in rows:
        values = [float(c.rstrip("*")) for c in row.split()[-4:]]
        assert all(0.0 <= v <= 100.0 for v in values)
    assert (out / "match.png").is_file()
    assert (out / "scene" / "top.txt").is_file() and (out / "scene" / "cameras").is_dir()
    assert any(f"xvmatch associate --model {tiny_models['full_bundle']}" in line
               for line in lines)


# --------------------------------------------------------------------------------------------
# help and imports


@pytest.mark.parametrize("command", COMMANDS)
def test_help_of_every_command_has_an_example(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "example:" in out and EXAMPLES[command] in out
    assert EXAMPLES[command].startswith(f"xvmatch {command} ")


def test_top_level_help_lists_every_command(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert all(c in out for c in COMMANDS)


def test_help_lists_the_commands_in_the_order_a_user_needs_them(capsys):
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    order = ["demo", "associate", "evaluate", "offset", "synth", "show", "baseline",
             "fit-geometry", "train", "export", "noise"]
    positions = [out.index(f"\n    {c}") for c in order]
    assert positions == sorted(positions)


def test_version_prints_the_file_formats(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--version"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith("xvmatch ")
    for what in ("geometry features: version 2", "matcher bundle: format 1",
                 "matcher file (.pt): format 1", "camera file: version 1",
                 "synthetic dataset: schema 1"):
        assert what in out


def test_unknown_command_is_a_usage_error(capsys):
    with pytest.raises(SystemExit) as info:
        main(["frobnicate"])
    assert info.value.code == 2


@pytest.mark.slow
def test_associate_does_not_import_torch(files, tmp_path):
    # A stand-in ``torch`` package on the path makes any import of it succeed and land in
    # sys.modules, whether or not the real torch is installed here.
    fake = tmp_path / "fake_site" / "torch"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("FAKE = True\n")
    top, hor = files
    script = textwrap.dedent(
        f"""
        import sys
        from xvmatch.cli import main
        rc = main(["associate", "--top", {str(top)!r}, "--hor", {str(hor)!r},
                   "--out", {str(tmp_path / "p.csv")!r}, "--quiet"])
        assert rc == 0, rc
        leaked = sorted(m for m in sys.modules if m == "torch" or m.startswith("torch."))
        assert not leaked, leaked
        import torch  # the control: the stand-in is importable, so the check above can fail
        assert torch.FAKE
        print("ok")
        """
    )
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join(
            [str(fake.parent), *filter(None, [os.environ.get("PYTHONPATH")])]
        ),
    )
    proc = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"


# --------------------------------------------------------------------------------------------
# Ctrl-C during training (issue 28)

_CTRL_C = '''
import os
import signal

from lightning.pytorch.callbacks import Callback


class CtrlC(Callback):
    """Presses Ctrl-C (a real SIGINT to this process) at the first training batch."""

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        os.kill(os.getpid(), signal.SIGINT)
'''


@pytest.mark.slow
def test_ctrl_c_during_train_is_an_interruption_not_a_rejected_configuration(
        tmp_path, tiny_synth, capsys, monkeypatch):
    import signal
    from pathlib import Path

    pytest.importorskip("lightning")
    (tmp_path / "ctrl_c_callback.py").write_text(_CTRL_C)
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.chdir(tmp_path)
    data = tiny_synth["overview"]
    config = Path(__file__).resolve().parents[1] / "configs" / "appearance_cpu.yaml"
    handler = signal.getsignal(signal.SIGINT)
    # Ctrl-C as in a terminal, even when the test run was started with SIGINT ignored (in the
    # background by a non-interactive shell).
    signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        rc = main(["train", "--config", str(config),
                   "--data.init_args.train_data", f"[{data}]",
                   "--data.init_args.val_data", str(data),
                   "--data.init_args.input_height", "32", "--data.init_args.input_width", "16",
                   "--data.init_args.workers", "1",
                   "--model.init_args.net.init_args.input_size", "[32, 16]",
                   "--model.init_args.net.init_args.widths", "[4, 8, 8, 16]",
                   "--trainer.default_root_dir", str(tmp_path),
                   "--trainer.max_epochs", "1", "--trainer.enable_progress_bar", "false",
                   "--trainer.callbacks+=ctrl_c_callback.CtrlC"])
    finally:
        signal.signal(signal.SIGINT, handler)  # Lightning ignores SIGINT after a Ctrl-C
    err = capsys.readouterr().err
    assert rc == 130, err
    assert err.strip().splitlines()[-1] == "xvmatch: interrupted"
    # Not reported as a bad configuration (a logging handler left by another test may print a
    # stack naming this test, so look for the command's own error line, not the word).
    assert "xvmatch: error" not in err
