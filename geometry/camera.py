"""Pinhole camera in the convention of Eq. 4 of the geometric-priors paper.

A world point ``X`` (metres, z up) maps to pixels through ``lambda * [u, v, 1]^T = K R (X - c)``:
``R`` rotates world into camera axes (x right, y down, z forward) and ``c`` is the camera centre.
The ground is the plane z = :data:`GROUND_Z`; :func:`check_camera_sense` refuses a camera that
cannot exist in this world (a negative focal length, a centre below the ground or absurdly far,
an image that sees no ground, a top camera looking up).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from xvmatch.core.array_checks import as_points

__all__ = [
    "GROUND_Z",
    "MAX_CENTRE_COORD",
    "ROTATION_TOL",
    "Camera",
    "CameraSenseError",
    "FrameCameras",
    "check_camera_sense",
    "intrinsics_from_fov",
    "look_rotation",
    "same_camera",
]

GROUND_Z = 0.0
"""Height of the ground plane in world coordinates (metres; the world's z axis points up)."""

MAX_CENTRE_COORD = 1e5
"""Largest ``|x|``, ``|y|`` or ``|z|`` of a camera centre, metres (100 km): beyond any site a
camera watches, and far below where float64 pixels lose their precision."""

ROTATION_TOL = 1e-6
"""Largest ``|R R^T - I|`` entry of a rotation: a file written with 7 significant digits passes,
a matrix that is not a rotation does not."""

_FORM_TOL = 1e-9
"""Largest relative departure of ``K`` from the form ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``."""

_DESCENT_TOL = 1e-9
"""A unit ray points down when its z component is below ``-_DESCENT_TOL`` (rounding cannot
decide it)."""


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


class CameraSenseError(ValueError):
    """A camera that makes no physical sense; ``field`` is ``"K"``, ``"R"`` or ``"c"`` and the
    message is ``"<field>: <reason>"``.

    Attributes:
        field: the camera field at fault.
        reason: what is wrong with it, in one line.
    """

    def __init__(self, field: str, reason: str):
        super().__init__(f"{field}: {reason}")
        self.field = field
        self.reason = reason


def _check_intrinsics(K: np.ndarray) -> None:
    """Focal lengths finite and > 0, principal point finite, the form of Eq. 4's ``K``."""
    for name, value in (("fx", K[0, 0]), ("fy", K[1, 1])):
        if not np.isfinite(value) or value <= 0:
            raise CameraSenseError("K", f"focal length {name} = {value:g} must be > 0")
    for name, value in (("cx", K[0, 2]), ("cy", K[1, 2]), ("skew", K[0, 1])):
        if not np.isfinite(value):
            raise CameraSenseError("K", f"{name} = {value:g} must be finite")
    lower = np.abs([K[1, 0], K[2, 0], K[2, 1]]).max() / max(K[0, 0], K[1, 1])
    if not (lower <= _FORM_TOL and abs(K[2, 2] - 1.0) <= _FORM_TOL):
        raise CameraSenseError("K", "expected [[fx, s, cx], [0, fy, cy], [0, 0, 1]], got rows "
                               f"2-3 {K[1:].tolist()}")


def _check_rotation(R: np.ndarray) -> None:
    """``R`` orthonormal with det +1, within :data:`ROTATION_TOL`."""
    err = float(np.abs(R @ R.T - np.eye(3)).max()) if np.isfinite(R).all() else np.inf
    det = float(np.linalg.det(R)) if np.isfinite(R).all() else np.nan
    if not err <= ROTATION_TOL or not det > 0:
        raise CameraSenseError("R", f"not a proper rotation (max |R R^T - I| = {err:.2g}, "
                               f"det = {det:.6g}); store R with full precision, world -> camera")


def _check_centre(c: np.ndarray) -> None:
    """``c`` finite, within :data:`MAX_CENTRE_COORD`, above the ground plane."""
    for axis, value in zip("xyz", c, strict=True):
        if not np.isfinite(value) or abs(value) > MAX_CENTRE_COORD:
            raise CameraSenseError("c", f"camera centre {axis} = {value:g} m must be finite and "
                                   f"within +-{MAX_CENTRE_COORD:g} m")
    if c[2] <= GROUND_Z:
        where = "on" if c[2] == GROUND_Z else "below"
        raise CameraSenseError("c", f"camera centre z = {c[2]:g} m is {where} the ground "
                               f"(z = {GROUND_Z:g}, z up); a camera must be above it")


def _corner_rays(K: np.ndarray, R: np.ndarray, width: int, height: int) -> np.ndarray:
    """Unit world directions ``(4, 3)`` of the rays through the image corners (Eq. 5)."""
    corners = np.array([[0.0, 0.0, 1.0], [width, 0.0, 1.0], [0.0, height, 1.0],
                        [width, height, 1.0]])
    d = np.linalg.solve(K, corners.T).T @ R  # R^T K^-1 [u, v, 1]^T, row-vector form
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def _check_sees_ground(K: np.ndarray, R: np.ndarray, width: int, height: int) -> None:
    """Some of the image sees the ground in front of the camera.

    A ray's z component is affine in the pixel, so the image's lowest-pointing ray goes through
    a corner: the ground is in view when a corner's ray points down.
    """
    lowest = float(_corner_rays(K, R, width, height)[:, 2].min())
    if not lowest < -_DESCENT_TOL:
        angle = float(np.degrees(np.arcsin(np.clip(lowest, -1.0, 1.0))))
        raise CameraSenseError("R", f"the image sees no ground: its lowest ray points "
                               f"{angle:.3g} degrees above the horizontal (the camera looks "
                               "up); R is world -> camera, z up")


def _check_looks_down(R: np.ndarray) -> None:
    """The optical axis (third row of ``R`` in world axes) points down."""
    axis_z = float(R[2, 2])
    if not axis_z < -_DESCENT_TOL:
        angle = float(np.degrees(np.arcsin(np.clip(axis_z, -1.0, 1.0))))
        raise CameraSenseError("R", f"a top camera must look down, but its optical axis points "
                               f"{angle:.3g} degrees above the horizontal; R is world -> "
                               "camera, z up")


def check_camera_sense(K: np.ndarray, R: np.ndarray, c: np.ndarray, width: int, height: int,
                       *, top: bool = False) -> None:
    """Refuse a camera that cannot exist in the world of Eq. 4 (z up, ground z = 0).

    The rules, in the order checked:

    * ``K``: focal lengths ``fx``, ``fy`` finite and > 0; principal point and skew finite;
      ``K`` of the form ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
    * ``R``: a proper rotation, ``max |R R^T - I| <= ROTATION_TOL`` and ``det R > 0``.
    * ``c``: finite, every coordinate within ``+-MAX_CENTRE_COORD`` metres, and above the
      ground, ``c_z > GROUND_Z``.
    * ``top``: the optical axis points down (its world z component is negative); this holds
      for the top (overview, drone) camera only: a horizontal camera may look level or up a
      little.
    * the image sees the ground in front of the camera: the ray through at least one image
      corner points below the horizontal.

    Args:
        K: (3, 3) intrinsics.
        R: (3, 3) rotation, world -> camera.
        c: (3,) camera centre, metres.
        width, height: image size in pixels, > 0.
        top: the camera is the top camera.

    Raises:
        CameraSenseError: the first rule broken, naming the field, e.g.
            ``"K: focal length fx = -800 must be > 0"``.
    """
    K = np.asarray(K, dtype=float)
    R = np.asarray(R, dtype=float)
    c = np.asarray(c, dtype=float).reshape(-1)
    if K.shape != (3, 3) or R.shape != (3, 3) or c.shape != (3,):
        raise ValueError(f"check_camera_sense needs K (3, 3), R (3, 3), c (3,); got {K.shape}, "
                         f"{R.shape}, {c.shape}")
    _check_intrinsics(K)
    _check_rotation(R)
    _check_centre(c)
    if top:
        _check_looks_down(R)
    _check_sees_ground(K, R, int(width), int(height))


@dataclass(frozen=True)
class FrameCameras:
    """The two calibrated cameras of a frame pair.

    Attributes:
        top: the top/overview camera.
        hor: the horizontal/egocentric camera.
    """

    top: Camera
    hor: Camera
