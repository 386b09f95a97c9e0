"""Box-level scenes for issue 67: an oblique or nadir top camera, walking handheld cameras.

The world is the one of :mod:`xvmatch.datasets.box_scene`: people walk on the ground z = 0
(metres, z up) with :func:`~xvmatch.datasets.box_scene.simulate_walks`, 1.5-1.95 m tall. They
are seen by

* a TOP camera looking at the walking area from a pitch drawn in ``top_pitch`` (20 degrees:
  a low building camera or oblique drone, the horizon in or above the image; 90: a nadir
  drone), ``top_height`` metres up and ``height / tan(pitch)`` away horizontally, so that its
  optical axis meets the ground near the centre of the shared area. It is static by default;
  ``top_drift_speed`` and ``top_yaw_rate`` make it drift and yaw slowly (a drone), and
  ``top_pitch_rate`` tilts it steadily up or down about its drawn pitch (a drone's gimbal);
* one or more HORIZONTAL cameras (``"hor1"``, ``"hor2"``, ...) held at 1.4-1.7 m,
  ``hor_reach`` in front of a walker (their holder) who never appears in their own view. The
  holder walks slowly; the camera looks at the shared group (a smoothed gaze at its centroid),
  with a smooth head turn, a pan now and then and a small pitch / roll wobble.

**Boxes: one projection for every camera and pitch.** A person is a vertical cylinder of their
height and width; their box is the image bounding box of the cylinder's bottom and top circles
(32 points each), so an oblique camera sees an upright person and a nadir one a
head-and-shoulders blob leaning away from the image centre. A person with a body point nearer
than ``near_clip`` to the image plane (or behind it) is absent. Nearer people (smaller depth of
the body's mid-axis) hide the part of farther people that their clipped boxes cover
(:func:`~xvmatch.datasets.box_scene._visible_parts`); a person whose visible area is below
``min_visible_fraction`` of the full, unclipped box (hidden or truncated by the image border) is
dropped, the others keep the box of their visible part, inside the image (``box_extent``:
or running on past a border that cuts it, as trackers give boxes, or their whole box, behind
nearer people and past the border, as amodal annotations give it).

**Partial overlap: by placing part of the crowd outside one view.** The crowd is made of groups,
each walking in its own square (walks of separate :func:`simulate_walks` calls, translated):

* the SHARED group, in a square centred on the world origin, fitted inside the top image (the
  square shrinks, then the camera rises, up to the highest of ``top_height``, then a drifting,
  turning drone drifts and turns less, until it is) and in front of every handheld camera,
  whose holder stands far enough away that the square fills at most ~85% of its field of view;
* the TOP-ONLY group, in a square inside the top image (every frame checked) and outside every
  handheld camera's field of view (its bearing from the holder more than ``hfov / 2 + 15``
  degrees off the camera's mean gaze);
* per handheld camera k, a HOR-ONLY group in a square inside that camera's field of view and
  outside the top image on every frame (beside the top camera's footprint, under its near edge
  or behind it).

Per scene an overlap fraction is drawn for the top view and for each handheld view in
``overlap``; the top view gets ``n_top`` people (drawn in ``n_people``), ``round(p_top * n_top)``
of them shared, and handheld view k gets ``round(n_shared * (1 - p_k) / p_k)`` own people. Where
no square satisfying the conditions is found (a small footprint, cameras facing each other)
that group is left out; :attr:`ObliqueScene.overlap_target` gives the fractions the groups
actually placed aim at (a holder the top camera sees counts as one of its top-only people).
Measured per person over a 10 s clip (whoever is in a view at some time), the fractions match
those targets on the tests' scenes; frame by frame they scatter around them, naturally, and the
top view's is lower by up to about 0.2: near people hide shared ones from the level handheld
camera, which turns and pans; a moving top camera's footprint moves.

Everything random is drawn from the one generator given to :func:`make_oblique_scene`, in a
fixed order (group sizes and fractions; the top camera and the shared square; the handheld
cameras' fields of view and image sizes; each holder with its hor-only square; the top-only
square; the walks, group by group; then per handheld camera its height and motion), so a scene
is a pure function of the generator's seed, bit for bit. Ids are the person index (ground
truth; index 0 holds ``hor1``, the CVMHAT convention of id 0).
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from xvmatch.datasets.box_scene import (
    PeopleState,
    SceneConfig,
    _ou_step,
    _visible_parts,
    simulate_walks,
)
from xvmatch.formats.camera_io import save_cameras
from xvmatch.formats.mot_boxes import FrameBoxes, write_mot_boxes
from xvmatch.geometry.camera import Camera, intrinsics_from_fov, look_rotation

__all__ = [
    "BOX_EXTENTS",
    "ObliqueScene",
    "ObliqueSceneConfig",
    "distorted",
    "jittered",
    "make_oblique_scene",
    "pitch_drifted",
    "project_view",
    "sloped",
    "top_distorted",
    "top_rolled",
    "write_oblique_scene",
]

BOX_EXTENTS = ("visible", "past_border", "amodal")
"""What a person's box may cover (:attr:`ObliqueSceneConfig.box_extent`)."""

# Points sampled on each of a body cylinder's two circles (bottom and top) for its image box.
_CIRCLE_POINTS = 32
# Height (m) up to which a group's square is checked against a camera's image (heads).
_CHECK_HEIGHT = 2.0
# Margin (fraction of the image width) kept between a group's square and an image border.
_IMAGE_MARGIN = 0.03
# Part of a handheld camera's half field of view the shared square may fill.
_SHARED_CONE = 0.85
# Extra angle (degrees) beyond a handheld camera's half field of view for the top-only group.
_OUTSIDE_CONE_DEG = 15.0
# Side (m) of the square a holder walks in (by default), and the gap (m) kept between squares.
_HOLDER_AREA = 2.0
_GROUP_GAP = 1.0
# Candidate squares tried for a top-only or hor-only group before it is left out, and holder
# azimuths tried for a hor-only group (the candidates shared among them).
_TRIES = 300
_AZIMUTHS = 6
# Time constant (s) of the smoothing of a handheld camera's gaze at the shared group.
_GAZE_SMOOTHING = 1.0
# Time constant (s) of the pitch / roll wobble of a handheld camera.
_WOBBLE_TIME = 1.0
# Side (m) of an edge group's square (enlarged for big groups), across a bottom image edge.
_EDGE_SIDE = 3.0


@dataclass(frozen=True)
class ObliqueSceneConfig:
    """What shapes an oblique scene; lengths in metres, angles in degrees, times in seconds.

    Every ``(min, max)`` pair is drawn uniformly (integers inclusive).

    Attributes:
        n_people: people in the top view's groups (shared + top-only), drawn once per scene.
        n_hor: number of handheld cameras (``"hor1"`` ... ``"horK"``), each with its holder.
        overlap: fraction of a view's people also seen by the other view, drawn for the top view
            and for each handheld view (see the module docstring).
        area: side of the shared group's square (shrunk to fit the top image if needed).
        group_area: side of a top-only or hor-only group's square (enlarged for big groups).
        height_range: body height, per person.
        width_range: body width (the cylinder's diameter), per person.
        min_separation: smallest distance between two people of a group (>= the widest body).
        fps: frame rate.
        walk_speed: preferred walking speed (m/s), per person.
        stop_probability: probability per second that a walker stops.
        stop_duration: mean duration of a stop (s, exponentially distributed): with
            ``stop_probability`` it sets the share of people standing at any time,
            ``p d / (1 + p d)`` (a third by default; 0.5 a second for 30 s, a lingering crowd,
            94 %).
        top_size: top image (width, height), pixels.
        top_pitch: downward pitch of the top camera (90: nadir).
        top_height: height of the top camera (raised where the shared square cannot fit,
            up to the range's top; a drone's drift and turn slowed past it).
        top_hfov: horizontal field of view of the top camera.
        top_drift_speed: horizontal drift speed of the top camera (m/s), direction uniform;
            (0, 0) keeps it static.
        top_yaw_rate: yaw rate of the top camera (degrees per second), sign uniform.
        top_pitch_rate: pitch rate of the top camera (degrees per second), sign uniform; the
            drawn pitch is the clip's middle one, the camera's position does not change (a
            gimbal tilting). (0, 0), the default, keeps the pitch and every draw as before.
        hor_sizes: image sizes a handheld camera's is drawn from (uniformly).
        hor_hfov: horizontal field of view of a handheld camera.
        hor_height: height of a handheld camera (at most its holder's height - 0.1).
        hor_reach: distance of the camera in front of its holder's body axis.
        hor_extra_distance: added to the holder's smallest distance from the shared square's
            centre (the one at which the square fits the camera's field of view).
        holder_speed: walking speed of a holder (m/s), in their square.
        holder_area: side of the square a holder walks in (m), per holder: 2 m, the default,
            turns on the spot; 10 m walks past the scene. A fixed side draws nothing, so the
            default scenes are as before.
        hor_distortion: radial distortion k1 of a handheld camera's lens (Brown's model on
            the pinhole's normalised image coordinates), per camera: 0, the default, a
            pinhole; negative, barrel (about -0.1 a phone's wide lens, -0.25 an action
            camera's). A fixed value draws nothing, so the rest of the scene is as without.
        hor_pitch: mean pitch of a handheld camera (positive looks down), per camera.
        hor_wobble: standard deviation of the smooth pitch and roll wobble about that mean.
        head_turn_std: standard deviation of the smooth head turn about the gaze at the group.
        head_turn_time: correlation time of that head turn.
        pan_rate: pans per second (a pan turns away and back, smoothly).
        pan_angle: amplitude of a pan (sign uniform).
        pan_duration: duration of a pan, out and back.
        near_clip: a person with a body point nearer than this to a camera's image plane is
            absent from its view.
        min_visible_fraction: a person whose visible area is below this fraction of the full box
            is dropped.
        edge_people: people drawn per camera (top and each handheld) who walk in a square
            across its image's bottom edge, where their boxes are cut by it: a close drone's
            near edge, a handheld camera's passers-by. Extra people, not counted in
            :attr:`ObliqueScene.overlap_target`. (0, 0), the default, keeps every draw as
            before.
        box_extent: what a kept person's box covers (:data:`BOX_EXTENTS`): ``"visible"``,
            the default, their visible part clipped to the image (annotation tools' boxes);
            ``"past_border"``, that part run on past a border that cuts it to their whole
            box's edge (trackers' boxes); ``"amodal"``, their whole box, behind nearer people
            and past the border (the MOTChallenge annotations'). Draws nothing.
    """

    n_people: tuple[int, int] = (3, 12)
    n_hor: int = 1
    overlap: tuple[float, float] = (0.3, 1.0)
    area: tuple[float, float] = (5.0, 10.0)
    group_area: tuple[float, float] = (3.0, 6.0)
    height_range: tuple[float, float] = (1.5, 1.95)
    width_range: tuple[float, float] = (0.4, 0.5)
    min_separation: float = 0.6
    fps: float = 10.0
    walk_speed: tuple[float, float] = (0.3, 1.4)
    stop_probability: float = 0.1
    stop_duration: float = 5.0
    top_size: tuple[int, int] = (1920, 1080)
    top_pitch: tuple[float, float] = (20.0, 90.0)
    top_height: tuple[float, float] = (4.0, 60.0)
    top_hfov: tuple[float, float] = (55.0, 85.0)
    top_drift_speed: tuple[float, float] = (0.0, 0.0)
    top_yaw_rate: tuple[float, float] = (0.0, 0.0)
    top_pitch_rate: tuple[float, float] = (0.0, 0.0)
    hor_sizes: tuple[tuple[int, int], ...] = ((3640, 2048), (1920, 1080))
    hor_hfov: tuple[float, float] = (60.0, 80.0)
    hor_height: tuple[float, float] = (1.4, 1.7)
    hor_reach: float = 0.3
    hor_extra_distance: tuple[float, float] = (0.0, 4.0)
    holder_speed: tuple[float, float] = (0.1, 0.5)
    holder_area: tuple[float, float] = (_HOLDER_AREA, _HOLDER_AREA)
    hor_distortion: tuple[float, float] = (0.0, 0.0)
    hor_pitch: tuple[float, float] = (-3.0, 5.0)
    hor_wobble: float = 1.0
    head_turn_std: float = 8.0
    head_turn_time: float = 2.0
    pan_rate: float = 0.05
    pan_angle: tuple[float, float] = (15.0, 40.0)
    pan_duration: tuple[float, float] = (1.5, 3.0)
    near_clip: float = 0.3
    min_visible_fraction: float = 0.3
    edge_people: tuple[int, int] = (0, 0)
    box_extent: str = "visible"

    def __post_init__(self) -> None:
        def pair(name: str, low: float, high: float = np.inf) -> None:
            value = getattr(self, name)
            if len(value) != 2 or not low <= value[0] <= value[1] <= high:
                raise ValueError(
                    f"ObliqueSceneConfig.{name} must be (min, max) with {low} <= min <= max "
                    f"<= {high}, got {value}"
                )

        pair("n_people", 1, 60)
        pair("overlap", 0.05, 1.0)
        pair("area", 1.0)
        pair("group_area", 1.0)
        pair("height_range", 0.5, 2.5)
        pair("width_range", 0.1, 1.0)
        pair("walk_speed", 0.0)
        pair("top_pitch", 5.0, 90.0)
        pair("top_height", 2.5)
        pair("top_hfov", 1.0, 170.0)
        pair("top_drift_speed", 0.0)
        pair("top_yaw_rate", 0.0)
        pair("top_pitch_rate", 0.0, 30.0)
        pair("hor_hfov", 1.0, 170.0)
        pair("hor_height", 0.5)
        pair("hor_extra_distance", 0.0)
        pair("holder_speed", 0.0)
        pair("holder_area", 1.0, 100.0)
        pair("hor_pitch", -45.0, 45.0)
        pair("hor_distortion", -0.5, 0.5)
        pair("pan_angle", 0.0, 180.0)
        pair("pan_duration", 1e-3)
        pair("edge_people", 0, 20)
        if self.box_extent not in BOX_EXTENTS:
            raise ValueError(f"ObliqueSceneConfig.box_extent must be one of {BOX_EXTENTS}, "
                             f"got {self.box_extent!r}")
        if not 1 <= int(self.n_hor) <= 8:
            raise ValueError(f"ObliqueSceneConfig.n_hor must be in 1..8, got {self.n_hor}")
        if not self.hor_sizes:
            raise ValueError("ObliqueSceneConfig.hor_sizes must hold at least one size")
        sizes = [("top_size", self.top_size)]
        sizes += [(f"hor_sizes[{i}]", size) for i, size in enumerate(self.hor_sizes)]
        for name, size in sizes:
            if len(size) != 2 or min(size) < 8:
                raise ValueError(f"ObliqueSceneConfig.{name} must be (width, height) >= 8, "
                                 f"got {size}")
        for name in ("fps", "min_separation", "near_clip", "head_turn_time", "stop_duration"):
            if not getattr(self, name) > 0:
                raise ValueError(f"ObliqueSceneConfig.{name} must be > 0, "
                                 f"got {getattr(self, name)}")
        for name in ("hor_reach", "hor_wobble", "head_turn_std", "pan_rate", "stop_probability"):
            if not getattr(self, name) >= 0:
                raise ValueError(f"ObliqueSceneConfig.{name} must be >= 0, "
                                 f"got {getattr(self, name)}")
        if self.min_separation < self.width_range[1]:
            raise ValueError(
                f"ObliqueSceneConfig.min_separation ({self.min_separation}) must be >= the "
                f"largest width ({self.width_range[1]}) so that bodies never intersect"
            )
        if not 0.0 <= self.min_visible_fraction <= 1.0:
            raise ValueError("ObliqueSceneConfig.min_visible_fraction must be in [0, 1], "
                             f"got {self.min_visible_fraction}")


@dataclass(frozen=True, eq=False)
class ObliqueScene:
    """A drawn scene: its people, its cameras frame by frame, and the boxes of every view.

    Attributes:
        config: the configuration it was drawn from.
        people: the 3D state (:class:`~xvmatch.datasets.box_scene.PeopleState`); ids are the
            person index; ``people.wearer`` (index 0) holds ``hor1``, and ``head_yaw``,
            ``head_pitch``, ``head_roll`` are ``hor1``'s camera angles.
        top_cameras: F top cameras, ``top_cameras[f - 1]`` for frame f.
        hor_cameras: ``{view: F cameras}`` for the views ``"hor1"``, ``"hor2"``, ...
        top: ``{frame: FrameBoxes}`` of the top view, frames 1..F (possibly empty records).
        hor: ``{view: {frame: FrameBoxes}}`` of the handheld views.
        groups: ``{name: person indices}``: ``"holders"`` (``holders[k - 1]`` holds ``horK``),
            ``"shared"``, ``"top_only"`` and ``"horK_only"``; with
            :attr:`ObliqueSceneConfig.edge_people`, ``"top_edge"`` and ``"horK_edge"`` too.
        overlap: the fractions drawn, ``{"top": p, "hor1": p1, ...}``.
        overlap_target: the fractions the placed groups aim at (``overlap`` unless a group was
            rounded or left out): shared / (shared + top-only) for the top view, shared /
            (shared + horK-only) for view horK.
        hor_distortion: ``{view: k1}``, each handheld lens's distortion drawn (0: a pinhole).
        top_distortion: the top lens's distortion (:func:`top_distorted`; 0: a pinhole).
        ground: ``(F, N)`` the ground's height under each person, metres, where it slopes
            (:func:`sloped`); None: level. Every view's boxes are projected with these, so the
            transforms below compose in any order.
    """

    config: ObliqueSceneConfig
    people: PeopleState
    top_cameras: list[Camera]
    hor_cameras: dict[str, list[Camera]]
    top: dict[int, FrameBoxes]
    hor: dict[str, dict[int, FrameBoxes]]
    groups: dict[str, np.ndarray]
    overlap: dict[str, float]
    overlap_target: dict[str, float]
    hor_distortion: dict[str, float] = field(default_factory=dict)
    top_distortion: float = 0.0
    ground: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        """Number of frames F."""
        return self.people.n_frames


# --------------------------------------------------------------------------------------------
# Projection


def project_view(
    positions: np.ndarray,
    heights: np.ndarray,
    widths: np.ndarray,
    camera: Camera,
    *,
    near_clip: float = 0.3,
    min_visible_fraction: float = 0.3,
    present: np.ndarray | None = None,
    k1: float = 0.0,
    extent: str = "visible",
    ground: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Boxes of upright people in one camera's image, with occlusion and truncation.

    Each person is a vertical cylinder of diameter ``widths`` from the ground to ``heights``;
    the full box is the image bounding box of 32 points on each of its two circles. A person
    with a point nearer than ``near_clip`` to the image plane (or behind it) is absent; one
    whose full box misses the image is absent. Visibility: the boxes clipped to the image hide
    one another, nearest (depth of the body's mid-axis) in front
    (:func:`~xvmatch.datasets.box_scene._visible_parts`); a person whose visible area is below
    ``min_visible_fraction`` of the full, unclipped box is dropped, the others keep the bounding
    box of their visible part, or as ``extent`` says (:attr:`ObliqueSceneConfig.box_extent`:
    run on past a border that cuts it, as trackers give it; the whole box, amodal).

    Args:
        positions: ``(N, 2)`` ground positions, metres.
        heights: ``(N,)`` body heights, metres.
        widths: ``(N,)`` body widths, metres.
        camera: the camera.
        near_clip: metres.
        min_visible_fraction: in [0, 1].
        present: ``(N,)`` bool, people that may be seen (e.g. not the camera's holder);
            ``None``: everyone.
        k1: the lens's radial distortion (:func:`distorted`), 0: a pinhole.
        extent: ``"visible"``, ``"past_border"`` or ``"amodal"``.
        ground: ``(N,)`` the height of the ground under each person's feet, metres (a sloping
            ground, :func:`sloped`); ``None``: 0 for everyone.

    Returns:
        (index, boxes): ``(M,)`` int64 indices into N, ascending, and ``(M, 4)`` ``x, y, w, h``
        boxes in pixels, inside the image (but with ``extent`` ``"past_border"`` or
        ``"amodal"``).
    """
    if extent not in BOX_EXTENTS:
        raise ValueError(f"project_view: extent must be one of {BOX_EXTENTS}, got {extent!r}")
    positions = np.asarray(positions, dtype=float).reshape(-1, 2)
    n = positions.shape[0]
    heights = np.asarray(heights, dtype=float).reshape(n)
    widths = np.asarray(widths, dtype=float).reshape(n)
    base = np.zeros(n) if ground is None else np.asarray(ground, dtype=float).reshape(n)
    angle = np.linspace(0.0, 2.0 * np.pi, _CIRCLE_POINTS, endpoint=False)
    ring = np.stack([np.cos(angle), np.sin(angle)], axis=1)  # (P, 2)
    xy = positions[:, None, :] + 0.5 * widths[:, None, None] * ring[None]  # (N, P, 2)
    z = base[:, None] + np.concatenate([np.zeros((n, _CIRCLE_POINTS)),
                                        np.broadcast_to(heights[:, None], (n, _CIRCLE_POINTS))],
                                       axis=1)
    points = np.concatenate([np.concatenate([xy, xy], axis=1), z[..., None]], axis=2)
    uv, depth = camera.project(points)  # (N, 2P, 2), (N, 2P)
    if k1:
        uv = distorted(uv, camera.K, k1)
    front = (depth > near_clip).all(axis=1)
    if present is not None:
        front &= np.asarray(present, dtype=bool).reshape(n)
    uv = np.where(front[:, None, None], uv, 0.0)
    full = np.concatenate([uv.min(axis=1), uv.max(axis=1)], axis=1)  # x0, y0, x1, y1
    full_area = (full[:, 2] - full[:, 0]) * (full[:, 3] - full[:, 1])
    size = np.array([camera.width, camera.height, camera.width, camera.height], dtype=float)
    clipped = np.clip(full, 0.0, size)
    seen = front & (clipped[:, 2] > clipped[:, 0]) & (clipped[:, 3] > clipped[:, 1])
    seen &= full_area > 0
    idx = np.flatnonzero(seen)
    if idx.size == 0:
        return np.empty(0, dtype=np.int64), np.empty((0, 4))
    mid = np.concatenate([positions[idx], base[idx, None] + 0.5 * heights[idx, None]], axis=1)
    area, part = _visible_parts(clipped[idx], camera.depth(mid))
    keep = (area > 0) & (area >= min_visible_fraction * full_area[idx])
    part = part[keep]
    if extent == "past_border":  # a side the border cut (and no nearer person hides) runs on
        whole, inside = full[idx[keep]], clipped[idx[keep]]
        part = np.where((whole != inside) & (part == inside), whole, part)
    elif extent == "amodal":
        part = full[idx[keep]]
    boxes = np.concatenate([part[:, :2], part[:, 2:] - part[:, :2]], axis=1)
    return idx[keep].astype(np.int64), boxes


def distorted(uv: np.ndarray, K: np.ndarray, k1: float) -> np.ndarray:
    """Pinhole pixels ``(..., 2)`` moved by radial distortion ``k1`` (Brown's model, one term:
    the normalised radius r becomes r (1 + k1 r^2)); for barrel distortion (k1 < 0) the factor
    stops at the radius where the image of a ray would turn back (r^2 = -1 / (3 k1)), so no
    point far out of view folds into the image."""
    f, c = np.array([K[0, 0], K[1, 1]]), K[:2, 2]
    xy = (np.asarray(uv, float) - c) / f
    r2 = np.sum(xy * xy, axis=-1, keepdims=True)
    if k1 < 0:
        r2 = np.minimum(r2, -1.0 / (3.0 * k1))
    return c + f * xy * (1.0 + k1 * r2)


def jittered(frames: dict[int, FrameBoxes], sigma: float, rng: np.random.Generator,
             size: tuple[int, int], clip: bool = True) -> dict[int, FrameBoxes]:
    """One view's boxes ``{frame: FrameBoxes}`` with each edge moved by a normal draw of
    ``sigma`` times the box's height (an annotator's or a detector's looseness), then clipped
    to the ``size`` image as annotation tools and detectors clip them (``clip``; else only a
    side already past the border may stay past it), at least 2 px wide and tall."""
    out = {}
    for f in sorted(frames):
        rec = frames[f]
        b = np.asarray(rec.boxes, float).reshape(-1, 4)
        x0, y0, x1, y1 = (b[:, 0], b[:, 1], b[:, 0] + b[:, 2], b[:, 1] + b[:, 3])
        step = sigma * b[:, 3:4] * rng.standard_normal((len(b), 4))
        lo = (np.minimum(x0, 0.0), np.minimum(y0, 0.0)) if not clip else (0.0, 0.0)
        hi = (np.maximum(x1, size[0]), np.maximum(y1, size[1])) if not clip else size
        x0, x1 = (np.clip(v + step[:, k], lo[0], hi[0]) for k, v in ((0, x0), (2, x1)))
        y0, y1 = (np.clip(v + step[:, k], lo[1], hi[1]) for k, v in ((1, y0), (3, y1)))
        x0, y0 = np.minimum(x0, size[0] - 2.0), np.minimum(y0, size[1] - 2.0)
        w, h = np.maximum(x1 - x0, 2.0), np.maximum(y1 - y0, 2.0)
        out[f] = FrameBoxes(f, rec.ids, np.column_stack([x0, y0, w, h]))
    return out


def _project_frames(
    people: PeopleState,
    cameras: Sequence[Camera],
    config: ObliqueSceneConfig,
    hidden: int | None = None,
    k1: float = 0.0,
    ground: np.ndarray | None = None,
) -> dict[int, FrameBoxes]:
    """``{frame: FrameBoxes}`` of one view over all frames (``hidden``: its camera's holder;
    ``k1``: its lens's distortion; ``ground``: ``(F, N)`` the ground's height under each
    person, a sloping ground)."""
    present = np.ones(people.n_people, dtype=bool)
    if hidden is not None:
        present[hidden] = False
    records = {}
    for f, cam in enumerate(cameras):
        idx, boxes = project_view(
            people.positions[f], people.heights, people.widths, cam,
            near_clip=config.near_clip, min_visible_fraction=config.min_visible_fraction,
            present=present, k1=k1, extent=config.box_extent,
            ground=None if ground is None else ground[f],
        )
        records[f + 1] = FrameBoxes(f + 1, people.ids[idx], boxes)
    return records


# --------------------------------------------------------------------------------------------
# Placing the groups


def _wrap(angle: np.ndarray | float) -> np.ndarray:
    """Angles wrapped to [-pi, pi)."""
    return np.mod(np.asarray(angle) + np.pi, 2.0 * np.pi) - np.pi


def _square_points(centre: np.ndarray, side: float) -> np.ndarray:
    """A 7 x 7 grid over the square at ground and head height, ``(98, 3)``."""
    t = np.linspace(-0.5 * side, 0.5 * side, 7)
    gx, gy = np.meshgrid(t, t)
    xy = np.column_stack([gx.ravel(), gy.ravel()]) + np.asarray(centre)[None]
    return np.concatenate([np.column_stack([xy, np.zeros(len(xy))]),
                           np.column_stack([xy, np.full(len(xy), _CHECK_HEIGHT)])])


def _inside(cameras: Sequence[Camera], points: np.ndarray, near: float) -> bool:
    """Every point in front of every camera and inside its image, off the border."""
    for cam in cameras:
        uv, depth = cam.project(points)
        m = _IMAGE_MARGIN * cam.width
        ok = (depth > near) & (uv[:, 0] >= m) & (uv[:, 0] <= cam.width - m)
        ok &= (uv[:, 1] >= m) & (uv[:, 1] <= cam.height - m)
        if not ok.all():
            return False
    return True


def _outside(cameras: Sequence[Camera], points: np.ndarray) -> bool:
    """No point inside any camera's image, widened by the margin (behind it counts as out)."""
    for cam in cameras:
        uv, depth = cam.project(points)
        m = _IMAGE_MARGIN * cam.width
        inside = (depth > 0) & (uv[:, 0] >= -m) & (uv[:, 0] <= cam.width + m)
        inside &= (uv[:, 1] >= -m) & (uv[:, 1] <= cam.height + m)
        if inside.any():
            return False
    return True


def _off_axis(apex: np.ndarray, gaze: float, points: np.ndarray) -> np.ndarray:
    """Absolute bearing of ground points ``(..., >=2)`` from ``apex`` off ``gaze``, radians."""
    d = np.asarray(points)[..., :2] - apex
    return np.abs(_wrap(np.arctan2(d[..., 1], d[..., 0]) - gaze))


@dataclass(frozen=True)
class _Region:
    """A group's walking square: centre (2,), side, metres."""

    centre: np.ndarray
    side: float

    @property
    def radius(self) -> float:
        return float(self.side / np.sqrt(2.0))

    def clear_of(self, others: Sequence[_Region]) -> bool:
        return all(np.hypot(*(self.centre - o.centre)) >= self.radius + o.radius + _GROUP_GAP
                   for o in others)


def _group_side(n: int, drawn: float, min_sep: float) -> float:
    """Side of a square for n people ``min_sep`` apart: ``drawn``, enlarged when too small
    for simulate_walks (``n min_sep^2 <= (side - min_sep)^2 / 2``, with 20% to spare)."""
    need = min_sep + 1.2 * np.sqrt(2.0 * n) * min_sep
    return float(max(drawn, need))


def _top_camera(yaw: float, pitch: float, height: float, aim: np.ndarray, hfov: float,
                size: tuple[int, int], shift: np.ndarray, dyaw: float,
                dpitch: float = 0.0) -> Camera:
    """The top camera looking at ground point ``aim``, moved by ``shift``, yawed by ``dyaw``
    and pitched by ``dpitch`` where it stands (kept within 5-90 degrees down)."""
    look = np.array([np.cos(yaw), np.sin(yaw)])
    distance = height / np.tan(pitch) if pitch < np.pi / 2 else 0.0
    c = np.array([*(aim - distance * look + shift), height])
    tilt = float(np.clip(pitch + dpitch, np.radians(5.0), np.pi / 2))
    return Camera(K=intrinsics_from_fov(size[0], size[1], hfov),
                  R=look_rotation(yaw + dyaw, tilt), c=c, width=size[0], height=size[1])


def _check_frames(n_frames: int) -> list[int]:
    """Frames whose cameras a placement is checked against: first, middle, last."""
    return sorted({0, (n_frames - 1) // 2, n_frames - 1})

def _hor_only_region(
    holder: _Region,
    gaze: float,
    half: float,
    side: float,
    reach: float,
    placed: Sequence[_Region],
    top_checks: Sequence[Camera],
    draws: np.ndarray,
) -> _Region | None:
    """A square of ``side`` within ``half`` (radians) of the holder's ``gaze``, at most
    ``reach + 30`` m away, clear of ``placed`` and outside every top image; None if none of the
    ``(T, 2)`` uniform ``draws`` (bearing, range) gives one."""
    for a, b in draws:
        r = 2.0 + side + b * (reach + 30.0)
        bearing = gaze + (2.0 * a - 1.0) * half
        c = holder.centre + r * np.array([np.cos(bearing), np.sin(bearing)])
        region = _Region(c, side)
        if not region.clear_of(placed):
            continue
        pts = _square_points(c, side)
        if (_off_axis(holder.centre, gaze, pts) <= half).all() and _outside(top_checks, pts):
            return region
    return None



# --------------------------------------------------------------------------------------------
# Handheld cameras


def _handheld_cameras(
    holder_xy: np.ndarray,
    target_xy: np.ndarray,
    cam_height: float,
    size: tuple[int, int],
    hfov: float,
    config: ObliqueSceneConfig,
    rng: np.random.Generator,
) -> tuple[list[Camera], np.ndarray]:
    """F cameras of one holder, and their ``(F, 3)`` yaw, pitch, roll (radians).

    The yaw is a smoothed bearing from the holder to ``target_xy`` (the shared group's
    centroid per frame), plus an Ornstein-Uhlenbeck head turn and pans (a raised-cosine turn
    away and back); pitch and roll wobble (Ornstein-Uhlenbeck) about a drawn mean pitch.
    """
    n_frames = holder_xy.shape[0]
    dt = 1.0 / config.fps
    mean_pitch = np.radians(rng.uniform(*config.hor_pitch))
    noise = rng.standard_normal((n_frames, 3))
    pan_draw = rng.random((n_frames, 4))
    turn_std = np.radians(config.head_turn_std)
    wobble_std = np.radians(config.hor_wobble)
    decay_turn = np.exp(-dt / config.head_turn_time)
    decay_wob = np.exp(-dt / _WOBBLE_TIME)
    blend = 1.0 - np.exp(-dt / _GAZE_SMOOTHING)
    state = np.array([turn_std, wobble_std, wobble_std]) * noise[0]
    angles = np.empty((n_frames, 3))
    gaze = 0.0
    pan_left, pan_len, pan_amp = 0.0, 1.0, 0.0
    lo_amp, hi_amp = np.radians(config.pan_angle)
    for t in range(n_frames):
        to = target_xy[t] - holder_xy[t]
        bearing = float(np.arctan2(to[1], to[0]))
        gaze = bearing if t == 0 else float(_wrap(gaze + blend * _wrap(bearing - gaze)))
        if t > 0:
            decay = np.array([decay_turn, decay_wob, decay_wob])
            std = np.array([turn_std, wobble_std, wobble_std])
            state = decay * state + std * np.sqrt(1.0 - decay**2) * noise[t]
            if pan_left <= 0 and pan_draw[t, 0] < config.pan_rate * dt:
                pan_len = config.pan_duration[0] + pan_draw[t, 1] * (
                    config.pan_duration[1] - config.pan_duration[0])
                pan_amp = (lo_amp + pan_draw[t, 2] * (hi_amp - lo_amp)) * (
                    1.0 if pan_draw[t, 3] < 0.5 else -1.0)
                pan_left = pan_len
            else:
                pan_left = max(0.0, pan_left - dt)
        pan = pan_amp * np.sin(np.pi * (1.0 - pan_left / pan_len)) ** 2 if pan_left > 0 else 0.0
        angles[t] = (float(_wrap(gaze + state[0] + pan)), mean_pitch + state[1], state[2])
    K = intrinsics_from_fov(size[0], size[1], hfov)
    cams = []
    for (x, y), (yaw, pitch, roll) in zip(holder_xy.tolist(), angles.tolist(), strict=True):
        c = np.array([x + config.hor_reach * np.cos(yaw), y + config.hor_reach * np.sin(yaw),
                      cam_height])
        cams.append(Camera(K=K, R=look_rotation(yaw, pitch, roll), c=c, width=size[0],
                           height=size[1]))
    return cams, angles


# --------------------------------------------------------------------------------------------
# The scene


def _draw_group_sizes(
    config: ObliqueSceneConfig, n_hor: int, rng: np.random.Generator
) -> tuple[float, list[float], int, int, list[int]]:
    """Group sizes from the drawn overlap fractions.

    Returns:
        ``(p_top, p_hor, n_shared, n_top_only, n_hor_only)``: the drawn overlap fractions of
        the top view and of each handheld view, and the people of the shared group, of the
        top-only group and of each hor-only group.
    """
    n_top = int(rng.integers(config.n_people[0], config.n_people[1] + 1))
    p_top = float(rng.uniform(*config.overlap))
    p_hor = [float(rng.uniform(*config.overlap)) for _ in range(n_hor)]
    n_shared = int(np.clip(np.round(p_top * n_top), 1, n_top))
    n_hor_only = [int(np.round(n_shared * (1.0 - p) / p)) for p in p_hor]
    return p_top, p_hor, n_shared, n_top - n_shared, n_hor_only


_FIT_STEPS = 200
"""Steps of fitting the shared square inside the top image (shrink it, raise, steady)."""

_MIN_STEADY = 0.05
"""The drone's drift and turn are slowed to no less than this share of the drawn ones."""


def _place_top_camera(
    config: ObliqueSceneConfig, times: np.ndarray, n_shared: int, rng: np.random.Generator
) -> tuple[list[Camera], list[Camera], float]:
    """The top camera, looking at the shared square; the square fitted inside its image.

    Args:
        config: the configuration.
        times: ``(F,)`` frame times, seconds.
        n_shared: people of the shared group.
        rng: the source of randomness.

    Returns:
        ``(top_cameras, top_checks, side)``: the F top cameras, those of the check frames
        (:func:`_check_frames`) and the side of the shared square, metres.
    """
    n_frames = times.shape[0]
    yaw = float(rng.uniform(-np.pi, np.pi))
    pitch = float(np.radians(rng.uniform(*config.top_pitch)))
    height = float(rng.uniform(*config.top_height))
    hfov = float(rng.uniform(*config.top_hfov))
    drift_dir = float(rng.uniform(-np.pi, np.pi))
    drift = float(rng.uniform(*config.top_drift_speed))
    yaw_rate = float(np.radians(rng.uniform(*config.top_yaw_rate))) * (
        1.0 if rng.random() < 0.5 else -1.0)
    side = float(rng.uniform(*config.area))
    aim = rng.uniform(-0.2, 0.2, size=2) * side
    pitch_rate = 0.0
    if config.top_pitch_rate[1] > 0:
        # From a child generator: the scene's own draws stay those of the same scene with a
        # static camera (a comparison on the same people), and of scenes drawn before.
        gimbal = rng.spawn(1)[0]
        pitch_rate = float(np.radians(gimbal.uniform(*config.top_pitch_rate))) * (
            1.0 if gimbal.random() < 0.5 else -1.0)
    middle = 0.5 * (times[0] + times[-1]) if len(times) else 0.0
    shift = drift * times[:, None] * np.array([np.cos(drift_dir), np.sin(drift_dir)])
    checks = _check_frames(n_frames)
    min_side = _group_side(n_shared, 0.0, config.min_separation)
    side = max(side, min_side)

    steady = 1.0  # the share of the drawn drift and turn the drone keeps

    def top_at(f: int) -> Camera:
        return _top_camera(yaw, pitch, height, aim, hfov, config.top_size, steady * shift[f],
                           steady * yaw_rate * times[f], pitch_rate * (times[f] - middle))

    for _ in range(_FIT_STEPS):
        if _inside([top_at(f) for f in checks], _square_points(np.zeros(2), side),
                   config.near_clip):
            break
        if side > min_side:
            side = max(min_side, 0.93 * side)
        elif height < config.top_height[1] or steady < _MIN_STEADY:
            height *= 1.05
        else:  # past the highest drone asked for: it drifts and turns less (an operator keeps
            # the people in view), rather than rising (a turn in place moves the square out of
            # the image at any height: seed [2, 6] rose to 67 km, every box 0 px)
            steady *= 0.8
    else:
        raise ValueError(f"no top camera of pitch {np.degrees(pitch):.0f} degrees and field of "
                         f"view {hfov:.0f} holds a shared square of {side:.1f} m in "
                         f"{_FIT_STEPS} steps; draw fewer shared people or a wider top_hfov")
    top_cameras = [top_at(f) for f in range(n_frames)]
    return top_cameras, [top_cameras[f] for f in checks], side


@dataclass(frozen=True)
class _Holders:
    """The placed holders of the handheld cameras, one entry per view.

    Attributes:
        hfov: horizontal fields of view, degrees.
        size: image sizes ``(width, height)``, pixels.
        regions: the holders' walking squares.
        gazes: the directions each holder films (radians).
        hor_only: each view's hor-only square, None where none was placed.
    """

    hfov: list[float]
    size: list[tuple[int, int]]
    regions: list[_Region]
    gazes: list[float]
    hor_only: list[_Region | None]


def _place_holder(
    config: ObliqueSceneConfig,
    azimuth0: float,
    hfov: float,
    n_hor_only: int,
    shared: _Region,
    placed: Sequence[_Region],
    top_checks: Sequence[Camera],
    rng: np.random.Generator,
) -> tuple[_Region, float, _Region | None]:
    """One holder around the shared square, far enough for it to fit their field of view.

    The holder tries a few azimuths (the first is ``azimuth0`` moved by a draw) until its
    hor-only square fits: in its view, outside the top image on every frame.

    Returns:
        ``(holder, gaze, hor_only)``: the holder's square, the direction they film (radians)
        and their hor-only square (None where none fits or ``n_hor_only`` is 0).
    """
    n_hor = int(config.n_hor)
    lo, hi = config.holder_area
    walk = lo if lo == hi else float(rng.uniform(lo, hi))
    half = _SHARED_CONE * np.radians(hfov) / 2.0
    hside = _group_side(n_hor_only, float(rng.uniform(*config.group_area)),
                        config.min_separation)
    extra = rng.uniform(*config.hor_extra_distance, size=_AZIMUTHS)
    azimuths = rng.uniform(-np.pi, np.pi, size=_AZIMUTHS)
    azimuths[0] = azimuth0 + (azimuths[0] / np.pi) * 0.5 * np.pi / n_hor
    draws = rng.random((_AZIMUTHS, _TRIES // _AZIMUTHS, 2))
    choice = None
    for i in range(_AZIMUTHS):
        distance = max(0.7 * shared.side / np.sin(half) + extra[i],
                       shared.radius + walk + _GROUP_GAP)
        holder = _Region(distance * np.array([np.cos(azimuths[i]), np.sin(azimuths[i])]),
                         walk)
        gaze = float(_wrap(azimuths[i] + np.pi))
        if not holder.clear_of(placed):
            continue
        if choice is None:
            choice = (holder, gaze, None)
        if n_hor_only == 0:
            break
        region = _hor_only_region(holder, gaze, half, hside, distance + shared.radius,
                                  [*placed, holder], top_checks, draws[i])
        if region is not None:
            return holder, gaze, region
    if choice is None:  # every azimuth crowded: the first, uncleared
        distance = 0.7 * shared.side / np.sin(half) + extra[0]
        holder = _Region(distance * np.array([np.cos(azimuths[0]), np.sin(azimuths[0])]),
                         walk)
        choice = (holder, float(_wrap(azimuths[0] + np.pi)), None)
    return choice


def _place_holders(
    config: ObliqueSceneConfig,
    shared: _Region,
    top_checks: Sequence[Camera],
    n_hor_only: Sequence[int],
    rng: np.random.Generator,
) -> tuple[_Holders, list[_Region]]:
    """The holders of the handheld cameras, each with its hor-only square.

    Returns:
        The :class:`_Holders` and every square placed so far (shared, holders, hor-only).
    """
    n_hor = int(config.n_hor)
    hor_hfov = [float(rng.uniform(*config.hor_hfov)) for _ in range(n_hor)]
    hor_size = [tuple(config.hor_sizes[int(rng.integers(len(config.hor_sizes)))])
                for _ in range(n_hor)]
    base = float(rng.uniform(-np.pi, np.pi))
    placed = [shared]
    holders = _Holders(hfov=hor_hfov, size=hor_size, regions=[], gazes=[], hor_only=[])
    for k in range(n_hor):
        holder, gaze, region = _place_holder(
            config, base + 2.0 * np.pi * k / n_hor, hor_hfov[k], n_hor_only[k], shared, placed,
            top_checks, rng)
        holders.regions.append(holder)
        holders.gazes.append(gaze)
        holders.hor_only.append(region)
        placed.append(holder)
        if region is not None:
            placed.append(region)
    return holders, placed


def _place_top_only(
    config: ObliqueSceneConfig,
    top_cameras: Sequence[Camera],
    top_checks: Sequence[Camera],
    holders: _Holders,
    placed: Sequence[_Region],
    n_top_only: int,
    side: float,
    rng: np.random.Generator,
) -> tuple[_Region | None, int, int]:
    """The top-only square: in the top image, outside every handheld view.

    Holders the top camera sees count as top-only people (fewer are placed).

    Returns:
        ``(top_only, n_top_only, holders_seen)``: the square (None where none fits or no one
        is left), the people placed in it (0 without it) and the holders the top camera sees.
    """
    holders_seen = sum(
        _inside(top_checks, np.array([[*h.centre, 0.0], [*h.centre, _CHECK_HEIGHT]]),
                config.near_clip)
        for h in holders.regions
    )
    n_top_only = max(0, n_top_only - holders_seen)
    top_only_side = _group_side(n_top_only, float(rng.uniform(*config.group_area)),
                                config.min_separation)
    cand_pix = rng.uniform(0.15, 0.85, size=(_TRIES, 2)) * np.array(config.top_size)
    if n_top_only > 0:
        ground = top_cameras[0].ray_directions(cand_pix)
        for ray in ground:
            if ray[2] >= -1e-6:
                continue
            c = top_cameras[0].c[:2] + ray[:2] * (top_cameras[0].c[2] / -ray[2])
            region = _Region(c, top_only_side)
            if np.hypot(*c) > 3.0 * side + 30.0 or not region.clear_of(placed):
                continue
            pts = _square_points(c, top_only_side)
            if not _inside(top_checks, pts, config.near_clip):
                continue
            if all((_off_axis(h.centre, g, pts) > np.radians(hf / 2.0 + _OUTSIDE_CONE_DEG)).all()
                   for h, g, hf in zip(holders.regions, holders.gazes, holders.hfov,
                                       strict=True)):
                return region, n_top_only, holders_seen
    return None, 0, holders_seen


def _walk(
    config: ObliqueSceneConfig, n_frames: int, n: int, region: _Region,
    speed: tuple[float, float], rng: np.random.Generator,
) -> PeopleState:
    """The walks of n people in ``region``'s square (centred on the origin)."""
    walk_config = SceneConfig(
        n_people=(n, n), area=region.side, height_range=config.height_range,
        width_range=config.width_range, min_separation=config.min_separation,
        fps=config.fps, walk_speed=speed, stop_probability=config.stop_probability,
        stop_duration=config.stop_duration,
        edge_margin=min(2.0, 0.2 * region.side), hor_wobble_deg=0.0,
        top_altitude=max(40.0, config.height_range[1] + 1.0),
    )
    return simulate_walks(walk_config, n_frames, rng)


def _walk_groups(
    config: ObliqueSceneConfig,
    n_frames: int,
    holders: _Holders,
    shared: _Region,
    top_only: _Region | None,
    sizes: tuple[int, int, Sequence[int]],
    rng: np.random.Generator,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The walks, group by group: holders, shared, top-only, hor-only.

    Args:
        config: the configuration.
        n_frames: number of frames F.
        holders: the placed holders.
        shared: the shared square.
        top_only: the top-only square, or None.
        sizes: ``(n_shared, n_top_only, n_hor_only)``.
        rng: the source of randomness.

    Returns:
        ``(positions, heights, widths, headings, groups)``: the people's walks (as in
        :class:`~xvmatch.datasets.box_scene.PeopleState`), translated into their squares, in
        the order holders, shared, top-only, hor-only, and ``{group name: person indices}``.
    """
    n_shared, n_top_only, n_hor_only = sizes
    parts = [(_walk(config, n_frames, 1, h, config.holder_speed, rng), h)
             for h in holders.regions]
    parts.append((_walk(config, n_frames, n_shared, shared, config.walk_speed, rng), shared))
    if top_only is not None:
        parts.append((_walk(config, n_frames, n_top_only, top_only, config.walk_speed, rng),
                      top_only))
    for k, region in enumerate(holders.hor_only):
        if region is not None:
            parts.append((_walk(config, n_frames, n_hor_only[k], region, config.walk_speed, rng),
                          region))
    positions = np.concatenate([p.positions + r.centre for p, r in parts], axis=1)
    heights = np.concatenate([p.heights for p, _ in parts])
    widths = np.concatenate([p.widths for p, _ in parts])
    headings = np.concatenate([p.headings for p, _ in parts], axis=1)
    groups = _group_indices([p.n_people for p, _ in parts], top_only is not None,
                            holders.hor_only)
    return positions, heights, widths, headings, groups


def _group_indices(
    counts: Sequence[int], has_top_only: bool, hor_only: Sequence[_Region | None]
) -> dict[str, np.ndarray]:
    """``{group name: person indices}`` from the people counts of the walked groups (holders,
    shared, top-only where ``has_top_only``, the hor-only squares that are not None)."""
    n_hor = len(hor_only)
    starts = np.cumsum([0, *counts])
    groups: dict[str, np.ndarray] = {"holders": np.arange(n_hor, dtype=np.int64)}
    groups["shared"] = np.arange(starts[n_hor], starts[n_hor + 1], dtype=np.int64)
    j = n_hor + 1
    groups["top_only"] = np.empty(0, dtype=np.int64)
    if has_top_only:
        groups["top_only"] = np.arange(starts[j], starts[j + 1], dtype=np.int64)
        j += 1
    for k, region in enumerate(hor_only):
        groups[f"hor{k + 1}_only"] = np.empty(0, dtype=np.int64)
        if region is not None:
            groups[f"hor{k + 1}_only"] = np.arange(starts[j], starts[j + 1], dtype=np.int64)
            j += 1
    return groups


def _edge_groups(
    config: ObliqueSceneConfig,
    n_frames: int,
    cameras: dict[str, Sequence[Camera]],
    rng: np.random.Generator,
) -> list[tuple[str, PeopleState, _Region]]:
    """Per camera ``{name: F cameras}``, the walks of its edge group
    (:attr:`ObliqueSceneConfig.edge_people`) in a square centred where the ray through its
    middle frame's bottom-edge centre meets the ground; none for a camera whose bottom edge
    looks above the horizon or a group drawn empty."""
    groups = []
    for name, cams in cameras.items():
        n = int(rng.integers(config.edge_people[0], config.edge_people[1] + 1))
        cam = cams[(n_frames - 1) // 2]
        ray = cam.ray_directions(np.array([[0.5 * cam.width, cam.height - 1.0]]))[0]
        if n == 0 or ray[2] >= -1e-6:
            continue
        centre = cam.c[:2] + ray[:2] * (cam.c[2] / -ray[2])
        region = _Region(centre, _group_side(n, _EDGE_SIDE, config.min_separation))
        groups.append((f"{name}_edge", _walk(config, n_frames, n, region, config.walk_speed,
                                             rng), region))
    return groups


def make_oblique_scene(
    config: ObliqueSceneConfig, n_frames: int, rng: np.random.Generator
) -> ObliqueScene:
    """Draw one scene (groups, cameras, walks) and project the boxes of every view.

    See the module docstring for the world, the cameras, the boxes and how the overlap is
    made.

    Args:
        config: the configuration.
        n_frames: number of frames F >= 1 (``fps`` per second).
        rng: the only source of randomness, e.g. ``np.random.default_rng(seed)``.

    Returns:
        The :class:`ObliqueScene`.
    """
    if int(n_frames) < 1:
        raise ValueError(f"n_frames must be >= 1, got {n_frames}")
    n_frames = int(n_frames)
    n_hor = int(config.n_hor)
    hor_names = [f"hor{k}" for k in range(1, n_hor + 1)]
    times = np.arange(n_frames) * (1.0 / config.fps)

    p_top, p_hor, n_shared, n_top_only, n_hor_only = _draw_group_sizes(config, n_hor, rng)
    top_cameras, top_checks, side = _place_top_camera(config, times, n_shared, rng)
    shared = _Region(np.zeros(2), side)
    holders, placed = _place_holders(config, shared, top_checks, n_hor_only, rng)
    n_hor_only = [0 if region is None else n
                  for n, region in zip(n_hor_only, holders.hor_only, strict=True)]
    top_only, n_top_only, holders_seen = _place_top_only(
        config, top_cameras, top_checks, holders, placed, n_top_only, side, rng)
    positions, heights, widths, headings, groups = _walk_groups(
        config, n_frames, holders, shared, top_only, (n_shared, n_top_only, n_hor_only), rng)

    # The handheld cameras, looking at the shared group's centroid.
    target = positions[:, groups["shared"]].mean(axis=1)
    hor_cameras: dict[str, list[Camera]] = {}
    hor_angles = []
    for k, name in enumerate(hor_names):
        cam_height = min(float(rng.uniform(*config.hor_height)), float(heights[k]) - 0.1)
        cams, angles = _handheld_cameras(positions[:, k], target, cam_height, holders.size[k],
                                         holders.hfov[k], config, rng)
        hor_cameras[name] = cams
        hor_angles.append(angles)
        headings[:, k] = angles[:, 0]  # a holder faces where they film
    if config.edge_people[1] > 0:
        # From a child generator drawn last: every other draw stays that of the same scene
        # without edge people (a comparison on the same crowd).
        edges = _edge_groups(config, n_frames, {"top": top_cameras, **hor_cameras},
                             rng.spawn(1)[0])
        for name, walk, region in edges:
            start = positions.shape[1]
            positions = np.concatenate([positions, walk.positions + region.centre], axis=1)
            heights = np.concatenate([heights, walk.heights])
            widths = np.concatenate([widths, walk.widths])
            headings = np.concatenate([headings, walk.headings], axis=1)
            groups[name] = np.arange(start, positions.shape[1], dtype=np.int64)
    people = PeopleState(
        positions=positions, heights=heights, widths=widths, headings=headings,
        ids=np.arange(positions.shape[1], dtype=np.int64), wearer=0,
        head_yaw=hor_angles[0][:, 0], head_pitch=hor_angles[0][:, 1],
        head_roll=hor_angles[0][:, 2],
    )

    # The boxes; each handheld lens's distortion drawn last (none drawn for a fixed value).
    lo, hi = config.hor_distortion
    k1 = np.full(n_hor, lo) if lo == hi else rng.uniform(lo, hi, size=n_hor)
    overlap = {"top": p_top, **dict(zip(hor_names, p_hor, strict=True))}
    target_fraction = {"top": n_shared / (n_shared + n_top_only + holders_seen)}
    for k, name in enumerate(hor_names):
        target_fraction[name] = n_shared / (n_shared + n_hor_only[k])
    scene = ObliqueScene(
        config=config, people=people, top_cameras=top_cameras, hor_cameras=hor_cameras,
        top={}, hor={}, groups=groups, overlap=overlap, overlap_target=target_fraction,
        hor_distortion={name: float(k1[k]) for k, name in enumerate(hor_names)},
    )
    return replace(scene, top=_top_boxes(scene, top_cameras), hor=_hor_boxes(scene, hor_cameras))


def _top_boxes(scene: ObliqueScene, cameras: Sequence[Camera]) -> dict[int, FrameBoxes]:
    """The top view's boxes through ``cameras``, with the scene's top lens and ground."""
    return _project_frames(scene.people, cameras, scene.config, k1=scene.top_distortion,
                           ground=scene.ground)


def _hor_boxes(scene: ObliqueScene, cameras: dict[str, list[Camera]]
               ) -> dict[str, dict[int, FrameBoxes]]:
    """Each handheld view's boxes through ``cameras`` (view k's holder, person k, hidden from
    it), with its lens and the scene's ground."""
    return {name: _project_frames(scene.people, cams, scene.config, hidden=k,
                                  k1=scene.hor_distortion.get(name, 0.0), ground=scene.ground)
            for k, (name, cams) in enumerate(cameras.items())}


def pitch_drifted(scene: ObliqueScene, std_deg: float, time_s: float,
                  rng: np.random.Generator) -> ObliqueScene:
    """The same scene (its people, top view and holders' paths) with each handheld camera's
    pitch drifting about its own (Ornstein-Uhlenbeck: ``std_deg`` degrees of spread,
    ``time_s`` seconds of correlation), its boxes projected again: a holder who reframes,
    looking down at the path and up again, measured against the very scene held steady
    (a slower wobble drawn with the scene would place its groups anew)."""
    if not (std_deg >= 0 and time_s > 0):
        raise ValueError(f"pitch_drifted needs std_deg >= 0 and time_s > 0, got {std_deg}, "
                         f"{time_s}")
    spread = np.radians(std_deg)
    cameras = {}
    for name, cams in scene.hor_cameras.items():
        noise = rng.standard_normal(len(cams))
        drift = np.empty(len(cams))
        drift[0] = spread * noise[0]
        for t in range(1, len(cams)):
            drift[t] = _ou_step(drift[t - 1], spread, time_s, 1.0 / scene.config.fps, noise[t])
        c, s = np.cos(drift), np.sin(drift)  # about each camera's own x axis (its pitch)
        cameras[name] = [Camera(K=cam.K, R=np.array([[1.0, 0.0, 0.0], [0.0, ct, -st],
                                                     [0.0, st, ct]]) @ cam.R, c=cam.c,
                                width=cam.width, height=cam.height)
                         for cam, ct, st in zip(cams, c, s, strict=True)]
    return replace(scene, hor_cameras=cameras, hor=_hor_boxes(scene, cameras))


def sloped(scene: ObliqueScene, grade_deg: float, rng: np.random.Generator) -> ObliqueScene:
    """The same scene on a ground that slopes ``grade_deg`` degrees (a plane through the shared
    group's mean place, rising towards a direction drawn from ``rng``): people stand upright on
    it, each handheld camera rises and falls with its holder, the top camera flies where it
    was; every view's boxes projected again (on a ground already sloping, the slopes add). The
    methods take the ground to be level, so this measures what a park's or a street's slope
    costs them (what the boxes cannot tell)."""
    if not 0.0 <= grade_deg < 45.0:
        raise ValueError(f"sloped needs 0 <= grade_deg < 45, got {grade_deg}")
    up = rng.uniform(0.0, 2.0 * np.pi)
    rise = np.tan(np.radians(grade_deg)) * np.array([np.cos(up), np.sin(up)])
    shared = scene.groups.get("shared", np.empty(0, dtype=np.int64))
    pool = scene.people.positions[:, shared] if shared.size else scene.people.positions
    centre = pool.reshape(-1, 2).mean(axis=0)
    plane = (scene.people.positions - centre) @ rise  # (F, N)
    cameras = {name: [Camera(K=cam.K, R=cam.R, c=cam.c + np.array([0.0, 0.0,
                                                                  (cam.c[:2] - centre) @ rise]),
                             width=cam.width, height=cam.height) for cam in cams]
               for name, cams in scene.hor_cameras.items()}
    out = replace(scene, hor_cameras=cameras,
                  ground=plane if scene.ground is None else scene.ground + plane)
    return replace(out, top=_top_boxes(out, out.top_cameras), hor=_hor_boxes(out, cameras))


def top_distorted(scene: ObliqueScene, k1: float) -> ObliqueScene:
    """The same scene with the top camera's lens distorting radially by ``k1``
    (:func:`distorted`; a drone's wide lens whose video is not undistorted: about -0.1), its
    boxes projected again; the handheld views unchanged."""
    out = replace(scene, top_distortion=k1)
    return replace(out, top=_top_boxes(out, out.top_cameras))


def top_rolled(scene: ObliqueScene, roll_deg: float) -> ObliqueScene:
    """The same scene with the top camera rolled ``roll_deg`` degrees about its optical axis on
    every frame (a building camera mounted askew; a drone's gimbal holds it level), its boxes
    projected again; the handheld views unchanged."""
    c, s = np.cos(np.radians(roll_deg)), np.sin(np.radians(roll_deg))
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    cameras = [Camera(K=cam.K, R=turn @ cam.R, c=cam.c, width=cam.width, height=cam.height)
               for cam in scene.top_cameras]
    return replace(scene, top_cameras=cameras, top=_top_boxes(scene, cameras))


def write_oblique_scene(
    scene: ObliqueScene, directory: str | os.PathLike, name: str
) -> dict[str, Path]:
    """Write the boxes and the cameras of a scene in ``directory`` (which must exist).

    Files: ``NAME_top.txt``, ``NAME_hor1.txt``, ... (MOTChallenge boxes as
    :func:`~xvmatch.datasets.box_scene.write_box_scene` writes them; frames without a box leave
    no line), and per handheld view a folder ``NAME_cameras_horK/`` of per-frame camera files
    ``000001.json`` ... with the cameras ``top`` and ``ego`` (that view's camera), which
    :func:`~xvmatch.formats.camera_frames.open_cameras` reads. Every file is written
    atomically.

    Returns:
        ``{"top": path, "hor1": path, ..., "cameras_hor1": folder, ...}``.
    """
    folder = Path(directory)
    if not folder.is_dir():
        raise ValueError(f"write_oblique_scene: directory {os.fspath(folder)!r} does not exist")
    paths = {"top": folder / f"{name}_top.txt"}
    write_mot_boxes(paths["top"], scene.top)
    for view, records in scene.hor.items():
        paths[view] = folder / f"{name}_{view}.txt"
        write_mot_boxes(paths[view], records)
    for view, cams in scene.hor_cameras.items():
        cam_folder = folder / f"{name}_cameras_{view}"
        cam_folder.mkdir(exist_ok=True)
        for f, (top_cam, hor_cam) in enumerate(zip(scene.top_cameras, cams, strict=True)):
            save_cameras(cam_folder / f"{f + 1:06d}.json", {"top": top_cam, "ego": hor_cam})
        paths[f"cameras_{view}"] = cam_folder
    return paths
