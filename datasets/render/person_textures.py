"""Photographic textures on the rendered people, from permissively licensed images in a wheel.

The renderer's people wear flat colours; real clothing has weave, folds and prints, which an
appearance network trained on flat colours never saw (issue 31, item 3). This module lays real
photographic texture over each rendered person: the luminance of an image that ships inside the
scikit-image wheel (:data:`TEXTURE_SOURCES`, each CC0 or public domain, named with its
licence), sampled at a scale tied to the person's height in that view, so that a person keeps
one texture, at one body-relative scale, in every view and frame. Only the image files are read
(OpenCV), scikit-image is never imported, so ``pip install --no-deps scikit-image`` suffices
(``make test`` does).
"""

from __future__ import annotations

import functools
import importlib.util
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

__all__ = [
    "TEXTURE_PACKAGE",
    "TEXTURE_SIZE",
    "TEXTURE_SOURCES",
    "PersonTextures",
    "apply_person_textures",
    "draw_person_textures",
    "load_textures",
]

TEXTURE_PACKAGE = "skimage"
"""The installed package whose ``data/`` folder holds the images (the scikit-image wheel)."""

TEXTURE_SOURCES: tuple[tuple[str, str], ...] = (
    ("brick.png", "CC0 (CC0Textures, Bricks25)"),
    ("grass.png", "CC0 (DeviantArt, linolafett, Grass 01)"),
    ("gravel.png", "CC0 (CC0Textures, Gravel04)"),
    ("coffee.png", "CC0 (Rachel Michetti)"),
    ("chelsea.png", "CC0 (Stefan van der Walt)"),
    ("astronaut.png", "public domain (NASA)"),
    ("rocket.jpg", "public domain (SpaceX)"),
)
"""``(file, licence)`` of each image used, as scikit-image's data docstrings state them."""

TEXTURE_SIZE = 256
"""Side of each texture after cropping to a square and resizing (pixels)."""

_CONTRAST = 0.35  # a texture value of one standard deviation changes brightness by this share


def _data_folder() -> Path:
    spec = importlib.util.find_spec(TEXTURE_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise FileNotFoundError("person textures need the images of the scikit-image wheel: "
                                "pip install --no-deps scikit-image")
    return Path(next(iter(spec.submodule_search_locations))) / "data"


@functools.lru_cache(maxsize=1)
def load_textures() -> np.ndarray:
    """``(K, S, S)`` float32 textures: each image's luminance, centre-cropped to a square,
    resized to :data:`TEXTURE_SIZE`, high-passed (a wide blur subtracted, so a photo's
    large-scale shading does not pass for clothing) and scaled to zero mean and unit standard
    deviation.

    Raises:
        FileNotFoundError: scikit-image's images are not installed, or one is missing or
            unreadable.
    """
    folder = _data_folder()
    out = []
    for name, _ in TEXTURE_SOURCES:
        image = cv2.imread(str(folder / name), cv2.IMREAD_GRAYSCALE)
        if image is None:
            raise FileNotFoundError(f"{folder / name}: missing or unreadable (the scikit-image "
                                    "wheel's image); reinstall it: pip install --no-deps "
                                    "--force-reinstall scikit-image")
        h, w = image.shape
        side = min(h, w)
        y, x = (h - side) // 2, (w - side) // 2
        square = cv2.resize(image[y:y + side, x:x + side], (TEXTURE_SIZE, TEXTURE_SIZE),
                            interpolation=cv2.INTER_AREA).astype(np.float32)
        square -= cv2.GaussianBlur(square, (0, 0), TEXTURE_SIZE / 16)
        out.append((square - square.mean()) / max(float(square.std()), 1e-6))
    textures = np.stack(out)
    textures.setflags(write=False)
    return textures


@dataclass(frozen=True, eq=False)
class PersonTextures:
    """Each person's texture: which image, its offset and its scale.

    Attributes:
        index: ``(N,)`` texture of each person (into :func:`load_textures`).
        offset: ``(N, 2)`` texture pixel at the top-left of the person's box.
        scale: ``(N,)`` texture pixels per person height.
    """

    index: np.ndarray
    offset: np.ndarray
    scale: np.ndarray


def draw_person_textures(rng: np.random.Generator, n_people: int) -> PersonTextures:
    """Draw a texture for each of ``n_people`` people (uniform image, offset and a scale of
    0.5 to 1.5 texture sides per person height)."""
    n = int(n_people)
    return PersonTextures(rng.integers(0, len(TEXTURE_SOURCES), size=n),
                          rng.uniform(0, TEXTURE_SIZE, size=(n, 2)),
                          rng.uniform(0.5, 1.5, size=n) * TEXTURE_SIZE)


def apply_person_textures(image: np.ndarray, id_image: np.ndarray, textures: PersonTextures,
                          depth: float) -> np.ndarray:
    """``image`` with every person's pixels (``id_image``: person index + 1, 0 background)
    brightened and darkened by their texture: ``pixel * clip(1 + depth * 0.35 * t, 0.3,
    1.7)``, ``t`` the texture (unit standard deviation) sampled at the pixel's place in the
    person's box, in units of the person's height in this view. ``depth`` in [0, 1]; 0 returns
    ``image`` unchanged."""
    if not 0.0 <= depth <= 1.0:
        raise ValueError(f"texture depth must be in [0, 1], got {depth}")
    ys, xs = np.nonzero(id_image)
    if depth == 0.0 or ys.size == 0:
        return image
    person = id_image[ys, xs].astype(np.int64) - 1
    n = int(person.max()) + 1
    top = np.full(n, np.inf)
    left = np.full(n, np.inf)
    bottom = np.full(n, -np.inf)
    np.minimum.at(top, person, ys)
    np.minimum.at(left, person, xs)
    np.maximum.at(bottom, person, ys)
    height = np.maximum(bottom - top + 1, 1.0)
    per_px = textures.scale[person] / height[person]
    tx = (np.floor((xs - left[person]) * per_px + textures.offset[person, 0]).astype(np.int64)
          % TEXTURE_SIZE)
    ty = (np.floor((ys - top[person]) * per_px + textures.offset[person, 1]).astype(np.int64)
          % TEXTURE_SIZE)
    value = load_textures()[textures.index[person], ty, tx]
    factor = np.clip(1.0 + depth * _CONTRAST * value, 0.3, 1.7)
    out = image.copy()
    out[ys, xs] = np.clip(out[ys, xs].astype(np.float32) * factor[:, None], 0, 255).astype(
        np.uint8)
    return out
