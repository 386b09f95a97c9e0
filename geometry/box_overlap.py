"""Overlap of axis-aligned boxes: the one intersection-over-union of the package (detections
against ground truth, tracklet linking, track metrics)."""

from __future__ import annotations

import numpy as np

from xvmatch.core.array_checks import as_boxes

__all__ = ["box_iou"]


def box_iou(boxes_a: np.ndarray, boxes_b: np.ndarray) -> np.ndarray:
    """Pairwise intersection over union of ``(x, y, w, h)`` boxes.

    Args:
        boxes_a: (M, 4) boxes.
        boxes_b: (N, 4) boxes.

    Returns:
        (M, N) IoU in [0, 1]; 0 where the union is empty (two zero-area boxes).
    """
    a = as_boxes(boxes_a, "boxes_a")
    b = as_boxes(boxes_b, "boxes_b")
    ax1, ay1 = a[:, 0] + a[:, 2], a[:, 1] + a[:, 3]
    bx1, by1 = b[:, 0] + b[:, 2], b[:, 1] + b[:, 3]
    iw = np.minimum(ax1[:, None], bx1[None, :]) - np.maximum(a[:, None, 0], b[None, :, 0])
    ih = np.minimum(ay1[:, None], by1[None, :]) - np.maximum(a[:, None, 1], b[None, :, 1])
    inter = np.clip(iw, 0, None) * np.clip(ih, 0, None)
    union = (a[:, 2] * a[:, 3])[:, None] + (b[:, 2] * b[:, 3])[None, :] - inter
    return np.divide(inter, union, out=np.zeros_like(inter), where=union > 0)
