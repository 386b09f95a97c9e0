"""The learned association pipeline: opened matchers, box records, images and cameras to pairs.

:func:`run_learned_association` is the whole run in one call, with its options in one typed
record (:class:`LearnedRunOptions`): it checks every input before any work starts (a frame over
the matcher's crowd limits, a box-only matcher given images, a matcher without camera cues given
cameras, image sources lacking a frame the boxes list, top-view boxes outside the top images,
cameras whose image size is not the images'), opens the image sources re-timed like the boxes
(``top_offset``), settles the non-association cost once
(:func:`~xvmatch.inference.matching.learned_association.non_association_cost`: given, else the
model's own), runs
:func:`~xvmatch.inference.matching.learned_association.associate_sequence_learned` and closes the
sources, also on an error. :func:`open_learned_inputs` is the same in two steps, for a caller that
uses the open images after the run (``xvmatch associate --draw``) or prints a note between the
checks and the work.

The models come opened (:func:`~xvmatch.inference.matching.learned_association.load_matcher_bundle`;
the command line also exports torch matcher files into bundles first), and the horizontal image
size comes resolved (:func:`xvmatch.formats.box_image_size.resolve_size`), so that this module
needs neither torch nor the command line. Bad input raises ``ValueError`` with one line; the
lines name the command-line options that supply each input (``--top-images``, ``--cameras``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from xvmatch.formats.box_image_size import check_boxes_in_image, runs_past_borders
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    check_crowd_size,
    non_association_cost,
)

if TYPE_CHECKING:
    from xvmatch.inference.matching.appearance_check import AppearanceCheck
    from xvmatch.inference.matching.camera_check import CameraCheck
    from xvmatch.inference.matching.camera_refinement import CameraRefinement

# The camera check and refinement (and the pair mining they use) are imported by the runs with
# cameras that use them: a box-only run starts sooner without them.

__all__ = [
    "LearnedInputs",
    "LearnedRun",
    "LearnedRunOptions",
    "RetimedFrames",
    "open_learned_inputs",
    "open_matcher_cameras",
    "open_view_images",
    "retimed",
    "run_learned_association",
]


@dataclass(frozen=True)
class LearnedRunOptions:
    """What a learned association run uses besides the boxes.

    Attributes:
        models: the opened matchers, one or several (an ensemble: costs averaged).
        hor_size: ``(W, H)`` of the horizontal images in pixels.
        hor_size_source: where ``hor_size`` comes from (``--image-size``, the images, ...),
            named in messages.
        names: how each model was named by the user (messages); empty: the bundles' names.
        top_images, hor_images: images of both views (a folder, a video, an image or a glob:
            :func:`xvmatch.formats.frame_sources.open_frames`), both or neither; they need
            matchers with an appearance network.
        cameras: a camera file or folder with cameras ``top`` and ``ego``
            (:func:`xvmatch.formats.camera_frames.open_cameras`); needs matchers that take
            camera cues.
        top_boxes: the top-view box file, named when a top box lies outside the top images
            or a frame's crowd is over the matcher's limits.
        hor_boxes: the horizontal-view box file, named when a frame's crowd is over the
            matcher's limits
            (:func:`~xvmatch.inference.matching.learned_association.check_crowd_size`).
        camera_id: top-view id of the horizontal camera's wearer (O given), or None.
        gamma: non-association cost in (0, 1]; None: the (first) model's own.
        mirror: also score the scene mirrored left-right and average the costs.
        workers: processes computing the geometry features (the same result for any number).
        top_offset: the top records are already re-timed by this many frames (top frame =
            horizontal frame + offset); the top images are re-timed the same way.
        keep_costs: also return each frame's cost matrix (:attr:`LearnedRun.costs`).
        appearance_check: with images, judge the appearance cue on the run's own box-only
            pseudo-matches and match from the boxes alone when it fails
            (:mod:`xvmatch.inference.matching.appearance_check`).
        refine_top_camera: with cameras, turn a fixed top camera to fit the run's head rays
            when the fit is clear (:mod:`xvmatch.inference.matching.camera_refinement`).
        camera_check: with cameras (refined when asked), judge them on the run's own box-only
            pseudo-matches and match without them when they fail
            (:mod:`xvmatch.inference.matching.camera_check`).
    """

    models: tuple[LearnedMatcher, ...]
    hor_size: tuple[int, int]
    hor_size_source: str = "the given size"
    names: tuple[str, ...] = ()
    top_images: str | None = None
    hor_images: str | None = None
    cameras: str | None = None
    top_boxes: str = "the top-view boxes"
    hor_boxes: str = "the horizontal-view boxes"
    camera_id: int | None = None
    gamma: float | None = None
    mirror: bool = False
    workers: int = 1
    top_offset: int = 0
    keep_costs: bool = False
    appearance_check: bool = False
    refine_top_camera: bool = False
    camera_check: bool = False

    def __post_init__(self) -> None:
        if not self.models:
            raise ValueError("no model given")
        if self.names and len(self.names) != len(self.models):
            raise ValueError(f"give one name per model ({len(self.models)}), got "
                             f"{len(self.names)}")
        if (self.top_images is None) != (self.hor_images is None):
            raise ValueError("give --top-images and --hor-images together")

    @property
    def model_names(self) -> tuple[str, ...]:
        """How each model is named in messages."""
        return self.names or tuple(m.bundle.name for m in self.models)


@dataclass(frozen=True, eq=False)
class LearnedRun:
    """The result of a learned association run.

    Attributes:
        pairs: ``{frame: [(top id, hor id)]}`` of every frame asked for.
        costs: ``{frame: (M, N) cost matrix}`` (input order of the frame's boxes) of every frame
            with boxes in both views when ``keep_costs`` was asked for, else None.
        gamma: the non-association cost used.
        hor_size: ``(W, H)`` of the horizontal images used.
        hor_size_source: where it comes from.
        models: the matchers used.
        rechecked: the frames scored again with FP32 because their INT8 assignment was a near
            tie (matchers opened with ``recheck``).
        checked: the appearance check of a run with ``appearance_check`` and images, else None.
        refinement: what became of the top camera of a run with cameras and
            ``refine_top_camera``, else None.
        camera_checked: the camera check of a run with cameras and ``camera_check``, else
            None (when it failed, the run was matched without the cameras).
        searched: ``{frame: row of the top record}`` of each frame's best camera location O of
            the geometry features' search (:mod:`~xvmatch.inference.matching.search_camera`).
    """

    pairs: dict[int, list[tuple[int, int]]]
    costs: dict[int, np.ndarray] | None
    gamma: float
    hor_size: tuple[int, int]
    hor_size_source: str
    models: tuple[LearnedMatcher, ...]
    rechecked: list[int] = field(default_factory=list)
    checked: AppearanceCheck | None = None
    refinement: CameraRefinement | None = None
    camera_checked: CameraCheck | None = None
    searched: dict[int, int] = field(default_factory=dict)


class RetimedFrames:
    """A per-frame source (images, cameras) re-timed like the boxes: frame ``f`` is the
    source's ``f + shift``."""

    def __init__(self, source, shift: int) -> None:
        self.source, self.shift = source, int(shift)

    @property
    def size(self) -> tuple[int, int]:
        """``(W, H)`` of the source's images."""
        return self.source.size

    def get(self, frame: int) -> np.ndarray:
        """The image of (re-timed) ``frame``."""
        return self.source.get(int(frame) + self.shift)

    def close(self) -> None:
        """Close the source."""
        self.source.close()


def open_view_images(path: str, box_frames: Iterable[int], needed: Iterable[int],
                     shift: int = 0):
    """Open one view's images and check they hold every frame the boxes need.

    Args:
        path: the images (:func:`xvmatch.formats.frame_sources.open_frames`).
        box_frames: the frames the view's boxes list (a single image serves one of them).
        needed: the frames whose images are read, checked in the order given.
        shift: the boxes are re-timed: box frame ``f`` is image frame ``f + shift``.

    Returns:
        An open source (``get(frame)``, ``size``, ``close()``) in the boxes' timing.

    Raises:
        FrameSourceError: an unreadable source or a missing frame (the source is closed).
    """
    from xvmatch.formats.frame_sources import check_frames, open_frames

    source = open_frames(path, box_frames=sorted(int(f) + shift for f in box_frames))
    try:
        check_frames(source, [int(f) + shift for f in needed])
    except BaseException:
        source.close()
        raise
    return retimed(source, shift)


def retimed(source, shift: int):
    """``source`` (``get(frame)``: images, cameras) with frame ``f`` showing its frame
    ``f + shift``: a :class:`RetimedFrames`, or ``source`` itself when ``shift`` is 0."""
    return RetimedFrames(source, shift) if shift else source


def open_matcher_cameras(path: str, named: Iterable[tuple[LearnedMatcher, str]],
                         frames: Iterable[int],
                         sizes: dict[str, tuple[tuple[int, int], str]]):
    """Open ``--cameras`` for the matchers ``named`` (``(matcher, its name)``), after the
    checks: every matcher takes camera cues, a folder holds a file for each of ``frames``, and
    every camera's image size is its view's (``sizes``: ``"top"``/``"hor"`` -> (size, where
    that size comes from)). Returns the :class:`~xvmatch.formats.camera_frames.CameraFrames`."""
    from xvmatch.formats.camera_frames import open_cameras

    for m, name in named:
        if not m.bundle.manifest.uses_cameras:
            raise ValueError(f"{name}: this matcher takes no camera cues; drop --cameras "
                             "or use a bundle trained with cameras (e.g. default)")
    cameras = open_cameras(path, sorted(frames))
    _check_camera_sizes(cameras, sizes)
    return cameras


def _check_camera_sizes(cameras, sizes: dict[str, tuple[tuple[int, int], str]]) -> None:
    """Every camera's image size must be its view's image size (``sizes``: view -> (size,
    where that size comes from))."""
    for where, cams in cameras.all():
        for view, cam in (("top", cams.top), ("hor", cams.hor)):
            if view not in sizes:
                continue
            want, source = sizes[view]
            if tuple(cam.image_size) != tuple(want):
                name = "ego" if view == "hor" else "top"
                label = "horizontal" if view == "hor" else "top"
                raise ValueError(f"{where}: camera {name!r} is {cam.width}x{cam.height} but the "
                                 f"{label} image size is {want[0]}x{want[1]} (from {source})")


class LearnedInputs:
    """The checked inputs of a run, images held open (:func:`open_learned_inputs`); a context
    manager that closes the images.

    Attributes:
        options: the run's options.
        frames: the frames to associate.
        images: ``{"top": source, "hor": source}`` (re-timed), or ``{}`` without images.
        cameras: the camera source (its top camera refined when asked), or None (also when
            the camera check failed).
        refined_cameras: the camera source as refined, also when the check left it out (for
            ``--write-cameras``), or None without cameras.
        refinement: what became of the top camera (``refine_top_camera``), or None.
        camera_checked: the camera check (``camera_check``), or None.
        gamma: the non-association cost (given, else the model's own).
    """

    def __init__(self, top: Mapping, hor: Mapping, frames: list[int],
                 options: LearnedRunOptions) -> None:
        self.top, self.hor, self.frames, self.options = top, hor, frames, options
        self.images: dict = {}
        self.cameras = None
        self.refined_cameras = None
        self.refinement: CameraRefinement | None = None
        self.camera_checked: CameraCheck | None = None
        self.gamma = non_association_cost(options.models, options.gamma)

    def _open(self) -> None:
        options, top, hor = self.options, self.top, self.hor
        check_crowd_size(top, hor, self.frames, options.top_boxes, options.hor_boxes,
                         options.top_offset)
        both = [f for f in self.frames if f in top and f in hor and len(top[f]) and len(hor[f])]
        named = list(zip(options.models, options.model_names, strict=True))
        sizes: dict[str, tuple[int, int]] = {}
        if options.top_images is not None:
            for m, name in named:
                if m.bundle.manifest.appearance is None:
                    raise ValueError(f"{name}: a box-only matcher cannot use images; drop "
                                     "--top-images/--hor-images or use a bundle with an "
                                     "appearance network (e.g. default)")
            for view, path, boxes, shift in (("top", options.top_images, top, options.top_offset),
                                             ("hor", options.hor_images, hor, 0)):
                self.images[view] = open_view_images(path, boxes, both, shift)
                sizes[view] = tuple(self.images[view].size)
            check_boxes_in_image(top, sizes["top"], options.top_boxes, "the images",
                                 past=runs_past_borders(top, hor))
        if options.cameras is not None:
            wanted = {"hor": (tuple(options.hor_size),
                              "the images" if sizes else options.hor_size_source)}
            if "top" in sizes:
                wanted["top"] = (sizes["top"], "the images")
            self.cameras = open_matcher_cameras(options.cameras, named, both, wanted)
            if options.refine_top_camera:
                from xvmatch.inference.matching.camera_refinement import refine_run_cameras

                self.cameras, self.refinement = refine_run_cameras(self.cameras, top, hor, both)
            self.refined_cameras = self.cameras
            if options.camera_check:
                from xvmatch.inference.matching.camera_check import check_run_cameras

                self.camera_checked = check_run_cameras(
                    top, hor, both, list(options.models), tuple(options.hor_size),
                    self.cameras, self.gamma,
                    None if self.refinement is None else self.refinement.fit_loss,
                    options.camera_id, workers=options.workers,
                    moving=self.refinement is not None and self.refinement.moving)
                if not self.camera_checked.trusted:
                    self.cameras = None

    def associate(self, progress: Callable[[Iterable[int]], Iterable[int]] | None = None
                  ) -> LearnedRun:
        """Run the matchers over :attr:`frames` (``progress`` wraps the frame iterator)."""
        options = self.options
        width, height = options.hor_size
        costs: dict | None = {} if options.keep_costs else None
        rechecked: list[int] = []
        checked: list[AppearanceCheck] = []
        searched: dict[int, int] = {}
        pairs = associate_sequence_learned(
            self.top,
            self.hor,
            hor_width=width,
            model=list(options.models),
            camera_id=options.camera_id,
            gamma=self.gamma,
            progress=progress,
            hor_height=height,
            frames=self.frames,
            mirror=options.mirror,
            workers=options.workers,
            top_images=self.images.get("top"),
            hor_images=self.images.get("hor"),
            cameras=self.cameras,
            costs_out=costs,
            rechecked=rechecked,
            appearance_check=options.appearance_check,
            checked=checked,
            searched=searched,
        )
        return LearnedRun(pairs, costs, self.gamma, (width, height), options.hor_size_source,
                          options.models, rechecked, checked[0] if checked else None,
                          self.refinement, self.camera_checked, searched)

    def close(self) -> None:
        """Close the image sources."""
        for source in self.images.values():
            source.close()
        self.images = {}

    def __enter__(self) -> LearnedInputs:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_learned_inputs(top: Mapping, hor: Mapping, frames: Iterable[int],
                        options: LearnedRunOptions) -> LearnedInputs:
    """Check every input of a run and open its images (see the module docstring).

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` of each view, the top one
            already re-timed by ``options.top_offset``.
        frames: the frames to associate.
        options: the run's options.

    Returns:
        The checked inputs, images open: use it as a context manager (or ``close()`` it).

    Raises:
        ValueError: input that does not fit (one line); nothing is left open.
    """
    inputs = LearnedInputs(top, hor, list(frames), options)
    try:
        inputs._open()
    except BaseException:
        inputs.close()
        raise
    return inputs


def run_learned_association(
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    options: LearnedRunOptions,
    progress: Callable[[Iterable[int]], Iterable[int]] | None = None,
) -> LearnedRun:
    """Associate ``frames`` with the learned matchers of ``options``; every input is checked
    before any work starts and the images are closed at the end.

    Args:
        top, hor: ``{frame: record}`` with ``ids`` and ``boxes`` of each view, the top one
            already re-timed by ``options.top_offset``.
        frames: the frames to associate.
        options: the run's options.
        progress: optional wrapper around the frame iterator (e.g. a progress bar).

    Returns:
        The :class:`LearnedRun`.

    Raises:
        ValueError: input that does not fit (one line).
    """
    with open_learned_inputs(top, hor, frames, options) as inputs:
        return inputs.associate(progress)

