"""Pinhole camera in the convention of Eq. 4 of the geometric-priors paper.

A world point ``X`` (metres, z up) maps to pixels through ``lambda * [u, v, 1]^T = K R (X - c)``:
``R`` rotates world into camera axes (x right, y down, z forward) and ``c`` is the camera centre.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from xvmatch.geometry.array_checks import as_points

__all__ = ["Camera", "intrinsics_from_fov", "look_rotation", "same_camera"]


def intrinsics_from_fov(width: int, height: int, hfov_deg: float) -> np.ndarray:
    """Intrinsic matrix with square pixels, principal point at the image centre.

    Args:
        width, height: image size in pixels.
        hfov_deg: horizontal field of view in degrees, in (0, 180).
    """
    if not 0.0 < hfov_deg < 180.0:
        raise ValueError(f"hfov_deg must be in (0, 180), got {hfov_deg}")
    f = 0.5 * width / np.tan(np.radians(hfov_deg) / 2.0)
    return np.array([[f, 0.0, width / 2.0], [0.0, f, height / 2.0], [0.0, 0.0, 1.0]])


def look_rotation(yaw: float, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """World-to-camera rotation ``R`` for a camera looking along ``yaw`` (radians).

    ``yaw`` is measured counter-clockwise from the world x axis in the ground plane, ``pitch``
    tilts the optical axis down (positive = looking down), ``roll`` turns the image clockwise.
    ``pitch = pi/2`` gives a nadir camera whose image "up" points along ``yaw``.
    """
    cy, sy = np.cos(yaw), np.sin(yaw)
    forward_flat = np.array([cy, sy, 0.0])
    right = np.array([sy, -cy, 0.0])
    up = np.array([0.0, 0.0, 1.0])
    cp, sp = np.cos(pitch), np.sin(pitch)
    forward = cp * forward_flat - sp * up
    down = -(sp * forward_flat + cp * up)
    cr, sr = np.cos(roll), np.sin(roll)
    x_axis = cr * right + sr * down
    y_axis = -sr * right + cr * down
    return np.stack([x_axis, y_axis, forward])


@dataclass(frozen=True)
class Camera:
    """Calibrated pinhole camera: intrinsics ``K``, rotation ``R`` (world->camera), centre ``c``.

    Attributes:
        K: (3, 3) intrinsic matrix.
        R: (3, 3) rotation, world to camera axes.
        c: (3,) camera centre in world coordinates (metres).
        width, height: image size in pixels.
    """

    K: np.ndarray
    R: np.ndarray
    c: np.ndarray
    width: int
    height: int
    _K_inv: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        K = np.asarray(self.K, dtype=float)
        R = np.asarray(self.R, dtype=float)
        c = np.asarray(self.c, dtype=float).reshape(-1)
        if K.shape != (3, 3) or R.shape != (3, 3) or c.shape != (3,):
            raise ValueError(
                f"Camera needs K (3, 3), R (3, 3), c (3,); got {K.shape}, {R.shape}, {c.shape}"
            )
        if abs(np.linalg.det(K)) < 1e-12:
            raise ValueError("Camera K is singular")
        if not np.allclose(R @ R.T, np.eye(3), atol=1e-6) or np.linalg.det(R) < 0:
            raise ValueError("Camera R must be a proper rotation (R R^T = I, det R = +1)")
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"Camera image size must be positive, got {self.width}x{self.height}")
        object.__setattr__(self, "K", K)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "c", c)
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))
        object.__setattr__(self, "_K_inv", np.linalg.inv(K))

    @property
    def image_size(self) -> tuple[int, int]:
        """(width, height) in pixels."""
        return self.width, self.height

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` to camera coordinates ``R (X - c)``, shape ``(..., 3)``."""
        pts = as_points(points, 3, "points")
        return (pts - self.c) @ self.R.T

    def depth(self, points: np.ndarray) -> np.ndarray:
        """Depth z of world points ``(..., 3)`` along the optical axis, shape ``(...)``."""
        return self.to_camera(points)[..., 2]

    def project(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Project world points ``(..., 3)`` with Eq. 4.

        Returns:
            (uv, depth): pixels ``(..., 2)`` and depth ``(...)``. Points with depth <= 0 are
            behind the camera; their pixels are NaN.
        """
        cam = self.to_camera(points)
        z = cam[..., 2]
        hom = cam @ self.K.T
        with np.errstate(divide="ignore", invalid="ignore"):
            uv = hom[..., :2] / hom[..., 2:3]
        uv = np.where((z > 0)[..., None], uv, np.nan)
        return uv, z

    def ray_directions(self, pixels: np.ndarray) -> np.ndarray:
        """Unit world directions ``(..., 3)`` of the rays through pixels ``(..., 2)`` (Eq. 5)."""
        uv = as_points(pixels, 2, "pixels")
        hom = np.concatenate([uv, np.ones((*uv.shape[:-1], 1))], axis=-1)
        d = (hom @ self._K_inv.T) @ self.R  # R^T K^-1 [u v 1]^T, row-vector form
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def back_project(self, pixels: np.ndarray, depth: np.ndarray) -> np.ndarray:
        """World points at the given depth (camera z) behind pixels ``(..., 2)``."""
        uv = as_points(pixels, 2, "pixels")
        hom = np.concatenate([uv, np.ones((*uv.shape[:-1], 1))], axis=-1)
        cam = (hom @ self._K_inv.T) * np.asarray(depth, dtype=float)[..., None]
        return cam @ self.R + self.c

    def in_image(self, uv: np.ndarray) -> np.ndarray:
        """Boolean mask of pixels ``(..., 2)`` inside the image."""
        uv = np.asarray(uv, dtype=float)
        return (uv[..., 0] >= 0) & (uv[..., 0] < self.width) & (uv[..., 1] >= 0) & (
            uv[..., 1] < self.height
        )

    def to_dict(self) -> dict:
        """JSON-ready record of the camera."""
        return {
            "K": self.K.tolist(),
            "R": self.R.tolist(),
            "c": self.c.tolist(),
            "width": self.width,
            "height": self.height,
        }

    @classmethod
    def from_dict(cls, data: dict) -> Camera:
        """Inverse of :meth:`to_dict`; raises ``ValueError`` naming a missing field."""
        missing = [k for k in ("K", "R", "c", "width", "height") if k not in data]
        if missing:
            raise ValueError(f"camera record lacks field(s): {', '.join(missing)}")
        return cls(
            K=np.asarray(data["K"]),
            R=np.asarray(data["R"]),
            c=np.asarray(data["c"]),
            width=data["width"],
            height=data["height"],
        )


def same_camera(a: Camera, b: Camera) -> bool:
    """The same camera, up to what writing a file can change (1e-9 of a rotation entry, a
    micrometre, a millionth of a pixel)."""
    return (a.image_size == b.image_size and np.allclose(a.K, b.K, rtol=0, atol=1e-6)
            and np.allclose(a.R, b.R, rtol=0, atol=1e-9)
            and np.allclose(a.c, b.c, rtol=0, atol=1e-6))
