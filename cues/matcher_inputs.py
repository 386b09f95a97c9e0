"""The learned matcher's inputs for one frame pair, computed in numpy outside the ONNX graphs.

* Geometry features (:func:`matcher_features`): the spatial-distribution features of
  :mod:`xvmatch.cues.spatial_features`; with calibrated cameras, of the boxes mapped to the
  ideal setting first (:mod:`xvmatch.geometry.view_rectification`, CVMHAT paper Sec. 5.1), and
  with the camera location O taken as the top-view person nearest the horizontal camera when one
  stands within :data:`WEARER_RADIUS` of it ("O given").
* Pair cues (:func:`frame_cues`), each ``(M, N)`` in [0, 1], in the order of
  :data:`~xvmatch.models.cross_view_matcher.CUES`: the appearance cost of two unit descriptors
  (:func:`appearance_cost`), and with cameras ``tanh`` of the ray distance of the boxes'
  top-centre rays (Eqs. 4-6 of the geometric-priors paper) and the cheirality failure (Eq. 7)
  (:func:`camera_cues`). A missing cue is zeros with its mask entry False.

Everything is given and returned in the input order of the boxes; :func:`canonical_cues` puts
cue matrices in the canonical order of a frame's features.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xvmatch.core.array_checks import as_boxes
from xvmatch.cues.cost_fusion import normalise_distance
from xvmatch.cues.spatial_features import (
    FeatureConfig,
    FrameFeatures,
    collate_frames,
    frame_features,
)
from xvmatch.geometry.camera import FrameCameras
from xvmatch.geometry.ray_priors import (
    DEFAULT_BETA,
    METRIC_MARGIN,
    box_rays,
    cheirality_cost,
    ray_distances,
)
from xvmatch.geometry.view_rectification import (
    NADIR_SCALE,
    ground_plane_boxes,
    level_horizontal_boxes,
)

__all__ = [
    "CUE_NAMES",
    "INPUT_SETTINGS",
    "WEARER_RADIUS",
    "MatcherInputs",
    "appearance_cost",
    "camera_cues",
    "canonical_cues",
    "collate_inputs",
    "frame_cues",
    "matcher_features",
    "matcher_inputs",
    "rectified_boxes",
    "wearer_row",
]

CUE_NAMES: tuple[str, ...] = ("app", "ray", "cheir")
"""Pair cues of the learned matcher, in input order (the same names as
:data:`xvmatch.models.cross_view_matcher.CUES`, which a test checks)."""

INPUT_SETTINGS: dict[str, tuple[tuple[str, ...], bool]] = {
    "boxes": ((), False),
    "images": (("app",), False),
    "cameras": (("ray", "cheir"), True),
    "images+cameras": (("app", "ray", "cheir"), True),
}
"""The input settings of the deployed matcher: the cues a frame has, and whether its geometry
is rectified by the cameras."""

WEARER_RADIUS: float = 1.0
"""A top-view person whose ground position lies within this many metres of the horizontal
camera's is taken as its carrier, the camera location O (hand-held cameras are held up to about
half a metre in front of the body)."""


def wearer_row(cameras: FrameCameras, top_boxes: np.ndarray,
               radius: float = WEARER_RADIUS) -> int | None:
    """Row of the top-view box that carries the horizontal camera, or None when no box's
    ground position (:func:`~xvmatch.geometry.view_rectification.ground_plane_boxes`) lies
    within ``radius`` metres of the camera centre (ties: the lowest row)."""
    boxes = ground_plane_boxes(cameras.top, top_boxes)
    if boxes.shape[0] == 0:
        return None
    centres = (boxes[:, :2] + 0.5 * boxes[:, 2:]) / NADIR_SCALE
    ground = np.array([cameras.hor.c[0], -cameras.hor.c[1]])
    dist = np.hypot(*(centres - ground).T)
    row = int(np.argmin(dist))
    return row if dist[row] <= radius else None


def rectified_boxes(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    cameras: FrameCameras,
    camera: int | None = None,
) -> tuple[np.ndarray, np.ndarray, int | None]:
    """Both views' boxes mapped to the ideal setting (CVMHAT paper Sec. 5.1,
    :mod:`xvmatch.geometry.view_rectification`), and the camera row: ``camera`` when given,
    else :func:`wearer_row`."""
    if camera is None:
        camera = wearer_row(cameras, top_boxes)
    return (ground_plane_boxes(cameras.top, top_boxes),
            level_horizontal_boxes(cameras.hor, hor_boxes), camera)


def matcher_features(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_size: tuple[float, float],
    config: FeatureConfig,
    camera: int | None = None,
    cameras: FrameCameras | None = None,
) -> FrameFeatures:
    """Geometry features of one frame pair, rectified when the cameras are known.

    Args:
        top_boxes, hor_boxes: ``(M, 4)``, ``(N, 4)`` x, y, w, h boxes in their images.
        hor_size: (width, height) of the horizontal image.
        config: hypothesis generation.
        camera: input row of the top box that is O when the user names it; None searches O
            (or, with cameras, takes :func:`wearer_row`).
        cameras: calibrated cameras, or None.

    Returns:
        :class:`~xvmatch.cues.spatial_features.FrameFeatures` (rows in canonical order).
    """
    if cameras is not None:
        top_boxes, hor_boxes, camera = rectified_boxes(top_boxes, hor_boxes, cameras, camera)
    return frame_features(top_boxes, hor_boxes, hor_size, config, camera)


def appearance_cost(top: np.ndarray, hor: np.ndarray) -> np.ndarray:
    """``(M, N)`` appearance cost ``|a - b| / 2`` in [0, 1] of unit descriptors ``(M, D)`` and
    ``(N, D)`` (the distance the Siamese branch is trained on, CVMHAT paper Sec. 3.3.2)."""
    top = np.asarray(top, dtype=np.float64)
    hor = np.asarray(hor, dtype=np.float64)
    cosine = top @ hor.T
    return np.clip(0.5 * np.sqrt(np.clip(2.0 - 2.0 * cosine, 0.0, None)), 0.0, 1.0)


def camera_cues(
    cameras: FrameCameras,
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    margin: float = METRIC_MARGIN,
    beta: float = DEFAULT_BETA,
) -> tuple[np.ndarray, np.ndarray]:
    """Raw camera cues between the boxes: ``(M, N)`` ray distances of the top-centre rays in
    metres (Eq. 6) and the cheirality cost, 0 or ``beta`` (Eq. 7 with depth ``margin``)."""
    rays_top = box_rays(cameras.top, as_boxes(top_boxes, "top_boxes"))
    rays_hor = box_rays(cameras.hor, as_boxes(hor_boxes, "hor_boxes"))
    return (ray_distances(rays_top, rays_hor),
            cheirality_cost(rays_top, rays_hor, margin=margin, beta=beta))


def frame_cues(
    shape: tuple[int, int],
    names: tuple[str, ...] = CUE_NAMES,
    app: np.ndarray | None = None,
    ray_distance: np.ndarray | None = None,
    cheirality: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The pair cues of a frame as the matcher takes them.

    Args:
        shape: (M, N).
        names: the cues the matcher takes, a subset of :data:`CUE_NAMES` in that order.
        app: ``(M, N)`` appearance cost in [0, 1], or None.
        ray_distance: ``(M, N)`` ray distances in metres (normalised here by ``tanh``,
            Section III-C of the geometric-priors paper), or None.
        cheirality: ``(M, N)`` cheirality cost (> 0 where Eq. 7 fails), or None.

    Returns:
        ``(cues (M, N, K) float32, mask (K,) bool)``; unavailable cues are zeros.
    """
    m, n = (int(v) for v in shape)
    values = {
        "app": None if app is None else np.asarray(app, dtype=np.float64),
        "ray": None if ray_distance is None else normalise_distance(ray_distance),
        "cheir": None if cheirality is None else (np.asarray(cheirality) > 0).astype(float),
    }
    cues = np.zeros((m, n, len(names)), np.float32)
    mask = np.zeros(len(names), bool)
    for k, name in enumerate(names):
        if name not in values:
            raise ValueError(f"unknown cue {name!r}; the matcher's cues are {CUE_NAMES}")
        v = values[name]
        if v is None:
            continue
        if v.shape != (m, n):
            raise ValueError(f"cue {name!r} has shape {v.shape}, expected {(m, n)}")
        cues[..., k] = np.clip(v, 0.0, 1.0)
        mask[k] = True
    return cues, mask


def canonical_cues(cues: np.ndarray, features: FrameFeatures) -> np.ndarray:
    """``(M, N, K)`` input-order cues in the canonical row and column order of ``features``."""
    return cues[features.top_order][:, features.hor_order]


@dataclass(frozen=True, eq=False)
class MatcherInputs:
    """Everything the matcher graph takes for one frame pair (rows in canonical order).

    Attributes:
        features: the geometry features.
        cues: ``(M, N, K)`` float32 pair cues in canonical order.
        cue_mask: ``(K,)`` bool, the cues this frame has.
    """

    features: FrameFeatures
    cues: np.ndarray
    cue_mask: np.ndarray


def matcher_inputs(
    top_boxes: np.ndarray,
    hor_boxes: np.ndarray,
    hor_size: tuple[float, float],
    config: FeatureConfig,
    names: tuple[str, ...] = CUE_NAMES,
    *,
    camera: int | None = None,
    cameras: FrameCameras | None = None,
    app: np.ndarray | None = None,
    margin: float = METRIC_MARGIN,
    beta: float = DEFAULT_BETA,
) -> MatcherInputs:
    """Features and cues of one frame pair in whichever input setting it comes: boxes only,
    with images (``app``, the appearance cost in input order), with cameras, or both.

    Args:
        top_boxes, hor_boxes, hor_size, config, camera, cameras: as in
            :func:`matcher_features`.
        names: the cues the matcher takes.
        app: ``(M, N)`` appearance costs (:func:`appearance_cost`), or None without images.
        margin, beta: the cheirality test's depth margin and cost (Eq. 7).
    """
    features = matcher_features(top_boxes, hor_boxes, hor_size, config, camera, cameras)
    ray = cheir = None
    if cameras is not None and ("ray" in names or "cheir" in names):
        ray, cheir = camera_cues(cameras, top_boxes, hor_boxes, margin, beta)
    m, n = features.top.shape[0], features.hor.shape[0]
    cues, mask = frame_cues((m, n), names, app=app, ray_distance=ray, cheirality=cheir)
    return MatcherInputs(features, canonical_cues(cues, features), mask)


def collate_inputs(frames: list[MatcherInputs], n_hypotheses: int | None = None
                   ) -> dict[str, np.ndarray]:
    """Pad a batch of frames with masks: the arrays of
    :func:`~xvmatch.cues.spatial_features.collate_frames` plus ``cues (B, M, N, K)``
    float32 (zero padding) and ``cue_mask (B, K)`` bool."""
    batch = collate_frames([f.features for f in frames], n_hypotheses)
    b, m, n = len(frames), batch["top"].shape[1], batch["hor"].shape[1]
    k = frames[0].cue_mask.shape[0] if frames else 0
    cues = np.zeros((b, m, n, k), np.float32)
    mask = np.zeros((b, k), bool)
    for i, f in enumerate(frames):
        mm, nn_ = f.cues.shape[:2]
        cues[i, :mm, :nn_] = f.cues
        mask[i] = f.cue_mask
    batch["cues"], batch["cue_mask"] = cues, mask
    return batch
