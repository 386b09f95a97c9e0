"""The handcrafted cues of the geometric-priors paper between the boxes of one image pair.

Raw cues (Section III of Ruiz-Ponce et al.): the HSV colour histogram distance (Eq. 3), the
distance between the projection rays of the box top-centres (Eqs. 4-6) and the cheirality cost
(Eq. 7); :meth:`PairCosts.normalised` squashes the first two into [0, 1] (Section III-C). Used
by the handcrafted baseline, the learned matcher's camera cues and their trials.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from xvmatch.core.array_checks import as_boxes
from xvmatch.cues.color_histogram import box_histograms, chi2_brd_distance
from xvmatch.cues.cost_fusion import normalise_distance
from xvmatch.cues.matcher_inputs import camera_cues
from xvmatch.geometry.camera import Camera, FrameCameras
from xvmatch.geometry.ray_priors import DEFAULT_BETA, METRIC_MARGIN

__all__ = ["PairCosts", "pair_costs"]


@dataclass(frozen=True, eq=False)
class PairCosts:
    """Raw cues between the M top-view boxes (rows) and N egocentric boxes (columns).

    Attributes:
        geo: (M, N) ray distances of Eq. 6 between the top-centre rays, world units (metres).
        hist: (M, N) chi-square BRD distances of Eq. 3 between the HSV histograms.
        hist_valid: (M, N) bool, False where either crop is empty (box outside its image).
        cheirality: (M, N) cost of Eq. 7: 0 where the constraint holds, ``beta`` elsewhere.
    """

    geo: np.ndarray
    hist: np.ndarray
    hist_valid: np.ndarray
    cheirality: np.ndarray

    @property
    def shape(self) -> tuple[int, int]:
        """(M, N)."""
        return self.geo.shape  # type: ignore[return-value]

    def normalised(self) -> dict[str, np.ndarray]:
        """``{"geo": tanh(d_geo), "hist": tanh(d_hist)}`` (Section III-C), each (M, N) in [0, 1].

        Pairs without appearance evidence (``hist_valid`` False) get ``d'_hist = 1``.
        """
        return {
            "geo": normalise_distance(self.geo),
            "hist": np.where(self.hist_valid, normalise_distance(self.hist), 1.0),
        }


def _check_image(image: np.ndarray, camera: Camera, name: str) -> None:
    shape = np.shape(image)
    if len(shape) != 3 or shape[2] != 3:
        raise ValueError(f"{name} must be an (H, W, 3) BGR image, got shape {shape}")
    if (shape[1], shape[0]) != camera.image_size:
        raise ValueError(
            f"{name} is {shape[1]}x{shape[0]} but its camera is "
            f"{camera.width}x{camera.height}; pass the image the camera was calibrated for"
        )


def pair_costs(
    top_camera: Camera,
    ego_camera: Camera,
    top_image: np.ndarray,
    ego_image: np.ndarray,
    top_boxes: np.ndarray,
    ego_boxes: np.ndarray,
    *,
    margin: float = METRIC_MARGIN,
    beta: float = DEFAULT_BETA,
) -> PairCosts:
    """Compute the raw cues of one image pair (Eqs. 3, 6 and 7).

    Args:
        top_camera: calibrated top/overview camera.
        ego_camera: calibrated egocentric camera.
        top_image: (H, W, 3) uint8 BGR top image, of ``top_camera``'s size.
        ego_image: (H', W', 3) uint8 BGR egocentric image, of ``ego_camera``'s size.
        top_boxes: (M, 4) ``(x, y, w, h)`` boxes in the top image (may run past its border).
        ego_boxes: (N, 4) boxes in the egocentric image.
        margin: depth margin of Eq. 7.
        beta: cost of violating Eq. 7.

    Returns:
        The :class:`PairCosts`; every matrix is finite (never NaN), also for empty crops,
        coincident camera centres or parallel rays.

    Raises:
        TypeError: a camera that is not a :class:`~xvmatch.geometry.camera.Camera`.
        ValueError: malformed boxes or images, an image that does not match its camera.
    """
    for cam, name in ((top_camera, "top_camera"), (ego_camera, "ego_camera")):
        if not isinstance(cam, Camera):
            raise TypeError(f"{name} must be a xvmatch.geometry.camera.Camera, got {type(cam)}")
    top_boxes = as_boxes(top_boxes, "top_boxes")
    ego_boxes = as_boxes(ego_boxes, "ego_boxes")
    _check_image(top_image, top_camera, "top_image")
    _check_image(ego_image, ego_camera, "ego_image")
    top_hist = box_histograms(top_image, top_boxes)
    ego_hist = box_histograms(ego_image, ego_boxes)
    geo, cheirality = camera_cues(FrameCameras(top_camera, ego_camera), top_boxes, ego_boxes,
                                  margin=margin, beta=beta)
    return PairCosts(
        geo=geo,
        hist=chi2_brd_distance(top_hist.histograms, ego_hist.histograms),
        hist_valid=top_hist.valid[:, None] & ego_hist.valid[None, :],
        cheirality=cheirality,
    )
