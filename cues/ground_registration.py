"""Two views' ground maps registered without correspondences, jointly with the association.

Each view's people are put on its own ground map (metres, from its calibration: the top view by
:class:`~xvmatch.geometry.people_calibration.PeopleCalibration`, the horizontal view by the box
heights of people about 1.72 m tall, as the CVMHAT method reads distances). The horizontal
camera's pose on the top map, its position ``c`` and heading ``theta``, is unknown and changes as
its holder walks and turns; it is *not* assumed to be a visible person (where the user names
the holder's top-view id, ``--camera-id``, it is sought near where the top view maps them,
:data:`HOLDER_RADIUS`). Per frame:

* **hypotheses**: every (top person i, horizontal person j, heading) triple puts j on i, which
  fixes ``c``; a hypothesis scores the horizontal people that land within :data:`RADIUS` of a
  top person (soft), minus the top people it puts inside the horizontal camera's field of view
  that nobody there explains (people seen in one view only are expected, so this weighs less)
  and, where the top camera is known (:class:`TopSight`), as much for each horizontal person
  nobody explains that it puts where the top camera would see them: with few people shared,
  a wrong pose (two people swapped: a half turn about their midpoint) explains as many as the
  right one, and only where it puts the others tells them apart; a top person counts as
  unexplained only where no horizontal person lands within :data:`RADIUS` nor, farther off,
  within :data:`RANGE_SPREAD` of their distance from the camera (charged at the round radius,
  the true pose paid for every person 20-50 m off, whose distance from a box errs by metres:
  on crowds 20-65 m across it lost to wrong poses, + consensus CVIDF1 92.5 and 78.1 with the
  true lens on two seeds of renders against 96.5 and 91.8 so), nor where they stand behind a
  nearer horizontal person (their bearing within half a body's width of theirs,
  :func:`shade`: annotators box people the camera sees, and a handheld camera among people
  sees few of those behind them; the true pose was charged for 3-5 such a frame in a crowd
  2-7 m away); under a nadir top view the commands keep the round radius and hide nobody
  (``spread`` 0), as either cost the real CVMHAT boxes a person's track; the :data:`KEEP`
  best distinct ones are kept;
* **time**: one hypothesis per frame is chosen by dynamic programming over the frames (Viterbi),
  each step paying for a jump in position or heading faster than a walker turns and walks
  (:data:`_STEP_M`, :data:`_STEP_DEG`; twice that where the rate was read from the walkers), so
  the registration is consistent from frame to frame and a frame that alone is ambiguous is
  decided by its neighbours; each frame is also offered its neighbours' hypotheses, carried
  onto its map and scored in it (:func:`carried`), so a pose that one frame's :data:`KEEP`
  left out for near-duplicates of another stays on offer there, and, in video mode where the
  top view's tracks show people missed (:data:`MISSED_SHARE`), the poses leading the choice at
  the frame before (:data:`LEAD`), so that the pose the choice holds stays on offer through
  frames whose own people rank it out; the whole clip is registered
  with the top map at a few scales (:func:`register_scales`) and the best kept
  (:func:`register_with_scale`; in video mode the one whose pairs hold along the tracks,
  :func:`xvmatch.inference.matching.ground_association.register_and_pair`);
* **people's heights**: a horizontal person's distance is read from their box as if they
  were of the crowd's height; where the top view tells each of its people's height (an oblique
  top camera: a box's height over a person of the crowd's height there), a horizontal person
  is put against top person ``i`` at ``i``'s height (``sizes``), where they would stand were
  they ``i``. People are 1.5-1.95 m tall: at 20 m, one 1.9 m tall read as 1.72 is put 1.9 m
  too near, more than the pairing's radius;
* **association**: under the chosen pose, Hungarian on the ground distances with a
  non-association distance (:data:`RADIUS`), stretched along each horizontal person's ray by
  :data:`RANGE_SPREAD` of their distance: a distance read from a box height errs along the ray
  (a person 10 % taller is put 10 % nearer), a bearing hardly. The registration keeps the round
  :data:`RADIUS` (stretched, it let wrong poses explain far people too: on the renders'
  scenes of seed 0 it lost 6 CVIDF1 points; in the association alone it gained 2-3 on seeds 0
  and 1).

This generalises the CVMHAT search over the camera location O and orientation theta (Sec. 3 of
the CVMHAT paper) to a camera that is not among the top view's people and a top view that is not
a nadir image.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
from scipy.optimize import linear_sum_assignment

from xvmatch.core import kernel_choice
from xvmatch.geometry.camera import Camera
from xvmatch.geometry.people_calibration import (
    BODY_WIDTH,
    PERSON_HEIGHT,
    cut_at_bottom,
    whole_boxes,
)

__all__ = [
    "HOLDER_RADIUS",
    "KEEP",
    "LEAD",
    "MAP_SCALES",
    "MISSED_SHARE",
    "RADIUS",
    "RANGE_SPREAD",
    "SCALE_FLOOR",
    "SCALE_MARGIN",
    "WIDTH_RATIO",
    "FramePose",
    "HandheldReading",
    "TopSight",
    "anchored_poses",
    "associate_on_ground",
    "box_width_ratio",
    "carried",
    "fitting_scales",
    "hor_ground_points",
    "hor_horizon",
    "map_motion",
    "margin_scale",
    "missed_share",
    "on_top_map",
    "pose_hypotheses",
    "ray_distances",
    "register_scales",
    "register_scales_twice",
    "register_sequence",
    "register_with_scale",
    "score_poses",
    "shade",
]

RADIUS = 1.5
"""Metres: a horizontal person mapped farther than this from every top person explains none."""

RANGE_SPREAD = 0.1
"""Relative spread of a horizontal person's distance read from their box height (people are
1.5-1.95 m tall, boxes cut by occlusion): along the camera's ray a mapped person may lie this
part of their distance away from their top-view partner (never less than :data:`RADIUS` / 2),
across it :data:`RADIUS` / 2 (the bearing, from the box's column, is sharp). A pose is not
charged for a top person it leaves unexplained in the horizontal camera's view where a
horizontal person lands within this part of that person's distance (module docstring)."""

WIDTH_RATIO = round(BODY_WIDTH / PERSON_HEIGHT, 4)
"""A person's box width over height when the view's boxes cannot tell
(:func:`box_width_ratio`): the calibration's body, 0.45 m wide, 1.72 m tall."""

_MIN_RATIO_BOXES = 20
"""Boxes not cut by a border :func:`box_width_ratio` needs to read a view's ratio."""

_MAX_PITCH_TAN = float(np.tan(np.radians(30.0)))
"""The steepest handheld pitch's tangent :func:`hor_ground_points` takes from a horizon."""

KEEP = 24
"""Pose hypotheses kept per frame for the choice over time."""

CARRY = 8
"""A neighbour's best hypotheses each frame is also offered (:func:`carried`)."""

LEAD = 8
"""The poses leading the choice over time at one frame (the best totals) that the next frame
is also offered (:func:`register_sequence`)."""

MISSED_SHARE = 0.1
"""The share of the top view's people missed within their own tracks' spans (video mode,
:func:`missed_share`) from which :func:`register_scales` offers each frame the poses leading
at the one before: a detector's misses (the renders' boxes, every 3rd frame at 10 a second:
0-5 % missed as annotated, 14-26 % where each person is missed a fifth of the time)."""

_HEADINGS = 72
"""Headings tried per (top, horizontal) pair: every 5 degrees."""

_FIRST = 1024
"""Best-scored candidate poses ordered before the distinct ones are picked (the rest only
where these hold fewer than :data:`KEEP` distinct ones)."""

_UNSEEN_WEIGHT = 0.3
"""Cost of a top person put in the horizontal camera's view that it does not see, against 1 for
a horizontal person explained: low, as occlusion and partial overlap hide many."""

_DIGITS = 9
"""Scores are rounded to this many decimals: the same choices on every CPU."""

_EDGE = 0.03
"""Part of the top image's width and height along its borders where a person standing is
taken as possibly cut off or unannotated (:class:`TopSight`)."""

MAP_SCALES = (0.7, 0.85, 1.0, 1.15, 1.3)
"""Scales of the top view's ground map tried against the horizontal view's
(:func:`register_with_scale`)."""

SCALE_MARGIN = 1.05
"""How many times the people explained at scale 1 another scale must explain to replace it."""

SCALE_FLOOR = 0.85
"""The least share of scale 1's clip score total (the people its chosen poses explain) another
scale's run needs for video mode to weigh its pairs along the tracks at all
(:func:`~xvmatch.inference.matching.ground_association.scale_along_tracks`): pairs of people
who stand still hold along the tracks under a wrong pose too, so on a crowd standing 94 % of
the time a wrong scale kept more of them (0.7: 280 pair-frames, all wrong, where scale 1
explained twice the people and kept 238, all right). Logged with no floor over every choice
of two walking render sets, 2 of the 218 that took another scale had under 0.85 of scale 1's
total (a lens's runs that were not kept); over the standing crowd's, 11 of 58 (0.51-0.85)
(docs/notes/oblique_top_camera.md, fifty-seventh session)."""

_STEP_M = 1.0
"""Metres per second a handheld camera's position may drift between frames at no cost."""

_STEP_DEG = 30.0
"""Degrees per second it may turn at no cost."""

HOLDER_RADIUS = 2.0
"""Metres on the top map within which a camera told where it stands (its holder seen,
``--camera-id``) is sought: the holder's point errs, and so does the handheld map's scale."""

_JUMP_COST = 2.0
"""Score lost per standard step beyond those (a frame's pose can jump where its evidence is
strong: a pan)."""


@dataclass(frozen=True)
class FramePose:
    """The horizontal camera's pose on the top view's ground map for one frame.

    Attributes:
        frame: the frame number.
        centre: (2,) position, metres.
        heading: radians, the direction it looks along.
        score: the frame's evidence for it.
    """

    frame: int
    centre: np.ndarray
    heading: float
    score: float


def hor_ground_points(boxes: np.ndarray, image_size: tuple[int, int], hfov_deg: float,
                      person_height: float = PERSON_HEIGHT,
                      width_ratio: float = WIDTH_RATIO,
                      horizon: float | None = None) -> np.ndarray:
    """Horizontal-view people on the camera's own ground map ``(M, 2)``: x forward, y left.

    Depth from box height (a person of ``person_height`` seen by a level camera,
    ``d = f H / h``: the distance along the optical axis, not along the ray, which is
    ``1 / cos`` of the bearing longer, 22 % at a 70 degree lens's edge), the offset across from
    the box's centre column. A box cut by the image's bottom edge (a passer-by, feet out of
    sight) shows only part of its height: its depth is read from its width (``width_ratio``
    times ``person_height`` wide, :func:`box_width_ratio`), no farther than its height allows
    nor than where a camera at ``person_height`` would still see the feet: a level one, or
    one pitched as its ``horizon`` row (:func:`hor_horizon`) says: looking up, it sees no feet
    for metres, and every passer-by there is cut."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    f = 0.5 * image_size[0] / np.tan(np.radians(hfov_deg) / 2.0)
    distance = f * person_height / np.maximum(boxes[:, 3], 1.0)
    cut = cut_at_bottom(boxes, image_size[1])
    if cut.any():
        by_width = f * width_ratio * person_height / np.maximum(boxes[cut, 2], 1.0)
        feet_seen = f * person_height / (0.5 * image_size[1])
        if horizon is not None:  # the lowest row's dip (its tangent) through the pitch
            low = 0.5 * image_size[1] / f
            pitch = float(np.clip((0.5 * image_size[1] - horizon) / f, -_MAX_PITCH_TAN,
                                  _MAX_PITCH_TAN))
            dip = (low + pitch) / (1.0 - low * pitch)
            feet_seen = person_height / dip if dip > 0 else np.inf
        distance[cut] = np.minimum(np.minimum(by_width, feet_seen), distance[cut])
    across = -(boxes[:, 0] + 0.5 * boxes[:, 2] - 0.5 * image_size[0]) / f
    return distance[:, None] * np.column_stack([np.ones(len(boxes)), across])


def box_width_ratio(frames: Iterable[np.ndarray], image_size: tuple[int, int]) -> float:
    """A view's people's width over height: the median over its boxes (``frames``, each
    frame's ``(N, 4)``) that no image border cuts
    (:func:`~xvmatch.geometry.people_calibration.whole_boxes`; :data:`WIDTH_RATIO` with fewer
    than :data:`_MIN_RATIO_BOXES`), rounded to 4 decimals; how :func:`hor_ground_points` reads
    a cut box's depth from its width."""
    boxes = np.concatenate([np.zeros((0, 4)),
                            *(np.asarray(b, dtype=float).reshape(-1, 4) for b in frames)])
    whole = whole_boxes(boxes, image_size)
    if whole.sum() < _MIN_RATIO_BOXES:
        return WIDTH_RATIO
    return round(float(np.median(boxes[whole, 2] / boxes[whole, 3])), 4)


def hor_horizon(frames: Sequence[np.ndarray], image_size: tuple[int, int]) -> float | None:
    """The horizon's row of a handheld view from its people (each frame's ``(N, 4)`` boxes;
    :func:`~xvmatch.geometry.people_model.handheld_horizon`), to a tenth of a pixel; None
    where they cannot tell it (:func:`hor_ground_points` then takes a level camera)."""
    from xvmatch.geometry.people_model import handheld_horizon

    boxes = [np.asarray(b, dtype=float).reshape(-1, 4) for b in frames]
    index = np.repeat(np.arange(len(boxes)), [len(b) for b in boxes])
    row = handheld_horizon(index, np.concatenate([np.zeros((0, 4)), *boxes]), image_size)
    return None if row is None else round(row, 1)


@dataclass(frozen=True)
class HandheldReading:
    """What a handheld view's people tell of it, whatever its lens: their width over height
    (:func:`box_width_ratio`) and its horizon's row (:func:`hor_horizon`), read once per
    clip; how :func:`hor_ground_points` reads the boxes its bottom edge cuts.

    Attributes:
        image_size: the view's image size, pixels.
        width_ratio: its people's width over height.
        horizon: its horizon's row, or None (a level camera taken).
    """

    image_size: tuple[int, int]
    width_ratio: float = WIDTH_RATIO
    horizon: float | None = None

    @classmethod
    def of(cls, frames: Sequence[np.ndarray], image_size: tuple[int, int]) -> HandheldReading:
        """The reading of a view from its boxes, each frame's ``(N, 4)``."""
        size = (int(image_size[0]), int(image_size[1]))
        return cls(size, box_width_ratio(frames, size), hor_horizon(frames, size))

    def points(self, boxes: np.ndarray, hfov_deg: float) -> np.ndarray:
        """One frame's people on the camera's own map (:func:`hor_ground_points`) with a lens
        of ``hfov_deg`` degrees."""
        return hor_ground_points(boxes, self.image_size, hfov_deg, width_ratio=self.width_ratio,
                                 horizon=self.horizon)


@dataclass(frozen=True)
class TopSight:
    """Where the top camera sees people standing on its ground map: a point is seen when it
    projects inside the top image (off its borders by :data:`_EDGE`) no farther from the map's
    origin (the camera's foot) than its people were seen.

    Attributes:
        ground: ``(3, 3)`` the map-to-image homography (``K [r1, r2, -R c]``).
        width, height: the top image's size, pixels.
        reach: metres from the map's origin out to which its people were seen.
    """

    ground: np.ndarray
    width: int
    height: int
    reach: float

    @classmethod
    def of(cls, camera: Camera, reach: float) -> TopSight:
        """The sight of a top camera in its own ground frame (above the map's origin)."""
        ground = camera.K @ np.column_stack([camera.R[:, 0], camera.R[:, 1],
                                             -camera.R @ camera.c])
        return cls(ground, int(camera.width), int(camera.height), float(reach))

    def scaled(self, scale: float) -> TopSight:
        """The same sight on the map multiplied by ``scale``."""
        return TopSight(self.ground @ np.diag([1.0 / scale, 1.0 / scale, 1.0]), self.width,
                        self.height, self.reach * scale)

    def bounds(self) -> np.ndarray:
        """``(5,)`` the pixel bounds (u from, to; v from, to) and the squared reach."""
        mx, my = _EDGE * self.width, _EDGE * self.height
        return np.array([mx, self.width - mx, my, self.height - my, self.reach ** 2])

    def sees(self, points: np.ndarray) -> np.ndarray:
        """``(...)`` whether people standing at ``points`` ``(..., 2)`` are in sight (the
        pixel's bounds times its ``w > 0``: no division)."""
        x, y = points[..., 0], points[..., 1]
        g = self.ground
        u, v, w = (g[r, 0] * x + g[r, 1] * y + g[r, 2] for r in range(3))
        u0, u1, v0, v1, far = self.bounds()
        return ((w > 0) & (u > u0 * w) & (u < u1 * w) & (v > v0 * w) & (v < v1 * w)
                & (x * x + y * y < far))


def _rotations(headings: np.ndarray) -> np.ndarray:
    c, s = np.cos(headings), np.sin(headings)
    return np.stack([np.stack([c, -s], -1), np.stack([s, c], -1)], -2)  # (H, 2, 2)


_SIGMA = 0.5 * RADIUS
"""Metres: the spread of a mapped person across their ray (and along it, at least)."""


def ray_distances(top: np.ndarray, mapped: np.ndarray, rays: np.ndarray,
                  sizes: np.ndarray | None = None) -> np.ndarray:
    """``(N, M)`` distances (metres) of top people ``(N, 2)`` from horizontal people mapped on
    the top map ``(M, 2)``, with the offset along each one's ray from the camera (``rays``
    ``(M, 2)``, on the top map) shrunk by its spread: :data:`RANGE_SPREAD` of the distance, at
    least :data:`RADIUS` / 2, over :data:`RADIUS` / 2 (a distance read from a box height errs
    along the ray, a bearing hardly). Near the camera, the plain distance. ``sizes`` ``(N,)``:
    each top person's height over the crowd's, a horizontal person compared with them read at
    their height (their ray that many times as long)."""
    top = np.asarray(top, float).reshape(-1, 2)
    mapped, rays = np.asarray(mapped, float).reshape(-1, 2), np.asarray(rays, float).reshape(-1, 2)
    length = np.hypot(rays[:, 0], rays[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):  # a ray of no length: any direction
        unit = np.where(length[:, None] > 1e-9, rays / length[:, None], [1.0, 0.0])
    shrink = _SIGMA / np.maximum(_SIGMA, RANGE_SPREAD * length)
    dx = top[:, None, 0] - mapped[None, :, 0]
    dy = top[:, None, 1] - mapped[None, :, 1]
    if sizes is not None:
        grow = np.asarray(sizes, float).reshape(-1)[:, None] - 1.0
        dx = dx - grow * rays[None, :, 0]
        dy = dy - grow * rays[None, :, 1]
    along = (dx * unit[:, 0] + dy * unit[:, 1]) * shrink
    across = dy * unit[:, 0] - dx * unit[:, 1]
    return np.hypot(along, across)


def pose_hypotheses(top: np.ndarray, hor: np.ndarray, hfov_deg: float,
                    sizes: np.ndarray | None = None, sight: TopSight | None = None,
                    spread: float = RANGE_SPREAD) -> tuple[np.ndarray, np.ndarray]:
    """The best poses ``(K, 3)`` (x, y, heading) of the horizontal camera on the top map for
    one frame, and their scores ``(K,)``, best first (module docstring).

    Args:
        top: ``(N, 2)`` top-view people on its ground map.
        hor: ``(M, 2)`` horizontal-view people on the camera's ground map (x forward).
        hfov_deg: the horizontal camera's field of view.
        sizes: ``(N,)`` each top person's height over the crowd's, or None (all alike): a
            horizontal person is put against top person ``i`` at ``sizes[i]`` times their
            distance (read from their box as if of the crowd's height), where they would stand
            were they ``i``.
        sight: where the top camera sees people (:class:`TopSight`), or None: a pose that puts
            a horizontal person nobody explains in the top camera's sight pays as for a top
            person unseen.
        spread: the part of a top person's distance from the camera within which a
            horizontal person landing keeps them from being charged as missed
            (:data:`RANGE_SPREAD`), and nobody charged who stands behind a nearer horizontal
            person (:func:`shade`); 0: the round :data:`RADIUS` alone and nobody hidden, as
            for a nadir top view.
    """
    return _hypotheses(top, hor, hfov_deg, sizes, sight, plain=False, spread=spread)[0]


def _hypotheses(top: np.ndarray, hor: np.ndarray, hfov_deg: float, sizes: np.ndarray | None,
                sight: TopSight | None, plain: bool, spread: float = RANGE_SPREAD,
                at: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """:func:`pose_hypotheses` with the ``sight``, then, with ``plain`` and a sight, without
    it: the poses' terms are computed once for both (the sight only adds its count). ``at``
    ``(2,)``: the camera stands about there (its holder seen, ``--camera-id``): the poses
    standing there (:func:`anchored_poses`) and those within :data:`HOLDER_RADIUS` of it."""
    top, hor = np.asarray(top, float).reshape(-1, 2), np.asarray(hor, float).reshape(-1, 2)
    if not len(top) or not len(hor):
        return [(np.zeros((0, 3)), np.zeros(0))] * (2 if plain and sight is not None else 1)
    n, m = len(top), len(hor)
    headings = np.arange(_HEADINGS) * (2 * np.pi / _HEADINGS)
    turned = np.einsum("hab,mb->hma", _rotations(headings), hor)  # (H, M, 2)
    size = np.ones(n) if sizes is None else np.asarray(sizes, float).reshape(-1)
    # c = top_i - size_i turned_j for every (heading, i, j): j read at i's height, on i.
    centres = (top[None, :, None, :] - size[None, :, None, None] * turned[:, None, :, :]
               ).reshape(-1, 2)  # (P, 2), P = H N M, in (heading, i, j) order
    # Horizontal person k of pose p put against top person i at i's height:
    # centre_p + size_i turned_hk - top_i; the nearest top person of each (pose, k) and the
    # nearest horizontal person of each (pose, i) are kept (pose_terms).
    cx = np.ascontiguousarray(centres[:, 0].reshape(_HEADINGS, n * m))
    cy = np.ascontiguousarray(centres[:, 1].reshape(_HEADINGS, n * m))
    grown = turned[:, :, None, :] * size[None, None, :, None]  # (H, M, N, 2)
    poses = np.column_stack([centres, np.repeat(headings, n * m)])
    scores = _scores(cx, cy, grown, turned, top, hor, headings, hfov_deg, sight,
                     plain and sight is not None, spread)
    if at is not None:  # the poses near where the camera stands, and those standing there
        at = np.asarray(at, float).reshape(2)
        near = np.hypot(poses[:, 0] - at[0], poses[:, 1] - at[1]) <= HOLDER_RADIUS
        fixed = anchored_poses(top, hor, at)
        marks = _pose_scores(fixed, top, hor, hfov_deg, sizes, sight, plain and sight is not None,
                             spread)
        poses = np.concatenate([fixed, poses[near]])
        scores = [np.concatenate([m, s[near]]) for m, s in zip(marks, scores, strict=True)]
    out = []
    for score in scores:
        order = _best_first(score, _FIRST)
        keep = _distinct(poses, order)
        if len(keep) < KEEP and len(order) < len(score):  # the prefix ran out: the whole order
            keep = _distinct(poses, _best_first(score, len(score)))
        out.append((poses[keep], score[keep]))
    return out


def _scores(cx: np.ndarray, cy: np.ndarray, grown: np.ndarray, turned: np.ndarray,
            top: np.ndarray, hor: np.ndarray, headings: np.ndarray, hfov_deg: float,
            sight: TopSight | None, plain: bool = False, spread: float = RANGE_SPREAD
            ) -> list[np.ndarray]:
    """``(P,)`` the scores of poses ``p = h Q + q`` (:func:`pose_terms`' arguments): the
    horizontal people explained, less :data:`_UNSEEN_WEIGHT` per person left unexplained where
    they would be seen; with ``plain``, then the scores were there no ``sight``."""
    # The horizontal camera's view: a bearing within the half field of view (|across| <
    # ahead tan(half), no arctan), as far as its people reach.
    tan_half = float(np.tan(np.radians(hfov_deg) / 2)) if hfov_deg < 180 else np.inf
    reach = 1.2 * float(np.max(np.hypot(hor[:, 0], hor[:, 1])))
    near_hor, missed, unseen = pose_terms(cx, cy, grown, turned, top, (
        np.cos(headings), np.sin(headings), tan_half, reach * reach), sight, spread,
        shade(hor) if spread > 0 else None)  # nobody hidden under a nadir top view
    explained = np.exp(-0.5 * near_hor / _SIGMA**2).sum(axis=1)
    # Rounded so that a last-bit difference of exp() between CPUs cannot reorder near-ties.
    return [np.round(explained - _UNSEEN_WEIGHT * count, _DIGITS)
            for count in ([missed + unseen, missed] if plain else [missed + unseen])]


def score_poses(poses: np.ndarray, top: np.ndarray, hor: np.ndarray, hfov_deg: float,
                sizes: np.ndarray | None = None, sight: TopSight | None = None,
                spread: float = RANGE_SPREAD) -> np.ndarray:
    """``(K,)`` the scores of given poses ``(K, 3)`` (x, y, heading) for one frame, as
    :func:`pose_hypotheses` scores its own (arguments as its): a pose found in another frame
    is scored in this one."""
    poses = np.asarray(poses, float).reshape(-1, 3)
    top, hor = np.asarray(top, float).reshape(-1, 2), np.asarray(hor, float).reshape(-1, 2)
    if not len(poses) or not len(top) or not len(hor):
        return np.zeros(len(poses))
    return _pose_scores(poses, top, hor, hfov_deg, sizes, sight, spread=spread)[0]


def _pose_scores(poses: np.ndarray, top: np.ndarray, hor: np.ndarray, hfov_deg: float,
                 sizes: np.ndarray | None, sight: TopSight | None, plain: bool = False,
                 spread: float = RANGE_SPREAD) -> list[np.ndarray]:
    """:func:`score_poses` on arrays of its shapes (none empty), with the ``sight``, then,
    with ``plain``, without it (:func:`_scores`)."""
    size = np.ones(len(top)) if sizes is None else np.asarray(sizes, float).reshape(-1)
    headings = np.ascontiguousarray(poses[:, 2])
    turned = np.einsum("hab,mb->hma", _rotations(headings), hor)  # (K, M, 2)
    grown = turned[:, :, None, :] * size[None, None, :, None]  # (K, M, N, 2)
    return _scores(np.ascontiguousarray(poses[:, :1]), np.ascontiguousarray(poses[:, 1:2]),
                   grown, turned, top, hor, headings, hfov_deg, sight, plain, spread)


def anchored_poses(top: np.ndarray, hor: np.ndarray, at: np.ndarray) -> np.ndarray:
    """``(N M, 3)`` poses of a horizontal camera standing at ``at`` ``(2,)`` on the top map
    (where the top view sees its holder, ``--camera-id``), one per pair of a top person ``i``
    ``(N, 2)`` and a horizontal one ``j`` ``(M, 2)``: the heading that puts ``j`` on ``i``'s
    bearing (a bearing read from a box holds where its distance errs), in ``[0, 2 pi)``,
    rounded to :data:`_DIGITS` (the same poses on every CPU)."""
    at = np.asarray(at, float).reshape(2)
    to_top = np.arctan2(top[:, 1] - at[1], top[:, 0] - at[0])
    of_hor = np.arctan2(hor[:, 1], hor[:, 0])
    headings = np.round(np.mod(to_top[:, None] - of_hor[None, :], 2 * np.pi), _DIGITS)
    return np.column_stack([np.tile(at, (headings.size, 1)), headings.reshape(-1)])


def _best_first(score: np.ndarray, count: int) -> np.ndarray:
    """The first ``count`` indices of ``np.argsort(-score, kind="stable")`` (the highest
    scores, a tie in index order), without sorting the rest: a partition, then the leaders
    sorted."""
    neg = -np.asarray(score, float)
    if count >= len(neg):
        return np.argsort(neg, kind="stable")
    worst = neg[np.argpartition(neg, count - 1)[:count]].max()
    better = np.flatnonzero(neg < worst)  # all of them lead; then the ties, in index order
    lead = np.concatenate([better, np.flatnonzero(neg == worst)[:count - len(better)]])
    return lead[np.argsort(neg[lead], kind="stable")]


def shade(hor: np.ndarray) -> np.ndarray:
    """``(3, M)`` where each horizontal person hides those behind them from the camera: their
    depth along the optical axis, their bearing's tangent (across over depth) and its half
    span, half a body's width over the depth (:data:`BODY_WIDTH`)."""
    hor = np.asarray(hor, float).reshape(-1, 2)
    return np.ascontiguousarray(np.stack([hor[:, 0], hor[:, 1] / hor[:, 0],
                                          0.5 * BODY_WIDTH / hor[:, 0]]))


def pose_terms(cx: np.ndarray, cy: np.ndarray, grown: np.ndarray, turned: np.ndarray,
               top: np.ndarray, view: tuple[np.ndarray, np.ndarray, float, float],
               sight: TopSight | None, spread: float = RANGE_SPREAD,
               shadows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The terms of :func:`pose_hypotheses`' scores for every pose ``p = h Q + q`` (``cx``,
    ``cy`` ``(H, Q)`` its centre, facing heading ``h``): ``(P, M)`` each horizontal person's
    least squared distance to a top person (``grown`` ``(H, M, N, 2)``: horizontal people
    turned, at each top person's height) and two ``(P,)`` counts of the people it leaves
    unexplained where they would be seen: top people (``top`` ``(N, 2)``) in the horizontal
    camera's view (``view``: the headings' cos and sin, tan of the half field of view, the
    squared reach) with no horizontal person within :data:`RADIUS` nor, farther off, within
    ``spread`` of their distance from the camera (:data:`RANGE_SPREAD`; 0: the radius alone),
    and not behind a nearer horizontal person (``shadows``, :func:`shade`; None: nobody
    hidden), and horizontal people (``turned`` ``(H, M, 2)``) in the top camera's
    ``sight`` (zeros without one).

    The compiled kernel where numba is loaded (:mod:`~xvmatch.core.kernel_choice`: one pass,
    no ``(N, P)`` array), else numpy, horizontal person by horizontal person as an ``(N, P)``
    slab along the poses; the same arithmetic and comparisons, so the same bits either way."""
    cos_h, sin_h, tan_half, reach2 = view
    shadows = np.zeros((3, 0)) if shadows is None else np.ascontiguousarray(shadows, float)
    kernels = kernel_choice.kernels()
    if kernels is not None:
        ground = np.zeros((3, 3)) if sight is None else np.ascontiguousarray(sight.ground, float)
        bounds = np.zeros(0) if sight is None else sight.bounds()
        return kernels.pose_terms(cx, cy, np.ascontiguousarray(grown),
                                  np.ascontiguousarray(turned), top, cos_h, sin_h, tan_half,
                                  reach2, RADIUS**2, spread**2, ground, bounds, shadows)
    n, m = len(top), grown.shape[1]
    near_hor = np.empty((m, cx.size))
    near_top = np.full((n, cx.size), np.inf)
    dx, dy = np.empty((n, *cx.shape)), np.empty((n, *cx.shape))
    for k in range(m):
        np.add(cx, grown[:, k, :, 0].T[:, :, None], out=dx)
        dx -= top[:, 0, None, None]
        np.add(cy, grown[:, k, :, 1].T[:, :, None], out=dy)
        dy -= top[:, 1, None, None]
        dx *= dx
        dy *= dy
        dx += dy  # squared distances (N, H, N M)
        d2 = dx.reshape(n, -1)
        np.minimum(near_top, d2, out=near_top)
        d2.min(axis=0, out=near_hor[k])
    cos, sin = np.repeat(cos_h, cx.shape[1]), np.repeat(sin_h, cx.shape[1])
    rel_x, rel_y = top[:, 0, None] - cx.reshape(-1), top[:, 1, None] - cy.reshape(-1)
    ahead = rel_x * cos + rel_y * sin
    across = -rel_x * sin + rel_y * cos
    dist2 = ahead * ahead + across * across
    lone = ((near_top > RADIUS**2) & (ahead > 0.5) & (np.abs(across) < ahead * tan_half)
            & (dist2 < reach2) & (near_top > spread**2 * dist2))
    if shadows.shape[1]:  # behind a nearer horizontal person: hidden
        bearing = across / np.where(lone, ahead, 1.0)
        for depth, tangent, half in shadows.T:
            lone &= ~((depth < ahead) & (np.abs(bearing - tangent) < half))
    missed = lone.sum(axis=0)
    unseen = np.zeros_like(missed)
    if sight is not None:  # horizontal people alone where the top camera would see them
        where = (np.stack([cx.reshape(-1), cy.reshape(-1)], -1)[None]
                 + np.repeat(turned.transpose(1, 0, 2), cx.shape[1], axis=1))  # (M, P, 2)
        unseen = ((near_hor > RADIUS**2) & sight.sees(where)).sum(axis=0)
    return np.ascontiguousarray(near_hor.T), missed, unseen


def _distinct(poses: np.ndarray, order: np.ndarray, block: int = 512, limit: int = KEEP
              ) -> list[int]:
    """The first ``limit`` of ``order`` (indices into ``poses`` ``(P, 3)``) each 1 m or 10
    degrees away from every one kept before it (greedy, in order). The compiled kernel where
    numba is loaded (one pass, :mod:`~xvmatch.core.kernel_choice`), else numpy: a block of
    candidates at a time, those near an earlier block's kept ones struck out at once, then the
    first left kept and those near it struck out, until ``limit``; the same comparisons either
    way."""
    order = np.asarray(order, np.int64)
    kernels = kernel_choice.kernels()
    if kernels is not None:
        return kernels.distinct_poses(np.ascontiguousarray(poses[:, 0]),
                                      np.ascontiguousarray(poses[:, 1]),
                                      np.ascontiguousarray(poses[:, 2]), order, limit,
                                      _APART_RAD).tolist()
    keep: list[int] = []
    for start in range(0, len(order), block):
        cand = order[start:start + block]
        free = _apart(poses[cand], poses[keep]).all(axis=1) if keep else np.ones(len(cand), bool)
        x, y, th = poses[cand, 0], poses[cand, 1], poses[cand, 2]
        while free.any():
            i = int(np.argmax(free))
            keep.append(int(cand[i]))
            if len(keep) == limit:
                return keep
            free[i] = False
            # _apart's test against one pose, written out: the hot loop, no broadcast
            dx, dy = x - x[i], y - y[i]
            free &= (dx * dx + dy * dy > 1.0) | (np.abs(_wrap(th - th[i])) > _APART_RAD)
    return keep


def _apart(poses: np.ndarray, others: np.ndarray) -> np.ndarray:
    """``(K, L)`` whether each of poses ``(K, 3)`` is more than 1 m or 10 degrees from each
    of ``others`` ``(L, 3)``."""
    dx = poses[:, None, 0] - others[None, :, 0]
    dy = poses[:, None, 1] - others[None, :, 1]
    return ((dx * dx + dy * dy > 1.0)
            | (np.abs(_wrap(poses[:, None, 2] - others[None, :, 2])) > _APART_RAD))


_APART_RAD = float(np.radians(10.0))
"""Two poses this far apart in heading (or 1 m in position) are distinct hypotheses."""


def _wrap(angle: np.ndarray | float) -> np.ndarray | float:
    return (np.asarray(angle) + np.pi) % (2 * np.pi) - np.pi


_MOTION_MIN_SHARED = 3
"""Top people seen in two consecutive frames needed to tell how the top map moved."""

_MOTION_TRIM_M = 1.0
"""A person farther than this from the first fit's motion is left out of the second."""

MOTION_WINDOW_S = 1.5
"""Seconds either side over which the top map's motion is averaged (:func:`map_motion`)."""


def _rigid(src: np.ndarray, dst: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The 2-D rotation ``R`` and translation ``t`` with ``R @ src + t`` closest to ``dst`` in
    least squares (Procrustes without scale)."""
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - ms).T @ (dst - md))
    d = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, d]) @ u.T
    return rot, md - rot @ ms


def _step_motion(before: np.ndarray, now: np.ndarray) -> np.ndarray:
    """``(3,)`` (tx, ty, angle) of the rigid motion taking ``now`` onto ``before`` (the same
    people in two frames): a least-squares fit, then again without the people it fits worst."""
    rot, shift = _rigid(now, before)
    near = np.hypot(*(now @ rot.T + shift - before).T) <= _MOTION_TRIM_M
    if _MOTION_MIN_SHARED <= near.sum() < len(now):
        rot, shift = _rigid(now[near], before[near])
    return np.array([shift[0], shift[1], np.arctan2(rot[1, 0], rot[0, 0])])


def map_motion(frames: list[int], tops: list[np.ndarray], ids: list[np.ndarray], fps: float
               ) -> list[np.ndarray | None]:
    """Per frame (``frames`` ascending), how its top map lies on the previous frame's: ``(3,)``
    (tx, ty, angle) taking frame k's map onto frame k-1's, or None (the first frame, or fewer
    than :data:`_MOTION_MIN_SHARED` people shared).

    A drone that drifts and turns moves its whole ground map; the same people (the top view's own
    track ids, video mode) in two consecutive frames tell how, up to their own walking
    (:func:`_step_motion`). A drone's motion is steady and people's walking is not the same
    from step to step, so each step is given the steps' motion within :data:`MOTION_WINDOW_S`
    of it over their time (the mean rate there): on the renders, the raw steps cost static
    drones 1.4 CVIDF1 points, the mean rate none."""
    times = np.asarray(frames, float) / fps
    steps: list[np.ndarray | None] = [None]
    for k in range(1, len(tops)):
        prev = {int(i): n for n, i in enumerate(np.asarray(ids[k - 1]).ravel())}
        both = [(n, prev[int(i)]) for n, i in enumerate(np.asarray(ids[k]).ravel())
                if int(i) in prev]
        steps.append(None if len(both) < _MOTION_MIN_SHARED else _step_motion(
            np.asarray(tops[k - 1])[[b for _, b in both]],
            np.asarray(tops[k])[[a for a, _ in both]]))
    # The frames within the window, found by bisection (a little wider), then tested exactly:
    # linear in the clip's length rather than quadratic.
    lows = np.searchsorted(times, times - 2 * MOTION_WINDOW_S, side="left")
    highs = np.searchsorted(times, times + 2 * MOTION_WINDOW_S, side="right")
    out: list[np.ndarray | None] = [None]
    for k in range(1, len(tops)):
        near = [j for j in range(lows[k], highs[k])
                if steps[j] is not None and abs(times[j] - times[k]) <= MOTION_WINDOW_S]
        elapsed = sum(times[j] - times[j - 1] for j in near)
        out.append(None if steps[k] is None or elapsed <= 0 else np.round(
            np.sum([steps[j] for j in near], axis=0) * ((times[k] - times[k - 1]) / elapsed),
            _DIGITS))
    return out


def _moved(poses: np.ndarray, motion: np.ndarray | None) -> np.ndarray:
    """Poses ``(K, 3)`` on frame k's map carried onto frame k-1's by ``motion``
    (:func:`map_motion`)."""
    if motion is None:
        return poses
    c, s = np.cos(motion[2]), np.sin(motion[2])  # element by element: no BLAS, the same bits
    x, y = poses[:, 0], poses[:, 1]              # on every CPU
    return np.column_stack([c * x - s * y + motion[0], s * x + c * y + motion[1],
                            poses[:, 2] + motion[2]])


def _moved_on(poses: np.ndarray, motion: np.ndarray | None) -> np.ndarray:
    """Poses ``(K, 3)`` on frame k-1's map carried onto frame k's (:func:`_moved` undone)."""
    if motion is None:
        return poses
    c, s = np.cos(motion[2]), np.sin(motion[2])
    x, y = poses[:, 0] - motion[0], poses[:, 1] - motion[1]
    return np.column_stack([c * x + s * y, c * y - s * x, poses[:, 2] - motion[2]])


def _near_stand(poses: np.ndarray, stand: np.ndarray | None) -> np.ndarray:
    """The poses ``(K, 3)`` within :data:`HOLDER_RADIUS` of where the camera stands (its
    holder seen by the top view, ``--camera-id``); all of them where that is not known."""
    if stand is None:
        return poses
    return poses[np.hypot(*(poses[:, :2] - stand).T) <= HOLDER_RADIUS]


def carried(candidates: list[tuple[np.ndarray, np.ndarray]], tops: list[np.ndarray],
            hors: list[np.ndarray], hfov_deg: float, sizes: list, sights: list,
            motions: list[np.ndarray | None] | None = None, spread: float = RANGE_SPREAD,
            holders: Sequence[np.ndarray | None] | None = None
            ) -> list[tuple[np.ndarray, np.ndarray]]:
    """Each frame's hypotheses ``(poses, scores)``, then the :data:`CARRY` best of each
    neighbour's carried onto its map (by the top map's ``motions``, :func:`map_motion`) and
    scored in it (:func:`score_poses`), best first, those within 1 m and 10 degrees of one
    kept before left out: a pose that leads on either side of a frame where it fell out of
    the :data:`KEEP` best (near-duplicates of others kept in its place) stays on offer there,
    so the choice over time does not hinge on which of near-equal poses one frame kept. All
    24 carried, not 8: more clips found, but more lost (docs/notes/oblique_top_camera.md).
    ``holders``: per frame, where the camera stands (:func:`anchored_poses`) or None; into a
    frame where it stands, only the poses within :data:`HOLDER_RADIUS` of there are carried."""
    out = []
    for k, (poses, scores) in enumerate(candidates):
        near = []
        if len(poses) and k > 0 and len(candidates[k - 1][0]):
            near.append(_moved_on(candidates[k - 1][0][:CARRY],
                                  None if motions is None else motions[k]))
        if len(poses) and k + 1 < len(candidates) and len(candidates[k + 1][0]):
            near.append(_moved(candidates[k + 1][0][:CARRY],
                               None if motions is None else motions[k + 1]))
        if not near:
            out.append((poses, scores))
            continue
        extra = _near_stand(np.concatenate(near), None if holders is None else holders[k])
        extra = extra[_apart(extra, poses).all(axis=1)]  # this frame's own stand for them
        marks = score_poses(extra, tops[k], hors[k], hfov_deg, sizes[k], sights[k], spread)
        keep = _distinct(extra, np.argsort(-marks, kind="stable"), limit=len(extra))
        out.append((np.concatenate([poses, extra[keep]]),
                    np.concatenate([scores, marks[keep]])))
    return out


def register_sequence(frames: list[int], candidates: list[tuple[np.ndarray, np.ndarray]],
                      fps: float, motions: list[np.ndarray | None] | None = None,
                      slack: float = 1.0,
                      rescore: Callable[[int, np.ndarray], tuple[np.ndarray, np.ndarray]]
                      | None = None) -> list[FramePose]:
    """One pose per frame from each frame's hypotheses (``(poses, scores)``), chosen by Viterbi
    over the frames with a cost on fast jumps (module docstring); frames without hypotheses
    split the sequence into runs, each chosen on its own. With ``motions``
    (:func:`map_motion`), a jump is measured after the top map's own motion is taken out (a
    drifting drone), so only the handheld camera's own walk and turn pay. ``slack``: how many
    times :data:`_STEP_M` and :data:`_STEP_DEG` a second go free (more where ``fps`` was read
    from the walkers and may be too high,
    :data:`~xvmatch.inference.matching.frame_rate.READ_RATE_SLACK`). ``rescore(k, poses)``:
    poses ``(K, 3)`` scored in frame ``k`` (those it keeps and their scores); with it each
    frame is also offered the :data:`LEAD` poses that lead the choice at the frame before (its
    best totals), carried onto its map: a pose the choice holds stays on offer through frames
    whose people alone rank it out of their own (a detector missed people, one person shared).
    :func:`register_scales` offers them in video mode where the top view's tracks show people
    missed (:data:`MISSED_SHARE`): there they mend clips (``benchmarks/oblique_association.py
    --box-misses 0.2 1 --choose-lens``); elsewhere they also hold wrong poses (a lingering
    crowd; frame by frame, ``benchmarks/oblique_tracking.py --seed 2`` 91.1 -> 56.4;
    docs/notes/oblique_top_camera.md)."""
    if not slack > 0:
        raise ValueError(f"slack must be positive, got {slack}")
    totals: list[np.ndarray] = []
    back: list[np.ndarray] = []
    candidates = list(candidates)  # a frame's own, then the poses leading at the one before
    for k, (poses, scores) in enumerate(candidates):
        if rescore is not None and len(poses) and k > 0 and len(candidates[k - 1][0]):
            lead = np.argsort(-totals[k - 1], kind="stable")[:LEAD]
            extra = _moved_on(candidates[k - 1][0][lead],
                              motions[k] if motions is not None else None)
            kept, marks = rescore(k, extra[_apart(extra, poses).all(axis=1)])
            if len(kept):
                poses, scores = np.concatenate([poses, kept]), np.concatenate([scores, marks])
                candidates[k] = (poses, scores)
        if not len(poses) or k == 0 or not len(candidates[k - 1][0]):
            totals.append(np.asarray(scores, float).copy())
            back.append(np.full(len(poses), -1))
            continue
        gap = max(1, frames[k] - frames[k - 1]) / fps
        prev = candidates[k - 1][0]
        here = _moved(poses, motions[k] if motions is not None else None)
        step = np.hypot(*(here[:, None, :2] - prev[None, :, :2]).transpose(2, 0, 1))
        turn = np.abs(_wrap(here[:, None, 2] - prev[None, :, 2]))
        free = slack * gap
        cost = _JUMP_COST * (np.maximum(step / (_STEP_M * free) - 1.0, 0.0)
                             + np.maximum(turn / (np.radians(_STEP_DEG) * free) - 1.0, 0.0))
        via = np.round(totals[k - 1][None, :] - cost, _DIGITS)
        best = np.argmax(via, axis=1)
        totals.append(np.round(scores + via[np.arange(len(poses)), best], _DIGITS))
        back.append(best)
    choice = [-1] * len(candidates)
    k = len(candidates) - 1
    while k >= 0:
        if not len(candidates[k][0]):
            k -= 1
            continue
        j = int(np.argmax(totals[k]))
        while k >= 0 and j >= 0:
            choice[k] = j
            j = int(back[k][j])
            k -= 1
    out = []
    for k, (poses, scores) in enumerate(candidates):
        if choice[k] >= 0:
            p = poses[choice[k]]
            out.append(FramePose(frames[k], p[:2].copy(), float(p[2]),
                                 float(scores[choice[k]])))
    return out


def missed_share(ids: Sequence[np.ndarray]) -> float:
    """The share of each id's frames, from its first to its last (``ids``: per frame, the
    view's track ids), in which it is missing: 0 where every track runs unbroken."""
    k = np.concatenate([np.full(len(i), n) for n, i in enumerate(ids)] or [np.zeros(0, int)])
    flat = np.concatenate([np.asarray(i).reshape(-1) for i in ids] or [np.zeros(0, int)])
    if not len(flat):
        return 0.0
    _, which = np.unique(flat, return_inverse=True)
    first = np.full(which.max() + 1, len(ids))
    last = np.full(which.max() + 1, -1)
    np.minimum.at(first, which, k)
    np.maximum.at(last, which, k)
    return float(1.0 - len(flat) / (last - first + 1).sum())


def _scored_in(frames: tuple[list, list, list, list, list | None], hfov_deg: float,
               spread: float, k: int, poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Poses ``(K, 3)`` offered to frame ``k`` of ``frames`` (its top people, horizontal
    people, sizes, sights and where its camera stands, per frame) and their scores there
    (:func:`score_poses`): where the camera's stand is known, those within
    :data:`HOLDER_RADIUS` of it, as :func:`carried` offers them."""
    tops, hors, sizes, sights, stands = frames
    poses = _near_stand(poses, None if stands is None else stands[k])
    return poses, score_poses(poses, tops[k], hors[k], hfov_deg, sizes[k], sights[k], spread)


def register_scales(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                    hfov_deg: float, fps: float, top_ids: list[np.ndarray] | None = None,
                    top_sizes: list[np.ndarray] | None = None,
                    sights: list[TopSight] | None = None, spread: float = RANGE_SPREAD,
                    slack: float = 1.0, holders: Sequence[np.ndarray | None] | None = None
                    ) -> dict[float, tuple[float, list[FramePose]]]:
    """The horizontal camera's pose per frame (:func:`register_sequence`) on the top map
    scaled by each of :data:`MAP_SCALES`: ``{scale: (total score, poses)}``, the poses on the
    top map multiplied by ``scale``. Arguments as :func:`register_with_scale`'s."""
    return _register_scales(frames, tops, hors, hfov_deg, fps, top_ids, top_sizes, sights,
                            plain=False, spread=spread, slack=slack, holders=holders)[0]


def register_scales_twice(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                          hfov_deg: float, fps: float, top_ids: list[np.ndarray] | None,
                          top_sizes: list[np.ndarray] | None, sights: list[TopSight],
                          spread: float = RANGE_SPREAD, slack: float = 1.0,
                          holders: Sequence[np.ndarray | None] | None = None
                          ) -> tuple[dict[float, tuple[float, list[FramePose]]],
                                     dict[float, tuple[float, list[FramePose]]]]:
    """:func:`register_scales` with the top camera's ``sights`` and without them, as two calls
    give them (bit for bit), each frame's pose terms computed once for both: video mode
    compares the two runs of every lens."""
    made, plain = _register_scales(frames, tops, hors, hfov_deg, fps, top_ids, top_sizes,
                                   sights, plain=True, spread=spread, slack=slack,
                                   holders=holders)
    return made, plain


def _register_scales(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                     hfov_deg: float, fps: float, top_ids: list[np.ndarray] | None,
                     top_sizes: list[np.ndarray] | None, sights: list[TopSight] | None,
                     plain: bool, spread: float = RANGE_SPREAD, slack: float = 1.0,
                     holders: Sequence[np.ndarray | None] | None = None
                     ) -> list[dict[float, tuple[float, list[FramePose]]]]:
    """:func:`register_scales` with the ``sights``, then, with ``plain`` and sights, without
    them."""
    twice = plain and sights is not None
    runs: list[dict[float, tuple[float, list[FramePose]]]] = [{} for _ in range(1 + twice)]
    motion = None if top_ids is None else map_motion(frames, tops, top_ids, fps)
    moved = motion is not None and any(m is not None for m in motion)
    missed = top_ids is not None and missed_share(top_ids) >= MISSED_SHARE
    sizes = top_sizes or [None] * len(tops)
    for scale in MAP_SCALES:
        scaled = [scale * np.asarray(p, float) for p in tops]
        seen = [None if v is None else v.scaled(scale) for v in sights or [None] * len(tops)]
        stands = None if holders is None else [None if h is None else scale * np.asarray(
            h, float) for h in holders]
        each = [_hypotheses(p, q, hfov_deg, z, v, twice, spread, a)
                for p, q, z, v, a in zip(scaled, hors, sizes, seen, stands or [None] * len(tops),
                                         strict=True)]
        # With the map's motion out, and (where any was read) with it left in: a static
        # camera's small crowd walking together reads as motion; the better-explained kept.
        variants = ([[None if m is None else np.array([scale * m[0], scale * m[1], m[2]])
                      for m in motion], None] if moved else [None])
        for k, kept in enumerate(runs):
            cands = [c[k] for c in each]
            looks = seen if k == 0 else [None] * len(tops)
            for motions in variants:
                poses = register_sequence(
                    frames, carried(cands, scaled, hors, hfov_deg, sizes, looks, motions, spread,
                                    stands), fps, motions, slack,
                    partial(_scored_in, (scaled, hors, sizes, looks, stands), hfov_deg,
                            spread) if missed else None)
                run = (round(sum(p.score for p in poses), 6), poses)
                if scale not in kept or run[0] > kept[scale][0]:
                    kept[scale] = run
    return runs


def register_with_scale(frames: list[int], tops: list[np.ndarray], hors: list[np.ndarray],
                        hfov_deg: float, fps: float, top_ids: list[np.ndarray] | None = None,
                        top_sizes: list[np.ndarray] | None = None,
                        sights: list[TopSight] | None = None, spread: float = RANGE_SPREAD,
                        slack: float = 1.0, holders: Sequence[np.ndarray | None] | None = None
                        ) -> tuple[float, list[FramePose]]:
    """The horizontal camera's pose per frame (:func:`register_sequence`) on the top map
    scaled by each of :data:`MAP_SCALES` (:func:`register_scales`), and the scale kept: the two
    maps' metres come from two estimates (the top camera's height from its people, each
    distance from a box height) that can disagree by a third, so another scale replaces 1
    where its chosen poses explain :data:`SCALE_MARGIN` times as many people over the clip (a
    small lead is noise). The totals tell the scale weakly (a pose fitted frame by frame
    absorbs a scale error; on the renders the best other scale's total is within 0.97-1.13 of
    scale 1's on most clips): video mode chooses along the tracks instead, among the scales
    whose total reaches :data:`SCALE_FLOOR` of scale 1's
    (:func:`xvmatch.inference.matching.ground_association.register_and_pair`).

    Args:
        frames: the frame numbers, in order.
        tops: per frame, the top view's people ``(N, 2)`` on its ground map (finite rows).
        hors: per frame, the horizontal view's people ``(M, 2)`` on its own map.
        hfov_deg: the horizontal camera's field of view.
        fps: frames per second of the frame numbers.
        top_ids: per frame, the top view's own track ids of ``tops`` (video mode only): the top
            map's motion from frame to frame is then taken out of the jumps
            (:func:`map_motion`); where any was read, each scale is also registered with the
            map left still, and the run whose poses explain more kept (a static camera's
            few people walking together read as motion: on a close render, 0.1 m a step
            tipped a clip to a wrong pose).
        top_sizes: per frame, each top person's height over the crowd's (``tops``' rows;
            :func:`pose_hypotheses`), or None.
        sights: per frame, where the top camera sees people on its map (:class:`TopSight`,
            :func:`pose_hypotheses`), or None.
        spread: see :func:`pose_hypotheses`.
        slack: see :func:`register_sequence`.
        holders: per frame, where the top view sees the horizontal camera's holder on its map
            (``--camera-id``; their box's ground point, ``(2,)``) or None (not seen): the
            camera is sought within :data:`HOLDER_RADIUS` of there, and at it with each
            heading a pair of people gives (:func:`anchored_poses`); None: no holder told.
    Returns:
        ``(scale, poses)``: the poses lie on the top map multiplied by ``scale``.
    """
    runs = register_scales(frames, tops, hors, hfov_deg, fps, top_ids, top_sizes, sights,
                           spread, slack, holders)
    best = margin_scale(runs)
    return best, runs[best][1]


def margin_scale(runs: dict[float, tuple[float, list[FramePose]]]) -> float:
    """The map scale :func:`register_with_scale` keeps of :func:`register_scales`' runs: the
    best total's, where it leads scale 1's by :data:`SCALE_MARGIN`, else 1."""
    best = max(MAP_SCALES, key=lambda s: (runs[s][0], -abs(s - 1.0)))
    return best if runs[best][0] > round(SCALE_MARGIN * runs[1.0][0], 6) else 1.0


def fitting_scales(runs: dict[float, tuple[float, list[FramePose]]]) -> list[float]:
    """The map scales of :func:`register_scales`' runs whose clip score total is at least
    :data:`SCALE_FLOOR` of scale 1's (scale 1 always): those video mode weighs by their pairs
    along the tracks."""
    one = runs[1.0][0]
    floor = one - (1.0 - SCALE_FLOOR) * abs(one)
    return [s for s, (total, _) in runs.items() if s == 1.0 or total >= floor]


def on_top_map(hor: np.ndarray, pose: FramePose) -> np.ndarray:
    """The horizontal view's people ``(M, 2)`` (its own ground map) placed on the top map
    under the pose: turned by its heading, moved to its centre."""
    rot = _rotations(np.array([pose.heading]))[0]
    return pose.centre + np.asarray(hor, float).reshape(-1, 2) @ rot.T


def associate_on_ground(top: np.ndarray, hor: np.ndarray, pose: FramePose,
                        sizes: np.ndarray | None = None) -> np.ndarray:
    """Pairs ``(P, 2)`` (top index, horizontal index) under the pose: Hungarian on the ground
    distances along each horizontal person's ray shrunk by its spread (:func:`ray_distances`,
    each read at the top person's ``sizes`` when given), pairs farther than :data:`RADIUS`
    left unmatched."""
    top, hor = np.asarray(top, float).reshape(-1, 2), np.asarray(hor, float).reshape(-1, 2)
    if not len(top) or not len(hor):
        return np.zeros((0, 2), dtype=np.int64)
    mapped = on_top_map(hor, pose)
    d = ray_distances(top, mapped, mapped - pose.centre, sizes)
    cost = np.where(d < RADIUS, d, 2 * RADIUS)
    rows, cols = linear_sum_assignment(cost)
    ok = d[rows, cols] < RADIUS
    return np.column_stack([rows[ok], cols[ok]]).astype(np.int64)
