"""A camera calibrated from people, drawn over one of its frames: the horizon, a ground grid and,
on each box, the height a person of the mean height would have there (``xvmatch calibrate
--draw``). Where the calibration is right, the grid lies flat on the floor and the drawn heights
match the boxes."""

from __future__ import annotations

import cv2
import numpy as np

from xvmatch.geometry.camera import Camera

__all__ = ["draw_calibration"]

_HORIZON = (0, 200, 255)
_GRID = (255, 200, 0)
_BOX = (200, 200, 200)
_PERSON = (60, 220, 60)
_SAMPLES = 200


def _polyline(image: np.ndarray, camera: Camera, points: np.ndarray, colour: tuple,
              thickness: int) -> None:
    """Draw the world points ``(K, 3)`` as a line, split where they leave the camera's front."""
    uv, depth = camera.project(points)
    ok = (depth > 1e-3) & np.isfinite(uv).all(axis=1) & (np.abs(uv) < 1e6).all(axis=1)
    runs = np.split(np.arange(len(ok)), np.flatnonzero(np.diff(ok.astype(np.int8))) + 1)
    for run in runs:
        if len(run) > 1 and ok[run[0]]:
            cv2.polylines(image, [np.round(uv[run]).astype(np.int32)], False, colour, thickness,
                          cv2.LINE_AA)


def _grid_extent(camera: Camera, feet: np.ndarray) -> tuple[float, float, float]:
    """(near, far, half width) of the ground grid, metres, in the camera's own frame: over the
    people's feet, or what the image sees near the camera when there are none."""
    reach = 3.0 * float(camera.c[2]) + 10.0
    if len(feet):
        far = float(np.nanmax(np.abs(feet))) * 1.3 + 2.0
        if np.isfinite(far):
            reach = far
    return -reach if camera.R[2, 2] < -0.9 else 0.5, reach, reach


def draw_calibration(image: np.ndarray, camera: Camera, boxes: np.ndarray,
                     feet: np.ndarray, person_height: float, step: float = 2.0) -> np.ndarray:
    """The frame ``image`` (H, W, 3 uint8, BGR) with the calibration drawn on a copy.

    Args:
        image: the frame, or a blank canvas of the camera's image size.
        camera: the calibrated camera, in its own ground frame (ground z = 0).
        boxes: ``(N, 4)`` x, y, w, h of the frame's people.
        feet: ``(N, 2)`` their ground points (NaN above the horizon).
        person_height: the mean height the calibration assumed, metres.
        step: grid spacing, metres.
    """
    out = np.ascontiguousarray(image.copy())
    thick = max(1, round(max(out.shape[:2]) / 900))
    near, far, half = _grid_extent(camera, feet)
    t = np.linspace(0.0, 1.0, _SAMPLES)
    for x in np.arange(np.ceil(near / step) * step, far + 1e-9, step):
        ys = -half + 2 * half * t
        _polyline(out, camera, np.column_stack([np.full_like(t, x), ys, np.zeros_like(t)]),
                  _GRID, thick)
    for y in np.arange(-np.floor(half / step) * step, half + 1e-9, step):
        xs = near + (far - near) * t
        _polyline(out, camera, np.column_stack([xs, np.full_like(t, y), np.zeros_like(t)]),
                  _GRID, thick)
    # The horizon: ground directions at infinity, as a line across the image.
    yaw = np.linspace(-np.pi, np.pi, 4 * _SAMPLES)
    far_points = camera.c + 1e7 * np.column_stack([np.cos(yaw), np.sin(yaw), np.zeros_like(yaw)])
    _polyline(out, camera, far_points, _HORIZON, 2 * thick)
    for (x, y, w, h), foot in zip(np.asarray(boxes, float), np.asarray(feet, float),
                                  strict=True):
        cv2.rectangle(out, (round(x), round(y)), (round(x + w), round(y + h)), _BOX, thick)
        if np.isfinite(foot).all():
            body = np.array([[*foot, 0.0], [*foot, person_height]])
            _polyline(out, camera, body, _PERSON, 2 * thick)
    return out
