"""A top camera whose tilt changes over the clip (a drone's gimbal), fitted from its people.

:func:`~xvmatch.geometry.people_calibration.calibrate_from_people` fits one camera to the whole
clip. A gimbal that tilts 12-24 degrees over 12 s leaves no single camera that explains the
boxes, and the one fit lands far off (on rendered close drones 48-60 degrees where the truth
went from 12-30 to 32-42), its ground map bent frame by frame. Here the same model (the lens,
roll and height shared by the clip, each followed person's own height) is fitted with a tilt
per window of :data:`WINDOW_S` seconds, neighbouring windows' tilts held together by a cost of
:data:`TILT_STEP_DEG` degrees a window (soft, so a steady tilt passes and a static camera keeps
one tilt). Where the windows' tilts spread over more than :data:`MIN_TILT_CHANGE_DEG` the
association maps each frame through its own tilt (interpolated between the windows' middles);
otherwise it keeps the one fit, unchanged. Given that one fit, a steady camera is told first and
cheaply: the windows' tilts fitted with its lens, roll and height held spread no more than
:data:`STEADY_DEG` (on renders a static camera's spread at most 1.3 degrees, a tilting one's
that the whole fit reads as tilting at least 2.4). On a long clip the whole fit's seven starts
are tried on :data:`START_BOXES` boxes; the best of them and the one fit are refined on all
(a 96 s drifting drone's fit 52 s -> 4 s, the same track; ``benchmarks/tilt_fit_speed.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from xvmatch.geometry.people_calibration import MIN_BOXES, PeopleCalibration
from xvmatch.geometry.people_model import (
    MAX_FIT_BOXES,
    PERSON_HEIGHT,
    UsableBoxes,
    fit_model,
    model_starts,
    prior_focal,
    usable_boxes,
)

__all__ = ["MIN_TILT_CHANGE_DEG", "START_BOXES", "STEADY_DEG", "TILT_STEP_DEG", "WINDOW_S",
           "TiltTrack", "fit_tilt_track"]

WINDOW_S = 3.0
"""Seconds of clip per tilt (a gimbal moves slowly; each window needs enough boxes to read)."""

TILT_STEP_DEG = 10.0
"""The scale of the cost on a tilt's change from one window to the next, degrees."""

MIN_TILT_CHANGE_DEG = 3.0
"""The least spread of the windows' tilts (degrees, the calibration's own tolerance) for the
camera to be read as tilting; below it the clip's one fit is kept."""

STEADY_DEG = 1.0
"""A camera whose windows' tilts, fitted with the clip's one lens, roll and height held, spread
no more than this (degrees) is steady without the whole fit (:func:`fit_tilt_track`)."""


START_BOXES = 600
"""Boxes (evenly spread over the clip) the whole fit's starts are tried on where a clip has
more; the best of them, and the clip's one fit where given, are then refined on all (the best
alone can stay in a dip of a few boxes: a window 9 degrees off on a 96 s render)."""


@dataclass(frozen=True)
class TiltTrack:
    """The windows' fit: each window's middle frame number and tilt (degrees), with the shared
    focal length, roll (degrees) and height (metres)."""

    frames: tuple[float, ...]
    tilts_deg: tuple[float, ...]
    focal: float
    roll_deg: float
    camera_height: float

    @property
    def change_deg(self) -> float:
        """How far the windows' tilts spread, degrees."""
        return float(np.ptp(self.tilts_deg)) if self.tilts_deg else 0.0

    @property
    def tilting(self) -> bool:
        """Whether the camera reads as tilting (:data:`MIN_TILT_CHANGE_DEG`)."""
        return self.change_deg > MIN_TILT_CHANGE_DEG

    def tilt_at(self, frames: np.ndarray) -> np.ndarray:
        """Each frame's tilt (degrees), interpolated between the windows' middles (the end
        windows' held beyond them)."""
        return np.interp(np.asarray(frames, float), self.frames, self.tilts_deg)

    def calibrations(self, calib: PeopleCalibration, frames: np.ndarray
                     ) -> dict[int, PeopleCalibration]:
        """``{frame: calibration}`` for each distinct frame: ``calib`` with this track's lens,
        roll, height and that frame's tilt."""
        base = replace(calib, focal=round(self.focal, 2), roll_deg=round(self.roll_deg, 3),
                       camera_height=round(self.camera_height, 4))
        keys = np.unique(np.asarray(frames, np.int64))
        return {int(f): replace(base, tilt_deg=round(float(t), 3))
                for f, t in zip(keys, self.tilt_at(keys), strict=True)}


def fit_tilt_track(frames: np.ndarray, ids: np.ndarray, boxes: np.ndarray,
                   image_size: tuple[int, int], fps: float,
                   start: PeopleCalibration | None = None) -> TiltTrack | None:
    """The model of :mod:`~xvmatch.geometry.people_model` with a tilt per window of
    :data:`WINDOW_S` seconds (module docstring); None where the clip spans fewer than two
    windows or has too few usable boxes.

    Args:
        frames: ``(N,)`` frame number of each box.
        ids: ``(N,)`` the person each box is (track ids, or boxes linked by IoU).
        boxes: ``(N, 4)`` x, y, w, h, pixels.
        image_size: the view's (width, height).
        fps: frames per second of the frame numbers (the windows are seconds).
        start: the clip's one fit (an oblique camera), when made: each window's tilt is first
            fitted with its lens, roll and height held, and where those tilts spread no more
            than :data:`STEADY_DEG` the camera is steady and that track is returned (not
            tilting) without the whole fit (0.05-0.1 s a clip where it takes 1-2.5 s); on a
            clip of more than :data:`START_BOXES` usable boxes it is also a start of the whole
            fit.
    """
    frames = np.asarray(frames, np.int64).reshape(-1)
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    size = (int(image_size[0]), int(image_size[1]))
    b = usable_boxes(frames, np.asarray(ids).reshape(-1), boxes, size)
    if len(b.h) < MIN_BOXES:
        return None
    if len(b.h) > MAX_FIT_BOXES:  # evenly spread over the clip, as the one fit
        b = b.take(np.linspace(0, len(b.h) - 1, MAX_FIT_BOXES).round().astype(np.int64))
    span = max(1, round(WINDOW_S * fps))
    b = b.windowed(np.unique((b.frame - b.frame.min()) // span, return_inverse=True)[1])
    if b.n_windows < 2:
        return None
    prior_f = prior_focal(size)
    if start is not None:
        one = np.concatenate([np.radians([start.tilt_deg, start.roll_deg]),
                              np.log([start.focal, start.camera_height]),
                              np.full(b.n_tracks, PERSON_HEIGHT)])
        held = _track(b, fit_model(b, size, prior_f, [one], hold=(1, 2, 3),
                                   tilt_step_deg=TILT_STEP_DEG))
        if held.change_deg <= STEADY_DEG:
            return held
    starts = model_starts(b, size, prior_f)
    if len(b.h) > START_BOXES:  # the starts tried on a few boxes; the best and the one fit
        few = b.take(np.linspace(0, len(b.h) - 1, START_BOXES).round().astype(np.int64))
        starts = [fit_model(few, size, prior_f, starts, tilt_step_deg=TILT_STEP_DEG)]
        if start is not None:
            starts.append(one)
    return _track(b, fit_model(b, size, prior_f, starts, tilt_step_deg=TILT_STEP_DEG))


def _track(b: UsableBoxes, params: np.ndarray) -> TiltTrack:
    """The fit's parameters (:mod:`~xvmatch.geometry.people_model`) as a track, each window's
    middle frame its boxes' mean."""
    n = b.n_windows
    middles = np.bincount(b.window, b.frame, n) / np.bincount(b.window, minlength=n)
    return TiltTrack(frames=tuple(float(m) for m in middles),
                     tilts_deg=tuple(round(float(np.degrees(t)), 3) for t in params[:n]),
                     focal=float(np.exp(params[n + 1])), roll_deg=float(np.degrees(params[n])),
                     camera_height=float(np.exp(params[n + 2])))
