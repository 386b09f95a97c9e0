"""Camera poses from point correspondences, with OpenCV's solvers.

Section IV-A of the geometric-priors paper calibrates its two cameras this way: the static
(overview) camera by PnP from known world points, the mobile camera by its relative pose to the
static one (essential matrix), chained with the static pose and scaled by a known distance.
These helpers return :class:`~xvmatch.geometry.camera.Camera` objects in the convention of Eq. 4,
``lambda [u, v, 1]^T = K R (X - c)``; OpenCV's ``x_cam = R X + t`` maps to it by ``c = -R^T t``.

Misuse (wrong shapes, too few points) and degenerate input (collinear points, no parallax, a
solver that finds no solution) raise :class:`PoseEstimationError`, a ``ValueError`` whose
message says what to change.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from xvmatch.geometry.camera import Camera

__all__ = [
    "PoseEstimationError",
    "RelativePose",
    "camera_from_pnp",
    "camera_from_relative_pose",
    "estimate_relative_pose",
    "reprojection_rmse",
]

MIN_PNP_POINTS = 4
MIN_ESSENTIAL_POINTS = 5


class PoseEstimationError(ValueError):
    """Pose cannot be estimated from the given correspondences; the message says why."""


@dataclass(frozen=True)
class RelativePose:
    """Relative pose of camera b with respect to camera a, up to scale.

    Camera-a coordinates map to camera-b coordinates as ``x_b = R x_a + s t`` for an unknown
    scale ``s > 0``: an essential matrix fixes only the direction of the translation.

    Attributes:
        R: (3, 3) rotation from camera-a axes to camera-b axes.
        t: (3,) unit translation direction, in camera-b axes.
        inliers: (N,) bool, correspondences consistent with the pose and in front of both
            cameras.
    """

    R: np.ndarray
    t: np.ndarray
    inliers: np.ndarray


def _check_points(points: np.ndarray, dim: int, name: str) -> np.ndarray:
    arr = np.asarray(points, dtype=float)
    if arr.ndim != 2 or arr.shape[1] != dim:
        raise PoseEstimationError(f"{name} must have shape (N, {dim}), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise PoseEstimationError(f"{name} contains NaN or inf")
    return arr


def _check_K(K: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(K, dtype=float)
    if arr.shape != (3, 3) or not np.isfinite(arr).all():
        raise PoseEstimationError(f"{name} must be a finite 3x3 intrinsic matrix, got {arr.shape}")
    if abs(np.linalg.det(arr)) < 1e-12:
        raise PoseEstimationError(f"{name} is singular; check the focal lengths")
    return arr


def _rank(points: np.ndarray, rel_tol: float = 1e-9) -> int:
    """Affine rank of a point set (0: coincident, 1: collinear, 2: coplanar, ...)."""
    centred = points - points.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    scale = max(float(sv[0]) if sv.size else 0.0, 1e-300)
    return int(np.sum(sv > rel_tol * scale)) if sv.size and sv[0] > 0 else 0


def _normalised(pixels: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Pixels to normalised image coordinates ``K^-1 [u, v, 1]``, shape (N, 2)."""
    hom = np.concatenate([pixels, np.ones((pixels.shape[0], 1))], axis=1) @ np.linalg.inv(K).T
    return hom[:, :2] / hom[:, 2:3]


def _rotation_only_residual_deg(xa: np.ndarray, xb: np.ndarray) -> float:
    """Median angle (degrees) left between the bearings of b and the best-rotated bearings of a.

    The rotation is the least-squares (Kabsch) fit; a residual near 0 means one rotation explains
    every correspondence, i.e. there is no parallax to observe a translation from.
    """
    a = np.concatenate([xa, np.ones((xa.shape[0], 1))], axis=1)
    b = np.concatenate([xb, np.ones((xb.shape[0], 1))], axis=1)
    a /= np.linalg.norm(a, axis=1, keepdims=True)
    b /= np.linalg.norm(b, axis=1, keepdims=True)
    U, _, Vt = np.linalg.svd(b.T @ a)
    R = U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt
    cos = np.clip(np.sum(b * (a @ R.T), axis=1), -1.0, 1.0)
    return float(np.degrees(np.median(np.arccos(cos))))


def _sampson_residuals(R: np.ndarray, t: np.ndarray, xa: np.ndarray, xb: np.ndarray) -> np.ndarray:
    """Sampson distances of normalised correspondences to the epipolar geometry E = [t]x R."""
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    E = tx @ R
    a = np.concatenate([xa, np.ones((xa.shape[0], 1))], axis=1)
    b = np.concatenate([xb, np.ones((xb.shape[0], 1))], axis=1)
    Ea = a @ E.T
    Etb = b @ E
    num = np.sum(b * Ea, axis=1)
    den = np.sqrt(Ea[:, 0] ** 2 + Ea[:, 1] ** 2 + Etb[:, 0] ** 2 + Etb[:, 1] ** 2)
    return num / np.maximum(den, 1e-12)


def _refine_pose(
    R0: np.ndarray, t0: np.ndarray, xa: np.ndarray, xb: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Levenberg-Marquardt refinement of (R, t) on the inliers, minimising Sampson errors.

    RANSAC returns the pose of its best minimal sample; this polishes it with all inliers.
    R is updated by a rotation vector, t on its unit sphere through a tangent basis.
    """
    t0 = t0 / np.linalg.norm(t0)
    _, _, vt = np.linalg.svd(t0[None, :])
    e1, e2 = vt[1], vt[2]  # orthonormal basis of the plane perpendicular to t0

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R = Rotation.from_rotvec(p[:3]).as_matrix() @ R0
        t = t0 + p[3] * e1 + p[4] * e2
        return R, t / np.linalg.norm(t)

    def residuals(p: np.ndarray) -> np.ndarray:
        return _sampson_residuals(*unpack(p), xa, xb)

    result = least_squares(residuals, np.zeros(5), method="lm")
    return unpack(result.x)


def reprojection_rmse(camera: Camera, world_points: np.ndarray, pixels: np.ndarray) -> float:
    """Root-mean-square reprojection error in pixels of world points under ``camera`` (Eq. 4).

    Returns ``inf`` if any point is behind the camera.
    """
    pts = _check_points(world_points, 3, "world_points")
    uv = _check_points(pixels, 2, "pixels")
    proj, depth = camera.project(pts)
    if (depth <= 0).any():
        return float("inf")
    return float(np.sqrt(np.mean(np.sum((proj - uv) ** 2, axis=1))))


def camera_from_pnp(
    world_points: np.ndarray,
    pixels: np.ndarray,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    dist_coeffs: np.ndarray | None = None,
) -> Camera:
    """Static camera pose from known world points and their pixels (PnP, ``cv2.solvePnP``).

    Non-coplanar points are solved with SQPnP (globally optimal) and refined by Levenberg-
    Marquardt; coplanar points with OpenCV's iterative solver (homography initialisation).

    Args:
        world_points: (N, 3) world points in metres, N >= 4, not all collinear.
        pixels: (N, 2) their pixels ``(u, v)`` in the image.
        K: (3, 3) intrinsic matrix.
        width, height: image size in pixels.
        dist_coeffs: optional OpenCV distortion coefficients; the returned camera is the
            undistorted pinhole model.

    Returns:
        The camera with ``R`` and ``c`` such that ``pixels ~ K R (world_points - c)``.

    Raises:
        PoseEstimationError: too few points, degenerate geometry, no solution, or a solution
            that puts the points behind the camera.
    """
    pts = _check_points(world_points, 3, "world_points")
    uv = _check_points(pixels, 2, "pixels")
    K = _check_K(K, "K")
    if pts.shape[0] != uv.shape[0]:
        raise PoseEstimationError(
            f"world_points and pixels must pair up, got {pts.shape[0]} and {uv.shape[0]} points"
        )
    if pts.shape[0] < MIN_PNP_POINTS:
        raise PoseEstimationError(
            f"PnP needs at least {MIN_PNP_POINTS} correspondences, got {pts.shape[0]}"
        )
    world_rank = _rank(pts)
    if world_rank < 2:
        raise PoseEstimationError(
            "world_points are coincident or collinear; PnP needs points spanning a plane"
        )
    if _rank(uv) < 2:
        raise PoseEstimationError("pixels are coincident or collinear; the pose is not determined")
    dist = np.zeros(5) if dist_coeffs is None else np.asarray(dist_coeffs, dtype=float)
    flag = cv2.SOLVEPNP_ITERATIVE if world_rank == 2 else cv2.SOLVEPNP_SQPNP
    try:
        ok, rvec, tvec = cv2.solvePnP(pts, uv, K, dist, flags=flag)
        if ok and flag == cv2.SOLVEPNP_SQPNP:
            rvec, tvec = cv2.solvePnPRefineLM(pts, uv, K, dist, rvec, tvec)
    except cv2.error as exc:
        raise PoseEstimationError(f"cv2.solvePnP failed: {exc}") from exc
    if not ok or not np.isfinite(rvec).all() or not np.isfinite(tvec).all():
        raise PoseEstimationError("cv2.solvePnP found no pose; check the correspondences")
    R, _ = cv2.Rodrigues(rvec)
    c = -R.T @ tvec.reshape(3)
    camera = Camera(K=K, R=R, c=c, width=width, height=height)
    if np.median(camera.depth(pts)) <= 0:
        raise PoseEstimationError(
            "PnP solution puts the points behind the camera; check the correspondences"
        )
    return camera


def _checked_pose_inputs(
    pixels_a: np.ndarray, pixels_b: np.ndarray, K_a: np.ndarray, K_b: np.ndarray,
    threshold_px: float, confidence: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Check the inputs of :func:`estimate_relative_pose`; returns them as float arrays.

    Raises:
        PoseEstimationError: points of the wrong shape, counts that differ or below
            :data:`MIN_ESSENTIAL_POINTS`, bad RANSAC settings, or coincident/collinear pixels.
    """
    uv_a = _check_points(pixels_a, 2, "pixels_a")
    uv_b = _check_points(pixels_b, 2, "pixels_b")
    K_a = _check_K(K_a, "K_a")
    K_b = _check_K(K_b, "K_b")
    if uv_a.shape[0] != uv_b.shape[0]:
        raise PoseEstimationError(
            f"pixels_a and pixels_b must pair up, got {uv_a.shape[0]} and {uv_b.shape[0]} points"
        )
    n = uv_a.shape[0]
    if n < MIN_ESSENTIAL_POINTS:
        raise PoseEstimationError(
            f"relative pose needs at least {MIN_ESSENTIAL_POINTS} correspondences, got {n}"
        )
    if not 0.0 < confidence < 1.0 or not threshold_px > 0:
        raise PoseEstimationError("confidence must be in (0, 1) and threshold_px > 0")
    if _rank(uv_a) < 2 or _rank(uv_b) < 2:
        raise PoseEstimationError("pixels are coincident or collinear; the pose is not determined")
    return uv_a, uv_b, K_a, K_b


def _best_decomposition(
    E: np.ndarray, xa: np.ndarray, xb: np.ndarray, ransac_mask: np.ndarray
) -> tuple[int, np.ndarray, np.ndarray, np.ndarray]:
    """Decompose each essential-matrix candidate; keep the pose with most points in front.

    Args:
        E: ``(3k, 3)`` stacked candidates (the 5-point solver may return several).
        xa, xb: ``(N, 2)`` normalised image points.
        ransac_mask: ``(N,)`` uint8 RANSAC inliers.

    Returns:
        ``(count, R, t, mask)`` of the best candidate: points in front of both cameras,
        rotation, translation and the cheirality mask (count -1 and the identity if none).

    Raises:
        PoseEstimationError: ``cv2.recoverPose`` failed.
    """
    eye = np.eye(3)
    count, R, t, pose_mask = -1, eye, np.zeros(3), ransac_mask
    for k in range(E.shape[0] // 3):  # the 5-point solver may return several candidates
        candidate = np.ascontiguousarray(E[3 * k : 3 * k + 3])
        try:
            found = cv2.recoverPose(candidate, xa, xb, eye, mask=ransac_mask.copy().reshape(-1, 1))
        except cv2.error as exc:
            raise PoseEstimationError(f"cv2.recoverPose failed: {exc}") from exc
        if int(found[0]) > count:
            count, R, t, pose_mask = int(found[0]), found[1], found[2], found[3]
    return count, R, t, pose_mask


def estimate_relative_pose(
    pixels_a: np.ndarray,
    pixels_b: np.ndarray,
    K_a: np.ndarray,
    K_b: np.ndarray,
    *,
    threshold_px: float = 1.0,
    confidence: float = 0.999,
    min_parallax_deg: float = 0.1,
    refine: bool = True,
) -> RelativePose:
    """Relative pose of camera b to camera a from matched pixels with known intrinsics.

    Pixels are normalised with each ``K`` so the two cameras may differ, then the essential
    matrix is estimated with RANSAC (``cv2.findEssentialMat``, 5-point), decomposed with the
    cheirality check of ``cv2.recoverPose`` and refined on the inliers. The translation is a
    unit direction: scale is not observable from two views (Section IV-A fixes it with a known
    camera height).

    Args:
        pixels_a: (N, 2) pixels in camera a, N >= 5.
        pixels_b: (N, 2) matching pixels in camera b.
        K_a, K_b: (3, 3) intrinsic matrices.
        threshold_px: RANSAC epipolar distance threshold in pixels.
        confidence: RANSAC confidence in (0, 1).
        min_parallax_deg: median angle between the bearings of b and the best-rotated
            bearings of a below which the translation direction is declared unobservable
            (pure rotation or far scene); keep it above the pixel noise, ~noise_px / f rad.
        refine: polish the RANSAC pose on all inliers (Levenberg-Marquardt on Sampson errors,
            ``scipy.optimize.least_squares``); deterministic, and several times more accurate
            than the pose of one minimal sample.

    Returns:
        The relative pose ``x_b = R x_a + s t``.

    Raises:
        PoseEstimationError: too few or mismatched points, no essential matrix, too few
            inliers in front of both cameras, or too little parallax.
    """
    uv_a, uv_b, K_a, K_b = _checked_pose_inputs(pixels_a, pixels_b, K_a, K_b, threshold_px,
                                                confidence)
    n = uv_a.shape[0]

    xa = _normalised(uv_a, K_a)
    xb = _normalised(uv_b, K_b)
    parallax = _rotation_only_residual_deg(xa, xb)
    if parallax < min_parallax_deg:
        raise PoseEstimationError(
            f"median parallax {parallax:.3g} deg < min_parallax_deg={min_parallax_deg}: the views "
            "differ by (almost) a pure rotation, so the translation direction is unobservable; "
            "move the camera or use points nearer to it"
        )
    focal = 0.25 * (K_a[0, 0] + K_a[1, 1] + K_b[0, 0] + K_b[1, 1])
    eye = np.eye(3)
    try:
        E, mask = cv2.findEssentialMat(
            xa, xb, eye, method=cv2.RANSAC, prob=confidence, threshold=threshold_px / focal
        )
    except cv2.error as exc:
        raise PoseEstimationError(f"cv2.findEssentialMat failed: {exc}") from exc
    if E is None or E.ndim != 2 or E.shape[1] != 3 or E.shape[0] % 3 or E.shape[0] == 0:
        raise PoseEstimationError("no essential matrix found; check the correspondences")

    ransac_mask = mask.reshape(-1).astype(np.uint8) if mask is not None else np.ones(n, np.uint8)
    count, R, t, pose_mask = _best_decomposition(E, xa, xb, ransac_mask)
    if count < MIN_ESSENTIAL_POINTS:
        raise PoseEstimationError(
            f"only {count} correspondences lie in front of both cameras under the best pose; "
            "check the matches or raise threshold_px"
        )
    inliers = pose_mask.reshape(-1) > 0
    t = t.reshape(3) / np.linalg.norm(t)
    if refine:
        R, t = _refine_pose(R, t, xa[inliers], xb[inliers])
    return RelativePose(R=R, t=t, inliers=inliers)


def camera_from_relative_pose(
    reference: Camera,
    pose: RelativePose,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    baseline: float = 1.0,
) -> Camera:
    """Place camera b in the world frame of a reference camera a, given their relative pose.

    With ``x_a = R_a (X - c_a)`` and ``x_b = R x_a + baseline * t``:
    ``R_b = R R_a`` and ``c_b = c_a - baseline * R_b^T t``, so ``||c_b - c_a|| = baseline``.
    This is the paper's chaining of the mobile camera's relative pose with the PnP pose of
    the static one (Section IV-A).

    Args:
        reference: camera a, in world coordinates.
        pose: pose of camera b relative to camera a (from :func:`estimate_relative_pose`).
        K: (3, 3) intrinsics of camera b.
        width, height: image size of camera b.
        baseline: distance between the camera centres in world units. The default 1.0 gives a
            camera only correct up to scale: ray directions and cheirality with ``margin=0``
            are valid, metric distances (Eq. 6) and the 0.5 m margin of Eq. 7 are not.

    Returns:
        Camera b.
    """
    if not isinstance(reference, Camera):
        raise TypeError(f"reference must be a Camera, got {type(reference)}")
    if not np.isfinite(baseline) or baseline <= 0:
        raise PoseEstimationError(f"baseline must be a finite distance > 0, got {baseline}")
    K = _check_K(K, "K")
    t = np.asarray(pose.t, dtype=float).reshape(3)
    if not np.linalg.norm(t) > 0:
        raise PoseEstimationError("pose.t must be a non-zero translation direction")
    R_b = np.asarray(pose.R, dtype=float) @ reference.R
    c_b = reference.c - baseline * R_b.T @ (t / np.linalg.norm(t))
    return Camera(K=K, R=R_b, c=c_b, width=width, height=height)
