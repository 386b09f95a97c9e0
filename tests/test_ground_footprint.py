"""A camera's field of view on the ground (``GroundCamera.ground_footprint``, drawn by
``multicam``'s ``birdseye.png``): it lies in front of the camera, also when the image holds the
horizon (issue 69, item 6: rays above the horizon were drawn behind the camera)."""

from __future__ import annotations

import numpy as np
import pytest

from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation
from xvmatch.geometry.ground_plane import GroundCamera


def _camera(yaw_deg: float, pitch_deg: float, hfov_deg: float = 90.0) -> Camera:
    """A 640x360 camera 4 m above (3, -2) looking along ``yaw_deg``, ``pitch_deg`` down."""
    return Camera(intrinsics_from_fov(640, 360, hfov_deg),
                  look_rotation(np.radians(yaw_deg), np.radians(pitch_deg)),
                  np.array([3.0, -2.0, 4.0]), 640, 360)


@pytest.mark.parametrize("yaw", [0.0, 70.0, 200.0])
@pytest.mark.parametrize("pitch", [3.0, 12.0, 25.0])
def test_a_view_holding_the_horizon_lies_in_front_and_within_range(yaw, pitch):
    cam = _camera(yaw, pitch)
    ground = GroundCamera.from_camera(cam)
    top = ground.H[2] @ np.array([320.0, 0.0, 1.0])
    assert top < 0, "the image's top edge should be above the horizon in this test"
    poly = ground.ground_footprint(max_range=50.0)
    forward = np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw))])
    ahead = (poly - cam.c[:2]) @ forward
    assert (ahead > 0).all(), f"{(ahead <= 0).sum()} footprint points behind the camera"
    anchor = ground.to_ground(np.array([320.0, 360.0]))[0]
    reach = np.linalg.norm(poly - anchor, axis=1)
    assert reach.max() == pytest.approx(50.0, rel=1e-6)  # the horizon's rays end at the range
    # The far edge is an arc of the range around the nearest ground: many points on it.
    assert (np.isclose(reach, 50.0, rtol=1e-6)).sum() >= 10


def test_the_footprint_of_a_view_below_the_horizon_is_its_projected_border():
    cam = _camera(30.0, 89.0, hfov_deg=60.0)  # nearly straight down: the whole image is ground
    ground = GroundCamera.from_camera(cam)
    poly = ground.ground_footprint(max_range=1e3)
    corners = ground.to_ground(np.array([[0.0, 0.0], [640.0, 0.0], [640.0, 360.0],
                                         [0.0, 360.0]]))[0]
    for corner in corners:  # each image corner is a vertex, unchanged by the clipping
        assert np.linalg.norm(poly - corner, axis=1).min() < 1e-9
    assert len(poly) == 128


def test_a_homography_camera_has_the_same_footprint_as_its_calibrated_one():
    cam = _camera(120.0, 8.0)
    calibrated = GroundCamera.from_camera(cam)
    plain = GroundCamera(-3.0 * calibrated.H, 640, 360)  # any scale and sign of H
    np.testing.assert_allclose(plain.ground_footprint(40.0), calibrated.ground_footprint(40.0),
                               atol=1e-9)
