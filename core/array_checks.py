"""The one place that validates user arrays at public entry points, with actionable messages."""

from __future__ import annotations

import numpy as np

__all__ = ["as_boxes", "as_points"]


def as_boxes(boxes: np.ndarray, name: str = "boxes_xywh") -> np.ndarray:
    """Validate boxes as a float ``(N, 4)`` array of ``(x, y, w, h)``; an empty input gives (0, 4).

    Raises:
        ValueError: wrong shape, NaN/inf, or a negative width or height.
    """
    arr = np.asarray(boxes, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, 4)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{name} must have shape (N, 4) as (x, y, w, h), got {arr.shape}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf; drop or fix those detections first")
    if (arr[:, 2:] < 0).any():
        raise ValueError(f"{name} has a negative width or height; boxes are (x, y, w, h)")
    return arr


def as_points(points: np.ndarray, dim: int, name: str, finite: bool = False) -> np.ndarray:
    """Validate a float ``(..., dim)`` array (``finite``: also reject NaN/inf)."""
    arr = np.asarray(points, dtype=float)
    if arr.ndim == 1 and arr.size == 0:
        arr = arr.reshape(0, dim)
    if arr.ndim == 0 or arr.shape[-1] != dim:
        raise ValueError(f"{name} must have shape (..., {dim}), got {arr.shape}")
    if finite and not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN or inf")
    return arr
