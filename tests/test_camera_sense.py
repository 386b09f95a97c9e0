"""Cameras are checked for physical sense where they are read (issue 65): a negative focal
length, a centre far away or below the ground, an image that sees no ground, a top camera
looking up, a homography whose bottom edge sees the sky, and degenerate --fit-homography points
are each refused in one line naming the file, the camera and the field."""

from __future__ import annotations

import json
import math
import os
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.cli import main
from xvmatch.formats.camera_io import CameraFileError, load_cameras, load_ground_cameras
from xvmatch.geometry.camera import (
    MAX_CENTRE_COORD,
    Camera,
    CameraSenseError,
    check_camera_sense,
    intrinsics_from_fov,
    look_rotation,
)
from xvmatch.geometry.ground_plane import (
    COLLINEAR_TOL,
    GroundCamera,
    check_ground_view,
    fit_homography,
    ground_from_camera,
)

TOP_SIZE, EGO_SIZE = (1280, 720), (640, 360)


def _top() -> Camera:
    """An oblique overview camera 12 m up, 40 degrees down."""
    return Camera(intrinsics_from_fov(*TOP_SIZE, 70.0), look_rotation(0.5, math.radians(40)),
                  [-10.0, -6.0, 12.0], *TOP_SIZE)


def _ego() -> Camera:
    """An egocentric camera at eye height, looking level."""
    return Camera(intrinsics_from_fov(*EGO_SIZE, 80.0), look_rotation(2.0, 0.02, 0.01),
                  [1.0, 2.0, 1.6], *EGO_SIZE)


def _record() -> dict:
    return {"version": 1, "cameras": {"top": _top().to_dict(), "ego": _ego().to_dict()}}


def _write(path: Path, record: dict) -> Path:
    path.write_text(json.dumps(record))
    return path


# Each impossible camera: the camera, the change to its record, and the line's field + words.
IMPOSSIBLE = [
    ("top", lambda r: r["K"][0].__setitem__(0, -800.0),
     r"cameras\.top\.K: focal length fx = -800 must be > 0"),
    ("ego", lambda r: r["K"][1].__setitem__(1, -500.0),
     r"cameras\.ego\.K: focal length fy = -500 must be > 0"),
    ("ego", lambda r: r["K"].__setitem__(2, [0.0, 0.0, -1.0]),
     r"cameras\.ego\.K: expected \[\[fx, s, cx\], \[0, fy, cy\], \[0, 0, 1\]\]"),
    ("top", lambda r: r["c"].__setitem__(0, 1e9),
     r"cameras\.top\.c: camera centre x = 1e\+09 m must be finite and within \+-100000 m"),
    ("top", lambda r: r["c"].__setitem__(2, -12.0),
     r"cameras\.top\.c: camera centre z = -12 m is below the ground"),
    ("ego", lambda r: r["c"].__setitem__(2, 0.0),
     r"cameras\.ego\.c: camera centre z = 0 m is on the ground"),
    ("top", lambda r: r.__setitem__("R", look_rotation(0.5, math.radians(-40)).tolist()),
     r"cameras\.top\.R: a top camera must look down, but its optical axis points 40 degrees "
     r"above the horizontal"),
    ("ego", lambda r: r.__setitem__("R", look_rotation(2.0, math.radians(-60)).tolist()),
     r"cameras\.ego\.R: the image sees no ground: its lowest ray points [\d.]+ degrees above "
     r"the horizontal"),
    ("ego", lambda r: r.__setitem__("R", (look_rotation(2.0) * 1.001).tolist()),
     r"cameras\.ego\.R: not a proper rotation"),
]


def _impossible(tmp_path: Path, case: int, name: str = "cams.json") -> Path:
    camera, change, _ = IMPOSSIBLE[case]
    record = _record()
    change(record["cameras"][camera])
    return _write(tmp_path / name, record)


def test_valid_cameras_load(tmp_path: Path) -> None:
    cams = load_cameras(_write(tmp_path / "cams.json", _record()), required=("top", "ego"))
    assert list(cams) == ["top", "ego"]
    # A horizontal camera may look up a little, as long as its image sees some ground.
    record = _record()
    record["cameras"]["ego"]["R"] = look_rotation(2.0, math.radians(-15)).tolist()
    assert "ego" in load_cameras(_write(tmp_path / "up.json", record))
    # A nadir (drone) top camera is the steepest looking down.
    record["cameras"]["top"]["R"] = look_rotation(0.3, math.pi / 2).tolist()
    assert "top" in load_cameras(_write(tmp_path / "nadir.json", record))


@pytest.mark.parametrize("case", range(len(IMPOSSIBLE)))
def test_impossible_camera_is_refused_in_one_line(tmp_path: Path, case: int) -> None:
    path = _impossible(tmp_path, case)
    with pytest.raises(CameraFileError, match=r"^" + str(path).replace(".", r"\.") + ": "
                       + IMPOSSIBLE[case][2]) as info:
        load_cameras(path)
    assert "\n" not in str(info.value)


def test_only_the_top_camera_must_look_down(tmp_path: Path) -> None:
    record = _record()
    level = look_rotation(0.5, math.radians(-5)).tolist()  # sees ground at its bottom
    record["cameras"]["ego"]["R"] = level
    assert "ego" in load_cameras(_write(tmp_path / "ego.json", record))
    record["cameras"]["top"]["R"] = level
    with pytest.raises(CameraFileError, match=r"cameras\.top\.R: a top camera must look down"):
        load_cameras(_write(tmp_path / "top.json", record))


def test_check_camera_sense_names_the_field() -> None:
    top = _top()
    check_camera_sense(top.K, top.R, top.c, *TOP_SIZE, top=True)
    K = top.K.copy()
    K[0, 2] = np.nan
    with pytest.raises(CameraSenseError, match=r"^K: cx = nan must be finite") as info:
        check_camera_sense(K, top.R, top.c, *TOP_SIZE)
    assert info.value.field == "K"
    with pytest.raises(CameraSenseError, match=r"^c: camera centre y = inf m") as info:
        check_camera_sense(top.K, top.R, [0.0, np.inf, 5.0], *TOP_SIZE)
    assert info.value.field == "c"
    with pytest.raises(ValueError, match="needs K"):
        check_camera_sense(top.K[:2], top.R, top.c, *TOP_SIZE)


def test_per_frame_camera_files_name_the_frame_file(tmp_path: Path) -> None:
    from xvmatch.formats.camera_frames import open_cameras

    folder = tmp_path / "cams"
    folder.mkdir()
    _write(folder / "000001.json", _record())
    _impossible(folder, 0, "000002.json")
    with pytest.raises(CameraFileError,
                       match=r"000002\.json: cameras\.top\.K: focal length fx = -800"):
        open_cameras(folder, [1, 2])


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_a_fifo_camera_file_is_refused_at_once(tmp_path: Path) -> None:
    fifo = tmp_path / "cams.json"
    os.mkfifo(fifo)
    with pytest.raises(CameraFileError, match=r"cams\.json: is a FIFO, not a regular file"):
        load_cameras(fifo)
    with pytest.raises(CameraFileError, match="is a FIFO"):
        load_ground_cameras(fifo)
    with pytest.raises(FileNotFoundError):
        load_cameras(tmp_path / "missing.json")


# --- multicam: static cameras, K R c or H ---------------------------------------------------

def _static(yaw: float = 0.4, pitch_deg: float = 35.0, roll: float = 0.0) -> Camera:
    R = look_rotation(yaw, math.radians(pitch_deg), roll)
    c = np.array([-10.0 * math.cos(yaw), -10.0 * math.sin(yaw), 6.0])
    return Camera(intrinsics_from_fov(*TOP_SIZE, 70.0), R, c, *TOP_SIZE)


def test_ground_cameras_are_checked_too(tmp_path: Path) -> None:
    record = {"version": 1, "cameras": {"cam1": _static().to_dict(),
                                        "cam2": _static(2.0).to_dict()}}
    assert list(load_ground_cameras(_write(tmp_path / "ok.json", record))) == ["cam1", "cam2"]
    bad = json.loads(json.dumps(record))
    bad["cameras"]["cam2"]["K"][0][0] = -800.0
    with pytest.raises(CameraFileError, match=r"neg\.json: cameras\.cam2\.K: focal length fx"):
        load_ground_cameras(_write(tmp_path / "neg.json", bad))
    # Upside down: the ground only at the top of the image, the bottom-centre pixel sees sky.
    bad = json.loads(json.dumps(record))
    bad["cameras"]["cam1"]["R"] = look_rotation(0.4, math.radians(10), math.pi).tolist()
    with pytest.raises(CameraFileError, match=r"flip\.json: cameras\.cam1: the bottom-centre "
                       r"pixel of the image sees no ground"):
        load_ground_cameras(_write(tmp_path / "flip.json", bad))
    # Rolled 90 degrees: the horizon crosses the bottom edge of the image.
    bad = json.loads(json.dumps(record))
    bad["cameras"]["cam1"]["R"] = look_rotation(0.4, math.radians(20), math.pi / 2).tolist()
    with pytest.raises(CameraFileError, match=r"roll\.json: cameras\.cam1: the bottom-\w+ "
                       r"corner .* sees no ground in front"):
        load_ground_cameras(_write(tmp_path / "roll.json", bad))


def test_h_camera_whose_bottom_edge_sees_the_sky_is_refused(tmp_path: Path) -> None:
    rolled = _static(pitch_deg=20.0, roll=math.pi / 2)
    H = ground_from_camera(rolled)  # the bottom-centre pixel sees ground, a corner does not
    with pytest.raises(ValueError, match=r"the bottom-\w+ corner .* sees no ground in front"):
        check_ground_view(H, *TOP_SIZE)
    record = {"version": 1, "cameras": {
        "cam1": {"H": GroundCamera.from_camera(_static()).H.tolist(), "width": TOP_SIZE[0],
                 "height": TOP_SIZE[1]},
        "cam2": {"H": H.tolist(), "width": TOP_SIZE[0], "height": TOP_SIZE[1]}}}
    with pytest.raises(CameraFileError, match=r"h\.json: cameras\.cam2\.H: the bottom-\w+ "
                       "corner"):
        load_ground_cameras(_write(tmp_path / "h.json", record))


# --- fit_homography: too few and (nearly) collinear points -----------------------------------

def _pairs(n: int = 6, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    cam = GroundCamera.from_camera(_static())
    uv = np.random.default_rng(seed).uniform([0, 400], [1280, 720], (n, 2))
    xy, ok = cam.to_ground(uv)
    assert ok.all()
    return uv, xy


def test_fit_homography_refuses_degenerate_points() -> None:
    uv, xy = _pairs()
    fit_homography(uv, xy, *TOP_SIZE)
    with pytest.raises(ValueError, match="at least 4 point pairs, got 3"):
        fit_homography(uv[:3], xy[:3], *TOP_SIZE)
    line = np.column_stack([np.linspace(0, 1000, 6), np.linspace(500, 700, 6)])
    with pytest.raises(ValueError, match=r"^image points: the points lie \(nearly\) in one"):
        fit_homography(line, xy, *TOP_SIZE)
    # Nearly in line: 0.1 % across.
    near = line + np.array([[0, 0.5], [0, -0.5], [0, 0.5], [0, -0.5], [0, 0.5], [0, -0.5]])
    with pytest.raises(ValueError, match=r"in one line .* below 0\.01"):
        fit_homography(near, xy, *TOP_SIZE)
    # Ground points in line, image points not.
    with pytest.raises(ValueError, match=r"^ground points: the points lie"):
        fit_homography(uv, np.column_stack([xy[:, 0], 2.0 * xy[:, 0] + 1.0]), *TOP_SIZE)
    # Three of four in line: the other point named.
    four = np.array([[100, 700], [600, 700], [1100, 700], [640, 450.0]])
    with pytest.raises(ValueError, match=r"the points other than point 3 lie"):
        fit_homography(four, xy[:4], *TOP_SIZE)
    # A repeated point in four is three distinct points.
    rep = uv[:4].copy()
    rep[1] = rep[0]
    with pytest.raises(ValueError, match="in one line"):
        fit_homography(rep, xy[:4], *TOP_SIZE)


def test_a_fit_whose_horizon_crosses_the_image_bottom_is_refused() -> None:
    """Ground points seen through a second perspective whose horizon runs through them (as from
    a mix-up of coordinate frames): the fit sees the sky along the image's bottom edge."""
    uv = np.array([[100, 700], [1100, 700], [900, 450], [300, 450.0], [640, 550]])
    xy, ok = GroundCamera.from_camera(_static()).to_ground(uv)
    assert ok.all()
    P = np.array([[1, 0, 0], [0, 1, 0], [0.3, 0, -0.3 * xy[:, 0].mean()]])
    h = np.column_stack([xy, np.ones(len(xy))]) @ P.T
    with pytest.raises(ValueError, match=r"sees no ground in front of the camera"):
        fit_homography(uv, h[:, :2] / h[:, 2:], *TOP_SIZE)


def test_fit_homography_tolerance_is_relative_to_the_spread() -> None:
    uv4 = np.array([[100, 700], [1100, 700], [900, 450], [300, 450.0]])
    square = np.array([[0, 0], [10, 0], [10, 10], [0, 10.0]])
    thin = square * np.array([1.0, COLLINEAR_TOL / 2])  # half the tolerance across
    for scale in (1e-2, 1.0, 1e2):
        fit_homography(uv4, square * scale, *TOP_SIZE)
        fit_homography(uv4, square * scale + 500.0, *TOP_SIZE)  # away from the origin
        with pytest.raises(ValueError, match=r"^ground points: the points lie"):
            fit_homography(uv4, thin * scale, *TOP_SIZE)
        with pytest.raises(ValueError, match=r"^ground points: the points lie"):
            fit_homography(uv4, thin * scale + 500.0, *TOP_SIZE)


# --- through the command line ----------------------------------------------------------------

def _fails(args: list[str], capsys, pattern: str) -> str:
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xvmatch: error:"), err
    assert pattern in err[0], err[0]
    return err[0]


def _boxes(path: Path) -> Path:
    rows = [f"{f},{k},{100 + 40 * k},{200 + f},30,80,1,-1,-1,-1" for f in (1, 2)
            for k in (1, 2, 3)]
    path.write_text("\n".join(rows) + "\n")
    return path


@pytest.mark.parametrize("case", [0, 3, 4, 6, 7])
def test_associate_refuses_an_impossible_camera(tmp_path: Path, capsys, case: int) -> None:
    top, hor = _boxes(tmp_path / "top.txt"), _boxes(tmp_path / "hor.txt")
    folder = tmp_path / "cams"
    folder.mkdir()
    _write(folder / "000001.json", _record())
    bad = _impossible(folder, case, "000002.json")
    line = _fails(["associate", "--top", str(top), "--hor", str(hor), "--model", "default",
                   "--cameras", str(folder), "--out", str(tmp_path / "a.txt"), "--quiet"],
                  capsys, f"{bad}: cameras.")
    assert re.search(IMPOSSIBLE[case][2], line), line
    assert not (tmp_path / "a.txt").exists()


def test_multicam_refuses_an_impossible_camera(tmp_path: Path, capsys) -> None:
    cams = {"cam1": _static().to_dict(), "cam2": _static(2.0).to_dict()}
    cams["cam2"]["c"][2] = -3.0
    path = _write(tmp_path / "cams.json", {"version": 1, "cameras": cams})
    boxes = [f"{n}={_boxes(tmp_path / (n + '.txt'))}" for n in ("cam1", "cam2")]
    _fails(["multicam", "--boxes", *boxes, "--cameras", str(path), "--out",
            str(tmp_path / "out"), "--quiet"], capsys,
           f"{path}: cameras.cam2.c: camera centre z = -3 m is below the ground")
    assert not (tmp_path / "out").exists()


def _fit(tmp_path: Path, uv: np.ndarray, xy: np.ndarray, capsys) -> tuple[list[str], Path]:
    csv = tmp_path / "points.csv"
    csv.write_text("camera,u,v,X,Y\n" + "".join(
        f"cam1,{u},{v},{x},{y}\n" for (u, v), (x, y) in zip(uv, xy, strict=True)))
    return ["multicam", "--fit-homography", str(csv), "--image-size",
            f"cam1={TOP_SIZE[0]}x{TOP_SIZE[1]}", "--out", str(tmp_path / "h.json"),
            "--quiet"], csv


def test_fit_homography_command_refuses_degenerate_points(tmp_path: Path, capsys) -> None:
    uv, xy = _pairs()
    args, csv = _fit(tmp_path, uv, xy, capsys)
    assert main(args) == 0 and (tmp_path / "h.json").is_file()
    (tmp_path / "h.json").unlink()
    args, csv = _fit(tmp_path, uv[:3], xy[:3], capsys)
    _fails(args, capsys, f"{csv}: camera cam1: a homography needs at least 4 point pairs, "
           "got 3")
    line = np.column_stack([np.linspace(0, 1000, 6), np.linspace(500, 700, 6)])
    args, csv = _fit(tmp_path, line, xy, capsys)
    _fails(args, capsys, f"{csv}: camera cam1: image points: the points lie (nearly) in one "
           "line")
    assert not (tmp_path / "h.json").exists()


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="needs FIFOs")
def test_fit_homography_command_refuses_a_fifo(tmp_path: Path, capsys) -> None:
    fifo = tmp_path / "points.csv"
    os.mkfifo(fifo)
    _fails(["multicam", "--fit-homography", str(fifo), "--image-size", "cam1=1280x720",
            "--out", str(tmp_path / "h.json")], capsys, "is a FIFO")


# --- properties -------------------------------------------------------------------------------

valid = st.fixed_dictionaries({
    "hfov": st.floats(20.0, 120.0),
    "yaw": st.floats(-math.pi, math.pi),
    "pitch_deg": st.floats(1.0, 90.0),  # looking down
    "roll": st.floats(-0.5, 0.5),
    "x": st.floats(-1e4, 1e4),
    "y": st.floats(-1e4, 1e4),
    "height": st.floats(0.1, 1e3),
    "size": st.sampled_from([(1920, 1080), (1280, 720), (640, 480), (100, 100)]),
})


def _camera_arrays(p: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, int]:
    K = intrinsics_from_fov(*p["size"], p["hfov"])
    R = look_rotation(p["yaw"], math.radians(p["pitch_deg"]), p["roll"])
    return K, R, np.array([p["x"], p["y"], p["height"]]), *p["size"]


@settings(max_examples=150, deadline=None)
@given(p=valid)
def test_valid_cameras_pass(p: dict) -> None:
    check_camera_sense(*_camera_arrays(p), top=True)


@settings(max_examples=150, deadline=None)
@given(p=valid, which=st.sampled_from(["fx", "fy", "both"]), top=st.booleans())
def test_a_flipped_focal_length_always_fails(p: dict, which: str, top: bool) -> None:
    K, R, c, w, h = _camera_arrays(p)
    for i, name in enumerate(("fx", "fy")):
        if which in (name, "both"):
            K[i, i] = -K[i, i]
    with pytest.raises(CameraSenseError, match=r"^K: focal length f[xy] = -[\d.e+]+ must be"):
        check_camera_sense(K, R, c, w, h, top=top)


@settings(max_examples=150, deadline=None)
@given(p=valid, depth=st.floats(0.0, MAX_CENTRE_COORD), top=st.booleans())
def test_a_centre_below_the_ground_always_fails(p: dict, depth: float, top: bool) -> None:
    K, R, c, w, h = _camera_arrays(p)
    c[2] = -depth
    with pytest.raises(CameraSenseError, match=r"^c: camera centre z = .* m is (below|on) the "
                       "ground"):
        check_camera_sense(K, R, c, w, h, top=top)
