"""Tests of xvmatch.inference.views.multicam_localisation (the VRL paper's principal axes, view
visibility and two-best-view choice)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam_localisation import (
    LocalisationOptions,
    axis_traces,
    localise,
    view_visibility,
)


def _cam(azimuth: float, roll: float = 0.0, dist: float = 10.0, height: float = 6.0):
    c = np.array([dist * math.cos(azimuth), dist * math.sin(azimuth), height])
    R = look_rotation(azimuth + math.pi, math.atan2(height, dist), roll)
    return GroundCamera.from_camera(Camera(intrinsics_from_fov(1280, 720, 70.0), R, c, 1280,
                                           720))


def _box(cam: GroundCamera, xy, height: float = 1.7, width: float = 0.5) -> np.ndarray:
    """The bounding box of an upright 3D rectangle facing the camera."""
    c = cam.camera
    to = np.asarray(xy, float) - c.c[:2]
    side = np.array([-to[1], to[0]]) / np.linalg.norm(to) * width / 2
    pts = np.array([[*(xy + s * side), z] for s in (-1, 1) for z in (0.0, height)])
    uv, _ = c.project(pts)
    lo, hi = uv.min(0), uv.max(0)
    return np.array([lo[0], lo[1], hi[0] - lo[0], hi[1] - lo[1]])


def test_vertical_axes_pass_through_the_person_even_when_the_camera_rolls():
    cam = _cam(0.4, roll=math.radians(12))
    xy = np.array([1.0, -0.5])
    o, d = axis_traces(cam, _box(cam, xy)[None], "vertical")
    off = (xy - o[0]) - ((xy - o[0]) @ d[0]) * d[0]
    assert np.linalg.norm(off) < 0.02
    o, d = axis_traces(cam, _box(cam, xy)[None], "column")
    off = (xy - o[0]) - ((xy - o[0]) @ d[0]) * d[0]
    assert np.linalg.norm(off) > 0.05  # the image column leans with the roll


def test_two_views_recover_the_position():
    cams = {"a": _cam(0.0), "b": _cam(1.6)}
    xy = np.array([0.7, 0.3])
    boxes = {n: {1: FrameBoxes(1, np.array([5]), _box(c, xy)[None])} for n, c in cams.items()}
    fallback = {5: (np.array([1]), np.array([[9.0, 9.0]]))}
    for method in ("two_best", "all"):
        est = localise(cams, boxes, fallback, LocalisationOptions(method=method))
        np.testing.assert_allclose(est[5][1][0], xy, atol=0.02)
    # One calibrated view only: the fallback is kept.
    one = localise({"a": cams["a"]}, {"a": boxes["a"]}, fallback)
    np.testing.assert_allclose(one[5][1][0], [9.0, 9.0])


def test_visibility_distance_and_occlusion():
    opts = LocalisationOptions()
    x = np.array([[0.0, 0.0], [0.0, 0.0]])
    centre = np.array([[10.0, 0.0], [0.0, 5.0]])
    fwd = -centre / np.linalg.norm(centre, axis=1, keepdims=True)
    half = np.full(2, math.radians(35))
    none = np.full((2, 1, 2), np.nan)
    v = view_visibility(x, centre, fwd, half, none, np.full(2, 5.0), opts)
    assert v[1] > v[0]  # the nearer camera sees the person better
    occluder = np.array([[[5.0, 0.05]], [[5.0, 0.05]]])  # in front of the first camera only
    w = view_visibility(x, centre, fwd, half, occluder, np.full(2, 5.0), opts)
    assert w[0] < v[0] - 0.3 and w[1] == pytest.approx(v[1])


def test_two_best_views_avoid_the_occluded_one():
    """Three cameras; the third sees the person half hidden (its box is the visible half, so
    its axis is off). The two most visible views give the position; fusing all is pulled."""
    cams = {"a": _cam(0.0), "b": _cam(2.0), "c": _cam(4.2)}
    xy = np.array([0.0, 0.0])
    other = 0.8 * cams["c"].camera.c[:2] / np.linalg.norm(cams["c"].camera.c[:2]) + \
        np.array([0.1, -0.1])
    boxes = {}
    for n, cam in cams.items():
        b = _box(cam, xy)
        if n == "c":
            b = np.array([b[0], b[1], 0.5 * b[2], b[3]])  # the right half is hidden
        boxes[n] = {1: FrameBoxes(1, np.array([1, 2]), np.stack([b, _box(cam, other)]))}
    fallback = {1: (np.array([1]), np.array([[0.3, 0.3]])),
                2: (np.array([1]), other[None])}
    best = localise(cams, boxes, fallback, LocalisationOptions("two_best"))[1][1][0]
    every = localise(cams, boxes, fallback, LocalisationOptions("all"))[1][1][0]
    assert np.linalg.norm(best - xy) < 0.02 < np.linalg.norm(every - xy)
