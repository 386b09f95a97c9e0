"""A simulated change of camera: the real-photo gap as a stress test and a training corruption.

:func:`camera_shift` passes a BGR image through another camera's colour and sensor chain (white
balance, exposure, tone curve, hue and saturation, blur, sensor noise, JPEG), with a strength in
[0, 3]: 1 is stronger than the appearance training's augmentation, 3 is a camera that barely
keeps colours. Two draws:

* ``per_image=True`` (the stress test of ``benchmarks/deployed_matcher_eval.py --shift``): the
  parameters are drawn from ``seed`` and the image's own bytes, so every image gets its own
  camera but the same image always gets the same picture;
* ``per_image=False`` (a site's camera): the parameters come from ``seed`` alone, so every frame
  of one view goes through the same camera, as a user's video does; only the sensor noise
  differs frame to frame (drawn from the bytes). This is the case site adaptation
  (``xvmatch adapt``) can learn to undo.
"""

from __future__ import annotations

import zlib

import cv2
import numpy as np

__all__ = ["MAX_STRENGTH", "camera_shift"]

MAX_STRENGTH = 3.0
"""The strongest shift the stress test runs."""


def camera_shift(image: np.ndarray, strength: float, seed: int = 0,
                 per_image: bool = True) -> np.ndarray:
    """A ``(H, W, 3)`` uint8 BGR image as another camera might record it.

    Args:
        image: the picture.
        strength: in [0, 3]; 0 returns the image unchanged.
        seed: which camera (with ``per_image``, mixed with the image's bytes).
        per_image: draw the camera from the image's bytes too (True), or from ``seed`` alone
            (False: one camera for a whole view; only the sensor noise changes per image).
    """
    image = np.ascontiguousarray(image)
    if image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise ValueError(f"image must be (H, W, 3) uint8, got {image.shape} {image.dtype}")
    s = float(strength)
    if not 0.0 <= s <= MAX_STRENGTH:
        raise ValueError(f"strength must be in [0, {MAX_STRENGTH:g}], got {strength}")
    if s == 0.0:
        return image
    crc = zlib.crc32(image.tobytes())
    rng = np.random.default_rng([seed, crc] if per_image else [seed])
    levels = np.arange(256, dtype=np.float64)[:, None] / 255.0
    gains = np.exp(rng.normal(0.0, 0.2 * s, 3) + rng.normal(0.0, 0.4 * s))  # white balance
    tone = np.clip(levels * gains, 0.0, 1.0) ** np.exp(rng.normal(0.0, 0.25 * s))  # exposure
    x = cv2.LUT(image, np.round(255.0 * tone).astype(np.uint8).reshape(256, 1, 3))
    hsv = cv2.cvtColor(x, cv2.COLOR_BGR2HSV)  # uint8 hue in [0, 180)
    hue = np.round(rng.normal(0.0, 6.0 * s)).astype(np.int16)
    hsv[..., 0] = ((hsv[..., 0].astype(np.int16) + hue) % 180).astype(np.uint8)
    saturation = np.clip(levels[:, 0] * 255.0 * np.exp(rng.normal(0.0, 0.35 * s)), 0, 255)
    hsv[..., 1] = cv2.LUT(hsv[..., 1], np.round(saturation).astype(np.uint8))
    x = cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)
    sigma = rng.uniform(0.0, 2.0 * s)
    if sigma > 0.3:
        x = cv2.GaussianBlur(x, (0, 0), sigma)
    noise_rng = rng if per_image else np.random.default_rng([seed, crc])
    noise = noise_rng.standard_normal(x.shape, dtype=np.float32)
    noise *= 255.0 * rng.uniform(0.0, 0.03 * s)
    x = np.clip(x + noise, 0, 255).astype(np.uint8)
    # Up to strength 1 as the first stress test drew it; beyond, down to quality 5.
    quality = round(95 - 70 * min(s, 1.0) * float(rng.uniform(0.5, 1.0)) - 10 * max(s - 1.0, 0))
    ok, buf = cv2.imencode(".jpg", x, [cv2.IMWRITE_JPEG_QUALITY, max(5, quality)])
    return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED) if ok else x
