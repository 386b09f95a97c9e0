"""``--refine-top-camera``: when the run's top camera is refined, what the user is told, and what
it does for the learned matcher (inference/matching/camera_refinement.py)."""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from tests.test_top_camera_refinement import _angle, _flying_scene, _mounted, _scene, _turned
from xvmatch.cli import main
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video, write_tracking_video
from xvmatch.formats.camera_frames import CameraFrames, open_cameras, save_camera_frames
from xvmatch.formats.camera_io import save_cameras
from xvmatch.formats.mot_boxes import FrameBoxes, read_predictions
from xvmatch.geometry.camera import FrameCameras
from xvmatch.inference.matching.camera_refinement import (
    FIT_LOSS,
    OFF_HINT,
    refine_run_cameras,
    refine_views_cameras,
)
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.matching.learned_pipeline import LearnedRunOptions, run_learned_association

TURN = np.array([0.6, -1.4, 1.2])  # degrees, about 1.9 degrees in all
TILT = 2.0 * np.array([-0.9, -0.44, 0.03]) / np.linalg.norm([-0.9, -0.44, 0.03])
"""A 2-degree error of the rendered overview camera, mostly a tilt: it hurts the matcher."""


def _records(boxes: list[np.ndarray], first: int = 1) -> dict[int, FrameBoxes]:
    return {first + k: FrameBoxes(first + k, np.arange(len(b)), b) for k, b in enumerate(boxes)}


@pytest.fixture(scope="module")
def scene():
    """The geometry tests' walking scene: exact cameras and each frame's boxes."""
    return _scene(11)


@pytest.mark.slow
def test_a_fixed_top_camera_is_turned_back(scene) -> None:
    top, hors, top_boxes, hor_boxes = scene
    wrong = _turned(top, TURN)
    cameras = CameraFrames("cams/", per_frame={1 + k: FrameCameras(wrong, h)
                                               for k, h in enumerate(hors)})
    frames = range(1, len(hors) + 1)
    used, what = refine_run_cameras(cameras, _records(top_boxes), _records(hor_boxes), frames)
    assert what.turned and what.fits
    assert what.message.startswith("cameras: turned the top camera 1.")
    assert what.message.endswith(OFF_HINT)
    assert _angle(used.get(1).top, top) < 0.3
    assert all(used.get(f).top is used.get(1).top for f in frames)
    assert all(used.get(f).hor is cameras.get(f).hor for f in frames)
    # the top records re-timed: the same fit from top frame f + 3
    shifted, again = refine_run_cameras(cameras, _records(top_boxes, first=4),
                                        _records(hor_boxes), frames, top_offset=3)
    assert again.fit.rotation_deg == what.fit.rotation_deg
    assert np.array_equal(shifted.get(1).top.R, used.get(1).top.R)


@pytest.mark.slow
def test_a_static_camera_file_keeps_its_form(scene) -> None:
    top, hors, top_boxes, hor_boxes = scene
    cameras = CameraFrames("cams.json", static=FrameCameras(_turned(top, TURN), hors[0]))
    # one egocentric camera for every frame: its head rays still meet the top ones on frame 1
    used, what = refine_run_cameras(cameras, _records(top_boxes), _records(hor_boxes),
                                    range(1, len(hors) + 1))
    assert used.static is not None and used.static.hor is hors[0] and not used.per_frame
    assert used.static.top is (what.fit.camera if what.turned else cameras.static.top)


@pytest.mark.slow
def test_an_exact_camera_is_used_as_given(scene) -> None:
    top, hors, top_boxes, hor_boxes = scene
    cameras = CameraFrames("cams/", per_frame={1 + k: FrameCameras(top, h)
                                               for k, h in enumerate(hors)})
    used, what = refine_run_cameras(cameras, _records(top_boxes), _records(hor_boxes),
                                    range(1, len(hors) + 1))
    assert used is cameras and not what.turned
    assert "about as well as given" in what.message and what.message.endswith("used as given")
    # kept as given because it already fits: track may leave the images to the over-time terms
    assert what.fit.loss_after <= FIT_LOSS and what.fits
    # kept as given with a loss no right camera reaches: neither a turned nor a fitting one
    poor = replace(what, fit=replace(what.fit, loss_after=FIT_LOSS + 0.01))
    assert not poor.fits and poor.turned == what.turned


@pytest.mark.slow
def test_a_flying_top_camera_is_turned_back_frame_by_frame() -> None:
    # A drone's per-frame cameras with a constant mount offset: each frame's top camera is
    # turned back by its own A_f^T Q A_f, the egocentric ones are kept, and the refinement
    # stays marked as moving (the camera check judges it whatever the fit).
    tops, hors, top_boxes, hor_boxes = _flying_scene(4)
    frames = range(1, len(hors) + 1)
    flying = CameraFrames("cams/", per_frame={
        1 + k: FrameCameras(_mounted(t, [1.5, -1.6, 1.2]), h)
        for k, (t, h) in enumerate(zip(tops, hors, strict=True))})
    used, what = refine_run_cameras(flying, _records(top_boxes), _records(hor_boxes), frames)
    assert what.turned and what.moving and what.fits and what.fit.frame == "camera"
    assert what.message.startswith("cameras: turned the moving top camera in its own frame")
    assert max(_angle(used.get(f).top, tops[f - 1]) for f in frames) < 0.3
    assert all(used.get(f).hor is flying.get(f).hor for f in frames)
    # exact telemetry: kept as given, still moving
    exact = CameraFrames("cams/", per_frame={1 + k: FrameCameras(t, h) for k, (t, h) in
                                             enumerate(zip(tops, hors, strict=True))})
    used, what = refine_run_cameras(exact, _records(top_boxes), _records(hor_boxes), frames)
    assert used is exact and not what.turned and what.moving
    assert what.message.startswith("cameras: the top camera changes from frame to frame; it "
                                   "lines up the people of both views about as well as given, "
                                   "on 24 frames")


@pytest.mark.slow
def test_a_moving_camera_still_on_its_sampled_frames_is_turned_frame_by_frame(scene) -> None:
    # The top camera is the same on every frame with boxes, another on a frame without any:
    # the fit is a fixed camera's, and that frame keeps its own camera, turned the same way.
    top, hors, top_boxes, hor_boxes = scene
    wrong = _turned(top, TURN)
    elsewhere = _turned(wrong, [0.0, 0.0, 30.0])
    last = len(hors) + 1
    cameras = CameraFrames("cams/", per_frame={
        **{1 + k: FrameCameras(wrong, h) for k, h in enumerate(hors)},
        last: FrameCameras(elsewhere, hors[-1])})
    used, what = refine_run_cameras(cameras, _records(top_boxes), _records(hor_boxes),
                                    range(1, last + 1))
    assert what.turned and what.moving and what.fit.frame == "fixed"
    assert _angle(used.get(1).top, top) < 0.3
    assert np.array_equal(used.get(last).top.R, _turned(elsewhere, what.fit.rotation_deg).R)


def test_a_short_clip_is_used_as_given(scene) -> None:
    top, hors, top_boxes, hor_boxes = scene
    short = CameraFrames("cams.json", static=FrameCameras(_turned(top, TURN), hors[0]))
    used, what = refine_run_cameras(short, _records(top_boxes[:4]), _records(hor_boxes[:4]),
                                    range(1, 5))
    assert used is short and what.fit is None and not what.moving
    assert "4 frame(s) with boxes in both views, too few" in what.message


@pytest.mark.slow
def test_several_views_share_one_fit(scene) -> None:
    # associate-multi: two egocentric views of one top view, each file holding the same
    # turned top camera; one fit over both views' head rays turns it once for both. View 2's
    # frame f is shown with top frame f + 12.
    top, hors, top_boxes, hor_boxes = scene
    half = len(hors) // 2
    wrong = _turned(top, TURN)

    def view(v: int, top_camera) -> CameraFrames:
        return CameraFrames(f"cams{v}/", per_frame={
            1 + k: FrameCameras(top_camera, hors[v * half + k]) for k in range(half)})

    hor = [_records(hor_boxes[:half]), _records(hor_boxes[half:])]
    frames = [range(1, half + 1)] * 2
    used, what = refine_views_cameras([view(0, wrong), view(1, wrong)], _records(top_boxes),
                                      hor, frames, [0, half])
    assert what.turned and what.fits and what.fit.frames == 2 * half
    assert _angle(used[0].get(1).top, top) < 0.3
    assert all(used[v].get(f).top is used[0].get(1).top for v in (0, 1) for f in frames[v])
    assert all(used[v].get(f).hor is hors[v * half + f - 1] for v in (0, 1) for f in frames[v])
    # files that disagree on the top camera: each as given
    given = [view(0, wrong), view(1, top)]
    used, what = refine_views_cameras(given, _records(top_boxes), hor, frames, [0, half])
    assert all(a is b for a, b in zip(used, given, strict=True)) and what.fit is None
    assert what.message == "cameras: the top camera differs between the views' files; used as given"
    assert what.moving


@pytest.mark.slow
def test_several_views_of_a_flying_camera_share_one_fit() -> None:
    # associate-multi under a drone in flight: each view's folder holds the drone's per-frame
    # telemetry (the same mount offset) for its own frames; view 2's frame f is shown with top
    # frame f + 12. One fit over both views turns every frame's top camera back.
    tops, hors, top_boxes, hor_boxes = _flying_scene(4)
    half = len(hors) // 2
    bias = [1.5, -1.6, 1.2]

    def view(v: int) -> CameraFrames:
        return CameraFrames(f"cams{v}/", per_frame={
            1 + k: FrameCameras(_mounted(tops[v * half + k], bias), hors[v * half + k])
            for k in range(half)})

    given = [view(0), view(1)]
    used, what = refine_views_cameras(given, _records(top_boxes),
                                      [_records(hor_boxes[:half]), _records(hor_boxes[half:])],
                                      [range(1, half + 1)] * 2, [0, half])
    assert what.turned and what.moving and what.fit.frame == "camera"
    assert what.fit.frames == 2 * half
    assert max(_angle(used[v].get(f).top, tops[v * half + f - 1])
               for v in (0, 1) for f in range(1, half + 1)) < 0.3


@pytest.fixture(scope="module")
def overview(tmp_path_factory):
    """A 40-frame rendered overview video, its files, and a camera folder whose top camera
    was calibrated 2 degrees off."""
    video = render_tracking_video(3, 40, SynthConfig(scenario="overview", n_people=(10, 14),
                                                     fps=25.0))
    folder = tmp_path_factory.mktemp("overview")
    files = write_tracking_video(video, folder)
    wrong = _turned(video.cameras[1].top, TILT)
    turned = folder / "turned"
    turned.mkdir()
    for f, cams in video.cameras.items():
        save_cameras(turned / f"{f:06d}.json", {"top": wrong, "ego": cams.hor})
    return video, files, turned


def _right(video, pairs) -> float:
    """Right pairs over true pairs plus wrong ones (the ids are the ground truth here, used
    only to score)."""
    found = [a == b for f in video.hor for a, b in pairs.get(f, [])]
    true = sum(len(set(video.top[f].ids.tolist()) & set(video.hor[f].ids.tolist()))
               for f in video.hor)
    return sum(found) / (true + len(found) - sum(found))


@pytest.mark.slow
def test_refinement_mends_the_matcher_on_a_miscalibrated_top_camera(overview) -> None:
    # Measured on this video: 0.415 with the camera as given, 1.000 refined (turned 2.15
    # degrees; the error was 2).
    video, _, turned = overview
    default = load_matcher_bundle("default")
    frames = sorted(video.hor)
    options = LearnedRunOptions((default,), video.hor_size, cameras=str(turned))
    off = run_learned_association(video.top, video.hor, frames, options)
    auto = run_learned_association(video.top, video.hor, frames,
                                   replace(options, refine_top_camera=True))
    assert off.refinement is None and auto.refinement.turned
    assert _right(video, off.pairs) < 0.7 and _right(video, auto.pairs) > 0.95, (
        _right(video, off.pairs), _right(video, auto.pairs))


@pytest.mark.slow
def test_associate_says_what_it_did(overview, tmp_path, capsys) -> None:
    _, files, turned = overview
    base = ["associate", "--top", str(files["top"]), "--hor", str(files["hor"]), "--model",
            "default", "--cameras", str(turned)]
    assert main([*base, "--out", str(tmp_path / "a.txt"), "--quiet"]) == 0
    said = capsys.readouterr().err
    assert "cameras: turned the top camera" in said and OFF_HINT in said
    assert main([*base, "--out", str(tmp_path / "b.txt"), "--quiet",
                 "--refine-top-camera", "off"]) == 0
    assert "cameras:" not in capsys.readouterr().err
    assert (tmp_path / "a.txt").read_bytes() != (tmp_path / "b.txt").read_bytes()


@pytest.mark.slow
def test_write_cameras_keeps_the_refined_cameras_for_next_time(overview, tmp_path, capsys) -> None:
    """``--write-cameras`` writes ``--cameras``' folder with the top camera as turned (the
    egocentric cameras as given): given back with ``--refine-top-camera off``, the same pairs,
    and ``track`` writes the same files. It replaces only a folder it made."""
    video, files, turned = overview
    base = ["associate", "--top", str(files["top"]), "--hor", str(files["hor"]), "--model",
            "default"]
    written = tmp_path / "refined"
    assert main([*base, "--cameras", str(turned), "--out", str(tmp_path / "a.txt"),
                 "--write-cameras", str(written)]) == 0
    said = capsys.readouterr().err
    assert f"cameras: wrote {written} (the top camera turned 2." in said
    given, again = open_cameras(turned), open_cameras(written)
    assert sorted(again.files) == sorted(given.files) == sorted(video.cameras)
    assert {Path(f).name for f in again.files.values()} == {p.name for p in turned.iterdir()}
    assert all(np.array_equal(again.get(f).hor.R, given.get(f).hor.R) for f in video.cameras)
    # 0.53 degrees from the true camera, 2.15 from the one given (2 degrees off)
    assert _angle(again.get(1).top, video.cameras[1].top) < 1.0
    assert _angle(again.get(1).top, given.get(1).top) > 1.5
    assert main([*base, "--cameras", str(written), "--refine-top-camera", "off", "--out",
                 str(tmp_path / "b.txt"), "--quiet"]) == 0
    assert (tmp_path / "a.txt").read_bytes() == (tmp_path / "b.txt").read_bytes()
    by_associate = {p.name: p.read_bytes() for p in written.glob("*.json")}
    more = tmp_path / "more"  # --cameras with a frame the boxes have not: written too
    shutil.copytree(turned, more)
    (more / "000999.json").write_bytes((turned / "000001.json").read_bytes())
    assert main([*base, "--cameras", str(more), "--out", str(tmp_path / "m.txt"), "--quiet",
                 "--write-cameras", str(written)]) == 0
    assert (written / "000999.json").is_file()
    (written / "notes.json").write_text("{}")  # the user's: never removed
    track = ["track", "--top", str(files["top"]), "--hor", str(files["hor"]), "--model",
             "default", "--cameras", str(turned), "--offset", "0", "--quiet"]
    assert main([*track, "--out", str(tmp_path / "t"), "--write-cameras", str(written)]) == 0
    assert (written / "notes.json").read_text() == "{}"
    (written / "notes.json").unlink()
    # the earlier run's frame 999 is gone, the rest as associate wrote it
    assert {p.name: p.read_bytes() for p in written.glob("*.json")} == by_associate
    assert main([*track, "--out", str(tmp_path / "t2"), "--write-cameras",
                 str(files["cameras"])]) == 2  # a folder it did not make
    assert "--write-cameras" in capsys.readouterr().err and not (tmp_path / "t2").exists()
    # One camera file (frame 1's cameras) for a run of 3 frames, too few to refine: the file
    # is written as given, in the same form.
    static = tmp_path / "static.json"
    save_cameras(static, {"top": given.get(1).top, "ego": given.get(1).hor})
    short = tmp_path / "short.txt"
    short.write_text("".join(line + "\n" for line in files["hor"].read_text().splitlines()
                             if int(line.split(",")[0]) <= 3))
    assert main(["associate", "--top", str(files["top"]), "--hor", str(short), "--model",
                 "default", "--cameras", str(static), "--out", str(tmp_path / "s.txt"),
                 "--write-cameras", str(tmp_path / "static_out.json")]) == 0
    assert "(the top camera as given)" in capsys.readouterr().err
    assert (tmp_path / "static_out.json").read_text() == static.read_text()
    for extra, message in ((["--refine-top-camera", "off"], "drop --refine-top-camera off"),
                           ([], "give --cameras")):
        args = [*base, "--out", str(tmp_path / "c.txt"), "--write-cameras",
                str(tmp_path / "x.json"), *extra]
        if extra:
            args += ["--cameras", str(turned)]
        assert main(args) == 2
        assert message in capsys.readouterr().err
    assert not (tmp_path / "c.txt").exists() and not (tmp_path / "x.json").exists()


def test_a_static_camera_file_is_written_as_one(scene, tmp_path) -> None:
    top, hors, _, _ = scene
    cameras = CameraFrames("cams.json", static=FrameCameras(_turned(top, TURN), hors[0]))
    save_camera_frames(cameras, tmp_path / "cams.json")
    again = open_cameras(tmp_path / "cams.json")
    assert again.static is not None and not again.per_frame
    for a, b in ((again.static.top, cameras.static.top), (again.static.hor, hors[0])):
        assert all(np.array_equal(getattr(a, k), getattr(b, k)) for k in ("K", "R", "c"))
        assert a.image_size == b.image_size


def test_a_dense_crowd_is_used_as_given(scene) -> None:
    # 120 x 50 people a frame: the search would hold 60,000 pairs over its 10 frames at least.
    top, hors, _, _ = scene
    rng = np.random.default_rng(0)

    def boxes(n: int, size: tuple[int, int]) -> np.ndarray:
        xy = rng.uniform([0, 0], [size[0] - 20, size[1] - 60], (n, 2))
        return np.column_stack([xy, np.full(n, 12.0), np.full(n, 36.0)])

    cameras = CameraFrames("cams.json", static=FrameCameras(_turned(top, TURN), hors[0]))
    used, what = refine_run_cameras(cameras, _records([boxes(120, (1280, 720))] * 12),
                                    _records([boxes(50, (640, 360))] * 12), range(1, 13))
    assert used is cameras and what.fit is None
    assert what.message.startswith("cameras: 6000 top x horizontal box pairs in a typical frame")


@pytest.mark.slow
def test_associate_multi_refines_the_shared_top_camera(tmp_path, capsys) -> None:
    # Two egocentric views of a rendered drone video, both camera folders holding the top
    # camera 2 degrees off: associate-multi turns it back on both views' boxes. Measured:
    # 0.306 of the pairs right as given, 1.000 refined.
    from xvmatch.datasets.multi_ego_scenes import (
        multi_ego_config,
        render_multi_ego,
        write_multi_ego_inputs,
    )

    frames = render_multi_ego([1, 0], n_ego=2, n_frames=20, config=multi_ego_config(2, fps=25.0))
    inputs = write_multi_ego_inputs(frames, tmp_path / "in", 1)
    wrong = _turned(frames[0].views[0].camera, TILT)
    folders = []
    for v in (1, 2):
        folder = tmp_path / f"turned{v}"
        folder.mkdir()
        for f in frames:
            save_cameras(folder / f"{f.frame:06d}.json", {"top": wrong, "ego": f.views[v].camera})
        folders.append(str(folder))
    size = "x".join(map(str, frames[0].views[1].camera.image_size))
    base = ["associate-multi", "--top", str(inputs.boxes[0]), "--hor", *map(str, inputs.boxes[1:]),
            "--model", "default", "--image-size", size, "--quiet", "--cameras", *folders]
    capsys.readouterr()
    written = [str(tmp_path / f"refined{v}") for v in (1, 2)]
    assert main([*base, "--out", str(tmp_path / "auto"), "--write-cameras", *written]) == 0
    said = capsys.readouterr().err
    assert "cameras: turned the top camera" in said and OFF_HINT in said
    assert main([*base, "--out", str(tmp_path / "again"), "--refine-top-camera", "off",
                 "--cameras", *written]) == 0  # the second --cameras wins: the ones written
    for name in ("top.txt", "hor1.txt", "hor2.txt"):
        assert (tmp_path / "auto" / name).read_bytes() == (tmp_path / "again" / name
                                                           ).read_bytes()
    assert main([*base, "--out", str(tmp_path / "one"), "--write-cameras", written[0]]) == 2
    assert "--write-cameras: one path per --cameras (2), got 1" in capsys.readouterr().err
    assert main([*base, "--out", str(tmp_path / "off"), "--refine-top-camera", "off"]) == 0
    assert "cameras:" not in capsys.readouterr().err
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
    from camera_refinement_eval import multi_pair_counts

    def right(out: Path) -> float:
        found, wrong, missed = multi_pair_counts(inputs, out)
        return found / (found + wrong + missed)

    off, auto = right(tmp_path / "off"), right(tmp_path / "auto")
    assert off < 0.7 and auto > 0.95, (off, auto)


@pytest.mark.slow
def test_a_flying_drone_s_cameras_are_mended_and_written(tmp_path, capsys) -> None:
    """``associate`` on a drone in flight whose telemetry carries a constant mount offset: the
    moving top camera is turned back frame by frame (the line says so), ``--write-cameras``
    writes each frame's camera as turned, and given back with ``--refine-top-camera off``
    they give the same pairs, closer to the truth than the cameras as given."""
    video = render_tracking_video(5, 40, SynthConfig(scenario="drone", n_people=(8, 12),
                                                     fps=25.0), flight=(2.0, 5.0))
    files = write_tracking_video(video, tmp_path)
    given = tmp_path / "telemetry"
    given.mkdir()
    for f, cams in video.cameras.items():
        save_cameras(given / f"{f:06d}.json", {"top": _mounted(cams.top, [2.0, -1.5, 1.0]),
                                               "ego": cams.hor})
    base = ["associate", "--top", str(files["top"]), "--hor", str(files["hor"]), "--model",
            "default", "--camera-check", "off"]
    written = tmp_path / "refined"
    assert main([*base, "--cameras", str(given), "--out", str(tmp_path / "a.txt"),
                 "--write-cameras", str(written), "--costs", str(tmp_path / "costs.json")]) == 0
    said = capsys.readouterr().err
    assert "cameras: turned the moving top camera in its own frame" in said
    assert f"cameras: wrote {written} (the moving top camera turned 2." in said
    # --costs records what the refinement did
    record = json.loads((tmp_path / "costs.json").read_text())["top_camera_refinement"]
    assert record["turned"] and record["moving"] and record["message"] in said
    fit = record["fit"]
    assert fit["frame"] == "camera" and fit["frames"] == 30 and 2.0 < fit["angle_deg"] < 3.0
    assert fit["loss_after"] < fit["loss_before"] and len(fit["rotation_deg"]) == 3
    again, before = open_cameras(written), open_cameras(given)
    for f in video.cameras:
        assert _angle(again.get(f).top, video.cameras[f].top) < 1.0
        assert _angle(before.get(f).top, video.cameras[f].top) > 2.5
    assert main([*base, "--cameras", str(written), "--refine-top-camera", "off", "--out",
                 str(tmp_path / "b.txt"), "--quiet"]) == 0
    assert (tmp_path / "a.txt").read_bytes() == (tmp_path / "b.txt").read_bytes()
    assert main([*base, "--cameras", str(given), "--refine-top-camera", "off", "--out",
                 str(tmp_path / "c.txt"), "--quiet"]) == 0
    pairs = {name: read_predictions(tmp_path / name) for name in ("a.txt", "c.txt")}
    assert _right(video, pairs["a.txt"]) > _right(video, pairs["c.txt"]) + 0.1, {
        name: _right(video, p) for name, p in pairs.items()}


def test_costs_say_when_no_fit_was_tried(scene, tmp_path) -> None:
    """A run too short to refine on: ``--costs`` records the refinement's line and no fit."""
    top, hors, top_boxes, hor_boxes = scene
    write = {"top": tmp_path / "top.txt", "hor": tmp_path / "hor.txt"}
    for name, boxes in (("top", top_boxes[:4]), ("hor", hor_boxes[:4])):
        write[name].write_text("".join(
            f"{f + 1},{i + 1},{x:.2f},{y:.2f},{w:.2f},{h:.2f},1,-1,-1,-1\n"
            for f, b in enumerate(boxes) for i, (x, y, w, h) in enumerate(b)))
    cameras = tmp_path / "cams.json"
    save_cameras(cameras, {"top": top, "ego": hors[0]})
    assert main(["associate", "--top", str(write["top"]), "--hor", str(write["hor"]),
                 "--model", "default", "--cameras", str(cameras), "--out",
                 str(tmp_path / "a.txt"), "--costs", str(tmp_path / "c.json"), "--quiet"]) == 0
    record = json.loads((tmp_path / "c.json").read_text())["top_camera_refinement"]
    assert record["fit"] is None and not record["turned"] and not record["moving"]
    assert "4 frame(s) with boxes in both views, too few" in record["message"]
    assert main(["associate", "--top", str(write["top"]), "--hor", str(write["hor"]),
                 "--model", "default", "--cameras", str(cameras), "--out",
                 str(tmp_path / "b.txt"), "--costs", str(tmp_path / "d.json"), "--quiet",
                 "--refine-top-camera", "off"]) == 0
    assert "top_camera_refinement" not in json.loads((tmp_path / "d.json").read_text())
