"""People as a few 3D primitives, their clothing, and how light shades them.

A person is built from at most :data:`N_SLOTS` convex primitives (feet, legs, arms, up to five
torso bands, backpack, neck, head, hair, hat, and the egocentric device for its carrier), each
sampled by :data:`N_VERTICES` surface points with outward normals. A renderer projects the
points, fills the convex hull of each primitive's projection, and sorts primitives by distance to
the camera (painter's algorithm): convex hulls of projected convex bodies are their exact
silhouettes, so occlusion between and within people is real, not faked.

Two kinds of primitive share one layout (16 points):

* ring cylinders: points 0-7 are the bottom ring, 8-15 the top ring (elliptic or rounded-box
  cross-section, possibly tapered and tilted: limbs swing). The top ring is also the cap polygon.
* ellipsoid samples (head and hair): 16 directions on (part of) an ellipsoid.

Clothing comes from a palette with look-alike groups (colours a person at 40 m is easily
confused with), three torso patterns (plain, horizontal stripes, two-tone), and optional hats and
backpacks; :func:`draw_appearances` draws it per scene with controllable look-alike rate, which is
what makes the appearance branch's task hard or easy.

Coordinates: world metres, z up; a person's body frame has x forward (its heading), y left.
Colours are BGR in 0-255 (OpenCV order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from xvmatch.datasets.box_scene import PeopleState

__all__ = [
    "CAP_SLOTS",
    "N_SLOTS",
    "N_VERTICES",
    "OVERLAY_SLOTS",
    "PATTERNS",
    "SLOT_NAMES",
    "Appearances",
    "BodyFrame",
    "body_frame",
    "draw_appearances",
    "walk_phases",
]

SLOT_NAMES: tuple[str, ...] = (
    "shoe_l", "shoe_r", "leg_l", "leg_r", "arm_l", "arm_r",
    "torso0", "torso1", "torso2", "torso3", "torso4",
    "bag", "neck", "head", "hair_back", "hair_cap", "hat", "device",
)  # fmt: skip
"""Primitive slots of a person, in template order."""
N_SLOTS = len(SLOT_NAMES)
N_VERTICES = 16
_S = {name: k for k, name in enumerate(SLOT_NAMES)}
_TORSO = np.arange(_S["torso0"], _S["torso4"] + 1)
_MAX_BANDS = _TORSO.size

OVERLAY_SLOTS: tuple[int, ...] = (_S["hair_cap"], _S["hat"], _S["device"])
"""Slots drawn right after the head whatever the viewpoint (they sit on top of it)."""
CAP_SLOTS: frozenset[int] = frozenset({*_TORSO.tolist(), _S["bag"], _S["hat"], _S["device"]})
"""Ring slots whose top cap is drawn when it faces the camera (only the top torso band's is on)."""
SHADED_SLOTS: frozenset[int] = frozenset(
    {_S[n] for n in ("leg_l", "leg_r", "arm_l", "arm_r", "bag", "head", "hair_back", "hair_cap",
                     "hat")} | set(_TORSO.tolist())
)
"""Slots whose side gets a self-shadow band (small ones are shaded flat)."""

PATTERNS: tuple[str, ...] = ("plain", "stripes", "two_tone")
"""Torso clothing patterns."""

# Clothing palette (BGR) and its look-alike groups: colours within a group are easily confused
# at low resolution or under a different white balance.
_TOP_PALETTE: dict[str, tuple[int, int, int]] = {
    "black": (32, 30, 30), "charcoal": (62, 60, 58), "navy": (92, 42, 28),
    "white": (236, 236, 234), "light_grey": (196, 196, 192), "beige": (160, 196, 218),
    "red": (44, 42, 200), "dark_red": (42, 34, 128), "orange": (32, 128, 236),
    "pink": (178, 142, 238), "blue": (182, 96, 36), "sky_blue": (230, 182, 112),
    "green": (62, 140, 52), "olive": (48, 112, 108), "yellow": (42, 204, 230),
    "purple": (128, 54, 112), "brown": (42, 72, 118), "teal": (128, 128, 30),
}  # fmt: skip
LOOKALIKE_GROUPS: tuple[tuple[str, ...], ...] = (
    ("black", "charcoal", "navy"),
    ("white", "light_grey", "beige"),
    ("red", "dark_red", "orange", "pink"),
    ("blue", "sky_blue", "teal"),
    ("green", "olive", "teal"),
    ("yellow", "orange", "beige"),
    ("purple", "dark_red", "navy"),
    ("brown", "olive", "dark_red"),
)
"""Groups of palette colours that look alike; look-alike outfits are drawn within one group."""
_BOTTOM_PALETTE = np.array(
    [(128, 82, 52), (34, 32, 32), (86, 86, 88), (110, 158, 182), (150, 186, 204), (52, 80, 44),
     (84, 48, 36), (60, 70, 96)], dtype=float,
)  # jeans, black, grey, khaki, beige, dark green, navy, brown
_SKIN = np.array(
    [(188, 208, 238), (150, 182, 226), (110, 146, 196), (76, 104, 148), (50, 68, 100)], dtype=float
)
_HAIR = np.array(
    [(26, 24, 28), (30, 44, 68), (42, 72, 112), (112, 170, 212), (162, 162, 168), (40, 70, 160)],
    dtype=float,
)
_SHOES = np.array([(28, 28, 28), (222, 222, 222), (40, 60, 92), (100, 100, 104)], dtype=float)
_DEVICE = (30.0, 30.0, 34.0)

# Body proportions as fractions of the height H (head radii, joint heights, limb radii).
_HEAD_R = np.array([0.053, 0.045, 0.065])  # front-back, left-right, vertical
_SHOULDER = 0.835
_HIP = 0.52
_ARM_R = 0.027
_ARM_LEN = 0.36
_LEG_R = (0.042, 0.029)  # thigh, ankle
_CHEST_DEPTH = 0.062  # half depth of the torso
_SHOE_H = 0.065
_STRIDE = 1.4  # metres per full gait cycle
_LEG_SWING = 0.42  # radians at full speed
_ARM_SWING = 0.35

_THETA = np.linspace(0.0, 2.0 * np.pi, 8, endpoint=False)
_RING = np.stack([np.cos(_THETA), np.sin(_THETA)], axis=1)  # (8, 2) ellipse profile
# Rounded-box profile for backpacks and devices: a squashed circle.
_BOX_RING = np.sign(_RING) * np.abs(_RING) ** 0.35


def _sphere_dirs(elevations: Sequence[float], counts: Sequence[int], az0: Sequence[float],
                 az_span: float = 2 * np.pi, pole: bool = False) -> np.ndarray:
    """Unit directions on rings of given elevations (degrees), plus the top pole if asked."""
    dirs = []
    for el, n, a0 in zip(elevations, counts, az0, strict=True):
        full = az_span >= 2 * np.pi - 1e-9
        az = np.radians(a0) + (np.arange(n) / (n if full else n - 1)) * az_span
        e = np.radians(el)
        dirs.append(np.stack([np.cos(e) * np.cos(az), np.cos(e) * np.sin(az),
                              np.full(n, np.sin(e))], axis=1))
    if pole:
        dirs.append(np.array([[0.0, 0.0, 1.0]]))
    out = np.concatenate(dirs)
    assert out.shape == (N_VERTICES, 3)
    return out


_HEAD_DIRS = _sphere_dirs((0.0, 50.0, -50.0), (8, 4, 4), (0.0, 45.0, 45.0))
_CAP_DIRS = _sphere_dirs((8.0, 45.0, 75.0), (8, 6, 2), (0.0, 30.0, 0.0))
_BACK_DIRS = _sphere_dirs((-35.0, 10.0, 50.0), (5, 5, 5), (90.0, 90.0, 90.0), np.pi, pole=True)


@dataclass(frozen=True, eq=False)
class Appearances:
    """Clothing and looks of the N people of a scene, as arrays (index = person index).

    Attributes:
        colours: ``(N, N_SLOTS, 3)`` base BGR colour of every slot.
        present: ``(N, N_SLOTS)`` which slots a person has (torso bands beyond their pattern,
            hats, backpacks, hair styles and the device are optional).
        n_bands: ``(N,)`` number of torso bands (1 plain, 2 two-tone, 5 stripes).
        pattern: ``(N,)`` index into :data:`PATTERNS`.
        lookalike_of: ``(N,)`` index of the person whose outfit this one copies, -1 if none.
    """

    colours: np.ndarray
    present: np.ndarray
    n_bands: np.ndarray
    pattern: np.ndarray
    lookalike_of: np.ndarray

    def to_dicts(self, ids: np.ndarray) -> list[dict]:
        """One JSON-ready record per person: pattern, main colours, accessories."""
        records = []
        ids = np.asarray(ids)
        for i in range(ids.shape[0]):
            src = int(self.lookalike_of[i])
            records.append({
                "pattern": PATTERNS[int(self.pattern[i])],
                "top": [[round(v) for v in self.colours[i, t].tolist()]
                        for t in _TORSO[: int(self.n_bands[i])]],
                "bottom": [round(v) for v in self.colours[i, _S["leg_l"]].tolist()],
                "hat": bool(self.present[i, _S["hat"]]),
                "bag": bool(self.present[i, _S["bag"]]),
                "lookalike_of": None if src < 0 else int(ids[src]),
            })
        return records


def _check_outfit_options(palette_size: int, lookalike: float, hat: float, bag: float,
                          pattern_weights: Sequence[float]) -> np.ndarray:
    """Refuse out-of-range options of :func:`draw_appearances`; returns the pattern weights."""
    n_names = len(_TOP_PALETTE)
    if not 2 <= palette_size <= n_names:
        raise ValueError(f"palette_size must be in 2..{n_names}, got {palette_size}")
    for label, p in (("lookalike", lookalike), ("hat", hat), ("bag", bag)):
        if not 0.0 <= p <= 1.0:
            raise ValueError(f"{label} must be a probability in [0, 1], got {p}")
    weights = np.asarray(pattern_weights, dtype=float)
    if weights.shape != (3,) or (weights < 0).any() or weights.sum() <= 0:
        raise ValueError(f"pattern_weights must be 3 non-negative weights, got {pattern_weights}")
    return weights


def _copy_lookalikes(rng: np.random.Generator, copy_from: np.ndarray, pattern: np.ndarray,
                     tops: np.ndarray, scene_names: list[str], top_colour: np.ndarray,
                     bottom_colour: np.ndarray) -> None:
    """Give each look-alike its source's pattern and bottoms, tops re-drawn in their groups.

    Args:
        rng: random generator (draws two group and two colour indices per look-alike).
        copy_from: ``(N,)`` source person of each look-alike, -1 if none.
        pattern: ``(N,)`` torso patterns, updated in place.
        tops: ``(N, 2)`` indices of the source people's top colours in ``scene_names``.
        scene_names: the scene's palette colour names.
        top_colour: ``(N, 2, 3)`` top colours, updated in place.
        bottom_colour: ``(N, 3)`` bottom colours, updated in place.
    """
    group_of = {name: [g for g in LOOKALIKE_GROUPS if name in g] for name in _TOP_PALETTE}
    for i in np.flatnonzero(copy_from >= 0):
        j = copy_from[i]
        pattern[i] = pattern[j]
        bottom_colour[i] = bottom_colour[j]
        for k in range(2):
            name = scene_names[tops[j, k]]
            group = group_of[name][int(rng.integers(0, len(group_of[name])))]
            twin = group[int(rng.integers(0, len(group)))]
            top_colour[i, k] = _TOP_PALETTE[twin]


def _torso_colours(pattern: np.ndarray, top_colour: np.ndarray, colours: np.ndarray,
                   present: np.ndarray) -> np.ndarray:
    """Colour the torso bands by pattern, in place; returns the ``(N,)`` band counts.

    Stripes alternate the two colours; two-tone puts the second colour on the lower band.
    """
    n_bands = np.array([1, 5, 2])[pattern]
    band_index = np.arange(_MAX_BANDS)
    which = np.where(pattern[:, None] == 1, band_index[None] % 2,
                     np.where(pattern[:, None] == 2, (band_index[None] == 0).astype(int), 0))
    colours[:, _TORSO] = np.take_along_axis(top_colour, which[..., None], axis=1)
    present[:, _TORSO] = band_index[None] < n_bands[:, None]
    return n_bands


def _skin_limbs_and_hair(rng: np.random.Generator, n_bands: np.ndarray,
                         bottom_colour: np.ndarray, draws: np.ndarray, colours: np.ndarray,
                         present: np.ndarray) -> None:
    """Colour arms, legs, shoes, head, neck and hair, in place (draws skin, shoes, hair).

    Args:
        rng: random generator.
        n_bands: ``(N,)`` torso band counts (long sleeves take the upper band's colour).
        bottom_colour: ``(N, 3)`` trouser colours.
        draws: ``(N, 4)`` uniform draws; column 1 picks short sleeves, column 2 baldness.
        colours, present: the outfit arrays, written in place.
    """
    n = n_bands.shape[0]
    upper = np.take_along_axis(colours[:, _TORSO], (n_bands - 1)[:, None, None], axis=1)[:, 0]
    skin = _SKIN[rng.integers(0, len(_SKIN), size=n)] + 6.0 * rng.standard_normal((n, 3))
    short_sleeves = draws[:, 1] < 0.3
    colours[:, _S["arm_l"]] = np.where(short_sleeves[:, None], skin, upper)
    colours[:, _S["arm_r"]] = colours[:, _S["arm_l"]]
    colours[:, _S["leg_l"]] = bottom_colour
    colours[:, _S["leg_r"]] = bottom_colour
    shoes = _SHOES[rng.integers(0, len(_SHOES), size=n)]
    colours[:, _S["shoe_l"]] = shoes
    colours[:, _S["shoe_r"]] = shoes
    colours[:, _S["head"]] = skin
    colours[:, _S["neck"]] = skin * 0.9
    hair = _HAIR[rng.integers(0, len(_HAIR), size=n)]
    colours[:, _S["hair_back"]] = hair
    colours[:, _S["hair_cap"]] = hair
    bald = draws[:, 2] < 0.06
    present[:, _S["hair_cap"]] = ~bald
    present[:, _S["hair_back"]] = ~bald


def _accessories(rng: np.random.Generator, n: int, hat: float, bag: float, top_rgb: np.ndarray,
                 colours: np.ndarray, present: np.ndarray) -> None:
    """Draw hats and backpacks and set the (absent) device, in place."""
    palette_size = top_rgb.shape[0]
    has_hat = rng.random(n) < hat
    colours[:, _S["hat"]] = top_rgb[rng.integers(0, palette_size, size=n)]
    present[:, _S["hat"]] = has_hat
    has_bag = rng.random(n) < bag
    colours[:, _S["bag"]] = top_rgb[rng.integers(0, palette_size, size=n)] * 0.7
    present[:, _S["bag"]] = has_bag
    colours[:, _S["device"]] = _DEVICE
    present[:, _S["device"]] = False


def draw_appearances(
    n: int,
    rng: np.random.Generator,
    *,
    lookalike: float = 0.25,
    palette_size: int = 12,
    pattern_weights: Sequence[float] = (0.5, 0.25, 0.25),
    hat: float = 0.2,
    bag: float = 0.25,
    colour_jitter: float = 10.0,
) -> Appearances:
    """Draw the outfits of ``n`` people.

    Each scene uses ``palette_size`` colours of the palette (fewer colours, more coincidences).
    A person copies the outfit of an earlier one with probability ``lookalike``, re-drawing each
    colour within its look-alike group and keeping the pattern: the two then differ only in
    shade, accessories and build, the hard negatives of cross-view matching.

    Args:
        n: number of people.
        rng: random generator (the only source of randomness).
        lookalike: probability in [0, 1] that a person is a look-alike of an earlier one.
        palette_size: number of clothing colours available in the scene, 2..18.
        pattern_weights: relative weights of plain, stripes and two-tone torsos.
        hat: probability of a hat.
        bag: probability of a backpack.
        colour_jitter: standard deviation of the per-person colour perturbation, 0-255 scale.

    Returns:
        The :class:`Appearances`.
    """
    weights = _check_outfit_options(palette_size, lookalike, hat, bag, pattern_weights)
    names = list(_TOP_PALETTE)
    scene_names = [names[k] for k in rng.permutation(len(names))[:palette_size]]
    top_rgb = np.array([_TOP_PALETTE[k] for k in scene_names], dtype=float)

    colours = np.zeros((n, N_SLOTS, 3))
    present = np.ones((n, N_SLOTS), dtype=bool)
    pattern = rng.choice(3, size=n, p=weights / weights.sum())
    tops = rng.integers(0, palette_size, size=(n, 2))
    bottoms = rng.integers(0, len(_BOTTOM_PALETTE), size=n)
    copy_from = np.full(n, -1)
    draws = rng.random((n, 4))
    for i in range(1, n):
        if draws[i, 0] < lookalike:
            copy_from[i] = int(rng.integers(0, i))
    top_colour = top_rgb[tops]  # (n, 2, 3)
    bottom_colour = _BOTTOM_PALETTE[bottoms]
    _copy_lookalikes(rng, copy_from, pattern, tops, scene_names, top_colour, bottom_colour)
    top_colour += colour_jitter * rng.standard_normal((n, 2, 3))
    bottom_colour += colour_jitter * rng.standard_normal((n, 3))
    n_bands = _torso_colours(pattern, top_colour, colours, present)
    _skin_limbs_and_hair(rng, n_bands, bottom_colour, draws, colours, present)
    _accessories(rng, n, hat, bag, top_rgb, colours, present)
    return Appearances(
        colours=np.clip(colours, 0.0, 255.0),
        present=present,
        n_bands=n_bands,
        pattern=pattern,
        lookalike_of=copy_from,
    )


@dataclass(frozen=True, eq=False)
class BodyFrame:
    """The primitives of every person on one frame, in world coordinates.

    Attributes:
        vertices: ``(N, N_SLOTS, 16, 3)`` surface points.
        normals: ``(N, N_SLOTS, 16, 3)`` unit outward normals at those points.
        axis: ``(N, N_SLOTS, 3)`` unit axis of ring cylinders (bottom to top), the cap normal.
        present: ``(N, N_SLOTS)`` slots that exist.
        cap: ``(N, N_SLOTS)`` slots whose top cap is drawn when it faces the camera.
        colours: ``(N, N_SLOTS, 3)`` base BGR colours.
        head: ``(N, 3)`` head centres (the 3D head point of the labels).
        ground: ``(N, 3)`` ground points under the body axis (z = 0).
        centre: ``(N, 3)`` body centres (half height), for ordering people by distance.
    """

    vertices: np.ndarray
    normals: np.ndarray
    axis: np.ndarray
    present: np.ndarray
    cap: np.ndarray
    colours: np.ndarray
    head: np.ndarray
    ground: np.ndarray
    centre: np.ndarray


def walk_phases(people: PeopleState, fps: float) -> tuple[np.ndarray, np.ndarray]:
    """Gait phase and swing amplitude of every person on every frame.

    The phase advances with the distance walked (one cycle per ``_STRIDE`` metres), so feet do
    not slide; the amplitude follows the speed, so people who stop stand with their legs
    together.

    Returns:
        (phase, amplitude): two ``(F, N)`` arrays, radians and [0, 1].
    """
    pos = people.positions
    step = np.zeros(pos.shape[:2])
    if people.n_frames > 1:
        step[1:] = np.hypot(*(pos[1:] - pos[:-1]).transpose(2, 0, 1))
    phase = 2.0 * np.pi * np.cumsum(step, axis=0) / _STRIDE
    speed = step * fps
    speed[0] = speed[1] if people.n_frames > 1 else 0.0
    amplitude = np.clip(speed / 0.8, 0.0, 1.0)
    return phase, amplitude


def _cylinder(bottom: np.ndarray, top: np.ndarray, r_bottom: np.ndarray, r_top: np.ndarray,
              profile: np.ndarray = _RING) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ring-cylinder points between two centres in the body frame.

    Args:
        bottom, top: ``(N, 3)`` ring centres.
        r_bottom, r_top: ``(N, 2)`` half sizes (forward, left) of the two rings.
        profile: ``(8, 2)`` ring shape on the unit circle / square.

    Returns:
        (vertices (N, 16, 3), normals (N, 16, 3), axis (N, 3)).
    """
    axis = top - bottom
    axis /= np.linalg.norm(axis, axis=1, keepdims=True)
    left = np.array([0.0, 1.0, 0.0]) - axis[:, 1:2] * axis
    left /= np.linalg.norm(left, axis=1, keepdims=True)
    fwd = np.cross(left, axis)
    ring_b = (profile[None, :, :1] * r_bottom[:, None, :1] * fwd[:, None]
              + profile[None, :, 1:] * r_bottom[:, None, 1:] * left[:, None])
    ring_t = (profile[None, :, :1] * r_top[:, None, :1] * fwd[:, None]
              + profile[None, :, 1:] * r_top[:, None, 1:] * left[:, None])
    verts = np.concatenate([bottom[:, None] + ring_b, top[:, None] + ring_t], axis=1)
    r_mean = 0.5 * (r_bottom + r_top)
    normal = (profile[None, :, :1] / r_mean[:, None, :1] * fwd[:, None]
              + profile[None, :, 1:] / r_mean[:, None, 1:] * left[:, None])
    normal /= np.linalg.norm(normal, axis=2, keepdims=True)
    return verts, np.concatenate([normal, normal], axis=1), axis


def _ellipsoid(centre: np.ndarray, radii: np.ndarray, dirs: np.ndarray,
               shift: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Ellipsoid samples ``centre + dirs * radii`` (N, 16, 3), radial normals, vertical axis."""
    verts = centre[:, None] + dirs[None] * radii[:, None]
    if shift is not None:
        verts = verts + shift[:, None]
    normals = dirs[None] / radii[:, None]
    normals = normals / np.linalg.norm(normals, axis=2, keepdims=True)
    axis = np.broadcast_to(np.array([0.0, 0.0, 1.0]), centre.shape)
    return verts, normals, axis


def _swing(origin: np.ndarray, angle: np.ndarray, length: np.ndarray,
           outward: np.ndarray) -> np.ndarray:
    """End point of a limb hanging from ``origin``, swung forward by ``angle`` (radians)."""
    return origin + length[:, None] * np.stack(
        [np.sin(angle), outward, -np.cos(angle)], axis=1
    ) / np.sqrt(1.0 + outward[:, None] ** 2)


_Built = tuple[np.ndarray, np.ndarray, np.ndarray]
"""One primitive's ``(vertices, normals, axis)``, as :func:`_cylinder` gives."""


def _leg_parts(H: np.ndarray, W: np.ndarray, swing: np.ndarray) -> list[tuple[str, _Built]]:
    """Legs and shoes of N people in the body frame, swinging with the gait.

    Args:
        H, W: ``(N,)`` heights and shoulder widths, metres.
        swing: ``(N,)`` signed gait swing of the frame (amplitude times sin(phase)).

    Returns:
        ``(slot name, primitive)`` pairs for both legs and both shoes.
    """
    zeros = np.zeros(H.shape[0])
    parts: list[tuple[str, _Built]] = []
    hip_z = _HIP * H
    leg_len = hip_z - _SHOE_H * 0.6
    for side, sign in (("l", 1.0), ("r", -1.0)):
        hip = np.stack([zeros, sign * 0.2 * W, hip_z], axis=1)
        foot = _swing(hip, sign * _LEG_SWING * swing, leg_len, zeros)
        r_top = np.stack([_LEG_R[0] * H, _LEG_R[0] * H], axis=1)
        r_bot = np.stack([_LEG_R[1] * H, _LEG_R[1] * H], axis=1)
        parts.append((f"leg_{side}", _cylinder(foot, hip, r_bot, r_top)))
        shoe_c = foot + np.array([0.035, 0.0, 0.0]) * (H[:, None] / 1.75)
        shoe_b = shoe_c.copy()
        shoe_b[:, 2] = np.maximum(foot[:, 2] - _SHOE_H * H * 0.6, 0.0)
        shoe_t = shoe_b + np.array([0.0, 0.0, 1.0]) * (_SHOE_H * H)[:, None]
        r = np.stack([0.072 * H / 1.75, 0.05 * H / 1.75], axis=1)
        parts.append((f"shoe_{side}", _cylinder(shoe_b, shoe_t, r, r)))
    return parts


def _torso_parts(H: np.ndarray, W: np.ndarray, n_bands: np.ndarray) -> list[tuple[int, _Built]]:
    """Torso bands from the hip to the shoulder, tapering towards the waist.

    Args:
        H, W: ``(N,)`` heights and shoulder widths, metres.
        n_bands: ``(N,)`` number of torso bands of each person's pattern.

    Returns:
        ``(slot index, primitive)`` pairs for all :data:`_MAX_BANDS` band slots.
    """
    zeros = np.zeros(H.shape[0])
    hip_z = _HIP * H
    shoulder_z = _SHOULDER * H
    half_w_top = 0.5 * W - 1.6 * (_ARM_R * H)
    parts: list[tuple[int, _Built]] = []
    for b in range(_MAX_BANDS):
        lo = b / np.maximum(n_bands, 1)
        hi = (b + 1) / np.maximum(n_bands, 1)
        lo, hi = np.minimum(lo, 1.0), np.minimum(hi, 1.0)
        z0 = hip_z + lo * (shoulder_z - hip_z)
        z1 = hip_z + np.maximum(hi, lo + 1e-3) * (shoulder_z - hip_z)

        def ring(t: np.ndarray) -> np.ndarray:
            taper = 0.86 + 0.14 * t
            return np.stack([_CHEST_DEPTH * H * (0.92 + 0.08 * t), half_w_top * taper], axis=1)

        parts.append((int(_TORSO[b]), _cylinder(np.stack([zeros, zeros, z0], axis=1),
                                                np.stack([zeros, zeros, z1], axis=1),
                                                ring(lo), ring(hi))))
    return parts


def _arm_and_bag_parts(H: np.ndarray, W: np.ndarray,
                       swing: np.ndarray) -> list[tuple[str, _Built]]:
    """Arms (swinging opposite to the legs) and the backpack behind the upper torso.

    Args:
        H, W: ``(N,)`` heights and shoulder widths, metres.
        swing: ``(N,)`` signed gait swing of the frame.

    Returns:
        ``(slot name, primitive)`` pairs for both arms and the bag.
    """
    n = H.shape[0]
    zeros = np.zeros(n)
    shoulder_z = _SHOULDER * H
    arm_r = _ARM_R * H
    parts: list[tuple[str, _Built]] = []
    for side, sign in (("l", 1.0), ("r", -1.0)):
        shoulder = np.stack([zeros, sign * (0.5 * W - arm_r), shoulder_z - arm_r], axis=1)
        hand = _swing(shoulder, -sign * _ARM_SWING * swing, _ARM_LEN * H, sign * 0.08 + zeros)
        r = np.stack([arm_r, arm_r], axis=1)
        parts.append((f"arm_{side}", _cylinder(hand, shoulder, r * 0.8, r)))
    bag_b = np.stack([-(_CHEST_DEPTH * H + 0.07), zeros, 0.60 * H], axis=1)
    bag_t = bag_b + np.array([0.0, 0.0, 1.0]) * (0.2 * H)[:, None]
    r = np.stack([np.full(n, 0.07), 0.33 * W], axis=1)
    parts.append(("bag", _cylinder(bag_b, bag_t, r, r, _BOX_RING)))
    return parts


def _head_parts(H: np.ndarray) -> tuple[list[tuple[str, _Built]], np.ndarray, np.ndarray]:
    """Head, neck, hair and hat of N people in the body frame.

    Args:
        H: ``(N,)`` heights, metres.

    Returns:
        ``(slot name, primitive)`` pairs, the ``(N, 3)`` head centres and ``(N, 3)`` head radii.
    """
    zeros = np.zeros(H.shape[0])
    shoulder_z = _SHOULDER * H
    radii = _HEAD_R[None] * H[:, None]
    head_c = np.stack([zeros, zeros, H - radii[:, 2]], axis=1)
    neck_r = np.stack([0.5 * radii[:, 0], 0.6 * radii[:, 1]], axis=1)
    hat_b = np.stack([-0.01 * H, zeros, H - 0.45 * radii[:, 2]], axis=1)
    hat_t = hat_b + np.array([0.0, 0.0, 1.0]) * (0.5 * radii[:, 2] + 0.03)[:, None]
    parts = [
        ("head", _ellipsoid(head_c, radii, _HEAD_DIRS)),
        ("neck", _cylinder(np.stack([-0.2 * radii[:, 0], zeros, shoulder_z - 0.02 * H], axis=1),
                           np.stack([-0.2 * radii[:, 0], zeros, head_c[:, 2]], axis=1),
                           neck_r, neck_r)),
        ("hair_cap", _ellipsoid(head_c, radii * 1.07, _CAP_DIRS,
                                shift=np.stack([-0.012 * H, zeros, zeros], axis=1))),
        ("hair_back", _ellipsoid(head_c, radii * 1.07, _BACK_DIRS)),
        ("hat", _cylinder(hat_b, hat_t, radii[:, :2] * 1.12, radii[:, :2] * 1.02)),
    ]
    return parts, head_c, radii


def _put_device(verts: np.ndarray, normals: np.ndarray, axes: np.ndarray, w: int,
                device_style: str, device_offset: np.ndarray, head_c: np.ndarray,
                radii: np.ndarray, arm_r: np.ndarray, cos_h: np.ndarray,
                sin_h: np.ndarray) -> None:
    """Draw the carrier's device (and, for a phone, the arms holding it), in place.

    Args:
        verts, normals, axes: the body-frame primitives of all people, written in place.
        w: index of the carrier.
        device_style: ``"head"`` or ``"hand"`` (see :func:`body_frame`).
        device_offset: ``(3,)`` device position relative to the carrier's ground point (world).
        head_c, radii: ``(N, 3)`` head centres and radii (:func:`_head_parts`).
        arm_r: ``(N,)`` arm radii.
        cos_h, sin_h: ``(N,)`` cosine and sine of the headings.
    """
    if device_style == "head":
        base = head_c[w:w + 1] + np.array([[0.6, 0.0, 0.55]]) * radii[w:w + 1]
        top = base + np.array([[0.0, 0.0, 0.05]])
        size = np.array([[0.05, 0.035]])
    else:
        off = np.asarray(device_offset, dtype=float)
        local = np.array([cos_h[w] * off[0] + sin_h[w] * off[1],
                          -sin_h[w] * off[0] + cos_h[w] * off[1], off[2]])
        base = local[None] - np.array([[0.0, 0.0, 0.08]])
        top = local[None] + np.array([[0.0, 0.0, 0.08]])
        size = np.array([[0.012, 0.045]])
        for side, sign in (("l", 1.0), ("r", -1.0)):
            k = _S[f"arm_{side}"]
            shoulder = verts[w, k, 8:].mean(axis=0)
            grip = local + np.array([-0.02, sign * 0.05, -0.05])
            r = np.array([[arm_r[w], arm_r[w]]])
            v, nrm, ax = _cylinder(grip[None], shoulder[None], r * 0.8, r)
            verts[w, k], normals[w, k], axes[w, k] = v[0], nrm[0], ax[0]
    v, nrm, ax = _cylinder(base, top, size, size, _BOX_RING)
    k = _S["device"]
    verts[w, k], normals[w, k], axes[w, k] = v[0], nrm[0], ax[0]


def _to_world(people: PeopleState, f: int, verts: np.ndarray, normals: np.ndarray,
              axes: np.ndarray, present: np.ndarray, appearances: Appearances,
              head_c: np.ndarray) -> BodyFrame:
    """Rotate the body-frame primitives by the headings about z and translate them to the ground.

    Args:
        people: the walks.
        f: 0-based frame index.
        verts, normals: ``(N, N_SLOTS, 16, 3)`` body-frame points and normals.
        axes: ``(N, N_SLOTS, 3)`` body-frame ring axes.
        present: ``(N, N_SLOTS)`` slots that exist.
        appearances: clothing of the people.
        head_c: ``(N, 3)`` body-frame head centres.

    Returns:
        The :class:`BodyFrame`.
    """
    n = people.n_people
    H = people.heights
    zeros = np.zeros(n)
    heading = people.headings[f]
    cos_h, sin_h = np.cos(heading), np.sin(heading)
    rot = np.zeros((n, 3, 3))
    rot[:, 0, 0], rot[:, 0, 1] = cos_h, -sin_h
    rot[:, 1, 0], rot[:, 1, 1] = sin_h, cos_h
    rot[:, 2, 2] = 1.0
    ground = np.concatenate([people.positions[f], np.zeros((n, 1))], axis=1)
    world = np.einsum("nij,nsvj->nsvi", rot, verts) + ground[:, None, None]
    world_n = np.einsum("nij,nsvj->nsvi", rot, normals)
    world_axes = np.einsum("nij,nsj->nsi", rot, axes)
    cap = np.zeros((n, N_SLOTS), dtype=bool)
    cap[np.arange(n), _TORSO[appearances.n_bands - 1]] = True
    for slot in ("bag", "hat", "device"):
        cap[:, _S[slot]] = True
    centre = ground + np.stack([zeros, zeros, 0.5 * H], axis=1)
    return BodyFrame(
        vertices=world,
        normals=world_n,
        axis=world_axes,
        present=present,
        cap=cap & present,
        colours=appearances.colours,
        head=ground + (head_c - np.stack([zeros, zeros, zeros], axis=1)),
        ground=ground,
        centre=centre,
    )


def body_frame(
    people: PeopleState,
    frame: int,
    appearances: Appearances,
    phase: np.ndarray,
    amplitude: np.ndarray,
    *,
    device_offset: np.ndarray | None = None,
    device_style: str = "head",
) -> BodyFrame:
    """Build every person's primitives on one frame (vectorised over people).

    Args:
        people: the walks.
        frame: 1-based frame number.
        appearances: clothing of the people.
        phase, amplitude: ``(F, N)`` gait phase and amplitude (:func:`walk_phases`).
        device_offset: ``(3,)`` position of the egocentric camera relative to the carrier's
            ground point (world axes); draws the device on the carrier, ``None`` draws none.
        device_style: ``"head"`` (head-worn camera, drone scenario) or ``"hand"`` (a phone held
            in both hands at ``device_offset``, overview scenario).

    Returns:
        The :class:`BodyFrame`.
    """
    if not 1 <= frame <= people.n_frames:
        raise ValueError(f"frame must be in 1..{people.n_frames}, got {frame}")
    if device_style not in ("head", "hand"):
        raise ValueError(f"device_style must be 'head' or 'hand', got {device_style!r}")
    f = frame - 1
    n = people.n_people
    H, W = people.heights, people.widths
    verts = np.zeros((n, N_SLOTS, N_VERTICES, 3))
    normals = np.zeros((n, N_SLOTS, N_VERTICES, 3))
    axes = np.zeros((n, N_SLOTS, 3))
    present = appearances.present.copy()
    swing = amplitude[f] * np.sin(phase[f])
    head_parts, head_c, radii = _head_parts(H)
    parts: list[tuple[str | int, _Built]] = [
        *_leg_parts(H, W, swing), *_torso_parts(H, W, appearances.n_bands),
        *_arm_and_bag_parts(H, W, swing), *head_parts,
    ]
    for slot, built in parts:
        k = _S[slot] if isinstance(slot, str) else slot
        verts[:, k], normals[:, k], axes[:, k] = built
    if device_offset is not None:
        w = people.wearer
        present[w, _S["device"]] = True
        heading = people.headings[f]
        _put_device(verts, normals, axes, w, device_style, device_offset, head_c, radii,
                    _ARM_R * H, np.cos(heading), np.sin(heading))
    return _to_world(people, f, verts, normals, axes, present, appearances, head_c)
