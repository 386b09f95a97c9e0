"""The bird's-eye picture of ``xvmatch multicam`` (``birdseye.png``): each global trajectory on the
ground, each camera's field of view outlined and named, a 5 m grid."""

from __future__ import annotations

import colorsys
from collections.abc import Mapping

import cv2
import numpy as np

from xvmatch.geometry.ground_plane import GroundCamera

__all__ = ["draw_birdseye"]


def _colour(k: int) -> tuple[int, int, int]:
    """A distinct BGR colour for index ``k`` (golden-ratio hues)."""
    r, g, b = colorsys.hsv_to_rgb((k * 0.618034) % 1.0, 0.85, 0.9)
    return int(255 * b), int(255 * g), int(255 * r)


def draw_birdseye(ground: Mapping[int, tuple[np.ndarray, np.ndarray]],
                  cameras: Mapping[str, GroundCamera], size: int = 1000) -> bytes:
    """PNG of the global trajectories on the ground, each camera's field of view outlined.

    Args:
        ground: ``{global_id: (frames (J,), (J, 2) ground xy in metres)}``.
        cameras: ``{name: GroundCamera}``; a camera with a pose (``camera``) is marked at its
            centre, else at the middle of its field of view.
        size: the picture's side in pixels.
    """
    paths = [xy for _fr, xy in ground.values() if len(xy)]
    pts = np.concatenate(paths) if paths else np.zeros((1, 2))
    lo, hi = np.percentile(pts, 0.5, axis=0) - 3.0, np.percentile(pts, 99.5, axis=0) + 3.0
    centres = [c.camera.c[:2] for c in cameras.values() if c.camera is not None]
    if centres:
        lo = np.minimum(lo, np.min(centres, axis=0) - 1.0)
        hi = np.maximum(hi, np.max(centres, axis=0) + 1.0)
    scale = (size - 40) / max(float((hi - lo).max()), 1e-6)
    canvas = np.full((size, size, 3), 255, np.uint8)

    def px(xy):
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.stack([20 + (xy[:, 0] - lo[0]) * scale,
                         size - 20 - (xy[:, 1] - lo[1]) * scale], 1).round().astype(np.int32)

    step = 5.0
    for x in np.arange(np.floor(lo[0] / step) * step, hi[0] + step, step):
        cv2.line(canvas, tuple(px([x, lo[1]])[0]), tuple(px([x, hi[1]])[0]), (235, 235, 235), 1)
    for y in np.arange(np.floor(lo[1] / step) * step, hi[1] + step, step):
        cv2.line(canvas, tuple(px([lo[0], y])[0]), tuple(px([hi[0], y])[0]), (235, 235, 235), 1)
    reach = float((hi - lo).max())
    for i, cam in enumerate(cameras.values()):  # fields of view, lightly filled
        overlay = canvas.copy()
        cv2.fillPoly(overlay, [px(cam.ground_footprint(max_range=reach))],
                     _colour(1000 + i), cv2.LINE_AA)
        canvas = cv2.addWeighted(overlay, 0.08, canvas, 0.92, 0.0)
    for i, (name, cam) in enumerate(cameras.items()):
        colour = tuple(int(0.6 * v + 100) for v in _colour(1000 + i))
        poly = px(cam.ground_footprint(max_range=reach))
        cv2.polylines(canvas, [poly], True, colour, 1, cv2.LINE_AA)
        anchor = px(cam.camera.c[:2])[0] if cam.camera is not None else poly.mean(0).astype(int)
        cv2.circle(canvas, tuple(int(v) for v in anchor), 6, colour, -1, cv2.LINE_AA)
        cv2.putText(canvas, name, (int(anchor[0]) + 8, int(anchor[1]) - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    for g, (_fr, xy) in ground.items():
        if len(xy) < 2:
            continue
        line = px(xy)
        cv2.polylines(canvas, [line], False, _colour(g), 2, cv2.LINE_AA)
        cv2.putText(canvas, str(g), tuple(int(v) for v in line[-1]), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, _colour(g), 1, cv2.LINE_AA)
    cv2.putText(canvas, f"grid {step:g} m; {len(ground)} global ids", (20, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    ok, png = cv2.imencode(".png", canvas)
    if not ok:
        raise OSError("could not encode birdseye.png")
    return png.tobytes()
