"""Tests of xvmatch.geometry.pose_from_points (PnP and relative pose, Section IV-A)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.pose_from_points import (
    PoseEstimationError,
    RelativePose,
    camera_from_pnp,
    camera_from_relative_pose,
    estimate_relative_pose,
    reprojection_rmse,
)

K_TOP = intrinsics_from_fov(1280, 720, 80.0)
K_EGO = np.array([[900.0, 0.0, 470.0], [0.0, 910.0, 360.0], [0.0, 0.0, 1.0]])  # differs from top


def _cameras() -> tuple[Camera, Camera]:
    top = Camera(K_TOP, look_rotation(math.pi / 2, math.radians(45)), [0.0, -6.0, 8.0], 1280, 720)
    R_ego = look_rotation(math.pi / 2 + 0.3, math.radians(5))
    ego = Camera(K_EGO, R_ego, [3.0, -1.0, 1.5], 960, 720)
    return top, ego


def _scene_points(n: int = 30) -> np.ndarray:
    """Points in a 8 x 8 x 2.5 m volume in front of both cameras (fixed seed)."""
    return np.random.default_rng(7).uniform([-4.0, 3.0, 0.0], [4.0, 11.0, 2.5], size=(n, 3))


def test_pnp_recovers_camera_from_exact_points() -> None:
    top, _ = _cameras()
    world = _scene_points(12)
    uv, depth = top.project(world)
    assert (depth > 0).all()
    cam = camera_from_pnp(world, uv, K_TOP, 1280, 720)
    np.testing.assert_allclose(cam.R, top.R, atol=1e-8)
    np.testing.assert_allclose(cam.c, top.c, atol=1e-6)
    assert (cam.width, cam.height) == (1280, 720)
    assert reprojection_rmse(cam, world, uv) < 1e-6


def test_pnp_coplanar_ground_points() -> None:
    top, _ = _cameras()
    grid = np.array([[x, y, 0.0] for x in (-3.0, 0.0, 3.0) for y in (3.0, 6.0, 9.0)])
    uv, _ = top.project(grid)
    cam = camera_from_pnp(grid, uv, K_TOP, 1280, 720)
    np.testing.assert_allclose(cam.R, top.R, atol=1e-6)
    np.testing.assert_allclose(cam.c, top.c, atol=1e-5)


def test_pnp_bad_inputs() -> None:
    top, _ = _cameras()
    world = _scene_points(6)
    uv, _ = top.project(world)
    with pytest.raises(PoseEstimationError, match="at least 4"):
        camera_from_pnp(world[:3], uv[:3], K_TOP, 1280, 720)
    with pytest.raises(PoseEstimationError, match="pair up"):
        camera_from_pnp(world, uv[:5], K_TOP, 1280, 720)
    line = np.array([[t, 2 * t + 3, 0.5] for t in range(6)], dtype=float)
    with pytest.raises(PoseEstimationError, match="collinear"):
        camera_from_pnp(line, top.project(line)[0], K_TOP, 1280, 720)
    with pytest.raises(PoseEstimationError, match="singular"):
        camera_from_pnp(world, uv, np.zeros((3, 3)), 1280, 720)
    with pytest.raises(PoseEstimationError, match="NaN"):
        camera_from_pnp(world, np.where(np.eye(6, 2) > 0, np.nan, uv), K_TOP, 1280, 720)
    with pytest.raises(PoseEstimationError, match=r"\(N, 3\)"):
        camera_from_pnp(world[:, :2], uv, K_TOP, 1280, 720)
    assert issubclass(PoseEstimationError, ValueError)


def test_relative_pose_recovers_rotation_and_translation_direction() -> None:
    top, ego = _cameras()
    world = _scene_points(30)
    uv_top, d_top = top.project(world)
    uv_ego, d_ego = ego.project(world)
    assert (d_top > 0).all() and (d_ego > 0).all()
    pose = estimate_relative_pose(uv_top, uv_ego, K_TOP, K_EGO)
    # x_ego = R_e (X - c_e) = R_e R_t^T x_top + R_e (c_t - c_e): R = R_e R_t^T, t ~ R_e (c_t - c_e).
    R_true = ego.R @ top.R.T
    t_true = ego.R @ (top.c - ego.c)
    np.testing.assert_allclose(pose.R, R_true, atol=1e-6)
    np.testing.assert_allclose(pose.t, t_true / np.linalg.norm(t_true), atol=1e-6)
    assert pose.inliers.all()
    # Chained with the static camera and scaled by the true baseline: the ego camera itself.
    baseline = float(np.linalg.norm(top.c - ego.c))
    cam = camera_from_relative_pose(top, pose, K_EGO, 960, 720, baseline=baseline)
    np.testing.assert_allclose(cam.R, ego.R, atol=1e-6)
    np.testing.assert_allclose(cam.c, ego.c, atol=1e-5)
    # Default baseline: up to scale, unit distance between the centres, same direction.
    unit = camera_from_relative_pose(top, pose, K_EGO, 960, 720)
    assert np.linalg.norm(unit.c - top.c) == pytest.approx(1.0)
    np.testing.assert_allclose(unit.c - top.c, (ego.c - top.c) / baseline, atol=1e-6)


def test_relative_pose_with_noise_and_outliers() -> None:
    top, ego = _cameras()
    rng = np.random.default_rng(11)
    world = _scene_points(40)
    uv_top = top.project(world)[0] + rng.normal(0.0, 0.3, (40, 2))
    uv_ego = ego.project(world)[0] + rng.normal(0.0, 0.3, (40, 2))
    uv_ego[:5] = rng.uniform([0, 0], [960, 720], (5, 2))  # 5 wrong matches
    pose = estimate_relative_pose(uv_top, uv_ego, K_TOP, K_EGO, threshold_px=1.5)
    R_err = pose.R @ (ego.R @ top.R.T).T
    angle = math.degrees(math.acos(np.clip((np.trace(R_err) - 1) / 2, -1, 1)))
    assert angle < 0.5
    t_true = ego.R @ (top.c - ego.c)
    assert pose.t @ t_true / np.linalg.norm(t_true) > math.cos(math.radians(3))
    assert pose.inliers[5:].mean() > 0.9 and pose.inliers[:5].sum() <= 1


def test_relative_pose_bad_inputs() -> None:
    top, ego = _cameras()
    world = _scene_points(30)
    uv_top, _ = top.project(world)
    uv_ego, _ = ego.project(world)
    with pytest.raises(PoseEstimationError, match="at least 5"):
        estimate_relative_pose(uv_top[:4], uv_ego[:4], K_TOP, K_EGO)
    with pytest.raises(PoseEstimationError, match="pair up"):
        estimate_relative_pose(uv_top, uv_ego[:10], K_TOP, K_EGO)
    with pytest.raises(PoseEstimationError, match="collinear"):
        line = np.column_stack([np.arange(8.0), np.arange(8.0)])
        estimate_relative_pose(line, line + 1.0, K_TOP, K_EGO)
    # Pure rotation (same centre): the translation direction is unobservable.
    turned = Camera(K_EGO, look_rotation(math.pi / 2 + 0.2, math.radians(30)), top.c, 960, 720)
    uv_turned, depth = turned.project(world)
    assert (depth > 0).all()
    with pytest.raises(PoseEstimationError, match="parallax"):
        estimate_relative_pose(uv_top, uv_turned, K_TOP, K_EGO)
    pose = RelativePose(R=np.eye(3), t=np.array([1.0, 0.0, 0.0]), inliers=np.ones(3, bool))
    with pytest.raises(PoseEstimationError, match="baseline"):
        camera_from_relative_pose(top, pose, K_EGO, 960, 720, baseline=0.0)


def test_reprojection_rmse_behind_camera_is_inf() -> None:
    top, _ = _cameras()
    behind = top.c - 2.0 * top.R[2]
    assert reprojection_rmse(top, behind[None], np.zeros((1, 2))) == math.inf
