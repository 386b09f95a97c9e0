"""A camera calibrated from the people it sees: horizon, tilt, roll, focal length and height.

People stand upright on one ground plane and are about :data:`PERSON_HEIGHT` tall (1.5-1.95 m).
For a level camera a person's box height is linear in its foot row,
``h = (H_person / h_camera) * (y_foot - y_horizon)``: the rows where heights vanish are the
horizon, the slope is the person's height over the camera's. A tilted camera bends that line
(the head is nearer the camera than the foot); the bend tells the focal length. This module fits
the whole pinhole model (:mod:`~xvmatch.geometry.people_model`) to a clip's boxes:

* **model**: ``K`` with square pixels and the principal point at the image centre, ``R`` =
  ``look_rotation(0, tilt, roll)``, centre ``(0, 0, h_camera)``; each box's foot pixel (bottom
  centre) is cast to the ground and a person of :data:`PERSON_HEIGHT` stood there, the foot row
  moved until the person's box has the box's centre row (loose edges); the residual is
  ``log(predicted height / box height)``;
* **start**: a robust linear fit of box height on foot row and column (the level-camera line,
  which gives the horizon line and ``H_person / h_camera``), for several focal lengths;
* **fit**: ``scipy.optimize.least_squares`` with a soft-L1 loss (people differ in height, boxes
  are cut by occlusion) and a weak prior on the focal length (:data:`PRIOR_HFOV_DEG`), which
  decides it only where the boxes cannot (a level camera, whose heights do not depend on it);
* **confidence**: the spread of the fit over resamples of the clip's time blocks (seeded).
  The strict calibration (``xvmatch calibrate``) also refuses a tilt that rests on the unknown
  lens (refitted at each end of :data:`LENS_RANGE_DEG`: the heights rarely tell the focal
  length, and the tilt moves with it by about 3 degrees per 10 of field of view at 30 degrees
  down) and a view whose people are seen from too steeply above for their heights to tell the
  tilt (:data:`MIN_UPRIGHT_ASPECT`).

A nadir camera (a drone looking straight down) shows no such line: its boxes are the heads and
shoulders seen from above, as wide as tall. It is recognised by the boxes' shape
(:data:`NADIR_ASPECT`; the strict calibration asks the same of the boxes in the image's middle,
:data:`MIDDLE_NADIR_ASPECT`) and reported as such; its ground map is the image itself, up to
scale.

The scale of everything (camera height, ground metres) rests on the people's mean height, so it
is good to a few per cent; directions (tilt, roll, horizon) do not depend on it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from xvmatch.geometry.camera import Camera
from xvmatch.geometry.people_model import (
    BLOCK_FRAMES,
    BODY_WIDTH,
    BORDER,
    MAX_FIT_BOXES,
    PERSON_HEIGHT,
    PRIOR_HFOV_DEG,
    PRIOR_LOG_STD,
    UsableBoxes,
    data_cost,
    fit_model,
    model_camera,
    model_starts,
    pinhole,
    predicted_heights,
    prior_focal,
    readable_boxes,
    usable_boxes,
    whole_boxes,
)

__all__ = [
    "BODY_WIDTH",
    "LENS_RANGE_DEG",
    "MIDDLE_NADIR_ASPECT",
    "MIN_BLOCKS",
    "MIN_BOXES",
    "MIN_HEIGHT_SHARE",
    "MIN_ROW_SPREAD",
    "MIN_TRACKED_ROW_SPREAD",
    "MIN_UPRIGHT_ASPECT",
    "NADIR_ASPECT",
    "NADIR_TILT_DEG",
    "PERSON_HEIGHT",
    "PRIOR_HFOV_DEG",
    "STEEP_ASPECT",
    "CalibrationError",
    "PeopleCalibration",
    "calibrate_from_people",
    "cut_at_bottom",
    "horizon_line",
    "measure_spread",
    "whole_boxes",
]

MIN_HEIGHT_SHARE = 0.5
"""A box tells its person's height (:meth:`PeopleCalibration.person_heights`) where at least
this share of its pixel height grows with it: seen steeply from above, a box's height is mostly
the body's width and the ground in front of the feet."""

_HEIGHT_READ = (1.5, 1.95)
"""Heights (m) between which :meth:`PeopleCalibration.person_heights` reads a box's person's
height off the model (nearly straight in the height there)."""

LENS_RANGE_DEG = (55.0, 85.0)
"""The fields of view the prior stands for (phones' main cameras, drones', most surveillance
cameras; the renders' too). Where the boxes do not tell the focal length (most
clips: the heights hardly depend on it), the strict calibration refits the tilt with each end
of this range held and refuses when either moves it more than :data:`MAX_TILT_STD_DEG`: the
tilt then rests on the lens, which only the caller knows (``--hfov``)."""

NADIR_ASPECT = 1.0
"""A view whose median box height over width is below this looks (nearly) straight down: from
above, a head and shoulders are about as wide as tall, or wider."""

STEEP_ASPECT = 1.6
"""Below this median height over width, a view whose boxes the pinhole fit cannot read is taken
as looking down too: upright people seen from less than about 60 degrees below the horizontal
are taller than that."""

MIDDLE_NADIR_ASPECT = 1.2
"""The strict calibration calls a view nadir (:data:`NADIR_ASPECT`) only where the boxes in
the image's middle columns are this squat too: straight down, a person under the camera is a
head and shoulders (the real CVMHAT drone views: 0.94-1.0, renders 0.6-1.15). An oblique view
through a wide lens has squat boxes at its sides only, where its people lean."""

MIN_UPRIGHT_ASPECT = 2.0
"""The strict calibration refuses a view whose boxes in the image's middle columns have a
median height over width below this: those people are seen from more than about 70 degrees
below the horizontal (for people 1.72 m tall and 0.45 m across; wider boxes, arms out, read
steeper and are refused sooner), their box heights are then mostly their bodies' width (which
differs from person to person), and on renders the fit reads such a camera 3 to 9 degrees too
shallow in most clips, the lens given or not (measured on 40 renders 55-90 degrees down)."""

_MIDDLE = 0.2
"""The middle columns: foot columns within this fraction of the image width of its centre."""

_LENS_COST_RISE = 2e-4
"""A lens held at an end of :data:`LENS_RANGE_DEG` that raises the fit's mean cost per box
by more than this (about a 2 % rms height error) is ruled out by the boxes."""

NADIR_TILT_DEG = 80.0
"""A fitted tilt steeper than this is reported as a nadir camera: the image is then the ground
up to a similarity, within a few per cent."""

MIN_BOXES = 30
"""Fewest usable boxes (inside the image, not cut by its border) a calibration is fitted from."""

MIN_BLOCKS = 3
"""Fewest stretches of 10 frames the usable boxes must come from in the strict calibration:
the confidence is the spread over resamples of them. The loose one (what the association
takes) fits any number, its spread not measured from a single stretch: a clip of 20 frames
(every 10th of a 6 s video) spans 2 or 3 by where its people happen to be readable."""

MIN_ROW_SPREAD = 0.15
"""The usable foot rows must spread over this fraction of the image height (between their 10th
and 90th percentiles): people at one distance cannot tell where the horizon is."""

MIN_TRACKED_ROW_SPREAD = 0.05
"""The same where the people were followed (video mode, the strict calibration): each one's
box grows and shrinks as they walk nearer and away, which tells the horizon over a narrower
band; the spread over resamples (:data:`MAX_TILT_STD_DEG`, :data:`MAX_HORIZON_STD`) judges
the rest. Measured on renders: rows over 5-15 % of the image height, tilt within 3 degrees
given the lens in 17 of 18 (the other refused by that spread)."""

MAX_TILT_STD_DEG = 3.0
"""A calibration whose tilt varies more than this over resamples of the clip is refused."""

MAX_HORIZON_STD = 0.03
"""Nor one whose horizon row varies more than this fraction of the image height, where the
horizon is within an image height of the image (farther off, the tilt says it all)."""

_N_RESAMPLES = 16


class CalibrationError(ValueError):
    """The boxes cannot tell the camera: too few, too close to one distance, or a fit that
    varies too much over the clip. The message says which and what to give instead."""


@dataclass(frozen=True, eq=False)
class _Fit:
    """An oblique fit as made, unrounded, and what its spread's resamples need."""

    boxes: UsableBoxes
    prior_f: float
    params: np.ndarray
    fixed_f: float | None
    seed: int


@dataclass(frozen=True)
class PeopleCalibration:
    """A view's camera as its people tell it.

    Attributes:
        kind: ``"oblique"`` (any camera that sees people upright, a level one included) or
            ``"nadir"`` (looking straight down).
        width, height: image size, pixels.
        focal: focal length, pixels.
        tilt_deg: downward pitch of the optical axis (0 level, 90 straight down).
        roll_deg: roll (look_rotation's convention, clockwise).
        camera_height: height of the camera over the ground, metres (from :data:`PERSON_HEIGHT`).
        horizon: ``(row at the left edge, row at the right edge)`` of the horizon line; rows
            above the image are negative.
        focal_from: ``"people"`` (the boxes told it), ``"prior"`` (they could not: the prior's
            :data:`PRIOR_HFOV_DEG`) or ``"given"`` (the caller's).
        tilt_std_deg, horizon_std_px, focal_rel_std: spread over resamples of the clip.
        n_boxes, n_frames: the usable boxes and the frames they came from.
        _fit: what the spread is measured from where it was left for later
            (:func:`measure_spread`), else None; not part of the record.
    """

    kind: str
    width: int
    height: int
    focal: float
    tilt_deg: float
    roll_deg: float
    camera_height: float
    horizon: tuple[float, float]
    focal_from: str
    tilt_std_deg: float
    horizon_std_px: float
    focal_rel_std: float
    n_boxes: int
    n_frames: int
    person_height: float = PERSON_HEIGHT
    _fit: _Fit | None = field(default=None, repr=False, compare=False)
    _camera: Camera = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        cam = pinhole(self.focal, np.radians(self.tilt_deg), np.radians(self.roll_deg),
                       self.camera_height, (self.width, self.height))
        object.__setattr__(self, "_camera", cam)

    @property
    def camera(self) -> Camera:
        """The pinhole camera in the view's own ground frame: above the origin, looking along
        +x (yaw 0), ground z = 0 in metres."""
        return self._camera

    @property
    def hfov_deg(self) -> float:
        """Horizontal field of view, degrees."""
        return float(np.degrees(2.0 * np.arctan(0.5 * self.width / self.focal)))

    def ground_points(self, pixels: np.ndarray) -> np.ndarray:
        """Foot pixels ``(N, 2)`` to ground points ``(N, 2)`` in the view's own frame (metres);
        NaN for a pixel at or above the horizon."""
        return _to_ground(self.camera, np.asarray(pixels, dtype=float))

    def standing_points(self, boxes: np.ndarray, sizes: np.ndarray | None = None) -> np.ndarray:
        """Where the people of boxes ``(N, 4)`` stand, ``(N, 2)`` in the view's own frame
        (metres): each box's foot point on the ground; for a box cut by the image's bottom edge
        (:func:`cut_at_bottom`: its feet out of sight, its bottom row the border's), where the
        ray through its top centre meets the plane of its person's height (``sizes`` ``(N,)``,
        each over :attr:`person_height`; 1 without); NaN where neither ray meets its plane."""
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        x, y, w, h = boxes.T
        points = _to_ground(self.camera, np.column_stack([x + 0.5 * w, y + h]))
        cut = cut_at_bottom(boxes, self.height) & (self.kind == "oblique")
        if cut.any():
            size = np.ones(len(boxes)) if sizes is None else np.asarray(sizes, float).reshape(-1)
            points[cut] = _to_ground(self.camera, np.column_stack([x + 0.5 * w, y])[cut],
                                     self.person_height * size[cut])
        return points

    def person_heights(self, frames: np.ndarray, boxes: np.ndarray) -> np.ndarray:
        """``(N,)`` each box's person's height in metres, read through this camera: the height
        at which the fit's model of a person standing at the box's foot point
        (:func:`~xvmatch.geometry.people_model.predicted_heights`) gives the box's height; NaN
        for a box that cannot tell (cut by the border, behind someone, too small, a nadir view,
        a foot at the horizon, or seen so steeply from above that under
        :data:`MIN_HEIGHT_SHARE` of its height comes from the person's height).
        ``frames`` ``(N,)``: each box's frame (who stands behind whom)."""
        frames = np.asarray(frames, dtype=np.int64).reshape(-1)
        boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
        out = np.full(len(boxes), np.nan)
        size = (self.width, self.height)
        ok = readable_boxes(frames, boxes, size)
        if self.kind != "oblique" or not ok.any():
            return out
        x, y, w, h = boxes[ok].T
        n = len(h)
        b = UsableBoxes(u=x + 0.5 * w, v=y + h, h=h, w=w, block=np.zeros(n, np.int64),
                        track=np.arange(n), n_tracks=n)
        camera = [np.radians(self.tilt_deg), np.radians(self.roll_deg), np.log(self.focal),
                  np.log(self.camera_height)]
        low, high = _HEIGHT_READ
        at = {m: predicted_heights(np.concatenate([camera, np.full(n, m)]), b, size)
              for m in (low, self.person_height, high)}
        with np.errstate(divide="ignore", invalid="ignore"):
            per_metre = (at[high] - at[low]) / (high - low)
            metres = low + (h - at[low]) / per_metre
            share = per_metre * self.person_height / at[self.person_height]
        metres[~(np.isfinite(metres) & (share >= MIN_HEIGHT_SHARE))] = np.nan
        out[ok] = metres
        return out

    def to_record(self) -> dict:
        """JSON-ready record of how the camera was estimated (the camera file's ``estimated``)."""
        return {
            "from": "people",
            "kind": self.kind,
            "tilt_deg": round(self.tilt_deg, 3),
            "roll_deg": round(self.roll_deg, 3),
            "horizon_rows": (None if self.kind == "nadir"
                             else [round(self.horizon[0], 2), round(self.horizon[1], 2)]),
            "hfov_deg": round(self.hfov_deg, 3),
            "focal_from": self.focal_from,
            "camera_height_m": round(self.camera_height, 3),
            "person_height_m": self.person_height,
            "tilt_std_deg": _measured(self.tilt_std_deg, 3),
            "horizon_std_px": _measured(self.horizon_std_px, 2),
            "focal_rel_std": _measured(self.focal_rel_std, 4),
            "boxes": self.n_boxes,
            "frames": self.n_frames,
        }


def _measured(value: float, digits: int) -> float | None:
    """``value`` rounded, or None where it was not measured (NaN: no resampling)."""
    return None if np.isnan(value) else round(value, digits)


def horizon_line(camera: Camera) -> tuple[float, float]:
    """Rows of the ground plane's vanishing line at the image's left and right edges.

    The line is ``l = K^-T R n`` with ``n`` the ground normal; a camera looking straight down
    has none (rows of +-inf)."""
    line = np.linalg.inv(camera.K).T @ camera.R @ np.array([0.0, 0.0, 1.0])
    if abs(line[1]) < 1e-12:
        return (-np.inf, -np.inf)
    rows = [-(line[0] * u + line[2]) / line[1] for u in (0.0, float(camera.width))]
    return float(rows[0]), float(rows[1])


def cut_at_bottom(boxes: np.ndarray, image_height: float) -> np.ndarray:
    """``(N,)`` boxes ``(N, 4)`` cut by the image's bottom edge (their bottom row within
    :data:`~xvmatch.geometry.people_model.BORDER` pixels of it): the person's feet are out of
    sight."""
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    return boxes[:, 1] + boxes[:, 3] >= image_height - BORDER


def _to_ground(camera: Camera, pixels: np.ndarray,
               at: float | np.ndarray = 0.0) -> np.ndarray:
    """Rays through ``pixels`` met with the plane ``at`` metres up (the ground by default; a
    scalar or one per pixel), as ground positions; NaN where they do not point down to it."""
    d = camera.ray_directions(pixels)
    drop = np.asarray(at, dtype=float) - camera.c[2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where((d[:, 2] < -1e-9) & (drop < 0), drop / d[:, 2], np.nan)
    return camera.c[:2] + s[:, None] * d[:, :2]


def _middle_aspect(b: UsableBoxes, size: tuple[int, int]) -> float:
    """Median height over width of the usable boxes in the image's middle columns (all of
    them where fewer than 10 are there): how steeply the people under the image centre are
    seen, without the lean of those at the sides."""
    middle = np.abs(b.u - 0.5 * size[0]) < _MIDDLE * size[0]
    pick = middle if middle.sum() >= 10 else np.ones_like(middle)
    return float(np.median(b.h[pick] / b.w[pick]))


def _nadir(b: UsableBoxes, widths: np.ndarray, size: tuple[int, int], n_frames: int,
           hfov: float | None) -> PeopleCalibration:
    """A camera straight down: focal from the given or prior hfov, height from the boxes'
    width (a head and shoulders about 0.5 m across)."""
    f = prior_focal(size, hfov)
    hc = PERSON_HEIGHT + f * 0.5 / float(np.median(widths))
    return PeopleCalibration(
        kind="nadir", width=size[0], height=size[1], focal=float(f), tilt_deg=90.0,
        roll_deg=0.0, camera_height=float(hc), horizon=(-np.inf, -np.inf),
        focal_from="given" if hfov else "prior", tilt_std_deg=0.0, horizon_std_px=0.0,
        focal_rel_std=0.0, n_boxes=len(b.h), n_frames=n_frames)


def calibrate_from_people(
    frames: np.ndarray,
    boxes: np.ndarray,
    image_size: tuple[int, int],
    *,
    ids: np.ndarray | None = None,
    hfov_deg: float | None = None,
    seed: int = 0,
    name: str = "the view",
    strict: bool = True,
    spread: bool | str = True,
) -> PeopleCalibration:
    """Estimate a static camera from its boxes over a clip (module docstring).

    Args:
        frames: ``(N,)`` frame number of each box (time blocks for the confidence).
        boxes: ``(N, 4)`` x, y, w, h in pixels.
        ids: ``(N,)`` the view's own track id of each box (video mode), or None: a person
            seen long enough gets a height of their own, so the fit reads the camera from how
            each person's box grows and shrinks rather than from the spread of heights.
        image_size: ``(width, height)`` of the view.
        hfov_deg: the horizontal field of view when known (then not fitted).
        seed: seed of the resampling behind the confidence.
        name: the view's name for messages.
        strict: refuse a fit the clip does not pin down (the ``calibrate`` command); False
            returns it anyway, its spread saying how loose it is (an association that must
            place the view somehow is better served by a loose fit than by none).
        spread: measure the fit's spread over resamples of the clip (16 more fits, most of
            the time); False leaves the ``*_std`` fields NaN, the fit itself unchanged (a
            caller that does not read them, with ``strict=False``); ``"later"`` (with
            ``strict=False``) leaves them NaN until :func:`measure_spread` measures them, the
            same figures as at once (a caller that may not need them); measured at once all
            the same where they decide the view (squat boxes, whose loose fit reads as nadir).

    Raises:
        CalibrationError: too few usable boxes (:data:`MIN_BOXES`); with ``strict``, also
            boxes from too few stretches of the clip (:data:`MIN_BLOCKS`), foot rows in too
            narrow a band, a tilt or horizon that the clip does not pin down
            (:data:`MAX_TILT_STD_DEG`, :data:`MAX_HORIZON_STD`), people seen from too steeply
            above (:data:`MIN_UPRIGHT_ASPECT`) and, without ``hfov_deg``, a tilt that rests on
            the lens (:data:`LENS_RANGE_DEG`). The message says what to give instead.
        ValueError: ``spread`` other than True, False or ``"later"`` (not with ``strict``).
    """
    if spread not in (True, False, "later") or (strict and spread == "later"):
        raise ValueError(f"spread must be True, False or 'later' (not strict), got {spread!r}")
    frames = np.asarray(frames, dtype=np.int64).reshape(-1)
    boxes = np.asarray(boxes, dtype=float).reshape(-1, 4)
    size = (int(image_size[0]), int(image_size[1]))
    give = "give its camera with --cameras (or a longer clip with more people)"
    b = usable_boxes(frames, None if ids is None else np.asarray(ids).reshape(-1), boxes, size)
    _x, _y, w, h = boxes.T
    n_frames = int(np.unique(frames).size)
    if len(b.h) < MIN_BOXES:
        raise CalibrationError(
            f"{name}: {len(b.h)} boxes clear of the image border and of each other, the "
            f"calibration needs {MIN_BOXES}; {give}")
    n_blocks = int(b.block.max()) + 1
    if strict and n_blocks < MIN_BLOCKS:
        raise CalibrationError(
            f"{name}: its usable boxes span {n_blocks} stretch(es) of "
            f"{BLOCK_FRAMES} frames, the calibration needs {MIN_BLOCKS} to measure its "
            f"confidence; {give}")
    inside = (w > 0) & (h > 0)
    aspect = float(np.median(h[inside] / w[inside]))
    middle = _middle_aspect(b, size)
    if aspect < NADIR_ASPECT and (not strict or middle < MIDDLE_NADIR_ASPECT):
        return _settled(_nadir(b, w[inside], size, n_frames, hfov_deg))
    if strict and middle < MIN_UPRIGHT_ASPECT:
        raise CalibrationError(
            f"{name}: its people are seen from steeply above (the median height over width of "
            f"the boxes in the image's middle is {middle:.2f}, upright people read from "
            f"{MIN_UPRIGHT_ASPECT:g}): their boxes' heights are then mostly their width and do "
            f"not tell the tilt within {MAX_TILT_STD_DEG:g} degrees, nor whether it looks straight "
            "down; give its camera with --cameras")
    # one stretch: no resample differs from the clip
    spread = (spread if spread == "later" else bool(spread)) if n_blocks > 1 else False
    if spread == "later" and aspect < STEEP_ASPECT:  # a loose fit then reads as nadir: now
        spread = True
    calib, refusal = _oblique(b, size, n_frames, hfov_deg, seed, name, measure=spread,
                              lens=strict, keep_loose=not strict and aspect >= STEEP_ASPECT)
    if refusal is not None:
        if strict:
            raise refusal
        if aspect < STEEP_ASPECT:  # squat boxes the model cannot read: seen from above
            return _settled(_nadir(b, w[inside], size, n_frames, hfov_deg))
    if calib.tilt_deg > NADIR_TILT_DEG:
        return _settled(_nadir(b, w[inside], size, n_frames, hfov_deg))
    return _settled(calib)


def _settled(calib: PeopleCalibration) -> PeopleCalibration:
    """The estimate rounded far below what matters (a hundredth of a pixel, a millidegree, a
    tenth of a millimetre), so that a last-bit difference of the fit between CPUs changes
    neither the camera file nor any pair built on it."""
    horizon = tuple(round(float(v), 2) if np.isfinite(v) else float(v) for v in calib.horizon)
    return replace(calib, focal=round(calib.focal, 2), tilt_deg=round(calib.tilt_deg, 3),
                   roll_deg=round(calib.roll_deg, 3),
                   camera_height=round(calib.camera_height, 4), horizon=horizon,
                   tilt_std_deg=round(calib.tilt_std_deg, 3),
                   horizon_std_px=round(calib.horizon_std_px, 2),
                   focal_rel_std=round(calib.focal_rel_std, 4))


def _oblique(b: UsableBoxes, size: tuple[int, int], n_frames: int, hfov_deg: float | None,
             seed: int, name: str, measure: bool | str = True, lens: bool = False,
             keep_loose: bool = False
             ) -> tuple[PeopleCalibration | None, CalibrationError | None]:
    """The pinhole fit of a camera that sees people upright (:func:`calibrate_from_people`)
    and what a strict calibration refuses of it (None: nothing): feet in too narrow a band of
    rows (followed people, with ``lens``, may stay within a narrower one,
    :data:`MIN_TRACKED_ROW_SPREAD`), a fit the clip does not pin down, and with ``lens``
    (strict) and no ``hfov_deg``, a tilt that rests on the lens (:data:`LENS_RANGE_DEG`; the
    fit is then not returned). The fit is made once, whether the caller keeps it or refuses
    it; where the rows refuse, only with ``keep_loose`` (a caller that keeps a loose fit).
    ``measure``: the fit's spread over resamples (else NaN, and the fit is not judged loose;
    ``"later"``: kept measurable, :func:`measure_spread`)."""
    give = "give its camera with --cameras (or a longer clip with more people)"
    lo, hi = np.percentile(b.v, [10, 90])
    min_rows = MIN_TRACKED_ROW_SPREAD if lens and b.n_tracks > 1 else MIN_ROW_SPREAD
    refusal = None
    if hi - lo < min_rows * size[1]:
        refusal = CalibrationError(
            f"{name}: the people's feet stay within {hi - lo:.0f} rows "
            f"({100 * (hi - lo) / size[1]:.0f} % of the image height), too few distances to find "
            f"the horizon; {give}")
        if not keep_loose:
            return None, refusal
    if len(b.h) > MAX_FIT_BOXES:  # evenly spread over the clip: same answer, bounded time
        b = b.take(np.linspace(0, len(b.h) - 1, MAX_FIT_BOXES).round().astype(np.int64))
    prior_f = prior_focal(size, hfov_deg)
    fixed = prior_f if hfov_deg else None
    starts = (model_starts(b, size, prior_f, (hfov_deg,)) if hfov_deg
              else model_starts(b, size, prior_f))
    params = fit_model(b, size, prior_f, starts, fixed, settle=True)
    fit = _Fit(b, prior_f, params, fixed, seed)
    spread = (_resample_spread(fit, size) if measure is True else np.full(3, np.nan))
    cam = model_camera(params, size)
    hor = horizon_line(cam)
    calib = PeopleCalibration(
        kind="oblique", width=size[0], height=size[1], focal=float(np.exp(params[2])),
        tilt_deg=float(np.degrees(params[0])), roll_deg=float(np.degrees(params[1])),
        camera_height=float(np.exp(params[3])), horizon=hor, focal_from=_focal_from(fit, spread),
        tilt_std_deg=float(spread[0]), horizon_std_px=float(spread[1]),
        focal_rel_std=float(spread[2]), n_boxes=len(b.h), n_frames=n_frames,
        _fit=fit if measure == "later" else None)
    if refusal is not None:
        return calib, refusal
    near = -size[1] <= np.mean(hor) <= 2 * size[1]  # a horizon far off the image is a tilt
    if calib.tilt_std_deg > MAX_TILT_STD_DEG or (
            near and calib.horizon_std_px > MAX_HORIZON_STD * size[1]):
        return calib, CalibrationError(
            f"{name}: the boxes do not pin the camera down (tilt {calib.tilt_deg:.1f} +- "
            f"{calib.tilt_std_deg:.1f} degrees, horizon +- {calib.horizon_std_px:.0f} px over the "
            f"clip); give --hfov if you know the field of view, or {give}")
    if lens and not hfov_deg:
        tilts = _lens_tilts(b, size, prior_f, params)
        if tilts and max(abs(t - calib.tilt_deg) for t in tilts) > MAX_TILT_STD_DEG:
            ends = " to ".join(f"{t:.1f}" for t in sorted(tilts))
            return None, CalibrationError(
                f"{name}: the boxes do not tell the field of view and the tilt rests on it "
                f"({calib.tilt_deg:.1f} degrees with a {calib.hfov_deg:.0f}-degree lens, {ends} "
                f"with {LENS_RANGE_DEG[0]:g}-{LENS_RANGE_DEG[1]:g}); give --hfov (the lens's "
                "horizontal field of view in degrees), or its camera with --cameras")
    return calib, None


def _lens_tilts(b: UsableBoxes, size: tuple[int, int], prior_f: float, params: np.ndarray
                ) -> list[float]:
    """The tilt (degrees) refitted with the focal length held at each end of
    :data:`LENS_RANGE_DEG`, started from the fit ``params``; an end whose fit is worse by
    :data:`_LENS_COST_RISE` a box is ruled out by the boxes and left out."""
    base = data_cost(params, b, size)
    out = []
    for hfov in LENS_RANGE_DEG:
        f = 0.5 * size[0] / np.tan(np.radians(hfov) / 2.0)
        p = fit_model(b, size, prior_f, [params], f)
        if (data_cost(p, b, size) - base) / len(b.h) <= _LENS_COST_RISE:
            out.append(float(np.degrees(p[0])))
    return out


def measure_spread(calib: PeopleCalibration) -> PeopleCalibration:
    """``calib`` with its spread over resamples measured, where :func:`calibrate_from_people`
    left it for later (``spread="later"``): the figures, and the focal length's source, as had
    it measured them at once (the same resamples of the same fit); any other as it is."""
    fit = calib._fit
    if fit is None:
        return calib
    spread = _resample_spread(fit, (calib.width, calib.height))
    return _settled(replace(calib, focal_from=_focal_from(fit, spread),
                            tilt_std_deg=float(spread[0]), horizon_std_px=float(spread[1]),
                            focal_rel_std=float(spread[2]), _fit=None))


def _focal_from(fit: _Fit, spread: np.ndarray) -> str:
    """Where a fit's focal length came from: ``"given"``, or, by its spread over resamples
    (``(3,)``, NaN: not measured), ``"prior"`` where the boxes left it at the prior's breadth,
    else ``"people"``."""
    if fit.fixed_f is not None:
        return "given"
    return "prior" if spread[2] >= 0.5 * PRIOR_LOG_STD else "people"


def _resample_spread(fit: _Fit, size: tuple[int, int]) -> np.ndarray:
    """Standard deviations of (tilt degrees, horizon row at the centre, log f) over fits to
    resamples of the clip's time blocks, each started from the whole clip's fit."""
    b, prior_f, params, fixed_f, seed = fit.boxes, fit.prior_f, fit.params, fit.fixed_f, fit.seed
    rng = np.random.default_rng([seed, 67])
    n_blocks = int(b.block.max()) + 1
    out = []
    for _ in range(_N_RESAMPLES):
        picks = rng.integers(0, n_blocks, n_blocks)
        counts = np.bincount(picks, minlength=n_blocks)
        index = np.repeat(np.arange(len(b.h)), counts[b.block])
        p = fit_model(b.take(index), size, prior_f, [params], fixed_f)
        cam = model_camera(p, size)
        out.append([np.degrees(p[0]), float(np.mean(horizon_line(cam))), p[2]])
    return np.std(np.array(out), axis=0)
