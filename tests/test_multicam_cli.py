"""End-to-end tests of ``xvmatch multicam`` and ``xvmatch evaluate --multicam``: outputs,
scores, and bad input refused with one line, exit 2, nothing written."""

from __future__ import annotations

import json

import numpy as np
import pytest

from xvmatch.cli import main
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    simulate_multicam_scene,
    write_multicam_scene,
)
from xvmatch.geometry.camera import look_rotation
from xvmatch.geometry.ground_plane import GroundCamera


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    root = tmp_path_factory.mktemp("mc") / "scene"
    sc = simulate_multicam_scene(MulticamConfig(n_cameras=3, n_people=(6, 6)), 60, seed=4)
    write_multicam_scene(root, sc)
    return root, sc


def _boxes_args(root, names=("cam1", "cam2", "cam3")):
    return ["--boxes", *(f"{n}={root / 'boxes' / (n + '.txt')}" for n in names)]


def test_multicam_end_to_end(scene, tmp_path, capsys):
    root, _sc = scene
    out = tmp_path / "out"
    rc = main(["multicam", *_boxes_args(root), "--cameras", str(root / "cameras.json"),
               "--out", str(out), "--quiet"])
    assert rc == 0
    for name in ("cam1.txt", "cam2.txt", "cam3.txt", "tracks.csv", "ground.csv",
                 "birdseye.png"):
        assert (out / name).is_file(), name
    assert (out / "birdseye.png").read_bytes()[:4] == b"\x89PNG"
    # The input rows, in order, with global ids.
    rows_in = (root / "boxes" / "cam2.txt").read_text().splitlines()
    rows_out = (out / "cam2.txt").read_text().splitlines()
    assert [r.split(",")[2:6] for r in rows_in] == [r.split(",")[2:6] for r in rows_out]
    capsys.readouterr()
    gt = [f"{n}={root / 'gt' / (n + '.txt')}" for n in ("cam1", "cam2", "cam3")]
    rc = main(["evaluate", "--multicam", str(out), "--gt", *gt, "--ground-gt",
               str(root / "ground_gt.csv"), "--json"])
    assert rc == 0
    scores = json.loads(capsys.readouterr().out)
    assert scores["P"] >= 0.9 and scores["R"] >= 0.9 and scores["idf1"]["IDF1"] >= 0.9
    assert scores["ground"]["median"] < 0.3
    # A second run into its own folder is allowed; dtw with whole tracks too, and the VRL
    # localisation, whose ground positions are scored the same way.
    assert main(["multicam", *_boxes_args(root), "--cameras", str(root / "cameras.json"),
                 "--out", str(out), "--quiet", "--method", "dtw", "--split-frames", "0"]) == 0
    header, *rows = (out / "tracks.csv").read_text().splitlines()
    assert header == "camera,track_id,first_frame,last_frame,global_id"
    keys = [tuple(r.split(",")[:2]) for r in rows]
    assert len(keys) == len(set(keys))  # whole tracks: one global id each
    assert main(["multicam", *_boxes_args(root), "--cameras", str(root / "cameras.json"),
                 "--out", str(out), "--quiet", "--localise", "two-best"]) == 0
    capsys.readouterr()
    assert main(["evaluate", "--multicam", str(out), "--gt", *gt, "--ground-gt",
                 str(root / "ground_gt.csv"), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["ground"]["median"] < 0.3


def _fails(args, capsys, pattern, out=None):
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error:"), err
    assert pattern in err[0], err[0]
    if out is not None:
        assert not out.exists()


def test_bad_input(scene, tmp_path, capsys):
    root, sc = scene
    cams = str(root / "cameras.json")
    out = tmp_path / "o"
    _fails(["multicam", *_boxes_args(root, ("cam1",)), "--cameras", cams, "--out", str(out)],
           capsys, "at least two cameras", out)
    _fails(["multicam", "--boxes", f"cam1={root / 'boxes/cam1.txt'}",
            f"cam9={root / 'boxes/cam2.txt'}", "--cameras", cams, "--out", str(out)],
           capsys, "camera cam9 is not in", out)
    # A box entirely outside its camera's image: the file, its line, the camera's size.
    lines = (root / "boxes" / "cam2.txt").read_text().splitlines()
    lines.insert(2, "1,555,5000.0,100.0,30.0,80.0,-1,-1,-1,-1")
    off = tmp_path / "off.txt"
    off.write_text("\n".join(lines) + "\n")
    _fails(["multicam", "--boxes", f"cam1={root / 'boxes/cam1.txt'}", f"cam2={off}",
            "--cameras", cams, "--out", str(out)], capsys,
           f"{off}:3: frame 1, id 555: the box lies entirely outside", out)
    # A singular homography, named with its file and camera.
    data = json.loads((root / "cameras.json").read_text())
    data["cameras"]["cam2"] = {"H": [[1, 2, 3], [2, 4, 6], [0, 0, 1]], "width": 1920,
                               "height": 1080}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    _fails(["multicam", *_boxes_args(root), "--cameras", str(bad), "--out", str(out)],
           capsys, "cameras.cam2.H", out)
    # A foot point above the horizon of a nearly level camera: the file and its line.
    level = sc.cameras["cam1"]
    data = json.loads((root / "cameras.json").read_text())
    data["cameras"]["cam1"]["R"] = look_rotation(0.0, np.radians(2.0)).tolist()
    tilted = tmp_path / "level.json"
    tilted.write_text(json.dumps(data))
    lines = (root / "boxes" / "cam1.txt").read_text().splitlines()
    lines.insert(0, f"1,777,{level.width / 2},40.0,20.0,60.0,-1,-1,-1,-1")
    sky = tmp_path / "sky.txt"
    sky.write_text("\n".join(lines) + "\n")
    _fails(["multicam", "--boxes", f"cam1={sky}", f"cam2={root / 'boxes/cam2.txt'}",
            "--cameras", str(tilted), "--out", str(out)], capsys,
           f"{sky}:1: frame 1, id 777: the box's foot point", out)
    # --above-horizon drop: such boxes (here every box above the level camera's horizon) sit
    # out with a warning, each track of them under a global id of its own.
    assert main(["multicam", "--boxes", f"cam1={sky}", f"cam2={root / 'boxes/cam2.txt'}",
                 "--cameras", str(tilted), "--out", str(out), "--quiet",
                 "--above-horizon", "drop"]) == 0
    assert "foot point lies above camera cam1's horizon" in capsys.readouterr().err
    rows = [r.split(",") for r in (out / "cam1.txt").read_text().splitlines()]
    assert len(rows) == len(lines)
    sky_id = [r[1] for r in rows
              if r[0] == "1" and float(r[2]) == level.width / 2 and float(r[3]) == 40.0]
    assert len(sky_id) == 1
    other_ids = {r[1] for r in (out / "cam2.txt").read_text().splitlines() for r in [r.split(",")]}
    assert sky_id[0] not in other_ids


def test_fit_homography(scene, tmp_path, capsys):
    _root, sc = scene
    cam = GroundCamera.from_camera(sc.cameras["cam1"])
    uv = np.array([[100, 1000], [1800, 1000], [1500, 600], [300, 600], [960, 800.0]])
    uv[:, 1] *= sc.cameras["cam1"].height / 1080
    uv[:, 0] *= sc.cameras["cam1"].width / 1920
    xy, ok = cam.to_ground(uv)
    assert ok.all()
    csv = tmp_path / "points.csv"
    csv.write_text("camera,u,v,X,Y\n" + "".join(
        f"cam1,{u},{v},{x},{y}\n" for (u, v), (x, y) in zip(uv, xy, strict=True)))
    out = tmp_path / "fitted.json"
    size = f"cam1={sc.cameras['cam1'].width}x{sc.cameras['cam1'].height}"
    assert main(["multicam", "--fit-homography", str(csv), "--image-size", size, "--out",
                 str(out), "--quiet"]) == 0
    H = np.array(json.loads(out.read_text())["cameras"]["cam1"]["H"])
    np.testing.assert_allclose(H, cam.H, atol=1e-6)
    csv.write_text("camera,u,v,X,Y\ncam1,1,2,3,4\n")
    _fails(["multicam", "--fit-homography", str(csv), "--image-size", size, "--out",
            str(tmp_path / "x.json")], capsys, "at least 4 point pairs")


def test_h_cameras_give_the_same_association(scene, tmp_path):
    """The association reads only each camera's homography: a cameras file of H cameras
    (what --fit-homography writes) gives the same output files but the picture."""
    root, sc = scene
    from xvmatch.formats.camera_io import save_cameras

    h_file = tmp_path / "h.json"
    save_cameras(h_file, {n: GroundCamera(GroundCamera.from_camera(c).H, c.width, c.height)
                          for n, c in sc.cameras.items()})
    outs = []
    for k, cams in enumerate((root / "cameras.json", h_file)):
        out = tmp_path / f"o{k}"
        assert main(["multicam", *_boxes_args(root), "--cameras", str(cams), "--out", str(out),
                     "--quiet"]) == 0
        outs.append(out)
    for name in ("cam1.txt", "cam2.txt", "cam3.txt", "tracks.csv", "ground.csv"):
        assert (outs[0] / name).read_text() == (outs[1] / name).read_text()
