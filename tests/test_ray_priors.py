"""Tests of xvmatch.geometry.ray_priors (Eqs. 4-7 of the geometric-priors paper)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ray_priors import (
    DEFAULT_BETA,
    METRIC_MARGIN,
    Rays,
    box_rays,
    box_top_centres,
    cheirality_cost,
    cheirality_mask,
    pixel_rays,
    ray_distances,
    triangulate_midpoints,
)

# f = 100 px, principal point (50, 50): pixel (50 + 100 a, 50 + 100 b) has camera ray (a, b, 1).
K_SIMPLE = np.array([[100.0, 0.0, 50.0], [0.0, 100.0, 50.0], [0.0, 0.0, 1.0]])


def _camera(R: np.ndarray, c: tuple[float, float, float]) -> Camera:
    return Camera(K=K_SIMPLE, R=R, c=np.array(c, dtype=float), width=100, height=100)


def _rays(camera: Camera, directions: list[list[float]]) -> Rays:
    """Rays with hand-chosen unit world directions (pixels unused by the tested functions)."""
    d = np.array(directions, dtype=float)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return Rays(camera=camera, pixels=np.zeros((len(d), 2)), directions=d)


def _scene() -> tuple[Camera, Camera, np.ndarray]:
    """Overview camera 10 m up looking down 50 deg, egocentric camera at eye height, 4 heads."""
    K = intrinsics_from_fov(640, 480, 70.0)
    top = Camera(K, look_rotation(math.pi / 2, math.radians(50)), [0.0, -8.0, 10.0], 640, 480)
    ego = Camera(K, look_rotation(math.pi / 2 + 0.4, 0.0), [2.5, -2.0, 1.5], 640, 480)
    heads = np.array([[0.0, 3.0, 1.75], [2.0, 4.0, 1.80], [-2.0, 4.5, 1.65], [1.0, 8.0, 1.70]])
    return top, ego, heads


def _head_boxes(camera: Camera, heads: np.ndarray) -> np.ndarray:
    """Boxes whose top centre is the projected head: (u - w/2, v, w, h)."""
    uv, depth = camera.project(heads)
    assert (depth > 0).all()
    n = len(uv)
    return np.column_stack([uv[:, 0] - 20.0, uv[:, 1], np.full(n, 40.0), np.full(n, 90.0)])


def test_box_top_centres_hand_computed() -> None:
    boxes = np.array([[10.0, 20.0, 30.0, 40.0], [0.0, 0.0, 0.0, 0.0]])
    np.testing.assert_allclose(box_top_centres(boxes), [[25.0, 20.0], [0.0, 0.0]])


def test_pixel_rays_hand_computed() -> None:
    # R = I: camera axes = world axes. Pixel (50, 50) -> (0, 0, 1); (150, 50) -> (1, 0, 1)/sqrt 2.
    rays = pixel_rays(_camera(np.eye(3), (0, 0, 0)), np.array([[50.0, 50.0], [150.0, 50.0]]))
    r = 1 / math.sqrt(2)
    np.testing.assert_allclose(rays.directions, [[0, 0, 1], [r, 0, r]])
    assert len(rays) == 2


def test_ray_distance_hand_computed() -> None:
    """Eq. 6: |c1c2 . (n_i x n_j)| / ||n_i x n_j||."""
    cam_a = _camera(np.eye(3), (0, 0, 0))
    cam_b = _camera(np.eye(3), (3, 0, 0))
    # Ray a: the z axis (pixel (50, 50)). Ray b from (3, 0, 0) along (0, 1, 1)/sqrt 2 (pixel
    # (50, 150)): n_a x n_b = (-1, 0, 0)/sqrt 2, baseline (3, 0, 0) -> (3/sqrt 2)/(1/sqrt 2) = 3.
    d = ray_distances(pixel_rays(cam_a, [[50.0, 50.0]]), pixel_rays(cam_b, [[50.0, 150.0]]))
    assert d.shape == (1, 1) and d[0, 0] == pytest.approx(3.0)
    # Hand-chosen directions: ray a along x from the origin, rays b from (0, 0, 2).
    cam_b2 = _camera(np.eye(3), (0, 0, 2))
    rays_a = _rays(cam_a, [[1, 0, 0]])
    rays_b = _rays(cam_b2, [[0, 1, 0], [1, 0, 0], [1, 0, -1]])
    d = ray_distances(rays_a, rays_b)
    # (0,1,0): skew, cross (0,0,1), |(0,0,2).(0,0,1)| / 1 = 2.
    # (1,0,0): parallel, ||(0,0,2) x (1,0,0)|| = ||(0,2,0)|| = 2.
    # (1,0,-1): meets the x axis at (2,0,0): 0.
    np.testing.assert_allclose(d, [[2.0, 2.0, 0.0]], atol=1e-12)


def test_triangulate_midpoint_hand_computed() -> None:
    # Line a: z axis. Line b: (2, 0, 5) + t (0, 1, 0). Closest points (0,0,5), (2,0,5) -> (1,0,5).
    cam_a = _camera(np.eye(3), (0, 0, 0))
    cam_b = _camera(np.eye(3), (2, 0, 5))
    points, parallel = triangulate_midpoints(_rays(cam_a, [[0, 0, 1]]), _rays(cam_b, [[0, 1, 0]]))
    np.testing.assert_allclose(points[0, 0], [1.0, 0.0, 5.0], atol=1e-12)
    assert not parallel[0, 0]


def test_true_pairs_intersect_wrong_pairs_do_not() -> None:
    top, ego, heads = _scene()
    rays_top = box_rays(top, _head_boxes(top, heads))
    rays_ego = box_rays(ego, _head_boxes(ego, heads))
    d = ray_distances(rays_top, rays_ego)
    assert d.shape == (4, 4)
    np.testing.assert_allclose(np.diag(d), 0.0, atol=1e-9)
    off = d[~np.eye(4, dtype=bool)]
    assert off.min() > 0.4, off  # closest wrong pair: 0.435 m
    points, parallel = triangulate_midpoints(rays_top, rays_ego)
    np.testing.assert_allclose(points[np.arange(4), np.arange(4)], heads, atol=1e-9)
    assert not parallel.any()
    holds = cheirality_mask(rays_top, rays_ego, margin=METRIC_MARGIN)
    assert np.diag(holds).all()


def test_point_behind_camera_fails_cheirality_despite_zero_distance() -> None:
    """A head behind the egocentric camera lies on the line through the mirrored pixel: the ray
    distance is 0, only cheirality (Eq. 7) tells the pair apart."""
    top, ego, _ = _scene()
    forward = ego.R[2]
    behind = ego.c - 3.0 * forward + np.array([0.0, 0.0, 0.2])
    mirrored = 2 * ego.c - behind  # in front, on the same line through the centre
    uv_ego, depth = ego.project(mirrored[None])
    assert depth[0] > 0 and ego.depth(behind[None])[0] < 0
    uv_top, _ = top.project(behind[None])
    rays_top, rays_ego = pixel_rays(top, uv_top), pixel_rays(ego, uv_ego)
    assert ray_distances(rays_top, rays_ego)[0, 0] == pytest.approx(0.0, abs=1e-9)
    assert not cheirality_mask(rays_top, rays_ego)[0, 0]
    assert cheirality_cost(rays_top, rays_ego)[0, 0] == DEFAULT_BETA


def test_metric_margin_rejects_the_camera_wearer() -> None:
    """A point 0.3 m in front of the egocentric camera passes z > 0 but not z > 0.5 (Eq. 7)."""
    top, ego, _ = _scene()
    close = ego.c + 0.3 * ego.R[2]
    rays_top = pixel_rays(top, top.project(close[None])[0])
    rays_ego = pixel_rays(ego, ego.project(close[None])[0])
    assert cheirality_mask(rays_top, rays_ego, margin=0.0)[0, 0]
    assert not cheirality_mask(rays_top, rays_ego, margin=METRIC_MARGIN)[0, 0]
    cost = cheirality_cost(rays_top, rays_ego, margin=METRIC_MARGIN, beta=50.0)
    assert cost[0, 0] == 50.0


def test_parallel_rays() -> None:
    cam_a = _camera(np.eye(3), (0, 0, 0))
    # Same orientation, 1 m apart along x: principal rays are parallel, 1 m apart, meet at
    # infinity in front of both.
    cam_b = _camera(np.eye(3), (1, 0, 0))
    rays_a, rays_b = pixel_rays(cam_a, [[50.0, 50.0]]), pixel_rays(cam_b, [[50.0, 50.0]])
    assert ray_distances(rays_a, rays_b)[0, 0] == pytest.approx(1.0)
    points, parallel = triangulate_midpoints(rays_a, rays_b)
    assert parallel[0, 0] and np.isfinite(points).all()
    assert cheirality_mask(rays_a, rays_b)[0, 0]
    # Facing each other on the z axis (b at z = 4 looking back): same line, distance 0; the
    # person between them is in front of both.
    flip = np.diag([-1.0, 1.0, -1.0])  # rotation by pi about y: camera z -> world -z
    facing = _camera(flip, (0, 0, 4))
    rays_f = pixel_rays(facing, [[50.0, 50.0]])
    assert ray_distances(rays_a, rays_f)[0, 0] == pytest.approx(0.0)
    assert cheirality_mask(rays_a, rays_f)[0, 0]
    # Back to back: nothing can be in front of both.
    away = _camera(flip, (0, 0, -4))
    assert not cheirality_mask(rays_a, pixel_rays(away, [[50.0, 50.0]]))[0, 0]


def test_coincident_centres_give_zero_distance_not_nan() -> None:
    cam_a = _camera(np.eye(3), (1, 2, 3))
    cam_b = _camera(look_rotation(0.3, 0.2), (1, 2, 3))
    pix = np.array([[10.0, 20.0], [60.0, 70.0]])
    d = ray_distances(pixel_rays(cam_a, pix), pixel_rays(cam_b, pix))
    np.testing.assert_allclose(d, 0.0, atol=1e-12)


def test_empty_sides() -> None:
    top, ego, heads = _scene()
    empty = box_rays(top, np.zeros((0, 4)))
    full = box_rays(ego, _head_boxes(ego, heads))
    assert ray_distances(empty, full).shape == (0, 4)
    assert cheirality_cost(full, empty).shape == (4, 0)


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match="singular"):
        Camera(K=np.zeros((3, 3)), R=np.eye(3), c=np.zeros(3), width=10, height=10)
    cam = _camera(np.eye(3), (0, 0, 0))
    with pytest.raises(ValueError, match="NaN"):
        box_rays(cam, np.array([[0.0, np.nan, 1.0, 1.0]]))
    with pytest.raises(ValueError, match=r"\(N, 4\)"):
        box_rays(cam, np.ones((2, 3)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 2\)"):
        pixel_rays(cam, np.ones(3))
    with pytest.raises(TypeError, match="Camera"):
        pixel_rays("top", np.ones((1, 2)))  # type: ignore[arg-type]
    rays = pixel_rays(cam, np.ones((1, 2)))
    with pytest.raises(ValueError, match="beta"):
        cheirality_cost(rays, rays, beta=0.5)
    with pytest.raises(ValueError, match="margin"):
        cheirality_mask(rays, rays, margin=-1.0)
    with pytest.raises(TypeError, match="Rays"):
        ray_distances(rays, np.ones((1, 3)))  # type: ignore[arg-type]


_angle = st.floats(-math.pi, math.pi, allow_nan=False)
_coord = st.floats(-20, 20, allow_nan=False)


@pytest.mark.slow
@settings(max_examples=80, deadline=None)
@given(
    yaw=st.tuples(_angle, _angle),
    pitch=st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)),
    centres=st.tuples(st.tuples(_coord, _coord, _coord), st.tuples(_coord, _coord, _coord)),
    boxes_a=arrays(float, st.tuples(st.integers(0, 5), st.just(4)), elements=st.floats(0, 1e4)),
    boxes_b=arrays(float, st.tuples(st.integers(0, 5), st.just(4)), elements=st.floats(0, 1e4)),
)
def test_never_nan(
    yaw: tuple[float, float],
    pitch: tuple[float, float],
    centres: tuple[tuple[float, ...], tuple[float, ...]],
    boxes_a: np.ndarray,
    boxes_b: np.ndarray,
) -> None:
    K = intrinsics_from_fov(640, 480, 60.0)
    cam_a = Camera(K, look_rotation(yaw[0], pitch[0]), np.array(centres[0]), 640, 480)
    cam_b = Camera(K, look_rotation(yaw[1], pitch[1]), np.array(centres[1]), 640, 480)
    rays_a, rays_b = box_rays(cam_a, boxes_a), box_rays(cam_b, boxes_b)
    d = ray_distances(rays_a, rays_b)
    assert d.shape == (len(boxes_a), len(boxes_b))
    assert np.isfinite(d).all() and (d >= 0).all()
    points, _ = triangulate_midpoints(rays_a, rays_b)
    assert np.isfinite(points).all()
    cost = cheirality_cost(rays_a, rays_b, margin=METRIC_MARGIN)
    assert set(np.unique(cost)) <= {0.0, DEFAULT_BETA}
