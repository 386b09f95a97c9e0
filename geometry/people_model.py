"""The model of people's box heights that calibrates a camera from them, and its fit.

A pinhole camera (square pixels, the principal point at the image centre) ``camera_height``
metres over one ground plane, looking along +x, tilted down by ``tilt`` and rolled by ``roll``
(:func:`~xvmatch.geometry.camera.look_rotation`); each person an upright cylinder
:data:`BODY_WIDTH` across, stood where the ray through the box's bottom meets the ground, and
:data:`PERSON_HEIGHT` tall unless followed long enough to have a height of their own. The
residual of a box is ``log(predicted height / box height)``, the person placed so that their
box's centre row is the box's (:func:`centred_heights`: a loose bottom edge would move the foot
row and the height together), fitted with a soft-L1 loss (people differ in height, boxes are
cut by occlusion) and weak priors on the focal length
(:data:`PRIOR_HFOV_DEG`) and the people's heights.

The tilt is one for the clip (:mod:`~xvmatch.geometry.people_calibration`, a static camera) or
one per window of frames (:mod:`~xvmatch.geometry.tilting_camera`, a gimbal that tilts), the
neighbouring windows' tilts then held together by a soft cost per step: one model, one call for
all windows. Parameters: ``(tilt of window 0, 1, ..., roll, log f, log camera height, height of
track 0, 1, ...)`` (radians, pixels, metres).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from xvmatch.core import kernel_choice
from xvmatch.geometry.camera import Camera, look_rotation

__all__ = [
    "BLOCK_FRAMES",
    "BODY_WIDTH",
    "BORDER",
    "BORDER_SHARE",
    "CENTRE_ROUNDS",
    "HANDHELD_HEIGHT_SHARE",
    "HIDING_GAP",
    "HIDING_SHARE",
    "MAX_FIT_BOXES",
    "OUTLINE_SMOOTH_PX",
    "PERSON_HEIGHT",
    "PRIOR_HFOV_DEG",
    "PRIOR_LOG_STD",
    "SOFT_SCALE",
    "UsableBoxes",
    "centred_heights",
    "data_cost",
    "fit_model",
    "forward_differences",
    "handheld_horizon",
    "model_camera",
    "model_starts",
    "pinhole",
    "predicted_heights",
    "prior_focal",
    "readable_boxes",
    "usable_boxes",
    "whole_boxes",
]

PERSON_HEIGHT = 1.72
"""Mean standing height of the people (m), the middle of 1.5-1.95 m: the calibration's scale."""

BODY_WIDTH = 0.45
"""Diameter (m) of the upright cylinder a person is modelled as: shoulders across, feet and
stride in depth."""

OUTLINE_SMOOTH_PX = 0.2
"""Within how many pixels of each other two corner rows of a person's outline have their
highest (lowest) rounded (:func:`_tie`): with the sharp highest row the fit's cost bends where
the corner on top changes, its settling stalls on a bend short of the minimum, and where it
stalls rests on the last bit of the CPU's arithmetic (one clip's calibration read 34.5 or
34.8 degrees by its CPU, its pairs 0 or 1 F1). Rounded, a box is shorter by at most 0.074
of this for each row nearly tied with the top or bottom (under 0.8 of it with all eight
nearly tied), and as sharp where they are tied or farther apart
(docs/notes/oblique_top_camera.md, sixty-fifth session)."""

PRIOR_HFOV_DEG = 70.0
"""Horizontal field of view (degrees) the focal length is drawn towards where the boxes cannot
tell it: a phone's main camera, a drone's, a surveillance camera's (60-80)."""

PRIOR_LOG_STD = 0.4
"""Spread of that prior on ``log f`` (a factor 1.5)."""

_PRIOR_WEIGHT = 1.0
"""The prior counts as much as this many boxes fitted exactly."""

BORDER = 2.0
"""A box within this many pixels of the image border is cut by it: its height says nothing."""

BORDER_SHARE = 0.1
"""A box whose top or bottom lies within this share of its height of the image's top or
bottom border may be cut by it too: a box's edges are loose by a few per cent of its height,
and a person cut by the border whose box ends a little inside it reads short (on renders
with 3 % loose edges, the free top fit read lenses of 110-130 degrees for 60-80 from such
boxes). A border at a box's side leaves its height whole."""

HIDING_SHARE = 0.5
"""Nearer people's boxes that span a box's foot or top row across this share of its width
hide its feet or head (a person's legs and head are the middle of their box); less, at a
side, leaves them in sight."""

HIDING_GAP = 0.1
"""A box that ends within this share of a nearer box's height above that box's top is taken
to end at it (its feet hidden): boxes' edges are loose by a few per cent of their height (on
renders with 3 % loose edges, the boxes ended just above a hider read 1.7-2.6 times too
short for the true camera)."""

_MIN_HEIGHT_PX = 8.0
"""Boxes lower than this (pixels) are too coarse to read a height from."""

_BAD_RESIDUAL = 3.0
"""Residual of a box whose foot the model puts at or above the horizon (log units: e^3)."""

CENTRE_ROUNDS = 2
"""Steps of :func:`centred_heights`' foot row (each multiplies its error by half the rate at
which box heights change with the row: well under a half where people stand upright)."""

SOFT_SCALE = 0.08
"""Soft-L1 scale of the height residuals: people's heights differ by about 8 %."""

SETTLE_TOLERANCE = 1e-15
"""Cost, step and gradient tolerance of :func:`fit_model`'s settling steps (``settle``)."""

_MIN_TRACK_BOXES = 10
"""A track with this many usable boxes gets a height of its own (in video mode)."""

_HEIGHT_STD = 0.3
"""Spread of people's heights about :data:`PERSON_HEIGHT` (m), the prior on a track's height."""

BLOCK_FRAMES = 10
"""Frames per time block of the usable boxes (the calibration's resampling unit)."""

MAX_FIT_BOXES = 4000
"""Most boxes a fit reads (evenly spread over the clip: same answer, bounded time)."""

_START_HFOVS = (45.0, 65.0, 90.0, 120.0)
"""Fields of view (degrees) the fit starts from, each with the level line's camera."""

_START_TILTS = (30.0, 50.0, 70.0)
"""Tilts (degrees) the fit also starts from, at the prior lens and 10 m up: the level line's
start points almost straight down where that line is nearly flat (a low drone whose people's
feet keep to a few rows), and the fit stayed there, a nadir call for upright people."""

_CAMERA_BOUNDS = (np.array([np.radians(-45.0), np.radians(-30.0), -np.inf, np.log(0.5)]),
                  np.array([np.radians(89.0), np.radians(30.0), np.inf, np.log(1e3)]))
_HEIGHT_BOUNDS = (1.0, 2.4)

HANDHELD_HEIGHT_SHARE = (0.7, 1.3)
"""A handheld camera's height over its people's (:func:`handheld_horizon`): from chest to
above head height, 1.2-2.2 m for people of :data:`PERSON_HEIGHT`."""


@dataclass(frozen=True)
class UsableBoxes:
    """The usable boxes of a clip: foot column ``u``, foot row ``v``, height ``h`` and width
    ``w`` (pixels), the time block of each (for resampling), its track (0: too short to have a
    height of its own), where known its frame, and its window of the tilt (all 0: one tilt)."""

    u: np.ndarray
    v: np.ndarray
    h: np.ndarray
    w: np.ndarray
    block: np.ndarray
    track: np.ndarray
    n_tracks: int
    frame: np.ndarray | None = None
    window: np.ndarray | None = None
    n_windows: int = 1

    def take(self, index: np.ndarray) -> UsableBoxes:
        """The boxes at ``index`` (repeats allowed), with the same tracks and windows."""
        return replace(self, u=self.u[index], v=self.v[index], h=self.h[index],
                       w=self.w[index], block=self.block[index], track=self.track[index],
                       frame=None if self.frame is None else self.frame[index],
                       window=None if self.window is None else self.window[index])

    def windowed(self, window: np.ndarray) -> UsableBoxes:
        """The same boxes with a tilt per window: ``window`` ``(N,)`` each box's, 0, 1, ...;
        the boxes ordered by window (stably): each window's rows one slice, the fit's residuals
        in that order (the model itself reads each box's own window, in any order)."""
        window = np.asarray(window, np.int64).reshape(-1)
        out = self.take(np.argsort(window, kind="stable"))
        return replace(out, window=np.sort(window), n_windows=int(window.max()) + 1)


def _behind_someone(frames: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Boxes whose foot row or top row the boxes of people nearer (whose feet are lower in the
    image) in the same frame span across at least :data:`HIDING_SHARE` of their width
    together: the visible part of a hidden person ends at the hiders' edge (or within
    :data:`HIDING_GAP` of it), so its height is not theirs. A box overlapped at a side only
    keeps its person's feet and head in sight (before, any touch set a box aside: a low
    drone over a crowd kept a third of its boxes)."""
    out = np.zeros(len(boxes), dtype=bool)
    order = np.argsort(frames, kind="stable")
    starts = np.flatnonzero(np.r_[True, np.diff(frames[order]) != 0])
    for rows in np.split(order, starts[1:]):
        if len(rows) < 2:
            continue
        x, y, w, h = boxes[rows].T
        bottom = y + h
        across = np.minimum(x + w, (x + w)[:, None]) - np.maximum(x, x[:, None])  # [hider, box]
        nearer = bottom[:, None] > bottom[None]
        spans_foot = y[:, None] <= bottom[None] + HIDING_GAP * h[:, None]
        spans_top = (y[:, None] <= y[None]) & (bottom[:, None] >= y[None])
        hiders = nearer & (spans_foot | spans_top)
        out[rows] = np.where(hiders, np.maximum(across, 0.0), 0.0).sum(axis=0) >= HIDING_SHARE * w
    return out


def whole_boxes(boxes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``(N,)`` boxes ``(N, 4)`` that no image border cuts (none within :data:`BORDER` pixels
    of one, nor with its top or bottom within :data:`BORDER_SHARE` of its height of the
    image's) and tall enough to read, in an image of ``size`` (width, height)."""
    x, y, w, h = np.asarray(boxes, dtype=float).reshape(-1, 4).T
    width, height = size
    m = np.maximum(BORDER, BORDER_SHARE * h)
    return ((x > BORDER) & (y > m) & (x + w < width - BORDER) & (y + h < height - m)
            & (h >= _MIN_HEIGHT_PX) & (w > 0))


def readable_boxes(frames: np.ndarray, boxes: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Boxes ``(N, 4)`` whose height is the person's: whole (:func:`whole_boxes`), not behind
    someone (in the same of ``frames`` ``(N,)``)."""
    return whole_boxes(boxes, size) & ~_behind_someone(frames, boxes)


def usable_boxes(frames: np.ndarray, ids: np.ndarray | None, boxes: np.ndarray,
                 size: tuple[int, int]) -> UsableBoxes:
    """Boxes ``(N, 4)`` x, y, w, h not cut by the image border, not behind someone and tall
    enough to read, each with its track (index 0: boxes of tracks too short to have a height of
    their own; left out when most boxes have a track)."""
    x, y, w, h = boxes.T
    ok = readable_boxes(frames, boxes, size)
    block = np.unique(frames[ok] // BLOCK_FRAMES, return_inverse=True)[1]
    track = np.zeros(int(ok.sum()), dtype=np.int64)
    n_tracks = 1
    if ids is not None:
        _keys, inverse, counts = np.unique(ids[ok], return_inverse=True, return_counts=True)
        long = counts >= _MIN_TRACK_BOXES
        number = np.cumsum(long) * long  # 1.. for long tracks, 0 for short ones
        track, n_tracks = number[inverse], int(long.sum()) + 1
    out = UsableBoxes(u=x[ok] + 0.5 * w[ok], v=y[ok] + h[ok], h=h[ok], w=w[ok], block=block,
                      track=track, n_tracks=n_tracks, frame=frames[ok])
    if n_tracks > 1 and np.mean(track > 0) >= 0.5:
        # Enough people were followed: the others' boxes, of mixed heights, only blur the fit.
        out = out.take(np.flatnonzero(track > 0))
    return out


def _box_rotations(params: np.ndarray, b: UsableBoxes) -> tuple[np.ndarray, np.ndarray]:
    """The camera's world-to-camera rotations ``(W, 3, 3)``, one per window of the tilt, and
    each box's window ``(N,)``."""
    n = b.n_windows
    roll = params[n]
    rotations = np.stack([look_rotation(0.0, t, roll) for t in params[:n]])
    window = np.zeros(len(b.u), np.int64) if n == 1 else np.asarray(b.window, np.int64)
    return rotations, window


def predicted_heights(params: np.ndarray, b: UsableBoxes, size: tuple[int, int]) -> np.ndarray:
    """Box heights the model predicts (``params``: module docstring); NaN where the foot is at
    or above the horizon.

    A person is an upright cylinder :data:`BODY_WIDTH` across, stood where the ray through the
    box's bottom meets the ground (the near edge of the feet: the axis is a radius farther); the
    predicted height is that of the image's bounding box of its outline at the feet and at the
    head (a camera from above sees the top of the head and the ground in front of the feet
    inside the box), its top and bottom rounded over :data:`OUTLINE_SMOOTH_PX`. Off the image
    centre a tilted camera sees people lean (their verticals meet below the image): the box's
    centre column is then halfway between the foot's and the head's, and the leaning body's
    width adds to the box's height."""
    return _model_heights(params, b, size, 0)


def _model_heights(params: np.ndarray, b: UsableBoxes, size: tuple[int, int],
                   rounds: int) -> np.ndarray:
    """The boxes' predicted heights, their foot rows moved ``rounds`` times so that each box's
    centre row is its own (:func:`centred_heights`; 0: :func:`predicted_heights`): the
    compiled kernel where numba is loaded (:mod:`~xvmatch.core.kernel_choice`), else numpy,
    the same bits either way (:mod:`~xvmatch.geometry.people_kernels`)."""
    n = b.n_windows
    f, hc = float(np.exp(params[n + 1])), float(np.exp(params[n + 2]))
    person = np.ascontiguousarray(params[n + 3:][b.track], dtype=float)
    rotations, window = _box_rotations(params, b)
    cx, cy = 0.5 * size[0], 0.5 * size[1]
    u, v, h = (np.ascontiguousarray(x, dtype=float) for x in (b.u, b.v, b.h))
    kernels = kernel_choice.kernels("people")
    if kernels is not None:
        return kernels.centred_box_heights(u, v, h, person, rotations, window, f, hc, cx, cy,
                                           0.5 * BODY_WIDTH, rounds, OUTLINE_SMOOTH_PX)
    turn = rotations[window]
    pred = _heights_numpy(u, v, person, turn, f, hc, cx, cy)
    centre = v - 0.5 * h
    for _ in range(rounds):
        pred = _heights_numpy(u, centre + 0.5 * np.where(np.isfinite(pred), pred, h), person,
                              turn, f, hc, cx, cy)
    return pred


def _to_world(x: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Rows of camera vectors ``(..., N, 3)`` in world axes (``x R``, ``turn`` each row's
    world-to-camera rotation ``(N, 3, 3)``): three products summed left to right, the
    kernel's order on every CPU (a BLAS product sums and fuses in its kernel's own)."""
    return ((x[..., 0, None] * turn[:, 0, :] + x[..., 1, None] * turn[:, 1, :])
            + x[..., 2, None] * turn[:, 2, :])


def _to_camera(x: np.ndarray, turn: np.ndarray) -> np.ndarray:
    """Rows of world vectors ``(..., N, 3)`` in camera axes (``R x``): :func:`_to_world`
    through the inverse rotations, the same sums."""
    return _to_world(x, turn.transpose(0, 2, 1))


def _heights_numpy(u: np.ndarray, v: np.ndarray, person: np.ndarray, turn: np.ndarray,
                   f: float, hc: float, cx: float, cy: float) -> np.ndarray:
    """The heights of the boxes with their foot pixels at ``u``, ``v`` (:func:`predicted_heights`),
    ``person`` tall, ``turn`` each box's world-to-camera rotation: the numpy form of
    :func:`~xvmatch.geometry.people_kernels.centred_box_heights`, operation for operation."""
    count = len(u)
    ray_row = (v - cy) / f

    def depth(z: np.ndarray) -> np.ndarray:
        """Camera coordinates' depth, NaN behind the camera."""
        return np.where(z > 1e-9, z, np.nan)

    def axis(column: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The body's axis at the ground and the radius along the ray: the box's bottom
        row sees the near edge of the feet (where the foot pixel's ray meets the ground,
        NaN above the horizon), the axis is a radius farther."""
        rays = np.empty((count, 3))  # the foot pixels' rays: column, row, 1
        rays[:, 0] = (column - cx) / f
        rays[:, 1] = ray_row
        rays[:, 2] = 1.0
        d = _to_world(rays, turn)
        with np.errstate(divide="ignore", invalid="ignore"):
            s = np.where(d[:, 2] < -1e-9, hc / -d[:, 2], np.nan)
            rim = s[:, None] * d
            along = rim.copy()
            along[:, 2] = 0.0
            # the length as the kernel's: a square root is exact, a SIMD hypot may not be
            along *= (0.5 * BODY_WIDTH / np.sqrt(rim[:, 0] * rim[:, 0] + rim[:, 1] * rim[:, 1])
                      )[:, None]
        return rim + along, along

    up = np.zeros((count, 3))
    up[:, 2] = person
    foot, _ = axis(u)
    with np.errstate(divide="ignore", invalid="ignore"):
        head = _to_camera(foot + up, turn)
        u_head = cx + f * head[:, 0] / depth(head[:, 2])
    foot, along = axis(u - 0.5 * (u_head - u))  # the box centre is the lean's middle
    side = np.empty_like(along)
    np.negative(along[:, 1], out=side[:, 0])
    side[:, 1] = along[:, 0]
    side[:, 2] = along[:, 2]
    # The body's outline (seen and in depth) at the feet and at the head, corner by corner:
    # each row's top and bottom a maximum and minimum over 8 rows.
    corners = np.empty((8, count, 3))
    for k, base in enumerate((foot, foot + up)):
        np.add(base, side, out=corners[4 * k])
        np.subtract(base, side, out=corners[4 * k + 1])
        np.add(base, along, out=corners[4 * k + 2])
        np.subtract(base, along, out=corners[4 * k + 3])
    with np.errstate(divide="ignore", invalid="ignore"):
        cam = _to_camera(corners, turn)
        rows = cy + f * cam[..., 1] / depth(cam[..., 2])
    return _smooth_span(rows)


def _smooth_span(rows: np.ndarray) -> np.ndarray:
    """The highest of ``rows`` ``(8, N)`` less the lowest, each rounded near a tie
    (:func:`_tie`), the rows folded in in order, the kernel's (NaN in, NaN out)."""
    hi, lo = rows[0].copy(), rows[0].copy()
    for row in rows[1:]:
        hi = np.maximum(hi, row) + _tie(np.abs(hi - row))
        lo = np.minimum(lo, row) - _tie(np.abs(lo - row))
    return hi - lo


def _tie(t: np.ndarray) -> np.ndarray:
    """What the higher of two rows ``t`` apart gains to round it: ``-(t / 2) (1 - t / e)^2``
    within ``e`` (:data:`OUTLINE_SMOOTH_PX`), else 0. The higher of ``a`` and ``b`` so rounded
    has one slope, a half each, at a tie, so its value there is exact and its slope continuous:
    no bend, and nothing added at a tie (as a square root's rounding adds half of ``e``, to a
    nadir view's four tied head corners most of all)."""
    e = OUTLINE_SMOOTH_PX
    r = 1.0 - t / e
    return np.where(t < e, -(0.5 * t) * (r * r), 0.0)


def centred_heights(params: np.ndarray, b: UsableBoxes, size: tuple[int, int]) -> np.ndarray:
    """Box heights the model predicts for the boxes' centre rows rather than their bottoms (the
    foot row solved from ``v = centre + height(v) / 2`` in :data:`CENTRE_ROUNDS` fixed-point
    steps): a box's loose bottom edge moves its foot row and its height together, and where
    each person followed has a height of their own the tilt rests on how heights change over
    the few rows they walk, which that shared error flattens (renders with 3 % loose edges
    read 3-8 degrees too level); the centre row's error is independent of the height's where
    both edges are as loose."""
    return _model_heights(params, b, size, CENTRE_ROUNDS)


def _residuals(params: np.ndarray, b: UsableBoxes, size: tuple[int, int], prior_f: float,
               tilt_step: float) -> np.ndarray:
    """Log height errors of the boxes, then the priors: the focal length's, each track's
    height's (people are :data:`PERSON_HEIGHT` +- :data:`_HEIGHT_STD` tall), which also sets
    the scale; with a tilt per window, each step between windows' tilts over ``tilt_step``
    (radians)."""
    n = b.n_windows
    pred = centred_heights(params, b, size)
    with np.errstate(divide="ignore", invalid="ignore"):
        r = np.log(pred / b.h)
    r = np.where(np.isfinite(r), r, _BAD_RESIDUAL)
    prior = np.sqrt(_PRIOR_WEIGHT) * SOFT_SCALE * (params[n + 1] - np.log(prior_f)) / PRIOR_LOG_STD
    heights = SOFT_SCALE * (params[n + 3:] - PERSON_HEIGHT) / _HEIGHT_STD
    steps = SOFT_SCALE * np.diff(params[:n]) / tilt_step
    return np.concatenate([r, [prior], heights, steps])


def data_cost(params: np.ndarray, b: UsableBoxes, size: tuple[int, int]) -> float:
    """The fit's soft-L1 cost without the focal length's prior (that of the boxes and of the
    people's heights), for one tilt."""
    r = _residuals(params, b, size, float(np.exp(params[2])), 1.0)
    z = (r / SOFT_SCALE) ** 2
    return float(np.sum(SOFT_SCALE ** 2 * (np.sqrt(1.0 + z) - 1.0)))


def _sparsity(b: UsableBoxes) -> np.ndarray:
    """Which parameters each residual depends on: a box on its window's tilt, the roll, focal
    length and height and its track's height; the priors on one each, a step on its two
    windows' tilts."""
    rows, n, k = len(b.h), b.n_windows, b.n_tracks
    window = np.zeros(rows, np.int64) if b.window is None else b.window
    every = np.arange(rows)
    out = np.zeros((rows + 1 + k + n - 1, n + 3 + k), dtype=bool)
    out[every, window] = True
    out[:rows, n:n + 3] = True
    out[every, n + 3 + b.track] = True
    out[rows, n + 1] = True
    out[rows + 1 + np.arange(k), n + 3 + np.arange(k)] = True
    steps = rows + 1 + k + np.arange(n - 1)
    out[steps, np.arange(n - 1)] = True
    out[steps, np.arange(1, n)] = True
    return out


def _least_squares(*args, **kwargs):
    """``scipy.optimize.least_squares``, imported at the first fit: half a second at start-up
    that a run fitting nothing (the nadir search) need not pay."""
    from scipy.optimize import least_squares

    return least_squares(*args, **kwargs)


def _level_line(b: UsableBoxes, size: tuple[int, int]) -> tuple[float, float, float]:
    """Robust fit of ``h = a (v - v0 - s (u - cx))``: slope ``a``, horizon row ``v0`` at the
    centre column and its slope ``s`` (the level-camera line, the fit's start)."""
    cx = 0.5 * size[0]
    A = np.column_stack([b.v, b.u - cx, np.ones_like(b.v)])

    def resid(p: np.ndarray) -> np.ndarray:
        return (A @ p - b.h) / np.maximum(b.h, 1.0)

    p0 = np.linalg.lstsq(A, b.h, rcond=None)[0]
    p = _least_squares(resid, p0, loss="soft_l1", f_scale=SOFT_SCALE).x
    a = p[0]
    if not a > 0:
        return 0.0, np.nan, 0.0
    return float(a), float(-p[2] / a), float(-p[1] / a)


def handheld_horizon(frames: np.ndarray, boxes: np.ndarray, size: tuple[int, int],
                     min_boxes: int = 20) -> float | None:
    """The horizon's row at the centre column of a handheld camera near level, at about head
    height, from its people's boxes ``(N, 4)`` in ``frames`` ``(N,)``: a person ``h`` pixels
    tall has the top of the head at ``v0 + b h``, ``b`` the camera's height over the person's
    less one, held within :data:`HANDHELD_HEIGHT_SHARE` (the level line :func:`_level_line`
    with its slope bounded: readable people all far off, as under a camera looking up, cannot
    tip it); a robust fit. None with fewer than ``min_boxes`` readable boxes."""
    b = usable_boxes(np.asarray(frames).reshape(-1), None,
                     np.asarray(boxes, dtype=float).reshape(-1, 4), size)
    if len(b.h) < min_boxes:
        return None
    top = b.v - b.h
    lo, hi = (share - 1.0 for share in HANDHELD_HEIGHT_SHARE)

    def resid(p: np.ndarray) -> np.ndarray:
        return (p[0] + p[1] * b.h - top) / np.maximum(b.h, 1.0)

    fit = _least_squares(resid, [float(np.median(top)), 0.0],
                         bounds=([-np.inf, lo], [np.inf, hi]), loss="soft_l1",
                         f_scale=SOFT_SCALE)
    return float(fit.x[0])


def _start(b: UsableBoxes, size: tuple[int, int], hfov: float) -> np.ndarray:
    """Parameters of one tilt from the level line at a given hfov, every track
    :data:`PERSON_HEIGHT` tall."""
    a, v0, slope = _level_line(b, size)
    f = 0.5 * size[0] / np.tan(np.radians(hfov) / 2.0)
    heights = np.full(b.n_tracks, PERSON_HEIGHT)
    if not np.isfinite(v0):
        return np.concatenate([[np.radians(30.0), 0.0, np.log(f), np.log(10.0)], heights])
    # Keep every foot below the start's horizon: the model needs their rays to meet the ground.
    v0 = min(v0, float(np.min(b.v - slope * (b.u - 0.5 * size[0]))) - 1.0)
    tilt = float(np.arctan2(0.5 * size[1] - v0, f))
    roll = float(-np.arctan(slope))
    hc = max(PERSON_HEIGHT / max(a, 1e-3) * np.cos(tilt), PERSON_HEIGHT * 1.05)
    return np.concatenate([[tilt, roll, np.log(f), np.log(hc)], heights])


def prior_focal(size: tuple[int, int], hfov_deg: float | None = None) -> float:
    """The focal length (pixels) of ``hfov_deg``, or of the prior's :data:`PRIOR_HFOV_DEG`."""
    return float(0.5 * size[0] / np.tan(np.radians(hfov_deg or PRIOR_HFOV_DEG) / 2.0))


def model_starts(b: UsableBoxes, size: tuple[int, int], prior_f: float,
                 hfovs: Sequence[float] = _START_HFOVS) -> list[np.ndarray]:
    """The fit's starts (parameters of one tilt): the level line's camera at each of
    ``hfovs``, then each of :data:`_START_TILTS` at the focal length ``prior_f``, 10 m up."""
    return [_start(b, size, hfov) for hfov in hfovs] + [
        np.concatenate([[np.radians(t), 0.0, np.log(prior_f), np.log(10.0)],
                        np.full(b.n_tracks, PERSON_HEIGHT)]) for t in _START_TILTS]


def fit_model(b: UsableBoxes, size: tuple[int, int], prior_f: float,
              starts: Sequence[np.ndarray], fixed_f: float | None = None,
              hold: Sequence[int] = (), tilt_step_deg: float = 10.0,
              settle: bool = False) -> np.ndarray:
    """Least squares from each start (parameters of one tilt, each window's tilt starting at
    it, or a whole fit's parameters with a tilt per window); the parameters (module docstring)
    of the lowest cost.

    Args:
        b: the boxes (with ``b.n_windows`` tilts).
        size: the image's (width, height).
        prior_f: the focal length the prior draws towards (pixels).
        starts: the starts, ``(tilt, roll, log f, log height, track heights...)``, or with
            ``b.n_windows`` tilts first.
        fixed_f: the focal length held (pixels), or None: fitted.
        hold: which of roll (1), log f (2) and log height (3) are held at each start's value.
        tilt_step_deg: the scale of the cost on a tilt's step between windows (degrees).
        settle: go on from the best start with exact trust-region steps to
            :data:`SETTLE_TOLERANCE` (:func:`_settle`).
    """
    n, k = b.n_windows, b.n_tracks
    lower = np.concatenate([np.full(n, _CAMERA_BOUNDS[0][0]), _CAMERA_BOUNDS[0][1:],
                            np.full(k, _HEIGHT_BOUNDS[0])])
    upper = np.concatenate([np.full(n, _CAMERA_BOUNDS[1][0]), _CAMERA_BOUNDS[1][1:],
                            np.full(k, _HEIGHT_BOUNDS[1])])
    free = np.ones(n + 3 + k, dtype=bool)
    free[[n - 1 + i for i in hold]] = False
    if fixed_f is not None:
        free[n + 1] = False
    sparsity = _sparsity(b)[:, free]
    step = np.radians(tilt_step_deg)
    lo, hi = lower[free], upper[free]

    def around(full: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
        """The residuals as a function of the free parameters, the others held at ``full``'s."""
        def fun(p: np.ndarray) -> np.ndarray:
            x = full.copy()
            x[free] = p
            return _residuals(x, b, size, prior_f, step)
        return fun

    best, best_cost = None, np.inf
    for x0 in starts:
        x0 = np.asarray(x0, float)
        tilts = x0[:n] if len(x0) == n + 3 + k else np.full(n, x0[0])
        full = np.clip(np.concatenate([tilts, x0[-3 - k:]]), lower + 1e-6, upper - 1e-6)
        if fixed_f is not None:
            full[n + 1] = np.log(fixed_f)
        res = _least_squares(around(full), full[free], loss="soft_l1", f_scale=SOFT_SCALE,
                             bounds=(lo, hi), jac_sparsity=sparsity)
        if res.cost < best_cost:
            x = full.copy()
            x[free] = res.x
            best, best_cost = x, res.cost
    if settle and best is not None:  # best is this call's own copy
        best[free] = _settle(around(best), best[free], lo, hi, sparsity)
    return best


def _settle(fun: Callable[[np.ndarray], np.ndarray], p: np.ndarray, lo: np.ndarray,
            hi: np.ndarray, structure: np.ndarray) -> np.ndarray:
    """The fit's free parameters ``p`` carried to its minimum's last digits (``fun``: the
    residuals of them, within ``lo``-``hi``; ``structure``: which parameters each residual
    reads). The sparse steps stop at their tolerance on a flat cost, and where they stop moves
    with the BLAS kernels' last bits (2e-4 of the focal length on a lingering crowd's clip,
    between OpenBLAS's kernels); exact steps scaled by the Jacobian, to
    :data:`SETTLE_TOLERANCE`, end within 1e-4 px of one focal length on each kernel tried,
    which ``people_calibration._settled`` rounds to one (where the cost has one minimum there:
    in a valley of shallow minima each start's fit stays in its own, docs/method.md)."""
    p0 = np.clip(p, lo + 1e-9, hi - 1e-9)
    last: dict[str, np.ndarray] = {}

    def residuals(x: np.ndarray) -> np.ndarray:
        last["x"], last["r"] = x.copy(), fun(x)
        return last["r"]

    def jacobian(x: np.ndarray) -> np.ndarray:
        f0 = last["r"] if "x" in last and np.array_equal(last["x"], x) else fun(x)
        return forward_differences(fun, x, f0, lo, hi, structure)

    return _least_squares(residuals, p0, jac=jacobian, loss="soft_l1", f_scale=SOFT_SCALE,
                          bounds=(lo, hi), tr_solver="exact", x_scale="jac",
                          ftol=SETTLE_TOLERANCE, xtol=SETTLE_TOLERANCE,
                          gtol=SETTLE_TOLERANCE).x


def forward_differences(fun: Callable[[np.ndarray], np.ndarray], x: np.ndarray,
                        f0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                        structure: np.ndarray) -> np.ndarray:
    """The dense Jacobian of ``fun`` at ``x`` (``f0``: its value there) by forward differences,
    one evaluation for each group of parameters that no residual reads together
    (``structure`` ``(M, N)``): a followed person's height moves only their own boxes, so all
    heights share one. Bit for bit scipy's dense ``"2-point"`` rule (a step of sqrt(eps)
    times ``max(1, |x|)``, turned or shortened at the bounds ``lo``-``hi``), where the
    evaluations it saves would each have moved only the residuals that ``structure`` marks."""
    h = np.sqrt(np.finfo(float).eps) * np.where(x >= 0, 1.0, -1.0) * np.maximum(1.0, np.abs(x))
    below, above = x - lo, hi - x
    fits = np.abs(h) <= np.maximum(below, above)
    h = np.where(((x + h < lo) | (x + h > hi)) & fits, -h, h)
    h = np.where(fits, h, np.where(above >= below, above, -below))
    step = (x + h) - x
    groups: list[tuple[list[int], np.ndarray]] = []  # parameters, and the residuals they move
    for j in range(len(x)):  # greedily: each parameter joins the first group it does not touch
        for group, rows in groups:
            if not (rows & structure[:, j]).any():
                group.append(j)
                rows |= structure[:, j]
                break
        else:
            groups.append(([j], structure[:, j].copy()))
    # Filled by parameter and returned transposed, column-major as scipy's: the trust-region
    # steps' BLAS calls then take the same path and give the same bits.
    transposed = np.empty((len(x), len(f0)))
    for group, _ in groups:
        moved = x.copy()
        moved[group] = x[group] + h[group]
        change = fun(moved) - f0
        for j in group:  # an unmarked residual's change is 0: signed as the step's, as scipy's
            transposed[j] = np.where(structure[:, j], change, 0.0) / step[j]
    return transposed.T


def pinhole(focal: float, tilt: float, roll: float, height: float,
            size: tuple[int, int]) -> Camera:
    """The model's camera: square pixels, the principal point at the image centre, above the
    origin looking along +x (``tilt``, ``roll`` in radians)."""
    K = np.array([[focal, 0.0, 0.5 * size[0]], [0.0, focal, 0.5 * size[1]], [0.0, 0.0, 1.0]])
    return Camera(K=K, R=look_rotation(0.0, tilt, roll), c=np.array([0.0, 0.0, height]),
                  width=size[0], height=size[1])


def model_camera(params: np.ndarray, size: tuple[int, int]) -> Camera:
    """The camera of one tilt's parameters (module docstring)."""
    tilt, roll, log_f, log_hc = params[:4]
    return pinhole(np.exp(log_f), tilt, roll, np.exp(log_hc), size)
