"""Boxes of calibrated views mapped to the ideal setting (CVMHAT paper Sec. 5.1):
``ground_plane_boxes`` (top view to a virtual nadir image) and ``level_horizontal_boxes``
(horizontal view to a level 90-degree camera), checked on cameras built from their pose."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.view_rectification import (
    MID_HEIGHT,
    NADIR_SCALE,
    PERSON_SIZE,
    ground_plane_boxes,
    level_horizontal_boxes,
)

W, H = 640, 360
SIDE = PERSON_SIZE * NADIR_SCALE


def _camera(c, yaw: float, pitch: float = 0.0, roll: float = 0.0, hfov: float = 60.0,
            size: tuple[int, int] = (W, H)) -> Camera:
    return Camera(intrinsics_from_fov(size[0], size[1], hfov), look_rotation(yaw, pitch, roll),
                  np.asarray(c, dtype=float), size[0], size[1])


def _boxes_around(uv: np.ndarray, w: float = 20.0, h: float = 50.0) -> np.ndarray:
    """``(N, 4)`` boxes of size w x h centred on the pixels ``uv (N, 2)``."""
    return np.column_stack([uv[:, 0] - w / 2, uv[:, 1] - h / 2, np.full(len(uv), w),
                            np.full(len(uv), h)])


def _centres(boxes: np.ndarray) -> np.ndarray:
    return boxes[:, :2] + 0.5 * boxes[:, 2:]


def _at_mid_height(xy) -> np.ndarray:
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    return np.column_stack([xy, np.full(len(xy), MID_HEIGHT)])


# Points on the plane z = MID_HEIGHT, in front of the cameras below (and inside their images).
OBLIQUE = _camera([2.0, -1.0, 10.0], yaw=0.3, pitch=math.radians(40.0))
OBLIQUE_POINTS = np.array([[2.0 + 8.0 * math.cos(0.3) + dx, -1.0 + 8.0 * math.sin(0.3) + dy]
                           for dx, dy in [(0.0, 0.0), (1.5, -1.0), (-2.0, 2.5), (4.0, 1.0)]])
NADIR = _camera([0.0, 0.0, 30.0], yaw=1.0, pitch=math.pi / 2)
NADIR_POINTS = np.array([[0.0, 0.0], [3.0, -2.0], [-4.0, 1.5], [1.0, 5.0]])


# --------------------------------------------------------------------------------------------
# ground_plane_boxes


@pytest.mark.parametrize(
    ("camera", "xy"), [(OBLIQUE, OBLIQUE_POINTS), (NADIR, NADIR_POINTS)], ids=["oblique", "nadir"]
)
def test_ground_plane_boxes_centre_on_the_scaled_ground_position(camera, xy):
    uv, depth = camera.project(_at_mid_height(xy))
    assert (depth > 0).all() and camera.in_image(uv).all()  # the scene is really seen
    out = ground_plane_boxes(camera, _boxes_around(uv))
    assert out.shape == (len(xy), 4)
    expected = np.column_stack([NADIR_SCALE * xy[:, 0], -NADIR_SCALE * xy[:, 1]])
    np.testing.assert_allclose(_centres(out), expected, atol=1e-6)
    np.testing.assert_allclose(out[:, 2:], SIDE)


def test_ground_plane_boxes_ignores_the_box_size_and_honours_its_options():
    uv, _ = OBLIQUE.project(_at_mid_height(OBLIQUE_POINTS))
    small = ground_plane_boxes(OBLIQUE, _boxes_around(uv, 4.0, 10.0))
    large = ground_plane_boxes(OBLIQUE, _boxes_around(uv, 40.0, 120.0))
    np.testing.assert_allclose(small, large, atol=1e-9)
    # Feet on the ground (height 0), 10 pixels per metre, 2 m boxes.
    feet = np.column_stack([OBLIQUE_POINTS, np.zeros(len(OBLIQUE_POINTS))])
    uv, _ = OBLIQUE.project(feet)
    out = ground_plane_boxes(OBLIQUE, _boxes_around(uv), height=0.0, scale=10.0, size=2.0)
    np.testing.assert_allclose(_centres(out), 10.0 * OBLIQUE_POINTS * [1.0, -1.0], atol=1e-6)
    np.testing.assert_allclose(out[:, 2:], 20.0)


@settings(max_examples=25, deadline=None)
@given(
    yaws=st.tuples(st.floats(-math.pi, math.pi), st.floats(-math.pi, math.pi)),
    pitches=st.tuples(st.floats(30.0, 90.0), st.floats(30.0, 90.0)),
    polar=st.lists(st.tuples(st.floats(0.0, 4.0), st.floats(-math.pi, math.pi)),
                   min_size=2, max_size=5),
)
def test_ground_plane_boxes_do_not_depend_on_the_camera_orientation(yaws, pitches, polar):
    """Same world points, two cameras at one place turned differently: the same nadir image
    (so the distances between the output centres are the scaled world distances)."""
    centre = np.array([1.0, -2.0, 10.0])
    # Within 4 m of the camera's foot every point is in front of a camera pitched >= 30 deg.
    xy = centre[:2] + np.array([[r * math.cos(a), r * math.sin(a)] for r, a in polar])
    outs = []
    for yaw, pitch in zip(yaws, pitches, strict=True):
        camera = _camera(centre, yaw, math.radians(pitch))
        uv, depth = camera.project(_at_mid_height(xy))
        assert (depth > 0).all()
        outs.append(_centres(ground_plane_boxes(camera, _boxes_around(uv))))
    dist = [np.linalg.norm(o[:, None] - o[None], axis=-1) for o in outs]
    world = NADIR_SCALE * np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    np.testing.assert_allclose(dist[0], dist[1], atol=1e-6)
    np.testing.assert_allclose(dist[0], world, atol=1e-6)
    np.testing.assert_allclose(outs[0], outs[1], atol=1e-6)


@pytest.mark.parametrize("z", [0.5, MID_HEIGHT, -3.0])
def test_ground_plane_boxes_refuse_a_camera_not_above_the_plane(z):
    camera = _camera([0.0, 0.0, z], yaw=0.0, pitch=0.3)
    with pytest.raises(ValueError, match="must be above the plane"):
        ground_plane_boxes(camera, np.array([[10.0, 10.0, 5.0, 10.0]]))


def test_ground_plane_boxes_of_no_box():
    assert ground_plane_boxes(OBLIQUE, np.zeros((0, 4))).shape == (0, 4)


# --------------------------------------------------------------------------------------------
# level_horizontal_boxes


@pytest.mark.parametrize("yaw", [0.0, 0.8, -2.5])
def test_level_90_degree_camera_maps_boxes_to_themselves(yaw):
    camera = _camera([1.0, 2.0, 1.6], yaw, hfov=90.0)
    rng = np.random.default_rng(3)
    xy = rng.uniform([0, 0], [W - 40, H - 100], size=(6, 2))
    boxes = np.column_stack([xy, rng.uniform(5, 40, 6), rng.uniform(20, 100, 6)])
    np.testing.assert_allclose(level_horizontal_boxes(camera, boxes), boxes, atol=1e-6)


def _person_box(camera: Camera, feet: np.ndarray, height: float = 1.75) -> np.ndarray:
    """The box around a person's projected head and feet points (plus a margin in x)."""
    head = feet + np.array([0.0, 0.0, height])
    uv, depth = camera.project(np.array([head, feet]))
    assert (depth > 0).all()
    x0, x1 = uv[:, 0].min() - 8.0, uv[:, 0].max() + 8.0
    y0, y1 = uv[:, 1].min(), uv[:, 1].max()
    return np.array([x0, y0, x1 - x0, y1 - y0])


@pytest.mark.parametrize(
    ("pitch", "roll"), [(0.15, 0.0), (0.0, 0.1), (0.2, -0.1), (-0.1, 0.08)],
    ids=["pitch", "roll", "pitch-roll", "up-roll"],
)
def test_tilted_camera_boxes_match_the_level_cameras_view(pitch, roll):
    centre, yaw = np.array([1.0, 2.0, 1.6]), 0.7
    real = _camera(centre, yaw, pitch, roll, hfov=70.0)
    level = _camera(centre, yaw, hfov=90.0)
    forward = np.array([math.cos(yaw), math.sin(yaw), 0.0])
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    people = [centre * [1, 1, 0] + d * forward + o * right
              for d, o in [(5.0, 0.0), (6.0, 1.0), (8.0, -2.0), (12.0, 3.0)]]
    boxes = np.array([_person_box(real, p) for p in people])
    expected = np.array([_person_box(level, p) for p in people])
    out = level_horizontal_boxes(real, boxes)
    np.testing.assert_allclose(_centres(out)[:, 0], _centres(expected)[:, 0], atol=1.0)
    np.testing.assert_allclose(out[:, 3], expected[:, 3], rtol=0.03)


def test_level_horizontal_boxes_of_no_box():
    camera = _camera([0.0, 0.0, 1.6], 0.0, pitch=0.2)
    out = level_horizontal_boxes(camera, np.zeros((0, 4)))
    assert out.shape == (0, 4)
