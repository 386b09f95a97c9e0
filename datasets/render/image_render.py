"""Rendering one view of a synthetic scene, with labels read from the rendered pixels.

A view is drawn back to front with OpenCV fills, no 3D library: the ground (a periodic texture
mapped by the ground-plane homography of the camera), distant ground and sky bands above and
below the horizon line, the buildings' visible faces, the people's cast shadows, then every
person primitive (:mod:`xvmatch.datasets.render.person_render`) as the filled convex hull of its
projected points, in decreasing distance to the camera (painter's algorithm). Each primitive is
shaded by the scene's sun: a lit colour, a darker self-shadow band on the side turned away from
the light, and a cap (shoulders, hat tops) when it faces the camera.

The same fills, in the same order, write person indices into a ``uint16`` id image, so the
labels come from the actual pixels: the tight box of what is visible, the visible fraction
(visible pixels over the pixels of the person's unoccluded, untruncated silhouette), and whether
the person runs past the image border.

Photometric differences between the views (white balance, exposure and gamma, optical and motion
blur, sensor noise, JPEG quality) are drawn per scene and view by :func:`draw_photometric` and
applied by :func:`apply_photometric`, separate from the geometry. How hard the data is, is one
record, :class:`Difficulty`, with three presets (``easy``, ``medium``, ``hard``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, fields

import cv2
import numpy as np

from xvmatch.datasets.render.person_render import (
    N_SLOTS,
    OVERLAY_SLOTS,
    SHADED_SLOTS,
    SLOT_NAMES,
    BodyFrame,
    body_frame,
    draw_appearances,
    walk_phases,
)
from xvmatch.datasets.synthetic_scenes import Building, SyntheticScene
from xvmatch.geometry.camera import Camera

__all__ = [
    "DIFFICULTIES",
    "Difficulty",
    "Photometric",
    "RenderedPair",
    "RenderedView",
    "SceneRenderer",
    "ViewLabels",
    "World",
    "apply_photometric",
    "draw_photometric",
    "make_world",
    "render_background",
    "render_people",
]

_SHIFT = 4  # sub-pixel bits of the OpenCV fills
_ONE = 1 << _SHIFT
_TEXTURE_PX = 512  # side of the periodic ground texture (a 30.72 m period)
_TEXTURE_M_PER_PX = 0.06
_HEAD_SLOT = SLOT_NAMES.index("head")
_SHADED = np.array([k in SHADED_SLOTS for k in range(N_SLOTS)])
_NOISE_STD = 32.0  # standard deviation of the cached noise bank, grey levels
# Heights above the horizon (fractions of the image height) where the sky gradient steps.
_SKY_BANDS = (0.0, 0.03, 0.08, 0.15, 0.24, 0.35, 0.5)


# --------------------------------------------------------------------------------------------
# Difficulty and photometry


@dataclass(frozen=True)
class Difficulty:
    """How hard the rendered data is: appearance ambiguity and image degradation.

    Attributes:
        lookalike: probability that a person copies an earlier person's outfit with colours
            re-drawn within their look-alike groups (see
            :func:`~xvmatch.datasets.render.person_render.draw_appearances`).
        palette_size: clothing colours available per scene (2-18); fewer means more people in
            the same colours.
        pattern_weights: relative frequency of plain, striped and two-tone torsos.
        hat: probability that a person wears a hat (it hides the hair from above).
        bag: probability of a backpack.
        colour_jitter: per-person standard deviation of clothing colours, 0-255 scale.
        white_balance: standard deviation of the per-channel log gain of each view.
        exposure: standard deviation of the log2 exposure of each view.
        gamma: standard deviation of each view's tone-curve gamma around 1.
        blur: largest Gaussian blur sigma (pixels) of a view, drawn uniformly from 0.
        motion_blur: largest length (pixels) of the egocentric camera's motion blur per frame.
        noise: largest sensor-noise standard deviation (grey levels) of a view.
        jpeg_quality: (min, max) JPEG quality of a view's files.
        sunny: probability of a sunny scene (strong directional light and cast shadows);
            otherwise overcast (soft light, faint shadows).
        texture: depth (0-1) of the photographic texture laid over each person
            (:mod:`xvmatch.datasets.render.person_textures`); 0, the default, draws none and leaves
            the renders and the manifests as before.
    """

    lookalike: float = 0.25
    palette_size: int = 12
    pattern_weights: tuple[float, float, float] = (0.5, 0.25, 0.25)
    hat: float = 0.2
    bag: float = 0.25
    colour_jitter: float = 10.0
    white_balance: float = 0.06
    exposure: float = 0.25
    gamma: float = 0.08
    blur: float = 0.8
    motion_blur: float = 4.0
    noise: float = 4.0
    jpeg_quality: tuple[int, int] = (75, 95)
    sunny: float = 0.75
    texture: float = 0.0

    def __post_init__(self) -> None:
        for name in ("lookalike", "hat", "bag", "sunny", "texture"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise ValueError(f"Difficulty.{name} must be in [0, 1], got {value}")
        for name in ("colour_jitter", "white_balance", "exposure", "gamma", "blur",
                     "motion_blur", "noise"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"Difficulty.{name} must be >= 0, got {getattr(self, name)}")
        low, high = self.jpeg_quality
        if not 1 <= low <= high <= 100:
            raise ValueError(f"Difficulty.jpeg_quality must be 1 <= min <= max <= 100, got "
                             f"{self.jpeg_quality}")
        if not 2 <= self.palette_size <= 18:
            raise ValueError(f"Difficulty.palette_size must be in 2..18, got {self.palette_size}")

    @classmethod
    def preset(cls, name: str) -> Difficulty:
        """One of :data:`DIFFICULTIES` by name: ``easy``, ``medium`` or ``hard``."""
        if name not in DIFFICULTIES:
            raise ValueError(
                f"unknown difficulty {name!r}; choose one of {', '.join(DIFFICULTIES)}"
            )
        return DIFFICULTIES[name]

    def to_dict(self) -> dict:
        """JSON-ready record (``texture`` only when set: older manifests stay as they were)."""
        return {f.name: getattr(self, f.name) for f in fields(self)
                if f.name != "texture" or self.texture}


DIFFICULTIES: dict[str, Difficulty] = {
    "easy": Difficulty(
        lookalike=0.0, palette_size=18, hat=0.3, bag=0.3, colour_jitter=6.0,
        white_balance=0.02, exposure=0.08, gamma=0.03, blur=0.3, motion_blur=0.0, noise=1.5,
        jpeg_quality=(90, 95), sunny=1.0,
    ),
    "medium": Difficulty(),
    "hard": Difficulty(
        lookalike=0.5, palette_size=6, pattern_weights=(0.7, 0.15, 0.15), hat=0.15, bag=0.15,
        colour_jitter=14.0, white_balance=0.12, exposure=0.45, gamma=0.15, blur=1.5,
        motion_blur=8.0, noise=8.0, jpeg_quality=(40, 75), sunny=0.5,
    ),
}
"""Named difficulty presets; ``medium`` is the default."""


@dataclass(frozen=True)
class Photometric:
    """The photometric character of one view (one camera) of a scene.

    Attributes:
        gains: (3,) per-channel BGR gains: white balance times exposure.
        gamma: exponent of the tone curve applied after the gains.
        blur_sigma: Gaussian blur sigma in pixels (0: none).
        noise_sigma: sensor-noise standard deviation in grey levels.
        motion_blur: largest motion-blur length in pixels, drawn per frame (0: none).
        jpeg_quality: JPEG quality of the view's files.
    """

    gains: tuple[float, float, float]
    gamma: float
    blur_sigma: float
    noise_sigma: float
    motion_blur: float
    jpeg_quality: int

    def to_dict(self) -> dict:
        """JSON-ready record."""
        return {
            "gains": [float(g) for g in self.gains],
            "gamma": float(self.gamma),
            "blur_sigma": float(self.blur_sigma),
            "noise_sigma": float(self.noise_sigma),
            "motion_blur": float(self.motion_blur),
            "jpeg_quality": int(self.jpeg_quality),
        }

    @functools.cached_property
    def lut(self) -> np.ndarray:
        """``(256, 1, 3)`` uint8 lookup table of gains and gamma, for ``cv2.LUT``."""
        x = np.arange(256, dtype=float)[:, None] / 255.0
        y = np.clip(x * np.asarray(self.gains)[None], 0.0, 1.0) ** self.gamma
        return np.round(255.0 * y).astype(np.uint8)[:, None, :]


def draw_photometric(rng: np.random.Generator, difficulty: Difficulty, *,
                     moving: bool) -> Photometric:
    """Draw a view's photometric parameters.

    Args:
        rng: random generator.
        difficulty: the spreads to draw from.
        moving: whether the camera moves (egocentric): only then is motion blur possible.
    """
    wb = np.exp(difficulty.white_balance * rng.standard_normal(3))
    exposure = 2.0 ** (difficulty.exposure * rng.standard_normal())
    gamma = float(np.exp(difficulty.gamma * rng.standard_normal()))
    blur = float(rng.uniform(0.0, difficulty.blur))
    noise = float(rng.uniform(0.25, 1.0) * difficulty.noise)
    quality = int(rng.integers(difficulty.jpeg_quality[0], difficulty.jpeg_quality[1] + 1))
    gains = wb / np.exp(np.log(wb).mean()) * exposure
    return Photometric(
        gains=(float(gains[0]), float(gains[1]), float(gains[2])),
        gamma=gamma,
        blur_sigma=blur,
        noise_sigma=noise,
        motion_blur=float(difficulty.motion_blur) if moving else 0.0,
        jpeg_quality=quality,
    )


@functools.lru_cache(maxsize=1)
def _noise_bank() -> np.ndarray:
    """A fixed ``(1024, 1536, 3)`` uint8 bank of Gaussian noise around 128 (std 32).

    Drawing fresh noise for every image costs more than the rest of the photometry; crops of
    one fixed bank at random offsets are as good for training and are deterministic.
    """
    rng = np.random.default_rng(0x5EED)
    bank = 128.0 + _NOISE_STD * rng.standard_normal((1024, 1536, 3), dtype=np.float32)
    return np.clip(np.round(bank), 0, 255).astype(np.uint8)


def _noise_crop(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """A ``(height, width, 3)`` crop of the noise bank at a random offset (tiled if needed)."""
    bank = _noise_bank()
    bh, bw = bank.shape[:2]
    if height > bh or width > bw:
        bank = np.tile(bank, (-(-height // bh) + 1, -(-width // bw) + 1, 1))
        bh, bw = bank.shape[:2]
    y = int(rng.integers(0, bh - height + 1))
    x = int(rng.integers(0, bw - width + 1))
    return bank[y : y + height, x : x + width]


def apply_photometric(image: np.ndarray, params: Photometric,
                      rng: np.random.Generator) -> np.ndarray:
    """Degrade a rendered BGR image like a camera: blur, motion blur, tone curve, noise.

    JPEG compression is left to the writer (``params.jpeg_quality``), so images in memory are
    not compressed twice.

    Args:
        image: ``(H, W, 3)`` uint8 BGR image (not modified).
        params: the view's :class:`Photometric`.
        rng: per-frame generator for the motion blur and the noise offsets.

    Returns:
        A new ``(H, W, 3)`` uint8 image.
    """
    out = image
    if params.blur_sigma > 0.05:
        out = cv2.GaussianBlur(out, (0, 0), params.blur_sigma)
    length = float(rng.uniform(0.0, params.motion_blur)) if params.motion_blur > 0 else 0.0
    angle = float(rng.uniform(0.0, np.pi))
    if length >= 1.5:
        size = int(np.ceil(length)) | 1
        kernel = np.zeros((size, size), np.float32)
        half = 0.5 * (length - 1.0)
        centre = (size - 1) / 2.0
        dx, dy = half * np.cos(angle), half * np.sin(angle)
        p0 = (round((centre - dx) * _ONE), round((centre - dy) * _ONE))
        p1 = (round((centre + dx) * _ONE), round((centre + dy) * _ONE))
        cv2.line(kernel, p0, p1, 1.0, 1, cv2.LINE_AA, _SHIFT)
        out = cv2.filter2D(out, -1, kernel / kernel.sum())
    out = cv2.LUT(out, params.lut)
    if params.noise_sigma > 0.05:
        beta = params.noise_sigma / _NOISE_STD
        noise = _noise_crop(rng, out.shape[0], out.shape[1])
        out = cv2.addWeighted(out, 1.0, noise, beta, -128.0 * beta)
    return out if out is not image else image.copy()


# --------------------------------------------------------------------------------------------
# The static world: ground, sky, buildings, light


@dataclass(frozen=True, eq=False)
class World:
    """What the views of a scene share besides the people.

    Attributes:
        texture: ``(T, T, 3)`` uint8 periodic ground texture, world-aligned, centred on the
            origin, ``metres_per_px`` per pixel (row index grows towards -y).
        metres_per_px: texture resolution.
        far_colour: BGR of the distant ground near the horizon.
        sky: BGR colours of the sky at the horizon and high up.
        light: (3,) unit vector towards the sun.
        ambient: light intensity of surfaces in shadow.
        diffuse: extra intensity of surfaces facing the sun.
        shadow: factor (0-1) by which cast shadows darken the ground; 1 is no shadow.
        buildings: the static buildings.
        facades: ``(B, 3)`` facade BGR colours.
        windows: ``(B, 3)`` window BGR colours.
        roofs: ``(B, 3)`` roof BGR colours.
    """

    texture: np.ndarray
    metres_per_px: float
    far_colour: tuple[float, float, float]
    sky: tuple[tuple[float, float, float], ...]
    light: np.ndarray
    ambient: float
    diffuse: float
    shadow: float
    buildings: tuple[Building, ...]
    facades: np.ndarray
    windows: np.ndarray
    roofs: np.ndarray


def _periodic_blobs(rng: np.random.Generator, cells: int, size: int) -> np.ndarray:
    """Smooth, periodic, zero-mean noise ``(size, size)`` float32 with ``cells`` bumps a side."""
    grid = rng.standard_normal((cells, cells)).astype(np.float32)
    pad = 2
    big = np.pad(grid, pad, mode="wrap")
    scale = size // cells
    up = cv2.resize(big, ((cells + 2 * pad) * scale,) * 2, interpolation=cv2.INTER_CUBIC)
    return up[pad * scale : pad * scale + size, pad * scale : pad * scale + size]


def _ground_texture(rng: np.random.Generator) -> np.ndarray:
    """A periodic ground texture: paving, asphalt, grass or large plaza slabs."""
    t = _TEXTURE_PX
    style = int(rng.choice(4, p=[0.4, 0.2, 0.2, 0.2]))
    jitter = rng.uniform(-12.0, 12.0, size=3)
    if style == 0:  # paving: small tiles or bricks with grout lines
        base = np.array([150.0, 160.0, 166.0]) + jitter
        ty, tx = [(8, 8), (8, 16), (16, 16), (16, 32)][int(rng.integers(0, 4))]
        tiles = rng.normal(1.0, 0.07, size=(t // ty, t // tx)).astype(np.float32)
        shade = cv2.resize(tiles, (t, t), interpolation=cv2.INTER_NEAREST)
        shade[::ty] *= 0.72
        shade[:, ::tx] *= 0.72
        grain, blobs = 10.0, 0.08
    elif style == 1:  # asphalt
        base = np.array([82.0, 84.0, 86.0]) + 0.5 * jitter
        shade = np.ones((t, t), np.float32)
        grain, blobs = 16.0, 0.12
    elif style == 2:  # grass
        base = np.array([58.0, 128.0, 92.0]) + jitter
        shade = np.ones((t, t), np.float32)
        grain, blobs = 18.0, 0.2
    else:  # plaza: large two-colour slabs
        base = np.array([176.0, 180.0, 182.0]) + jitter
        cell = 32
        check = (np.add.outer(np.arange(t) // cell, np.arange(t) // cell) % 2).astype(np.float32)
        shade = 1.0 - 0.14 * check
        shade[::cell] *= 0.8
        shade[:, ::cell] *= 0.8
        grain, blobs = 8.0, 0.06
    shade = shade * (1.0 + blobs * _periodic_blobs(rng, 8, t))
    tex = cv2.merge([shade * float(b) for b in base])
    noise = _noise_crop(rng, t, t)
    tex = cv2.scaleAdd(noise.astype(np.float32), grain / _NOISE_STD, tex) - 128.0 * (
        grain / _NOISE_STD
    )
    if style == 1:  # painted lines on asphalt
        colour = (235.0, 235.0, 235.0) if rng.random() < 0.6 else (40.0, 200.0, 230.0)
        for _ in range(int(rng.integers(2, 6))):
            if rng.random() < 0.5:
                y = int(rng.integers(0, t))
                tex[y : y + 2] = colour
            else:
                x = int(rng.integers(0, t))
                tex[:, x : x + 2] = colour
    return np.clip(tex, 0, 255).astype(np.uint8)


def make_world(scene: SyntheticScene, rng: np.random.Generator,
               difficulty: Difficulty | None = None) -> World:
    """Draw the ground texture, sky, light and building colours of a scene."""
    difficulty = Difficulty() if difficulty is None else difficulty
    texture = _ground_texture(rng)
    sunny = bool(rng.random() < difficulty.sunny)
    elevation = np.radians(rng.uniform(30.0, 65.0))
    azimuth = rng.uniform(-np.pi, np.pi)
    light = np.array([np.cos(elevation) * np.cos(azimuth),
                      np.cos(elevation) * np.sin(azimuth), np.sin(elevation)])
    if sunny:
        ambient, diffuse, shadow = rng.uniform(0.45, 0.6), rng.uniform(0.55, 0.7), 0.62
        sky = ((226.0, 216.0, 206.0), (200.0, 150.0, 100.0))
    else:
        ambient, diffuse, shadow = rng.uniform(0.7, 0.85), rng.uniform(0.15, 0.3), 0.88
        sky = ((214.0, 212.0, 208.0), (184.0, 182.0, 180.0))
    sky = tuple(tuple(float(c) for c in np.clip(np.array(s) + rng.uniform(-8, 8, 3), 0, 255))
                for s in sky)
    mean = np.array(cv2.mean(texture)[:3])
    far = 0.85 * mean + 0.15 * np.array(sky[0])
    b = len(scene.buildings)
    facade_palette = np.array([(170, 174, 178), (150, 170, 196), (70, 90, 150), (200, 204, 206),
                               (120, 128, 136), (130, 160, 180), (90, 110, 120)], dtype=float)
    facades = facade_palette[rng.integers(0, len(facade_palette), size=b)]
    facades = np.clip(facades + rng.uniform(-10, 10, size=(b, 3)), 0, 255)
    windows = np.clip(np.array([110.0, 92.0, 78.0]) + rng.uniform(-20, 20, size=(b, 3)), 0, 255)
    roofs = np.clip(facades * 0.7, 0, 255)
    return World(
        texture=texture,
        metres_per_px=_TEXTURE_M_PER_PX,
        far_colour=(float(far[0]), float(far[1]), float(far[2])),
        sky=sky,
        light=light,
        ambient=float(ambient),
        diffuse=float(diffuse),
        shadow=float(shadow),
        buildings=scene.buildings,
        facades=facades,
        windows=windows,
        roofs=roofs,
    )


def _fixed(uv: np.ndarray) -> np.ndarray:
    """Continuous pixel coordinates (pixel i spans [i, i+1)) to OpenCV fixed-point int32."""
    return np.round((np.clip(uv, -1e5, 1e5) - 0.5) * _ONE).astype(np.int32)


def _half_plane(width: int, height: int, line: np.ndarray, offset: float) -> np.ndarray:
    """The part of the image rectangle where ``line . (u, v, 1) >= offset`` (a convex polygon)."""
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    value = corners @ line[:2] + line[2] - offset
    out = []
    for i in range(4):
        j = (i + 1) % 4
        if value[i] >= 0:
            out.append(corners[i])
        if (value[i] >= 0) != (value[j] >= 0):
            t = value[i] / (value[i] - value[j])
            out.append(corners[i] + t * (corners[j] - corners[i]))
    return np.array(out).reshape(-1, 2)


def _fill(image: np.ndarray, polygon: np.ndarray, colour, line_type: int = cv2.LINE_AA) -> None:
    if len(polygon) >= 3:
        cv2.fillConvexPoly(image, _fixed(polygon), colour, line_type, _SHIFT)


def _draw_buildings(image: np.ndarray, camera: Camera, world: World) -> None:
    """Visible faces (and window rows) of every building fully in front of the camera."""
    if not world.buildings:
        return
    order = np.argsort([-np.hypot(*(np.asarray(b.centre) - camera.c[:2]))
                        for b in world.buildings])
    up = np.array([0.0, 0.0, 1.0])
    for k in order:
        building = world.buildings[k]
        corners = building.corners()
        uv, depth = camera.project(corners)
        if (depth < 0.5).any():
            continue
        lo, hi = uv.min(axis=0), uv.max(axis=0)
        if hi[0] < 0 or lo[0] > camera.width or hi[1] < 0 or lo[1] > camera.height:
            continue
        centre = corners.mean(axis=0)
        facade = world.facades[k]
        for i in range(4):
            j = (i + 1) % 4
            g0, g1 = corners[i], corners[j]
            normal = np.cross(g1 - g0, up)
            normal /= np.linalg.norm(normal)
            if normal @ (centre - g0) > 0:
                normal = -normal
            if normal @ (camera.c - g0) <= 0:
                continue
            shade = world.ambient + world.diffuse * max(0.0, float(normal @ world.light))
            _fill(image, uv[[i, j, j + 4, i + 4]], (facade * shade).tolist())
            length = np.linalg.norm(g1 - g0)
            floors = int((building.height - 1.0) // 3.0)
            if floors < 1 or length < 2.0:
                continue
            s = np.array([0.5 / length, 1.0 - 0.5 / length])
            z0 = 3.0 * np.arange(floors) + 1.0
            quads = np.stack([
                np.stack([g0 + s[0] * (g1 - g0) + z * up, g0 + s[1] * (g1 - g0) + z * up,
                          g0 + s[1] * (g1 - g0) + (z + 1.3) * up,
                          g0 + s[0] * (g1 - g0) + (z + 1.3) * up])
                for z in z0
            ])
            quv, _ = camera.project(quads)
            colour = (world.windows[k] * (0.8 + 0.4 * shade)).tolist()
            for q in quv:
                _fill(image, q, colour)
        if camera.c[2] > building.height:
            roof_shade = world.ambient + world.diffuse * float(world.light[2])
            _fill(image, uv[4:8], (world.roofs[k] * roof_shade).tolist())


def render_background(camera: Camera, world: World) -> np.ndarray:
    """The view without people: ground, distant ground, sky bands and buildings.

    Args:
        camera: the view's camera.
        world: the scene's :class:`World`.

    Returns:
        ``(H, W, 3)`` uint8 BGR image.
    """
    t = world.texture.shape[0]
    s = world.metres_per_px
    # Texture pixel (j, i) -> world (x, y) = (s (j + 0.5 - T/2), s (T/2 - i - 0.5)).
    tex_to_world = np.array([[s, 0.0, s * (0.5 - t / 2)], [0.0, -s, s * (t / 2 - 0.5)],
                             [0.0, 0.0, 1.0]])
    plane = np.column_stack([camera.R[:, 0], camera.R[:, 1], -camera.R @ camera.c])
    # OpenCV samples pixel centres at integers: shift by half a pixel both ways.
    half = np.array([[1.0, 0.0, -0.5], [0.0, 1.0, -0.5], [0.0, 0.0, 1.0]])
    to_image = half @ camera.K @ plane @ tex_to_world @ np.linalg.inv(half)
    image = cv2.warpPerspective(world.texture, to_image, camera.image_size,
                                flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_WRAP)
    # Horizon: pixels whose ray has zero vertical component, line . (u, v, 1) = 0, sky > 0.
    line = np.linalg.inv(camera.K).T @ camera.R[:, 2]
    norm = float(np.hypot(line[0], line[1]))
    if norm > 1e-12:
        line = line / norm
        far = max(30.0, 4.0 * camera.c[2])
        offset = -camera.K[1, 1] * max(camera.c[2], 0.1) / far
        _fill(image, _half_plane(camera.width, camera.height, line, offset), world.far_colour)
        horizon, zenith = np.array(world.sky[0]), np.array(world.sky[-1])
        for i, rise in enumerate(_SKY_BANDS):
            t = (i / (len(_SKY_BANDS) - 1)) ** 0.8
            colour = ((1.0 - t) * horizon + t * zenith).tolist()
            _fill(image, _half_plane(camera.width, camera.height, line, rise * camera.height),
                  colour)
    elif line[2] > 0:  # looking straight up: all sky
        image[:] = world.sky[-1]
    _draw_buildings(image, camera, world)
    return image


# --------------------------------------------------------------------------------------------
# People


@dataclass(frozen=True, eq=False)
class ViewLabels:
    """Labels of the people visible in one view of one frame, ascending ids.

    Boxes are ``(x, y, w, h)`` in pixels with ``(x, y)`` the top-left corner, pixel ``i``
    spanning ``[i, i + 1)`` (the convention of :class:`~xvmatch.geometry.camera.Camera`).

    Attributes:
        ids: ``(N,)`` int64 person ids (the same person has the same id in both views).
        boxes: ``(N, 4)`` tight box of the visible silhouette pixels.
        full_boxes: ``(N, 4)`` box of the whole projected body, occluders and image border
            ignored (it may run past the image).
        visible: ``(N,)`` visible silhouette pixels over the pixels of the whole silhouette,
            in (0, 1]; occlusion by nearer people and truncation both lower it.
        truncated: ``(N,)`` bool, the whole body does not fit in the image.
        visible_pixels: ``(N,)`` int64 count of visible silhouette pixels.
        ground: ``(N, 3)`` 3D ground point under the body axis, metres.
        head: ``(N, 3)`` 3D head centre, metres.
    """

    ids: np.ndarray
    boxes: np.ndarray
    full_boxes: np.ndarray
    visible: np.ndarray
    truncated: np.ndarray
    visible_pixels: np.ndarray
    ground: np.ndarray
    head: np.ndarray

    def __post_init__(self) -> None:
        n = np.asarray(self.ids).reshape(-1).shape[0]
        shapes = {
            "ids": ((n,), np.int64), "boxes": ((n, 4), np.float64),
            "full_boxes": ((n, 4), np.float64), "visible": ((n,), np.float64),
            "truncated": ((n,), bool), "visible_pixels": ((n,), np.int64),
            "ground": ((n, 3), np.float64), "head": ((n, 3), np.float64),
        }
        for name, (shape, dtype) in shapes.items():
            arr = np.asarray(getattr(self, name), dtype=dtype)
            if arr.size == 0:
                arr = arr.reshape(shape)
            if arr.shape != shape:
                raise ValueError(f"ViewLabels.{name} must have shape {shape}, got {arr.shape}")
            object.__setattr__(self, name, arr)

    def __len__(self) -> int:
        return int(self.ids.shape[0])

    @classmethod
    def empty(cls) -> ViewLabels:
        """Labels of a view with nobody in it."""
        return cls(*(np.empty(0) for _ in range(8)))

    def select(self, mask: np.ndarray) -> ViewLabels:
        """The labels of the rows where ``mask`` is true (or of the given indices)."""
        return ViewLabels(*(getattr(self, f.name)[mask] for f in fields(self)))


def _shadows(image: np.ndarray, camera: Camera, body: BodyFrame, world: World) -> None:
    """Darken the ground under each person's cast shadow (the hull of its body's shadow)."""
    light = world.light
    if world.shadow >= 0.999 or light[2] < 0.15:
        return
    pts = body.vertices - (body.vertices[..., 2:3] / light[2]) * light
    uv, depth = camera.project(pts)
    hulls = []
    for a in range(pts.shape[0]):
        keep = body.present[a]
        if not (depth[a][keep] > 0.2).all():
            continue
        p = uv[a][keep].reshape(-1, 2)
        lo, hi = p.min(axis=0), p.max(axis=0)
        if hi[0] < 0 or lo[0] > camera.width or hi[1] < 0 or lo[1] > camera.height:
            continue
        hulls.append(cv2.convexHull(_fixed(p)))
    if not hulls:
        return
    allpts = np.concatenate(hulls).reshape(-1, 2) // _ONE
    x0, y0 = np.maximum(allpts.min(axis=0) - 1, 0)
    x1, y1 = np.minimum(allpts.max(axis=0) + 2, [camera.width, camera.height])
    if x1 <= x0 or y1 <= y0:
        return
    mask = np.zeros((y1 - y0, x1 - x0), np.uint8)
    off = np.array([x0, y0], dtype=np.int32) * _ONE
    for h in hulls:
        cv2.fillConvexPoly(mask, h - off, 255, cv2.LINE_AA, _SHIFT)
    roi = image[y0:y1, x0:x1]
    factor = 255 - cv2.convertScaleAbs(mask, alpha=1.0 - world.shadow)
    roi[:] = cv2.multiply(roi, cv2.cvtColor(factor, cv2.COLOR_GRAY2BGR), scale=1.0 / 255.0)


def _project_people(
    camera: Camera, body: BodyFrame, allowed: np.ndarray, near_clip: float
) -> tuple[np.ndarray, ...]:
    """Project every primitive and find the people and primitives that can be drawn.

    Args:
        camera: the view's camera.
        body: the people's primitives on this frame.
        allowed: ``(N,)`` people that may appear.
        near_clip: a person with a body point nearer than this (camera depth) is left out.

    Returns:
        ``(uv, use, lo, hi, in_image, drawable)``: ``(N, S, 16, 2)`` pixel points, ``(N, S)``
        primitives of people in the image, ``(N, 2)`` pixel box corners of each person,
        ``(N,)`` people in the image and ``(N, S)`` primitives whose box meets the image.
    """
    width, height = camera.width, camera.height
    cam = (body.vertices - camera.c) @ camera.R.T
    z = cam[..., 2]
    present = body.present
    zmin = np.where(present[..., None], z, np.inf).min(axis=(1, 2))
    valid = allowed & (zmin > near_clip)
    hom = cam @ camera.K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = hom[..., :2] / np.where(hom[..., 2:3] > 1e-9, hom[..., 2:3], 1e-9)
    use = present & valid[:, None]
    p_lo, p_hi = uv.min(axis=2), uv.max(axis=2)  # (n, S, 2) per-primitive boxes
    lo = np.where(use[..., None], p_lo, np.inf).min(axis=1)
    hi = np.where(use[..., None], p_hi, -np.inf).max(axis=1)
    in_image = valid & (hi[:, 0] > 0) & (lo[:, 0] < width) & (hi[:, 1] > 0) & (lo[:, 1] < height)
    use &= in_image[:, None]
    drawable = use & (p_hi[..., 0] > 0) & (p_lo[..., 0] < width) & (p_hi[..., 1] > 0) & (
        p_lo[..., 1] < height
    )
    return uv, use, lo, hi, in_image, drawable


def _painter_order(
    camera: Camera, body: BodyFrame, drawable: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Painter's order of the drawable primitives.

    Far people first; within a person far primitives first, the overlays (hair, hat, device)
    right after the head.

    Returns:
        ``(who, slot, person_dist)``: person and slot index of each drawable primitive in
        drawing order, and the ``(N,)`` distance of each person's centre to the camera.
    """
    person_dist = np.linalg.norm(body.centre - camera.c, axis=1)
    prim_dist = np.linalg.norm(body.vertices.mean(axis=2) - camera.c, axis=2)
    for k, slot in enumerate(OVERLAY_SLOTS):
        prim_dist[:, slot] = prim_dist[:, _HEAD_SLOT] - 1e-4 * (k + 1)
    who, slot = np.nonzero(drawable)
    order = np.lexsort((-prim_dist[who, slot], who, -person_dist[who]))
    return who[order], slot[order], person_dist


def _shading(camera: Camera, body: BodyFrame, world: World) -> tuple[np.ndarray, ...]:
    """Lit colour from the visible lit side, a self-shadow band, a cap if facing.

    Returns:
        ``(base, dark, capc, band, draw_band, cap_visible)``: ``(N, S, 3)`` lit, shadow and cap
        colours, the ``(N, S, 16)`` points of the shadow band, and ``(N, S)`` whether the band
        and the cap are drawn.
    """
    to_cam = camera.c - body.vertices
    facing = np.einsum("nsvk,nsvk->nsv", body.normals, to_cam) > 0
    n_dot_l = body.normals @ world.light
    lit = facing & (n_dot_l > 0)
    n_lit = lit.sum(axis=2)
    lit_mean = np.where(lit, n_dot_l, 0.0).sum(axis=2) / np.maximum(n_lit, 1)
    intensity = world.ambient + world.diffuse * lit_mean
    band = facing & (n_dot_l <= 0) & _SHADED[None, :, None]
    draw_band = (band.sum(axis=2) >= 3) & (n_lit > 0)
    top_centre = body.vertices[:, :, 8:].mean(axis=2)
    cap_visible = body.cap & (
        np.einsum("nsk,nsk->ns", body.axis, camera.c - top_centre) > 0
    )
    cap_intensity = world.ambient + world.diffuse * np.clip(body.axis @ world.light, 0.0, None)
    colours = body.colours
    base = np.clip(colours * intensity[..., None], 0, 255)
    dark = np.clip(colours * world.ambient, 0, 255)
    capc = np.clip(colours * cap_intensity[..., None], 0, 255)
    return base, dark, capc, band, draw_band, cap_visible


def render_people(
    image: np.ndarray,
    camera: Camera,
    body: BodyFrame,
    world: World,
    ids: np.ndarray,
    *,
    allowed: np.ndarray | None = None,
    near_clip: float = 0.05,
) -> tuple[np.ndarray, ViewLabels]:
    """Draw the people into ``image`` in depth order and label them from the pixels.

    Args:
        image: ``(H, W, 3)`` uint8 background, drawn on in place.
        camera: the view's camera.
        body: the people's primitives on this frame.
        world: light of the scene.
        ids: ``(N,)`` person ids.
        allowed: ``(N,)`` bool, people that may appear (the egocentric camera's carrier does
            not); ``None`` allows everyone.
        near_clip: a person with a body point nearer than this (camera depth) is left out.

    Returns:
        (id_image, labels): ``(H, W)`` uint16 image of person index + 1 (0 = background) and
        the :class:`ViewLabels` of the people with at least one visible pixel.
    """
    width, height = camera.width, camera.height
    n = body.vertices.shape[0]
    id_image = np.zeros((height, width), np.uint16)
    allowed = np.ones(n, dtype=bool) if allowed is None else np.asarray(allowed, dtype=bool)
    if n == 0:
        return id_image, ViewLabels.empty()
    uv, use, lo, hi, in_image, drawable = _project_people(camera, body, allowed, near_clip)
    if not drawable.any():
        return id_image, ViewLabels.empty()
    who, slot, person_dist = _painter_order(camera, body, drawable)
    base, dark, capc, band, draw_band, cap_visible = _shading(camera, body, world)
    fixed = _fixed(uv)
    fill = cv2.fillConvexPoly
    hull_of = cv2.convexHull
    aa, l8 = cv2.LINE_AA, cv2.LINE_8
    for a, s in zip(who.tolist(), slot.tolist(), strict=True):
        pts = fixed[a, s]
        hull = hull_of(pts)
        fill(image, hull, base[a, s].tolist(), aa, _SHIFT)
        fill(id_image, hull, a + 1, l8, _SHIFT)
        if draw_band[a, s]:
            fill(image, hull_of(pts[band[a, s]]), dark[a, s].tolist(), aa, _SHIFT)
        if cap_visible[a, s]:
            fill(image, pts[8:], capc[a, s].tolist(), aa, _SHIFT)
    return id_image, _labels(id_image, camera, body, ids, use, fixed, lo, hi, person_dist,
                             in_image)


def _labels(id_image: np.ndarray, camera: Camera, body: BodyFrame, ids: np.ndarray,
            use: np.ndarray, fixed: np.ndarray, lo: np.ndarray, hi: np.ndarray,
            person_dist: np.ndarray, in_image: np.ndarray) -> ViewLabels:
    """Tight boxes, visible fractions and truncation of the drawn people, from the id image."""
    width, height = camera.width, camera.height
    cand = np.flatnonzero(in_image)
    truncated = (lo[:, 0] < 0) | (lo[:, 1] < 0) | (hi[:, 0] > width) | (hi[:, 1] > height)
    # Who may hide whom: a nearer person whose full box overlaps.
    overlap = (
        (lo[cand, None, 0] < hi[None, cand, 0]) & (lo[None, cand, 0] < hi[cand, None, 0])
        & (lo[cand, None, 1] < hi[None, cand, 1]) & (lo[None, cand, 1] < hi[cand, None, 1])
    )
    nearer = person_dist[None, cand] <= person_dist[cand, None]
    np.fill_diagonal(overlap, False)
    hidden_maybe = (overlap & nearer).any(axis=1)
    rows: list[tuple] = []
    for k, a in enumerate(cand.tolist()):
        c0, r0 = max(int(np.floor(lo[a, 0])), 0), max(int(np.floor(lo[a, 1])), 0)
        c1 = min(int(np.ceil(hi[a, 0])) + 1, width)
        r1 = min(int(np.ceil(hi[a, 1])) + 1, height)
        sub = id_image[r0:r1, c0:c1] == a + 1
        count = int(np.count_nonzero(sub))
        if count == 0:
            continue
        rr = np.flatnonzero(sub.any(axis=1))
        cc = np.flatnonzero(sub.any(axis=0))
        box = (c0 + cc[0], r0 + rr[0], cc[-1] - cc[0] + 1, rr[-1] - rr[0] + 1)
        if truncated[a] or hidden_maybe[k]:
            full_area = _silhouette_area(fixed[a][use[a]], lo[a], hi[a], width * height)
        else:
            full_area = float(count)
        rows.append((int(ids[a]), box, count, min(1.0, count / max(full_area, 1.0)), a))
    if not rows:
        return ViewLabels.empty()
    rows.sort(key=lambda r: r[0])
    idx = np.array([r[4] for r in rows])
    return ViewLabels(
        ids=np.array([r[0] for r in rows], dtype=np.int64),
        boxes=np.array([r[1] for r in rows], dtype=float),
        full_boxes=np.column_stack([lo[idx], hi[idx] - lo[idx]]),
        visible=np.array([r[3] for r in rows]),
        truncated=truncated[idx],
        visible_pixels=np.array([r[2] for r in rows], dtype=np.int64),
        ground=body.ground[idx],
        head=body.head[idx],
    )


def _silhouette_area(points: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                     budget: int) -> float:
    """Pixel area of the union of the primitives' hulls, drawn alone on a private canvas.

    Args:
        points: ``(P, 16, 2)`` fixed-point primitive points of one person.
        lo, hi: (2,) the person's full box corners, continuous pixels.
        budget: largest canvas area; bigger silhouettes are drawn at a reduced scale.
    """
    origin = np.floor(lo).astype(np.int64) - 1
    size = np.ceil(hi).astype(np.int64) - origin + 2
    area = float(size[0] * size[1])
    scale = 1.0 if area <= budget else float(np.sqrt(budget / area))
    shape = (max(int(np.ceil(size[1] * scale)), 1), max(int(np.ceil(size[0] * scale)), 1))
    canvas = np.zeros(shape, np.uint8)
    if scale == 1.0:
        local = (points - (origin * _ONE).astype(np.int32)).astype(np.int32)
    else:
        local = np.round((points - origin * _ONE) * scale).astype(np.int32)
    for pts in local:
        cv2.fillConvexPoly(canvas, cv2.convexHull(pts), 1, cv2.LINE_8, _SHIFT)
    return float(np.count_nonzero(canvas)) / (scale * scale)


# --------------------------------------------------------------------------------------------
# A scene, frame by frame


@dataclass(frozen=True, eq=False)
class RenderedView:
    """One rendered view of one frame.

    Attributes:
        image: ``(H, W, 3)`` uint8 BGR image, photometric effects applied (JPEG not yet).
        id_image: ``(H, W)`` uint16 person index + 1 per pixel (0 = background).
        labels: the :class:`ViewLabels`.
        camera: the view's camera.
        jpeg_quality: the quality the view is saved with.
    """

    image: np.ndarray
    id_image: np.ndarray
    labels: ViewLabels
    camera: Camera
    jpeg_quality: int


@dataclass(frozen=True, eq=False)
class RenderedPair:
    """Both views of one frame: ``top`` (top/overview) and ``ego`` (egocentric)."""

    frame: int
    top: RenderedView
    ego: RenderedView


class SceneRenderer:
    """Renders the frames of one :class:`SyntheticScene`, deterministically.

    Construction draws, from ``rng`` and in this order: the outfits, the world (ground, light,
    colours), the photometry of the top and of the egocentric view, and one seed per frame for
    the per-frame noise; so ``render(f)`` gives the same images whatever frames were rendered
    before. The static top/overview background is drawn once.

    Args:
        scene: the scene.
        rng: random generator, e.g. the one that drew the scene.
        difficulty: appearance and photometric difficulty.
    """

    def __init__(self, scene: SyntheticScene, rng: np.random.Generator,
                 difficulty: Difficulty | None = None) -> None:
        self.scene = scene
        self.difficulty = Difficulty() if difficulty is None else difficulty
        d = self.difficulty
        self.appearances = draw_appearances(
            scene.people.n_people, rng, lookalike=d.lookalike, palette_size=d.palette_size,
            pattern_weights=d.pattern_weights, hat=d.hat, bag=d.bag,
            colour_jitter=d.colour_jitter,
        )
        self.world = make_world(scene, rng, d)
        self.photometric = {
            "top": draw_photometric(rng, d, moving=False),
            "ego": draw_photometric(rng, d, moving=True),
        }
        self._frame_seeds = rng.integers(0, 2**63 - 1, size=(scene.n_frames, 2))
        self._textures = None
        if d.texture > 0:  # drawn last: the rest of the scene is the untextured one
            from xvmatch.datasets.render.person_textures import draw_person_textures

            self._textures = draw_person_textures(rng, scene.people.n_people)
        self._phase, self._amplitude = walk_phases(scene.people, scene.config.fps)
        self._top_background: tuple[Camera, np.ndarray] | None = None
        n = scene.people.n_people
        self._ego_allowed = np.arange(n) != scene.people.wearer
        self._device_style = "head" if scene.scenario == "drone" else "hand"

    def body(self, frame: int) -> BodyFrame:
        """The people's primitives on ``frame`` (1-based)."""
        return body_frame(
            self.scene.people, frame, self.appearances, self._phase, self._amplitude,
            device_offset=self.scene.device_offset[frame - 1], device_style=self._device_style,
        )

    def _background(self, camera: Camera, cache: bool) -> np.ndarray:
        if cache and self._top_background is not None and self._top_background[0] is camera:
            return self._top_background[1].copy()
        image = render_background(camera, self.world)
        if cache:
            self._top_background = (camera, image.copy())
        return image

    def render_view(self, frame: int, view: str, body: BodyFrame | None = None) -> RenderedView:
        """Render ``view`` (``"top"`` or ``"ego"``) of ``frame`` (1-based)."""
        if view not in ("top", "ego"):
            raise ValueError(f"view must be 'top' or 'ego', got {view!r}")
        if not 1 <= frame <= self.scene.n_frames:
            raise ValueError(f"frame must be in 1..{self.scene.n_frames}, got {frame}")
        body = self.body(frame) if body is None else body
        people = self.scene.people
        if view == "top":
            camera = self.scene.top_cameras[frame - 1]
            image = self._background(camera, cache=True)
            allowed, near = None, 0.05
        else:
            camera = self.scene.ego_cameras[frame - 1]
            image = self._background(camera, cache=False)
            allowed, near = self._ego_allowed, self.scene.config.ego_near_clip
        # Everyone casts a shadow, the carrier too (it may show in their own view).
        _shadows(image, camera, body, self.world)
        id_image, labels = render_people(image, camera, body, self.world, people.ids,
                                         allowed=allowed, near_clip=near)
        if self._textures is not None:
            from xvmatch.datasets.render.person_textures import apply_person_textures

            image = apply_person_textures(image, id_image, self._textures,
                                          self.difficulty.texture)
        seed = int(self._frame_seeds[frame - 1, 0 if view == "top" else 1])
        params = self.photometric[view]
        image = apply_photometric(image, params, np.random.default_rng(seed))
        return RenderedView(image=image, id_image=id_image, labels=labels, camera=camera,
                            jpeg_quality=params.jpeg_quality)

    def render(self, frame: int) -> RenderedPair:
        """Render both views of ``frame`` (1-based)."""
        body = self.body(frame)
        return RenderedPair(frame=frame, top=self.render_view(frame, "top", body),
                            ego=self.render_view(frame, "ego", body))
