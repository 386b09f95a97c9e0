"""HSV colour histograms of person boxes and the histogram distances of the Hist baseline.

Section IV-A of the geometric-priors paper describes the handcrafted appearance cue ("Hist"):
each bounding box is described by a 32-bin HSV colour histogram (8 bins for H, 2 for S, 2 for V),
L2-normalised, and two boxes are compared with the chi-square bin-ratio distance of Eq. 3.
Histogram intersection is provided as a common, parameter-free alternative.

Colours follow OpenCV's 8-bit HSV convention: H in [0, 180), S and V in [0, 256).
"""

from __future__ import annotations

from typing import NamedTuple

import cv2
import numpy as np

from xvmatch.core.array_checks import as_boxes

__all__ = [
    "HSV_BINS",
    "N_BINS",
    "BoxHistograms",
    "box_histograms",
    "chi2_brd_distance",
    "histogram_intersection",
    "hsv_bin_indices",
]

HSV_BINS: tuple[int, int, int] = (8, 2, 2)
"""Bins per channel (H, S, V), Section IV-A of the paper."""

N_BINS: int = HSV_BINS[0] * HSV_BINS[1] * HSV_BINS[2]
"""Length of one histogram (32)."""

_HSV_RANGES: tuple[int, int, int] = (180, 256, 256)  # OpenCV 8-bit: H in [0, 180), S, V in [0, 256)
_CHUNK_PIXELS = 1 << 22  # pixels gathered per bincount (~200 MB of temporaries at most)


class BoxHistograms(NamedTuple):
    """Histograms of N boxes and which of them saw any pixel.

    Attributes:
        histograms: (N, 32) float, each row L2-normalised; all zeros where ``valid`` is False.
        valid: (N,) bool, False for a box whose crop is empty after clipping to the image
            (zero width or height, or entirely outside the image).
    """

    histograms: np.ndarray
    valid: np.ndarray


def _check_image(image_bgr: np.ndarray) -> np.ndarray:
    image = np.asarray(image_bgr)
    if image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image_bgr must have shape (H, W, 3), got {image.shape}")
    if image.dtype != np.uint8:
        raise ValueError(
            f"image_bgr must be uint8 (OpenCV 8-bit BGR), got {image.dtype}; "
            "convert with np.clip(img, 0, 255).astype(np.uint8)"
        )
    return image


def _check_histograms(hist: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(hist, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 0)
    if arr.ndim != 2:
        raise ValueError(f"{name} must have shape (count, bins), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf")
    if (arr < 0).any():
        raise ValueError(f"{name} has negative bins; histograms are counts or their normalisation")
    return arr


def _check_pair(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    a = _check_histograms(a, "a")
    b = _check_histograms(b, "b")
    if a.shape[0] and b.shape[0] and a.shape[1] != b.shape[1]:
        raise ValueError(f"a and b must have the same number of bins, got {a.shape} and {b.shape}")
    return a, b


def hsv_bin_indices(image_bgr: np.ndarray) -> np.ndarray:
    """Histogram bin of every pixel of an 8-bit BGR image.

    Bin ``k = (h * 8 // 180) * 4 + (s * 2 // 256) * 2 + (v * 2 // 256)`` for OpenCV HSV values
    (Section IV-A: 8 x 2 x 2 bins).

    Args:
        image_bgr: (H, W, 3) uint8 BGR image.

    Returns:
        (H, W) int64 bin indices in [0, 32).

    Raises:
        ValueError: image not (H, W, 3) uint8.
    """
    image = _check_image(image_bgr)
    hsv = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_BGR2HSV)
    n_h, n_s, n_v = HSV_BINS
    r_h, r_s, r_v = _HSV_RANGES
    # uint16 arithmetic: 255 * 8 fits; min() guards any H outside [0, 180).
    h = np.minimum(hsv[..., 0].astype(np.uint16) * n_h // r_h, n_h - 1)
    s = hsv[..., 1].astype(np.uint16) * n_s // r_s
    v = hsv[..., 2].astype(np.uint16) * n_v // r_v
    return ((h * n_s + s) * n_v + v).astype(np.int64)


def _count_bins(
    bins_img: np.ndarray, x0: np.ndarray, y0: np.ndarray, crop_w: np.ndarray, area: np.ndarray
) -> np.ndarray:
    """Bin counts (n, 32) of n crops, gathered into one ``np.bincount`` without a Python loop.

    Pixel p of crop b lies at row ``y0 + p // w``, column ``x0 + p % w``; empty crops add none.
    """
    n = x0.shape[0]
    total = int(area.sum())
    box_of_pixel = np.repeat(np.arange(n), area)
    local = np.arange(total) - np.repeat(np.cumsum(area) - area, area)
    w_of_pixel = np.repeat(np.maximum(crop_w, 1), area)
    rows = np.repeat(y0, area) + local // w_of_pixel
    cols = np.repeat(x0, area) + local % w_of_pixel
    flat = box_of_pixel * N_BINS + bins_img[rows, cols]
    return np.bincount(flat, minlength=n * N_BINS).reshape(n, N_BINS).astype(float)


def box_histograms(image_bgr: np.ndarray, boxes_xywh: np.ndarray) -> BoxHistograms:
    """L2-normalised 8x2x2 HSV histograms of the crops of N boxes (Section IV-A, "Hist").

    A box covers the pixel columns ``floor(x) .. ceil(x + w) - 1`` and rows
    ``floor(y) .. ceil(y + h) - 1``, clipped to the image, so every partly covered pixel counts;
    a box with ``w == 0`` or ``h == 0`` covers no pixel.
    The pixels of all boxes are gathered and counted by one ``np.bincount`` (in chunks of
    about 4 M pixels, to bound memory on large frames).

    Args:
        image_bgr: (H, W, 3) uint8 BGR image (OpenCV order).
        boxes_xywh: (N, 4) boxes ``(x, y, w, h)`` in pixels; ``w, h >= 0``.

    Returns:
        ``BoxHistograms(histograms (N, 32), valid (N,))``. A box with an empty crop after
        clipping (zero area, or fully outside the image) gets an all-zero histogram and
        ``valid = False``; it is never NaN. Callers should not trust appearance costs of
        invalid boxes (e.g. set them to the non-association cost).

    Raises:
        ValueError: wrong image shape or dtype, boxes not (N, 4), non-finite or negative sizes.
    """
    image = _check_image(image_bgr)
    boxes = as_boxes(boxes_xywh)
    height, width = image.shape[:2]
    n = boxes.shape[0]

    x0 = np.clip(np.floor(boxes[:, 0]), 0, width).astype(np.int64)
    y0 = np.clip(np.floor(boxes[:, 1]), 0, height).astype(np.int64)
    x1 = np.clip(np.ceil(boxes[:, 0] + boxes[:, 2]), 0, width).astype(np.int64)
    y1 = np.clip(np.ceil(boxes[:, 1] + boxes[:, 3]), 0, height).astype(np.int64)
    degenerate = (boxes[:, 2] == 0) | (boxes[:, 3] == 0)  # a zero-size box covers no pixel
    x1 = np.where(degenerate, x0, x1)
    crop_w = np.maximum(x1 - x0, 0)
    crop_h = np.maximum(y1 - y0, 0)
    area = crop_w * crop_h
    valid = area > 0
    if not valid.any():
        return BoxHistograms(histograms=np.zeros((n, N_BINS)), valid=valid)

    # Convert only the region covering every crop, and index it from its corner.
    left, top = int(x0[valid].min()), int(y0[valid].min())
    right, bottom = int(x1[valid].max()), int(y1[valid].max())
    bins_img = hsv_bin_indices(image[top:bottom, left:right])
    x0, y0 = x0 - left, y0 - top

    counts = np.zeros((n, N_BINS))
    ends = np.cumsum(area)
    start = 0
    while start < n:  # boxes in chunks of <= _CHUNK_PIXELS pixels bound the memory used
        done = ends[start - 1] if start else 0
        stop = max(start + 1, int(np.searchsorted(ends, done + _CHUNK_PIXELS, side="right")))
        sl = slice(start, stop)
        counts[sl] = _count_bins(bins_img, x0[sl], y0[sl], crop_w[sl], area[sl])
        start = stop

    norms = np.linalg.norm(counts, axis=1, keepdims=True)
    hist = np.divide(counts, norms, out=np.zeros_like(counts), where=norms > 0)
    return BoxHistograms(histograms=hist, valid=valid)


def chi2_brd_distance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise chi-square bin-ratio distance, Eq. 3 of the geometric-priors paper.

    For L2-normalised histograms ``h^i, h^j`` with n bins (Eq. 3, after [11] Xie et al.)::

        d_hist = d_chi2 - 1/2 * ||h^i + h^j||_2^2 * sum_k (h^i_k - h^j_k)^2 h^i_k h^j_k
                                                       / (h^i_k + h^j_k)^3
        d_chi2 = 1/2 * sum_k (h^i_k - h^j_k)^2 / (h^i_k + h^j_k)

    The paper's typeset ``d_chi2`` shows ``h^j_k + h^j_k`` in its denominator; that is a typo:
    the distance of [11], whose bin-ratio derivation gives the correction term above, uses
    ``h^i_k + h^j_k``, which is also the only symmetric choice. Equivalently, per bin,
    ``1/2 (h^i_k - h^j_k)^2 / (h^i_k + h^j_k)^3 * sum_l (h^i_l h^j_k - h^i_k h^j_l)^2``, which
    shows the distance is >= 0 for unit-norm inputs (round-off below zero is clipped).

    Bins empty in both histograms (0/0) contribute 0. An all-zero histogram (an invalid crop)
    gives ``1/2 * sum_k h_k`` against any other histogram h, never NaN.

    Args:
        a: (M, B) L2-normalised, non-negative histograms.
        b: (N, B) L2-normalised, non-negative histograms.

    Returns:
        (M, N) distances in [0, sqrt(B)].
    """
    a, b = _check_pair(a, b)
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros((a.shape[0], b.shape[0]))
    hi = a[:, None, :]
    hj = b[None, :, :]
    total = hi + hj
    diff2 = (hi - hj) ** 2
    nonzero = total > 0
    safe = np.where(nonzero, total, 1.0)
    chi2_terms = np.where(nonzero, diff2 / safe, 0.0)
    # (h^i - h^j)^2 h^i h^j / (h^i + h^j)^3 as chi2_term * (h^i / total) * (h^j / total): the
    # two ratios are in [0, 1], so tiny bins cannot underflow total^3 into a 0/0.
    ratio_terms = chi2_terms * np.where(nonzero, hi / safe, 0.0) * np.where(nonzero, hj / safe, 0.0)
    sum_norm2 = np.sum(total**2, axis=-1)
    d = 0.5 * chi2_terms.sum(axis=-1) - 0.5 * sum_norm2 * ratio_terms.sum(axis=-1)
    return np.maximum(d, 0.0)


def histogram_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise normalised histogram intersection (a similarity), after Swain and Ballard.

    ``s_ij = sum_k min(a_ik, b_jk) / min(sum_k a_ik, sum_k b_jk)``, in [0, 1], equal to 1 for
    identical histograms. Dividing by the smaller mass keeps it symmetric and scale-free for
    L2-normalised inputs. Where either histogram is all zero (0/0) the similarity is 0.
    Use ``1 - s`` as a distance in [0, 1].

    Args:
        a: (M, B) non-negative histograms.
        b: (N, B) non-negative histograms.

    Returns:
        (M, N) similarities in [0, 1].
    """
    a, b = _check_pair(a, b)
    if a.shape[0] == 0 or b.shape[0] == 0:
        return np.zeros((a.shape[0], b.shape[0]))
    overlap = np.minimum(a[:, None, :], b[None, :, :]).sum(axis=-1)
    mass = np.minimum(a.sum(axis=1)[:, None], b.sum(axis=1)[None, :])
    s = np.divide(overlap, mass, out=np.zeros_like(overlap), where=mass > 0)
    return np.clip(s, 0.0, 1.0)
