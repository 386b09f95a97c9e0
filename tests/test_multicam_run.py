"""The multicam run as a library call (inference/views/multicam_run.py) and the files beside it
(formats/multicam_files.py, viz/birdseye.py): the run gives the association's answer, names the
line of a box at fault, and the readers refuse bad lines with the file and the line."""

from __future__ import annotations

import re

import numpy as np
import pytest

from xvmatch.datasets.multicam_scenes import MulticamConfig, simulate_multicam_scene
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.formats.multicam_files import (
    multicam_box_files,
    read_ground_csv,
    read_point_pairs,
    write_multicam_outputs,
)
from xvmatch.geometry.camera import look_rotation
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam import MulticamOptions, associate_cameras, relabel
from xvmatch.inference.views.multicam_run import (
    MulticamRunOptions,
    fit_ground_cameras,
    run_multicam,
)
from xvmatch.viz.birdseye import draw_birdseye


@pytest.fixture(scope="module")
def scene():
    sc = simulate_multicam_scene(MulticamConfig(n_cameras=2, n_people=(4, 4)), 30, seed=2)
    return sc, {n: GroundCamera.from_camera(c) for n, c in sc.cameras.items()}


def test_the_run_is_the_association_relabelled(scene):
    sc, cams = scene
    run = run_multicam(cams, sc.boxes, MulticamRunOptions())
    direct = associate_cameras(cams, sc.boxes, MulticamOptions())
    assert run.result.ground.keys() == direct.ground.keys()
    for g, (fr, xy) in direct.ground.items():
        np.testing.assert_array_equal(run.result.ground[g][0], fr)
        np.testing.assert_array_equal(run.result.ground[g][1], xy)
    expected = relabel(sc.boxes, direct)
    for name, frames in expected.items():
        for f, rec in frames.items():
            np.testing.assert_array_equal(run.relabelled[name][f].ids, rec.ids)


def test_a_box_above_the_horizon_is_named_by_its_line_or_left_out(scene, tmp_path):
    sc, cams = scene
    level = sc.cameras["cam1"]
    cams = {**cams, "cam1": GroundCamera.from_camera(
        type(level)(level.K, look_rotation(0.0, np.radians(2.0)), level.c, level.width,
                    level.height))}
    boxes = dict(sc.boxes)
    first = min(boxes["cam1"])
    rec = boxes["cam1"][first]
    sky = np.array([[level.width / 2, 40.0, 20.0, 60.0]])
    boxes["cam1"] = {**boxes["cam1"], first: FrameBoxes(first, np.r_[rec.ids, 777],
                                                        np.r_[rec.boxes, sky])}
    path = tmp_path / "cam1.txt"
    write_mot_boxes(path, boxes["cam1"])
    options = MulticamRunOptions(box_files={"cam1": str(path), "cam2": "cam2.txt"})
    with pytest.raises(ValueError, match=rf"^{path}:\d+: frame \d+, id \d+: the box's") as err:
        run_multicam(cams, boxes, options)
    # the line named holds the frame and the id named (many boxes are above this horizon)
    m = re.match(rf"{path}:(\d+): frame (\d+), id (\d+):", str(err.value))
    lines = path.read_text().splitlines()
    assert lines[int(m.group(1)) - 1].startswith(f"{m.group(2)},{m.group(3)},")
    told: list[str] = []
    run = run_multicam(cams, boxes, MulticamRunOptions(
        box_files=options.box_files, above_horizon="drop"), warn=told.append)
    assert len(told) == 1 and told[0].startswith(f"{path}: ")
    assert len(run.relabelled["cam1"][first]) == len(rec) + 1


def test_a_box_outside_its_image_is_named_by_its_line(scene, tmp_path):
    sc, cams = scene
    boxes = dict(sc.boxes)
    f = max(boxes["cam2"])
    rec = boxes["cam2"][f]
    far = np.array([[cams["cam2"].width + 10.0, 10.0, 20.0, 40.0]])
    boxes["cam2"] = {**boxes["cam2"], f: FrameBoxes(f, np.r_[rec.ids, 555],
                                                    np.r_[rec.boxes, far])}
    path = tmp_path / "cam2.txt"
    write_mot_boxes(path, boxes["cam2"])
    line = next(k for k, text in enumerate(path.read_text().splitlines(), 1)
                if text.startswith(f"{f},555,"))
    with pytest.raises(ValueError, match=rf"^{path}:{line}: frame {f}, id 555: the box lies "
                                         "entirely outside"):
        run_multicam(cams, boxes, MulticamRunOptions(box_files={"cam2": str(path)}))


def test_outputs_read_back_and_the_picture_is_a_png(scene, tmp_path):
    sc, cams = scene
    run = run_multicam(cams, sc.boxes, MulticamRunOptions())
    picture = draw_birdseye(run.result.ground, cams)
    assert picture[:4] == b"\x89PNG"
    write_multicam_outputs(tmp_path, sc.boxes, run.relabelled, run.result.ground, picture)
    back = read_ground_csv(tmp_path / "ground.csv")
    assert back.keys() == run.result.ground.keys()
    for g, (fr, xy) in run.result.ground.items():
        np.testing.assert_array_equal(back[g][0], fr)
        np.testing.assert_allclose(back[g][1], xy, atol=5e-5)  # written to 0.1 mm
    files = multicam_box_files(tmp_path, {"cam1": "gt1.txt", "cam2": "gt2.txt"})
    assert files == {n: str(tmp_path / f"{n}.txt") for n in ("cam1", "cam2")}
    with pytest.raises(ValueError, match=r"--gt cam9=gt9.txt: .*cam9.txt does not exist "
                                         r"\(multicam wrote cam1, cam2 there\)"):
        multicam_box_files(tmp_path, {"cam9": "gt9.txt"})


def test_bad_lines_are_named(tmp_path):
    ground = tmp_path / "ground.csv"
    ground.write_text("frame,global_id,X,Y\n1,2,0.5,0.5\n1,2,3\n")
    with pytest.raises(ValueError, match=rf"^{ground}:3: expected frame,global_id,X,Y"):
        read_ground_csv(ground)
    points = tmp_path / "points.csv"
    points.write_text("camera,u,v,X,Y\ncam1,1,2,3,4\ncam1,1,2,3,inf\n")
    with pytest.raises(ValueError, match=rf"^{points}:3: u, v, X, Y must be finite"):
        read_point_pairs(points)
    points.write_text("camera,u,v,X,Y\ncam1,1,2,3,4\n")
    with pytest.raises(ValueError, match="camera cam1: a homography needs at least 4"):
        fit_ground_cameras(read_point_pairs(points), {"cam1": (640, 480)}, points)
    with pytest.raises(ValueError, match=r"--image-size: camera cam1 of .* has no size"):
        fit_ground_cameras(read_point_pairs(points), {}, points)
