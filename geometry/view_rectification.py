"""Boxes of calibrated views mapped to the ideal setting of the spatial-distribution method.

The CVMHAT method (Section 3.2) assumes an exactly vertical top view and a level horizontal
camera. Section 5.1 of the CVMHAT paper relaxes both when the cameras are known: the top-view
subjects, taken as points, are mapped to the ideal vertical view, and the horizontal view is
rotated to zero pitch (the box centre mapped, its height rescaled). Here, with calibrated
cameras (``x_cam = R (X - c)``, pixels ``K x_cam / z``, :class:`~xvmatch.geometry.camera.Camera`):

* :func:`ground_plane_boxes`: each top-view box centre is back-projected onto the horizontal
  plane at a person's mid-height and placed in a virtual nadir image, ``u = s X``,
  ``v = -s Y`` (``s`` pixels per metre, seen from above, not mirrored). This is the ideal
  vertical view of the paper for any pitch of the real top camera, oblique overview cameras on
  buildings included, and it is metric.
* :func:`level_horizontal_boxes`: each horizontal-view box is re-projected into a virtual level
  camera at the same place and heading (zero pitch and roll) with the 90-degree field of view
  the spatial vectors assume (Eq. 6), so ``x_hor`` (Eq. 9) is the true bearing; its height is
  the distance between its re-projected top and bottom centres.

Both return ``(x, y, w, h)`` boxes for :func:`~xvmatch.cues.spatial_features.frame_features`
(the virtual horizontal image keeps the real image's size).
"""

from __future__ import annotations

import numpy as np

from xvmatch.core.array_checks import as_boxes
from xvmatch.geometry.camera import Camera, look_rotation

__all__ = [
    "MID_HEIGHT",
    "NADIR_SCALE",
    "PERSON_SIZE",
    "ground_plane_boxes",
    "level_horizontal_boxes",
]

MID_HEIGHT: float = 0.85
"""Height (metres) of the horizontal plane a top-view box centre is mapped to: about half a
standing adult, where the centre of a person's box lies in an oblique or a vertical view."""
NADIR_SCALE: float = 100.0
"""Pixels per metre of the virtual nadir image (the features are scale-free; any value works)."""
PERSON_SIZE: float = 0.5
"""Side (metres) of a person's box in the virtual nadir image (shoulder width)."""

_MIN_DOWN = 1e-3  # rays at or above the horizon meet the plane far away, never behind


def ground_plane_boxes(
    camera: Camera,
    boxes: np.ndarray,
    height: float = MID_HEIGHT,
    scale: float = NADIR_SCALE,
    size: float = PERSON_SIZE,
) -> np.ndarray:
    """Top-view boxes mapped to a virtual nadir image of the ground (CVMHAT paper, Sec. 5.1).

    Args:
        camera: the calibrated top/overview camera (above the plane).
        boxes: ``(M, 4)`` x, y, w, h boxes in its image.
        height: the plane the box centres are back-projected onto (metres above the ground).
        scale: pixels per metre of the virtual image.
        size: side of each output box in metres.

    Returns:
        ``(M, 4)`` boxes of side ``size * scale`` centred on ``(s X, -s Y)``, where ``(X, Y)``
        is where the ray through the box centre meets the plane. A ray at or above the horizon
        is treated as meeting the plane very far away along its heading.
    """
    boxes = as_boxes(boxes, "boxes")
    if boxes.shape[0] == 0:
        return np.zeros((0, 4))
    above = camera.c[2] - float(height)
    if not above > 0:
        raise ValueError(f"the top camera (centre at z = {camera.c[2]:g} m) must be above the "
                         f"plane z = {height:g} m it maps box centres onto")
    centres = boxes[:, :2] + 0.5 * boxes[:, 2:]
    d = camera.ray_directions(centres)
    t = above / np.maximum(-d[:, 2], _MIN_DOWN)
    ground = camera.c[None, :2] + t[:, None] * d[:, :2]
    side = float(size) * float(scale)
    u, v = float(scale) * ground[:, 0], -float(scale) * ground[:, 1]
    return np.column_stack([u - side / 2, v - side / 2, np.full_like(u, side),
                            np.full_like(u, side)])


def _level_camera(camera: Camera) -> tuple[np.ndarray, float]:
    """Rotation of the level camera with the same heading, and the 90-degree focal length."""
    forward = camera.R[2]  # optical axis in world coordinates
    yaw = float(np.arctan2(forward[1], forward[0]))
    return look_rotation(yaw), 0.5 * camera.width


def level_horizontal_boxes(camera: Camera, boxes: np.ndarray) -> np.ndarray:
    """Horizontal-view boxes re-projected into a level 90-degree camera (CVMHAT paper, Sec. 5.1).

    The virtual camera shares the real one's centre, heading and image size, with zero pitch
    and roll and focal length ``W / 2`` (horizontal field of view 90 degrees, Eq. 6): the box
    centre is mapped through the rotation homography ``K' R_level R^T K^-1``, and the height is
    the distance between the mapped top and bottom centres (the paper's ``h cos(gamma)`` for a
    pure pitch, exact for roll too).

    Args:
        camera: the calibrated horizontal camera.
        boxes: ``(N, 4)`` x, y, w, h boxes in its image.

    Returns:
        ``(N, 4)`` boxes in the virtual level image (same size as the real one).
    """
    boxes = as_boxes(boxes, "boxes")
    if boxes.shape[0] == 0:
        return np.zeros((0, 4))
    rotation, focal = _level_camera(camera)
    cx, cy = 0.5 * camera.width, 0.5 * camera.height
    u = boxes[:, 0] + 0.5 * boxes[:, 2]
    points = np.stack(
        [
            np.column_stack([u, boxes[:, 1] + 0.5 * boxes[:, 3]]),  # centre
            np.column_stack([u, boxes[:, 1]]),  # top centre
            np.column_stack([u, boxes[:, 1] + boxes[:, 3]]),  # bottom centre
        ]
    )
    d = camera.ray_directions(points) @ rotation.T  # level-camera coordinates
    z = np.maximum(d[..., 2], 1e-6)
    uv = focal * d[..., :2] / z[..., None] + np.array([cx, cy])
    height = np.maximum(uv[2, :, 1] - uv[1, :, 1], 1e-6)
    width = boxes[:, 2] * focal / camera.K[0, 0]
    centre = uv[0]
    return np.column_stack([centre[:, 0] - width / 2, uv[1, :, 1], width, height])
