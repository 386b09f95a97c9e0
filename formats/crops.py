"""Person crops cut from images: the appearance branch's input, the same in training, evaluation
and the ONNX runtime (numpy + OpenCV)."""

from __future__ import annotations

import numpy as np

__all__ = ["box_crops"]


def box_crops(
    image: np.ndarray, boxes: np.ndarray, size: tuple[int, int], context: float = 0.1
) -> np.ndarray:
    """Crops of ``(x, y, w, h)`` boxes, each enlarged by ``context`` of its size on every side
    and resized to one size; parts outside the image are filled by replicating the border.

    Args:
        image: ``(H, W, 3)`` uint8 image.
        boxes: ``(K, 4)`` boxes in pixels; they may run past the image.
        size: ``(width, height)`` of the crops.
        context: relative margin around each box.

    Returns:
        ``(K, size[1], size[0], 3)`` uint8 crops (shrunk with area interpolation, enlarged
        bilinearly).
    """
    import cv2

    width, height = int(size[0]), int(size[1])
    if width < 1 or height < 1:
        raise ValueError(f"size must be (width, height) >= 1, got {size}")
    boxes = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    crops = np.empty((boxes.shape[0], height, width, 3), np.uint8)
    img_h, img_w = image.shape[:2]
    for k, (x, y, w, h) in enumerate(boxes):
        x0, y0 = int(np.floor(x - context * w)), int(np.floor(y - context * h))
        x1, y1 = int(np.ceil(x + w + context * w)), int(np.ceil(y + h + context * h))
        x1, y1 = max(x1, x0 + 1), max(y1, y0 + 1)
        patch = image[max(y0, 0) : min(y1, img_h), max(x0, 0) : min(x1, img_w)]
        if patch.size == 0:
            patch = np.zeros((1, 1, 3), np.uint8)
        pad = (max(-y0, 0), max(y1 - img_h, 0), max(-x0, 0), max(x1 - img_w, 0))
        if any(pad):
            patch = cv2.copyMakeBorder(patch, *pad, cv2.BORDER_REPLICATE)
        shrink = patch.shape[1] > width and patch.shape[0] > height
        crops[k] = cv2.resize(patch, (width, height),
                              interpolation=cv2.INTER_AREA if shrink else cv2.INTER_LINEAR)
    return crops
