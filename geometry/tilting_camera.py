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
otherwise it keeps the one fit, unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
from scipy.optimize import least_squares

from xvmatch.geometry import people_calibration as pc
from xvmatch.geometry.people_calibration import PeopleCalibration

__all__ = ["MIN_TILT_CHANGE_DEG", "TILT_STEP_DEG", "WINDOW_S", "TiltTrack", "fit_tilt_track"]

WINDOW_S = 3.0
"""Seconds of clip per tilt (a gimbal moves slowly; each window needs enough boxes to read)."""

TILT_STEP_DEG = 10.0
"""The scale of the cost on a tilt's change from one window to the next, degrees."""

MIN_TILT_CHANGE_DEG = 3.0
"""The least spread of the windows' tilts (degrees, the calibration's own tolerance) for the
camera to be read as tilting; below it the clip's one fit is kept."""


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
                   image_size: tuple[int, int], fps: float) -> TiltTrack | None:
    """The model of :mod:`~xvmatch.geometry.people_calibration` with a tilt per window of
    :data:`WINDOW_S` seconds (module docstring); None where the clip spans fewer than two
    windows or has too few usable boxes.

    Args:
        frames: ``(N,)`` frame number of each box.
        ids: ``(N,)`` the person each box is (track ids, or boxes linked by IoU).
        boxes: ``(N, 4)`` x, y, w, h, pixels.
        image_size: the view's (width, height).
        fps: frames per second of the frame numbers (the windows are seconds).
    """
    frames = np.asarray(frames, np.int64).reshape(-1)
    boxes = np.asarray(boxes, float).reshape(-1, 4)
    size = (int(image_size[0]), int(image_size[1]))
    b = pc._usable(frames, np.asarray(ids).reshape(-1), boxes, size)
    if len(b.h) < pc.MIN_BOXES:
        return None
    if len(b.h) > pc._MAX_FIT_BOXES:  # evenly spread over the clip, as the one fit
        b = b.take(np.linspace(0, len(b.h) - 1, pc._MAX_FIT_BOXES).round().astype(np.int64))
    span = max(1, round(WINDOW_S * fps))
    window = np.unique((b.frame - b.frame.min()) // span, return_inverse=True)[1]
    n = int(window.max()) + 1
    if n < 2:
        return None
    parts = [np.flatnonzero(window == k) for k in range(n)]
    subsets = [b.take(rows) for rows in parts]
    prior_f = 0.5 * size[0] / np.tan(np.radians(pc.PRIOR_HFOV_DEG) / 2.0)

    def residuals(p: np.ndarray) -> np.ndarray:
        out = np.empty(len(b.h))
        for k, (rows, sub) in enumerate(zip(parts, subsets, strict=True)):
            pred = pc._heights(np.concatenate([[p[k]], p[n:]]), sub, size)
            with np.errstate(divide="ignore", invalid="ignore"):
                r = np.log(pred / sub.h)
            out[rows] = np.where(np.isfinite(r), r, pc._BAD_RESIDUAL)
        prior = pc._SOFT_SCALE * (p[n + 1] - np.log(prior_f)) / pc._PRIOR_LOG_STD
        heights = pc._SOFT_SCALE * (p[n + 3:] - pc.PERSON_HEIGHT) / pc._HEIGHT_STD
        steps = pc._SOFT_SCALE * np.diff(p[:n]) / np.radians(TILT_STEP_DEG)
        return np.concatenate([out, [prior], heights, steps])

    low, high = pc._CAMERA_BOUNDS
    lower = np.concatenate([np.full(n, low[0]), low[1:], np.full(b.n_tracks,
                                                                 pc._HEIGHT_BOUNDS[0])])
    upper = np.concatenate([np.full(n, high[0]), high[1:], np.full(b.n_tracks,
                                                                   pc._HEIGHT_BOUNDS[1])])
    starts = [pc._start(b, size, hfov) for hfov in pc._START_HFOVS] + [
        np.concatenate([[np.radians(t), 0.0, np.log(prior_f), np.log(10.0)],
                        np.full(b.n_tracks, pc.PERSON_HEIGHT)]) for t in pc._START_TILTS]
    sparsity = _sparsity(window, b.track, n, b.n_tracks)
    best, best_cost = None, np.inf
    for x0 in starts:
        x = np.clip(np.concatenate([np.full(n, x0[0]), x0[1:]]), lower + 1e-6, upper - 1e-6)
        res = least_squares(residuals, x, loss="soft_l1", f_scale=pc._SOFT_SCALE,
                            bounds=(lower, upper), jac_sparsity=sparsity)
        if res.cost < best_cost:
            best, best_cost = res.x, res.cost
    middles = tuple(float(np.mean(sub.frame)) for sub in subsets)
    return TiltTrack(frames=middles, tilts_deg=tuple(round(float(np.degrees(t)), 3)
                                                     for t in best[:n]),
                     focal=float(np.exp(best[n + 1])), roll_deg=float(np.degrees(best[n])),
                     camera_height=float(np.exp(best[n + 2])))


def _sparsity(window: np.ndarray, track: np.ndarray, n: int, n_tracks: int) -> np.ndarray:
    """Which parameters (``n`` tilts, roll, log f, log height, each track's height) each
    residual depends on: a box on its window's tilt, the shared three and its track's height;
    the focal length's prior, each height's prior and each step between windows on theirs."""
    rows = len(window)
    out = np.zeros((rows + 1 + n_tracks + n - 1, n + 3 + n_tracks), dtype=bool)
    every = np.arange(rows)
    out[every, window] = True
    out[:rows, n:n + 3] = True
    out[every, n + 3 + track] = True
    out[rows, n + 1] = True
    out[rows + 1 + np.arange(n_tracks), n + 3 + np.arange(n_tracks)] = True
    steps = rows + 1 + n_tracks + np.arange(n - 1)
    out[steps, np.arange(n - 1)] = True
    out[steps, np.arange(1, n)] = True
    return out
