"""Geometric priors between two calibrated views: ray distance and cheirality.

Section III-B of the geometric-priors paper. Each detection defines a projection ray from its
camera centre through one image point (Eqs. 4-5). Two detections of the same person give rays
that (nearly) intersect, so the distance between the rays (Eq. 6) is a geometric cost. The
cheirality constraint (Eq. 7) adds that the triangulated point must lie in front of both
cameras; violating pairs get the crisp cost ``beta >> 1``.

The image point is the **top centre of the box** ``(x + w/2, y)``, i.e. the head, as in
Section IV-A ("we consider the top-center point of bounding box"): the head is visible in both
an overview and an egocentric view far more often than the feet.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xvmatch.core.array_checks import as_boxes, as_points
from xvmatch.geometry.camera import Camera

__all__ = [
    "DEFAULT_BETA",
    "METRIC_MARGIN",
    "Rays",
    "box_rays",
    "box_top_centres",
    "cheirality_cost",
    "cheirality_mask",
    "pixel_rays",
    "ray_distances",
    "triangulate_midpoints",
]

METRIC_MARGIN: float = 0.5
"""Depth margin of Eq. 7 in metres, for cameras with a known metric scale."""

DEFAULT_BETA: float = 1e3
"""Cost given to pairs that violate the cheirality constraint (``beta >> 1``, Section III-B)."""

_PARALLEL_TOL = 1e-9  # |n_i x n_j| below this (sine of the angle) counts as parallel


@dataclass(frozen=True, eq=False)
class Rays:
    """Projection rays ``r = c + s n`` of N image points of one camera (Eq. 5).

    Attributes:
        camera: the camera; its centre ``c`` is the origin of every ray.
        pixels: (N, 2) image points the rays pass through.
        directions: (N, 3) unit world directions ``n`` (pointing in front of the camera).
    """

    camera: Camera
    pixels: np.ndarray
    directions: np.ndarray

    def __len__(self) -> int:
        return int(self.directions.shape[0])


def box_top_centres(boxes_xywh: np.ndarray) -> np.ndarray:
    """Top-centre (head) point ``(x + w/2, y)`` of each box, the point the paper projects.

    Args:
        boxes_xywh: (N, 4) boxes ``(x, y, w, h)`` in pixels.

    Returns:
        (N, 2) pixels.
    """
    boxes = as_boxes(boxes_xywh)
    return np.stack([boxes[:, 0] + 0.5 * boxes[:, 2], boxes[:, 1]], axis=1)


def pixel_rays(camera: Camera, pixels: np.ndarray) -> Rays:
    """Rays through pixels, ``n ~ R^T K^-1 [u, v, 1]^T`` (Eqs. 4-5).

    Args:
        camera: calibrated camera.
        pixels: (N, 2) pixel coordinates ``(u, v)``; they may lie outside the image.

    Returns:
        The N rays from ``camera.c``.
    """
    if not isinstance(camera, Camera):
        raise TypeError(f"camera must be a xvmatch.geometry.camera.Camera, got {type(camera)}")
    uv = as_points(pixels, 2, "pixels", finite=True).reshape(-1, 2)
    return Rays(camera=camera, pixels=uv, directions=camera.ray_directions(uv).reshape(-1, 3))


def box_rays(camera: Camera, boxes_xywh: np.ndarray) -> Rays:
    """Rays through the top-centre (head) point of each box (Eqs. 4-5, Section IV-A).

    Args:
        camera: calibrated camera.
        boxes_xywh: (N, 4) boxes ``(x, y, w, h)`` in pixels of ``camera``.

    Returns:
        The N head rays.
    """
    return pixel_rays(camera, box_top_centres(boxes_xywh))


def _check_rays(rays: Rays, name: str) -> None:
    if not isinstance(rays, Rays):
        raise TypeError(f"{name} must be Rays (see pixel_rays / box_rays), got {type(rays)}")


def ray_distances(rays_a: Rays, rays_b: Rays) -> np.ndarray:
    """Pairwise distance between the rays of two cameras, Eq. 6 of the geometric-priors paper.

    ``d_geo(r_i, r_j) = |c1c2 . (n_i x n_j)| / ||n_i x n_j||``, the length of the common
    perpendicular of the two (infinite) lines. For parallel rays (``||n_i x n_j|| < 1e-9``) the
    formula is 0/0 and the distance between the parallel lines, ``||c1c2 x n_i||``, is used.
    Whether the closest points lie in front of the cameras is left to the cheirality test.

    Args:
        rays_a: M rays of the first camera.
        rays_b: N rays of the second camera.

    Returns:
        (M, N) distances in world units (metres for a metric calibration), finite and >= 0.
        If both cameras share their centre, every distance is 0 (no baseline, no cue).
    """
    _check_rays(rays_a, "rays_a")
    _check_rays(rays_b, "rays_b")
    baseline = rays_b.camera.c - rays_a.camera.c
    n_i = rays_a.directions[:, None, :]
    n_j = rays_b.directions[None, :, :]
    cross = np.cross(n_i, n_j)
    sin = np.linalg.norm(cross, axis=-1)
    parallel = sin < _PARALLEL_TOL
    skew = np.abs(cross @ baseline) / np.where(parallel, 1.0, sin)
    para = np.linalg.norm(np.cross(baseline, rays_a.directions), axis=-1)[:, None]
    return np.where(parallel, para, skew)


def triangulate_midpoints(rays_a: Rays, rays_b: Rays) -> tuple[np.ndarray, np.ndarray]:
    """Midpoint triangulation of every pair of rays (the point q of Eq. 7).

    q is the midpoint of the common perpendicular: with ``w = c1 - c2``, ``b = n_i . n_j``,
    ``s = (b (n_j . w) - n_i . w) / (1 - b^2)``, ``t = (n_j . w - b (n_i . w)) / (1 - b^2)``,
    ``q = (c1 + s n_i + c2 + t n_j) / 2``, with ``1 - b^2`` computed as ``||n_i x n_j||^2``.
    The scale-free midpoint is enough for a sign test, and is exact for intersecting rays.

    Args:
        rays_a: M rays of the first camera.
        rays_b: N rays of the second camera.

    Returns:
        (points, parallel): points (M, N, 3) and a bool (M, N) mask of parallel pairs, whose
        intersection is at infinity or undefined; for those the point returned is the midpoint
        of the two camera centres (finite, never NaN).
    """
    _check_rays(rays_a, "rays_a")
    _check_rays(rays_b, "rays_b")
    c1, c2 = rays_a.camera.c, rays_b.camera.c
    w = c1 - c2
    n_i = rays_a.directions[:, None, :]
    n_j = rays_b.directions[None, :, :]
    b = np.sum(n_i * n_j, axis=-1)
    d = (rays_a.directions @ w)[:, None]
    e = (rays_b.directions @ w)[None, :]
    denom = np.sum(np.cross(n_i, n_j) ** 2, axis=-1)
    parallel = np.sqrt(denom) < _PARALLEL_TOL
    safe = np.where(parallel, 1.0, denom)
    s = np.where(parallel, 0.0, (b * e - d) / safe)
    t = np.where(parallel, 0.0, (e - b * d) / safe)
    points = 0.5 * (c1 + s[..., None] * n_i + c2 + t[..., None] * n_j)
    return points, parallel


def cheirality_mask(rays_a: Rays, rays_b: Rays, *, margin: float = 0.0) -> np.ndarray:
    """Pairs whose triangulated point lies in front of both cameras, Eq. 7.

    The constraint is ``z(q, c1) > margin AND z(q, c2) > margin`` with z the depth in each
    camera. Use ``margin=0`` (plain positive depth) when the relative pose is known only up to
    scale, and ``margin=METRIC_MARGIN`` (0.5 m) when the metric scale is known, which also
    rules out the wearer of the egocentric camera.

    Parallel pairs (see :func:`triangulate_midpoints`): rays pointing the same way meet at
    infinity ahead of both cameras, so they pass when both rays point forward; anti-parallel
    rays are tested at the midpoint of the camera centres (in front of both only when the
    cameras face each other).

    Args:
        rays_a: M rays of the first camera.
        rays_b: N rays of the second camera.
        margin: depth threshold, in world units, >= 0.

    Returns:
        (M, N) bool, True where the constraint holds.
    """
    if not np.isfinite(margin) or margin < 0:
        raise ValueError(f"margin must be a finite depth >= 0, got {margin}")
    points, parallel = triangulate_midpoints(rays_a, rays_b)
    z1 = rays_a.camera.depth(points)
    z2 = rays_b.camera.depth(points)
    holds = (z1 > margin) & (z2 > margin)
    forward_a = (rays_a.directions @ rays_a.camera.R[2] > 0)[:, None]
    forward_b = (rays_b.directions @ rays_b.camera.R[2] > 0)[None, :]
    same_way = np.sum(rays_a.directions[:, None, :] * rays_b.directions[None, :, :], axis=-1) > 0
    at_infinity = parallel & same_way
    return np.where(at_infinity, forward_a & forward_b, holds)


def cheirality_cost(
    rays_a: Rays, rays_b: Rays, *, margin: float = 0.0, beta: float = DEFAULT_BETA
) -> np.ndarray:
    """Cheirality cost matrix: 0 where Eq. 7 holds, ``beta`` where it is violated.

    Section III-B: "setting the corresponding cost in the association matrix to a value
    beta >> 1 when the cheirality constraint does not hold". Add it to a fused cost in [0, 1]
    (see ``xvmatch.cues.cost_fusion.add_cheirality``) so any violating pair costs more
    than a non-association cost ``gamma < beta`` and is never matched.

    Args:
        rays_a: M rays of the first camera.
        rays_b: N rays of the second camera.
        margin: depth threshold of Eq. 7; 0 without metric scale, ``METRIC_MARGIN`` with it.
        beta: finite cost of a violation, > 1.

    Returns:
        (M, N) float array with values in {0, beta}.
    """
    if not np.isfinite(beta) or beta <= 1.0:
        raise ValueError(f"beta must be a finite cost > 1 (the paper uses beta >> 1), got {beta}")
    holds = cheirality_mask(rays_a, rays_b, margin=margin)
    return np.where(holds, 0.0, float(beta))
