"""Tests of xvmatch.geometry.ground_plane (pixel <-> ground homographies, horizon refusal) and
of H cameras in the camera file."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.formats.camera_io import (
    CameraFileError,
    load_cameras,
    load_ground_cameras,
    save_cameras,
)
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ground_plane import (
    GroundCamera,
    HorizonError,
    fit_homography,
    foot_points,
    ground_from_camera,
    image_to_ground,
    normalise_homography,
)


def _camera(yaw=0.4, pitch_deg=35.0, height=6.0, hfov=70.0, roll=0.0) -> Camera:
    R = look_rotation(yaw, math.radians(pitch_deg), roll)
    c = np.array([-10.0 * math.cos(yaw), -10.0 * math.sin(yaw), height])
    return Camera(intrinsics_from_fov(1280, 720, hfov), R, c, 1280, 720)


cams = st.builds(
    _camera,
    yaw=st.floats(-math.pi, math.pi),
    pitch_deg=st.floats(15.0, 80.0),
    height=st.floats(2.5, 30.0),
    hfov=st.floats(30.0, 110.0),
    roll=st.floats(-0.2, 0.2),
)


@settings(max_examples=60, deadline=None)
@given(cam=cams, u=st.floats(0, 1280), v=st.floats(0, 720))
def test_pixel_ground_pixel_round_trip(cam, u, v):
    g = GroundCamera.from_camera(cam)
    xy, ok = g.to_ground(np.array([[u, v]]))
    if not ok[0]:  # above the horizon: the camera sees no ground there
        d = cam.ray_directions(np.array([u, v]))
        if d[2] < 0:  # the ray meets the ground, but numerically at the horizon
            hit = cam.c - cam.c[2] / d[2] * d
            assert np.linalg.norm(hit[:2]) > 1e4 * 0.999
        return
    back = g.to_image(xy)
    np.testing.assert_allclose(back[0], [u, v], atol=1e-6 * max(1.0, np.abs(xy).max()))
    # The ground point projects with the full camera to the same pixel, in front of it.
    uv, depth = cam.project(np.array([[xy[0, 0], xy[0, 1], 0.0]]))
    assert depth[0] > 0
    np.testing.assert_allclose(uv[0], [u, v], atol=1e-5 * max(1.0, np.abs(xy).max()))


@settings(max_examples=60, deadline=None)
@given(cam=cams, x=st.floats(-8, 8), y=st.floats(-8, 8))
def test_ground_pixel_ground_round_trip(cam, x, y):
    g = GroundCamera.from_camera(cam)
    uv, depth = cam.project(np.array([[x, y, 0.0]]))
    if depth[0] <= 0:
        assert np.isnan(g.to_image(np.array([[x, y]]))).all()
        return
    np.testing.assert_allclose(g.to_image(np.array([[x, y]]))[0], uv[0], rtol=1e-9, atol=1e-6)
    xy, ok = g.to_ground(uv)
    assert ok[0]
    np.testing.assert_allclose(xy[0], [x, y], atol=1e-7)


@settings(max_examples=30, deadline=None)
@given(cam=cams, seed=st.integers(0, 2**31))
def test_fit_homography_recovers_camera(cam, seed):
    rng = np.random.default_rng(seed)
    g = GroundCamera.from_camera(cam)
    uv = rng.uniform([0, 360], [1280, 720], size=(12, 2))
    xy, ok = g.to_ground(uv)
    uv, xy = uv[ok], xy[ok]
    if len(uv) < 4:
        return
    H = fit_homography(uv, xy, 1280, 720)
    np.testing.assert_allclose(H, g.H, atol=1e-6)


def test_horizon_and_behind_are_refused():
    cam = _camera(pitch_deg=20.0)
    H = ground_from_camera(cam)
    with pytest.raises(HorizonError, match=r"point 0 .* behind the camera"):
        image_to_ground(H, np.array([[640.0, 0.0]]))  # the sky
    xy, ok = image_to_ground(H, np.array([[640.0, 0.0], [640.0, 719.0]]), strict=False)
    assert ok.tolist() == [False, True] and np.isnan(xy[0]).all()
    # A pixel just below the horizon lands kilometres away: refused as at the horizon.
    horizon_v = (cam.K @ cam.R @ np.array([math.cos(0.4), math.sin(0.4), 0.0]))
    v = horizon_v[1] / horizon_v[2]
    with pytest.raises(HorizonError, match="at the horizon"):
        image_to_ground(H, np.array([[horizon_v[0] / horizon_v[2], v + 1e-4]]), max_range=100.0)


def test_sign_and_bad_homographies():
    cam = _camera()
    H = ground_from_camera(cam)
    np.testing.assert_allclose(normalise_homography(-3.0 * H, 1280, 720), H)
    with pytest.raises(ValueError, match="singular"):
        GroundCamera(np.array([[1, 2, 3], [2, 4, 6], [0, 0, 1.0]]), 100, 100)
    with pytest.raises(ValueError, match="NaN or inf"):
        GroundCamera(np.array([[1, 0, 0], [0, 1, 0], [0, 0, np.inf]]), 100, 100)
    with pytest.raises(ValueError, match="at least 4"):
        fit_homography(np.zeros((3, 2)), np.zeros((3, 2)), 100, 100)
    with pytest.raises(ValueError, match=r"image points: the points lie \(nearly\) in one line"):
        fit_homography(np.array([[0, 0], [1, 1], [2, 2], [3, 3.0]]),
                       np.array([[0, 0], [1, 1], [2, 2], [3, 3.0]]), 100, 100)


def test_foot_points():
    np.testing.assert_allclose(foot_points(np.array([[10, 20, 4, 30.0]])), [[12, 50]])


def test_camera_file_with_h_cameras(tmp_path):
    cam = _camera()
    H = ground_from_camera(cam)
    path = tmp_path / "cams.json"
    save_cameras(path, {"a": cam, "b": GroundCamera(H, 1280, 720)})
    loaded = load_ground_cameras(path)
    assert list(loaded) == ["a", "b"] and loaded["b"].camera is None
    np.testing.assert_allclose(loaded["a"].H, loaded["b"].H, atol=1e-12)
    with pytest.raises(CameraFileError, match=r"cameras\.b: a homography camera"):
        load_cameras(path)  # the two-view commands need K, R, c
    data = json.loads(path.read_text())
    data["cameras"]["b"]["H"] = [[1, 2, 3], [2, 4, 6], [0, 0, 1]]
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match=r"cams\.json: cameras\.b\.H: .*singular"):
        load_ground_cameras(path)
    data["cameras"]["b"] = {"H": H.tolist(), "width": 1280, "height": 720, "K": 1}
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match=r"cameras\.b: unknown field\(s\) K"):
        load_ground_cameras(path)
    data["cameras"]["b"] = {"H": [[1, 0, 0], [0, 1, 0], [0, 0, "x"]], "width": 1, "height": 1}
    path.write_text(json.dumps(data))
    with pytest.raises(CameraFileError, match=r"cameras\.b\.H: expected 3x3 numbers"):
        load_ground_cameras(path)
