"""``--cameras``' top camera refined on the run's own boxes before the learned matcher uses it.

A fixed top camera calibrated a degree or two off costs the learned matcher more than the
cameras give (docs/method.md, "How exact they must be"); :func:`~xvmatch.geometry.
top_camera_refinement.refine_top_camera` turns it to fit the video's head rays. This module
decides when (enough frames with boxes in both views, a crowd not too dense), keeps the given
camera when the fit gains too little to trust, and says what it did in one line. A top camera
that changes from frame to frame (a drone in flight) has the constant part of its error
refined (in its own frame or in the world) and is marked ``moving``: the camera check then
judges it whatever the fit.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace

from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.geometry.camera import FrameCameras, same_camera
from xvmatch.geometry.top_camera_refinement import (
    MIN_REFINE_FRAMES,
    TopCameraRefinement,
    refine_top_camera,
)

__all__ = ["CROWD_PAIRS", "FIT_LOSS", "MIN_GAIN", "CameraRefinement", "refine_run_cameras",
           "refine_views_cameras"]

MIN_GAIN: float = 0.05
"""Least drop of the refinement's loss (:class:`~xvmatch.geometry.top_camera_refinement.
TopCameraRefinement`, 0 to 1) for the turned camera to be used: smaller gains are as often a
chance alignment of unrelated heads as a real correction (renders, docs/method.md)."""

FIT_LOSS: float = 0.2
"""Highest loss of a top camera kept as given for it to count as fitting the head rays
(:attr:`CameraRefinement.fits`). Rendered videos (docs/tracking.md): exact cameras kept as
given 0.08 to 0.13; a top camera 3 degrees off whose fit was refused, or an exact one with the
egocentric camera 3 degrees off frame by frame, 0.35 and more; the two cannot be told apart, so
neither counts."""

OFF_HINT = "--refine-top-camera off uses it as given"

CROWD_PAIRS: int = 50_000
"""Most top x horizontal box pairs over :data:`~xvmatch.geometry.top_camera_refinement.
MIN_REFINE_FRAMES` typical frames that are refined (10 frames of 100 x 50 people: 20 s on this
project's 2-core machine, where 30 frames of 20 x 10 take 3 s); a denser crowd uses its camera
as given, and says so."""


@dataclass(frozen=True)
class CameraRefinement:
    """What became of the top camera.

    Attributes:
        turned: the refined top camera is used.
        fit: the refinement, or None when none was tried (``message`` says why).
        message: one line for the user.
        moving: the top camera changes from frame to frame (a drone in flight): only the
            constant part of its error can be refined, and a fit says little of the rest,
            so the camera check judges it (:mod:`xvmatch.inference.matching.camera_check`).
    """

    turned: bool
    fit: TopCameraRefinement | None
    message: str
    moving: bool = False

    @property
    def fit_loss(self) -> float | None:
        """The loss of the best fit found (0 to 1; whether used or not), or None when none was
        tried: how far even the best turn of the top camera leaves the head rays apart
        (:mod:`xvmatch.inference.matching.camera_check` judges the cameras above its
        ``DOUBT_LOSS``)."""
        return None if self.fit is None else self.fit.loss_after

    @property
    def fits(self) -> bool:
        """The top camera in use fits the video's head rays: turned to fit them, or kept as
        given with a loss of at most :data:`FIT_LOSS` (``track`` then leaves the images to the
        over-time terms, :data:`~xvmatch.inference.tracks.track_costs.FITTED_CAMERAS_W1`)."""
        return self.turned or (self.fit is not None and self.fit.loss_after <= FIT_LOSS)


def _turned_top(cameras: CameraFrames, fit: TopCameraRefinement, moving: bool) -> CameraFrames:
    """``cameras`` with each top camera turned as ``fit`` says: a fixed one is the fit's camera
    on every frame; a moving one's frames are turned one by one (also when the sampled frames
    happened to share one camera)."""

    def turned(c: FrameCameras) -> FrameCameras:
        return FrameCameras(fit.turn(c.top) if moving else fit.camera, c.hor)

    if cameras.static is not None:
        return replace(cameras, static=turned(cameras.static))
    return replace(cameras, per_frame={f: turned(c) for f, c in cameras.per_frame.items()})


def refine_run_cameras(
    cameras: CameraFrames,
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    top_offset: int = 0,
) -> tuple[CameraFrames, CameraRefinement]:
    """The run's cameras with the top camera refined when it is fixed and the fit is clear.

    Args:
        cameras: the opened ``--cameras`` (numbered by the horizontal frames).
        top, hor: ``{frame: record}`` with ``boxes`` of each view.
        frames: the horizontal frames of the run; top frame ``f + top_offset`` is shown with
            horizontal frame ``f``.
        top_offset: see ``frames`` (0 when ``top`` is already re-timed).

    Returns:
        ``(cameras to use, what was done)``.
    """
    used, what = refine_views_cameras([cameras], top, [hor], [frames], [top_offset])
    return used[0], what


def refine_views_cameras(
    cameras: Sequence[CameraFrames],
    top: Mapping,
    hors: Sequence[Mapping],
    frames: Sequence[Iterable[int]],
    top_offsets: Sequence[int],
) -> tuple[list[CameraFrames], CameraRefinement]:
    """:func:`refine_run_cameras` for several horizontal views that share one top view
    (``associate-multi``): one fit over the head rays of every view, so that the top camera
    all of their files hold, when it is one and the same fixed camera, is turned once for all.

    Args:
        cameras: per horizontal view, its opened ``--cameras`` (numbered by its frames).
        top: ``{frame: record}`` of the top view.
        hors: per horizontal view, ``{frame: record}``.
        frames: per horizontal view, its frames; top frame ``f + top_offsets[k]`` is shown
            with frame ``f`` of view ``k``.
        top_offsets: see ``frames``.

    Returns:
        ``(cameras to use, per view; what was done)``.
    """
    both = [[f for f in sorted(set(int(f) for f in fs))
             if len(hor.get(f, ())) and len(top.get(f + shift, ()))]
            for hor, fs, shift in zip(hors, frames, top_offsets, strict=True)]
    views = [[cams.static] if cams.static is not None else
             [cams.per_frame[f] for f in sorted(cams.per_frame)] for cams in cameras]
    held = [c for view in views for c in view]
    moving = not all(same_camera(held[0].top, c.top) for c in held[1:])
    if moving and all(same_camera(v[0].top, c.top) for v in views for c in v[1:]):
        # each view's file holds one fixed top camera, but not the same: one of them is wrong
        return list(cameras), CameraRefinement(
            False, None, "cameras: the top camera differs between the views' files; used as "
            "given", moving=True)
    changes = "the top camera changes from frame to frame"
    samples = [(k, f) for k, fs in enumerate(both) for f in fs]
    if len(samples) < MIN_REFINE_FRAMES:
        return list(cameras), CameraRefinement(
            False, None, f"cameras: {len(samples)} frame(s) with boxes in both views, too few "
            f"to check the top camera against ({MIN_REFINE_FRAMES} needed); used as given",
            moving=moving)
    pairs = sorted(len(top[f + top_offsets[k]].boxes) * len(hors[k][f].boxes)
                   for k, f in samples)
    if pairs[len(pairs) // 2] * MIN_REFINE_FRAMES > CROWD_PAIRS:
        return list(cameras), CameraRefinement(
            False, None, f"cameras: {pairs[len(pairs) // 2]} top x horizontal box pairs in a "
            "typical frame, too many to check the top camera against in reasonable time; used "
            "as given", moving=moving)
    tops = [cameras[k].get(f).top for k, f in samples] if moving else held[0].top
    fit = refine_top_camera(tops, [cameras[k].get(f).hor for k, f in samples],
                            [top[f + top_offsets[k]].boxes for k, f in samples],
                            [hors[k][f].boxes for k, f in samples])
    if fit.angle_deg == 0.0 or fit.loss_before - fit.loss_after < MIN_GAIN:
        return list(cameras), CameraRefinement(
            False, fit, f"cameras: {changes + '; it' if moving else 'the top camera'} lines up "
            f"the people of both views about as well as given, on "
            f"{fit.fitted_on(len(samples))} (misfit {fit.loss_before:.3f} as given, "
            f"{fit.loss_after:.3f} turned); used as given",
            moving=moving)
    return [_turned_top(c, fit, moving) for c in cameras], CameraRefinement(
        True, fit, f"cameras: {fit.describe(len(samples))}; {OFF_HINT}", moving=moving)
