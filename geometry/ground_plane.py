"""The ground plane z = 0 seen by static cameras: pixel <-> ground homographies, foot points.

A camera sees the ground through a plane homography. Written image -> ground, as the camera file
stores it (``docs/formats.md``), ``[X, Y, 1]^T ~ H [u, v, 1]^T`` with ``(X, Y)`` metres on the
ground z = 0. For a calibrated camera (Eq. 4 of the geometric-priors paper,
``lambda [u, v, 1]^T = K R (X - c)``) the ground -> image map is ``G = K [r1, r2, -R c]``
(``r1``, ``r2`` the first two columns of ``R``) and ``H = G^-1``; Eq. 1 of the
trajectory-correspondence paper projects each track point to the ground with it.

Sign convention. ``H`` and ``-H`` are the same homography, but the sign of the third coordinate
``w`` of ``H [u, v, 1]^T`` tells the ground in front of the camera (``w > 0``) from the part of
the image above the horizon, whose rays never meet the ground in front (``w < 0``); ``w = 0`` is
the horizon. With ``H = G^-1`` of a calibrated camera, ``w = 1 / depth`` of the ground point.
:func:`normalise_homography` fixes the sign of a user's ``H`` so that the bottom-centre pixel of
the image, which sees the floor in any camera that watches people walk, has ``w > 0``.
:func:`image_to_ground` refuses (or flags) pixels at or above the horizon, and those whose
ground point is farther than ``max_range`` metres (numerically at the horizon).

Physical sense. A camera file's homography must see the ground along the bottom edge of its
image (:func:`check_ground_view`); a calibrated camera whose bottom-centre pixel looks at the
sky has no such homography (:func:`ground_from_camera`); and :func:`fit_homography` refuses
fewer than :data:`MIN_POINT_PAIRS` pairs and point sets in (nearly) one line
(:data:`COLLINEAR_TOL`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from xvmatch.core.array_checks import as_points
from xvmatch.geometry.camera import Camera

__all__ = [
    "COLLINEAR_TOL",
    "MAX_RANGE",
    "MIN_POINT_PAIRS",
    "GroundCamera",
    "HorizonError",
    "check_ground_view",
    "fit_homography",
    "foot_points",
    "ground_from_camera",
    "ground_to_image",
    "image_to_ground",
    "normalise_homography",
]

MAX_RANGE = 1e4
"""Largest distance (metres) of a ground point from the world origin that counts as finite: a
foot point beyond it lies numerically at the horizon (10 km is beyond any floor a camera sees)."""

MIN_POINT_PAIRS = 4
"""Fewest image / ground point pairs a homography is fitted from (its 8 degrees of freedom)."""

COLLINEAR_TOL = 1e-2
"""A point set is (nearly) in one line when its spread across its best line is less than this
fraction of its spread along it (ratio of the singular values of the centred points); at 1 %
a pixel of noise moves the fitted horizon by tens of pixels."""

_COND_LIMIT = 1e12


class HorizonError(ValueError):
    """A pixel at or above a camera's horizon: it meets the ground behind the camera or at
    infinity. The message names the point's index."""


def _check_h(H: np.ndarray, name: str = "H") -> np.ndarray:
    """``H`` as a finite, invertible (3, 3) float array; ValueError naming ``name`` otherwise."""
    H = np.asarray(H, dtype=float)
    if H.shape != (3, 3):
        raise ValueError(f"{name} must be a 3x3 matrix, got shape {H.shape}")
    if not np.isfinite(H).all():
        raise ValueError(f"{name} contains NaN or inf")
    scale = np.abs(H).max()
    if scale == 0 or np.linalg.cond(H / scale) > _COND_LIMIT:
        raise ValueError(f"{name} is singular (condition number above {_COND_LIMIT:.0e}); "
                         "refit it from four or more image/ground point pairs, no three in line")
    return H


def normalise_homography(H: np.ndarray, width: int, height: int) -> np.ndarray:
    """``H`` (image -> ground) scaled to unit Frobenius norm, signed so that the bottom-centre
    pixel ``(width / 2, height)`` of the image has ``w > 0`` (see the module docstring).

    Args:
        H: (3, 3) image -> ground homography.
        width, height: image size in pixels.

    Returns:
        (3, 3) the same homography, normalised.

    Raises:
        ValueError: ``H`` not finite, singular, or the bottom-centre pixel on the horizon.
    """
    H = _check_h(H)
    H = H / np.linalg.norm(H)
    w = H[2] @ np.array([width / 2.0, float(height), 1.0])
    if abs(w) < 1e-12 * np.abs(H[2]).sum() * max(width, height, 1):
        raise ValueError("H puts the bottom-centre pixel of the image on the horizon; the "
                         "camera must see the floor at the bottom of its image")
    return H if w > 0 else -H


@dataclass(frozen=True, eq=False)
class GroundCamera:
    """A static camera as the ground plane sees it: its image -> ground homography, and its
    pinhole calibration when the camera file gives ``K, R, c``.

    Attributes:
        H: (3, 3) image -> ground homography, normalised (:func:`normalise_homography`).
        width, height: image size in pixels.
        camera: the full :class:`~xvmatch.geometry.camera.Camera`, or None for an ``H`` camera
            (then the camera centre and the vertical direction are unknown).
    """

    H: np.ndarray
    width: int
    height: int
    camera: Camera | None = None
    G: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if int(self.width) <= 0 or int(self.height) <= 0:
            raise ValueError(f"image size must be positive, got {self.width}x{self.height}")
        H = normalise_homography(self.H, int(self.width), int(self.height))
        object.__setattr__(self, "H", H)
        object.__setattr__(self, "G", np.linalg.inv(H))
        object.__setattr__(self, "width", int(self.width))
        object.__setattr__(self, "height", int(self.height))

    @classmethod
    def from_camera(cls, camera: Camera) -> GroundCamera:
        """The ground view of a calibrated camera (``H = G^-1``, ``G = K [r1, r2, -R c]``)."""
        return cls(ground_from_camera(camera), camera.width, camera.height, camera)

    def to_ground(self, uv: np.ndarray, max_range: float = MAX_RANGE) -> tuple[np.ndarray,
                                                                               np.ndarray]:
        """Ground points ``(..., 2)`` of pixels ``(..., 2)`` and their validity mask ``(...)``
        (:func:`image_to_ground` with ``strict=False``)."""
        return image_to_ground(self.H, uv, max_range=max_range, strict=False)

    def to_image(self, xy: np.ndarray) -> np.ndarray:
        """Pixels ``(..., 2)`` of ground points ``(..., 2)`` (NaN behind the camera)."""
        return ground_to_image(self.G, xy)

    def ground_footprint(self, max_range: float = 60.0) -> np.ndarray:
        """The part of the ground this camera sees, as a polygon ``(P, 2)`` in metres (for
        drawing fields of view).

        The image border, sampled, is first clipped in the image to the pixels below the
        horizon (``w > 0``, see the module docstring): a pixel at or above the horizon meets the
        ground behind the camera or nowhere, so projecting it would fold the polygon backwards
        (the crossing strips issue 69, item 6 saw). The clipped border is projected, and points
        farther than ``max_range`` metres from the camera's nearest visible ground point (the
        bottom-centre pixel's, always in front) are pulled in along their direction from it:
        the rays near the horizon end ``max_range`` in front of the camera, never behind.
        """
        t = np.linspace(0.0, 1.0, 33)[:-1]
        W, Hh = float(self.width), float(self.height)
        border = np.concatenate([
            np.stack([t * W, np.zeros_like(t)], 1), np.stack([np.full_like(t, W), t * Hh], 1),
            np.stack([(1 - t) * W, np.full_like(t, Hh)], 1), np.stack([np.zeros_like(t),
                                                                     (1 - t) * Hh], 1)])
        near = self.H @ np.array([W / 2, Hh, 1.0])
        anchor = near[:2] / near[2]
        # w is linear in the pixel: clip the polygon to the half-plane w >= floor (one
        # Sutherland-Hodgman pass); floor, a millionth of the bottom-centre pixel's w, puts the
        # clipped edge about a million times farther than the nearest ground, beyond any range.
        # The clipped edge is sampled (16 steps) so that its far arc is drawn round.
        floor = 1e-6 * near[2]
        w = np.concatenate([border, np.ones((len(border), 1))], 1) @ self.H[2]
        start = int(np.argmax(w))  # begin inside, so that every exit precedes its entry
        border, w = np.roll(border, -start, axis=0), np.roll(w, -start)
        kept: list[np.ndarray] = []
        exit_point = border[0]
        for i in range(len(border)):
            j = (i + 1) % len(border)
            if w[i] >= floor:
                kept.append(border[i])
            if (w[i] >= floor) != (w[j] >= floor):
                s = (floor - w[i]) / (w[j] - w[i])
                crossing = border[i] + s * (border[j] - border[i])
                if w[i] >= floor:
                    exit_point = crossing
                    kept.append(crossing)
                else:
                    kept.extend(exit_point + np.linspace(0.0, 1.0, 17)[1:, None]
                                * (crossing - exit_point))
        pixels = np.asarray(kept)
        hom = np.concatenate([pixels, np.ones((len(pixels), 1))], 1) @ self.H.T
        xy = hom[:, :2] / hom[:, 2:3]
        direction = xy - anchor
        dist = np.linalg.norm(direction, axis=1)
        far = dist > max_range
        with np.errstate(divide="ignore", invalid="ignore"):
            clipped = anchor + direction / dist[:, None] * max_range
        return np.where(far[:, None], clipped, xy)


def ground_from_camera(camera: Camera) -> np.ndarray:
    """Image -> ground homography ``H = (K [r1, r2, -R c])^-1`` of a calibrated camera, for the
    ground plane z = 0, normalised (Eq. 4 of the geometric-priors paper restricted to z = 0).

    Raises:
        ValueError: the camera centre lies on the ground plane (the homography is singular), or
            the bottom-centre pixel of the image sees no ground in front of the camera.
    """
    G = camera.K @ np.column_stack([camera.R[:, 0], camera.R[:, 1], -camera.R @ camera.c])
    try:
        H = np.linalg.inv(_check_h(G, "K [r1, r2, -R c]"))
    except np.linalg.LinAlgError:
        raise ValueError("the camera centre lies on the ground plane: no ground homography") \
            from None
    # Unscaled, w = 1 / depth of the ground point: its sign tells ground from sky.
    if H[2] @ np.array([camera.width / 2.0, float(camera.height), 1.0]) <= 0:
        raise ValueError("the bottom-centre pixel of the image sees no ground in front of the "
                         "camera (it looks up, or is upside down); R is world -> camera, z up")
    return normalise_homography(H, camera.width, camera.height)


def image_to_ground(H: np.ndarray, uv: np.ndarray, max_range: float = MAX_RANGE,
                    strict: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Pixels to the ground, ``[X, Y, 1]^T ~ H [u, v, 1]^T`` (Eq. 1 of the
    trajectory-correspondence paper).

    Args:
        H: (3, 3) image -> ground homography, normalised (:func:`normalise_homography`).
        uv: ``(..., 2)`` pixels.
        max_range: ground points farther than this from the origin (metres) are at the horizon.
        strict: raise :class:`HorizonError` on the first invalid point instead of flagging it.

    Returns:
        (xy, ok): ``(..., 2)`` ground points in metres (NaN where not ok) and the ``(...)``
        mask of points below the horizon within ``max_range``.

    Raises:
        HorizonError: with ``strict``, a pixel at or above the horizon, or beyond ``max_range``;
            the message gives its flat index and pixel.
    """
    pts = as_points(uv, 2, "uv")
    hom = pts @ H[:, :2].T + H[:, 2]
    w = hom[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        xy = hom[..., :2] / w[..., None]
    ok = (w > 0) & np.isfinite(xy).all(axis=-1)
    ok &= np.where(ok, np.linalg.norm(np.where(ok[..., None], xy, 0.0), axis=-1), np.inf) \
        <= max_range
    if strict and not ok.all():
        k = int(np.flatnonzero(~ok.reshape(-1))[0])
        u, v = pts.reshape(-1, 2)[k]
        where = "behind the camera (above the horizon)" if w.reshape(-1)[k] <= 0 else \
            f"at the horizon (farther than {max_range:g} m)"
        raise HorizonError(f"point {k} ({u:.1f}, {v:.1f}) projects to the ground {where}")
    return np.where(ok[..., None], xy, np.nan), ok


def ground_to_image(G: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Ground points ``(..., 2)`` (metres, z = 0) to pixels with the ground -> image map
    ``G = H^-1``; points behind the camera (``w <= 0``) give NaN."""
    pts = as_points(xy, 2, "xy")
    hom = pts @ G[:, :2].T + G[:, 2]
    w = hom[..., 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = hom[..., :2] / w[..., None]
    return np.where((w > 0)[..., None], uv, np.nan)


def foot_points(boxes_xywh: np.ndarray) -> np.ndarray:
    """Foot pixels ``(N, 2)`` of boxes ``(N, 4)`` ``x, y, w, h``: the bottom-centre
    ``(x + w / 2, y + h)``, where a standing person touches the ground."""
    b = np.asarray(boxes_xywh, dtype=float).reshape(-1, 4)
    return np.stack([b[:, 0] + 0.5 * b[:, 2], b[:, 1] + b[:, 3]], axis=1)


def check_ground_view(H: np.ndarray, width: int, height: int,
                      points: np.ndarray | None = None) -> None:
    """Refuse a homography whose image does not see the ground in front along its bottom edge.

    The bottom corners and the bottom-centre pixel (and ``points``, if given) must map to the
    ground in front of the camera (``w > 0``) within :data:`MAX_RANGE` of the origin: the horizon
    may cross the image, but not its bottom edge, as in any camera that watches people walk.

    Args:
        H: (3, 3) image -> ground homography, normalised (:func:`normalise_homography`).
        width, height: image size in pixels.
        points: optional ``(P, 2)`` pixels that must see the ground too (fitted points).

    Raises:
        ValueError: the first pixel that does not, in one line.
    """
    edge = np.array([[0.0, height], [width / 2.0, height], [float(width), height]])
    names = ["the bottom-left corner", "the bottom-centre pixel", "the bottom-right corner"]
    if points is not None:
        edge = np.concatenate([edge, np.asarray(points, dtype=float).reshape(-1, 2)])
        names += [f"image point {k}" for k in range(len(edge) - 3)]
    _, ok = image_to_ground(H, edge, strict=False)
    if ok.all():
        return
    k = int(np.flatnonzero(~ok)[0])
    u, v = edge[k]
    w = H[2] @ np.array([u, v, 1.0])
    where = "sees no ground in front of the camera (it lies above the horizon)" if w <= 0 else \
        f"meets the ground farther than {MAX_RANGE:g} m from the origin (at the horizon)"
    hint = "the image must see the ground along its bottom edge" if k < 3 else \
        "the fitted horizon crosses the points: check their pairing and units"
    raise ValueError(f"{names[k]} ({u:.1f}, {v:.1f}) {where}; {hint}")


def _thinness(points: np.ndarray) -> np.ndarray:
    """How nearly the points lie in one line: ``(P + 1,)`` ratios of their spread across their
    best line to their spread along it (singular values of the centred points), of all the
    points (entry 0), then with point ``k`` left out (entry ``k + 1``)."""
    x = points - points.mean(axis=0)
    n = len(x)
    s1, sxx = x.sum(axis=0), np.einsum("pi,pj->ij", x, x)
    # Leave-one-out covariances (P + 1, 2, 2), vectorised; row 0 keeps every point.
    sums = np.concatenate([s1[None], s1 - x])
    outer = np.concatenate([sxx[None], sxx - np.einsum("pi,pj->pij", x, x)])
    counts = np.concatenate([[n], np.full(n, n - 1)]).astype(float)[:, None]
    mean = sums / counts
    cov = outer / counts[:, :, None] - np.einsum("pi,pj->pij", mean, mean)
    eig = np.clip(np.linalg.eigvalsh(cov), 0.0, None)  # ascending
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(eig[:, 1] > 0, np.sqrt(eig[:, 0] / eig[:, 1]), 0.0)


def _check_spread(points: np.ndarray, name: str) -> None:
    """Refuse points that (but for at most one) lie within :data:`COLLINEAR_TOL` of one line."""
    ratios = _thinness(points)
    k = 0 if ratios[0] < COLLINEAR_TOL else int(np.argmin(ratios))
    if ratios[k] < COLLINEAR_TOL:
        which = f"the points other than point {k - 1}" if k else "the points"
        raise ValueError(f"{name}: {which} lie (nearly) in one line (spread across it "
                         f"{ratios[k]:.2g} of the spread along it, below {COLLINEAR_TOL:g}); a "
                         f"homography needs {MIN_POINT_PAIRS} points, no three in line")


def fit_homography(image_points: np.ndarray, ground_points: np.ndarray, width: int,
                   height: int) -> np.ndarray:
    """Image -> ground homography from four or more pixel / ground point pairs (OpenCV's
    ``findHomography``, least squares over all pairs), normalised.

    Degenerate input is refused before fitting: fewer than :data:`MIN_POINT_PAIRS` pairs, or
    image or ground points that, but for at most one, lie in (nearly) one line (spread across
    the line under :data:`COLLINEAR_TOL` of the spread along it; this covers repeated points
    and three of four in line). The fitted ``H`` must see every given image point and the
    bottom edge of the image on the ground in front (:func:`check_ground_view`).

    Args:
        image_points: ``(P, 2)`` pixels (lens distortion already removed).
        ground_points: ``(P, 2)`` the same points on the ground, metres.
        width, height: image size in pixels.

    Returns:
        (3, 3) ``H`` with ``[X, Y, 1]^T ~ H [u, v, 1]^T``.

    Raises:
        ValueError: fewer than four pairs, non-finite values, a degenerate configuration
            (points in line, repeated points), or a fit whose horizon crosses the points or the
            bottom edge of the image; one line.
    """
    import cv2

    img = as_points(image_points, 2, "image_points", finite=True).reshape(-1, 2)
    gnd = as_points(ground_points, 2, "ground_points", finite=True).reshape(-1, 2)
    if img.shape != gnd.shape:
        raise ValueError(f"image_points and ground_points differ in number: {len(img)} and "
                         f"{len(gnd)}")
    if len(img) < MIN_POINT_PAIRS:
        raise ValueError(f"a homography needs at least {MIN_POINT_PAIRS} point pairs, got "
                         f"{len(img)}")
    _check_spread(img, "image points")
    _check_spread(gnd, "ground points")
    H, _ = cv2.findHomography(img.astype(np.float64), gnd.astype(np.float64), 0)
    if H is None or not np.isfinite(H).all():
        raise ValueError("no homography fits these points (three or more in line, or repeated)")
    H = normalise_homography(H, width, height)
    check_ground_view(H, width, height, img)
    return H
