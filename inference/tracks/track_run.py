"""The track run: the boxes of a top and a horizontal view to one track id per person across the
views, in one call with its options in one typed record (what ``xvmatch track`` does).

:func:`run_tracking` warns of a view whose boxes jump like independent pictures', not a video's
(:func:`~xvmatch.cues.box_motion.jump_warning`), opens the images (:func:`open_track_images`:
both views or neither, every frame the boxes list, the top boxes inside the top images),
opens the cameras for the frames with boxes in both views at the offset (a camera file, or
per-frame files numbered by the horizontal frames, each camera the size of its view's images)
and refines a fixed top camera on the boxes
(:mod:`xvmatch.inference.matching.camera_refinement`), re-times both views (and their images
and cameras) so that top frame ``t + offset`` and horizontal frame ``t`` are tracked as
one moment (the rows keep their own frame numbers), judges the cameras
(:mod:`xvmatch.inference.matching.camera_check`: the cross-view weights come from the boxes
alone when they fail), without cameras takes the frame association of a top view whose people
stand upright from the ground maps (:mod:`xvmatch.inference.tracks.track_ground`; the nadir
search otherwise, warned of where they stand upright all the same), takes Eq. 17's ``w1`` at
:data:`~xvmatch.inference.tracks.track_costs.FITTED_CAMERAS_W1` when the images would enter the
cross-view weights and the refined cameras fit the video, computes the learned matcher's
box-only evidence (``weights="learned"``) and tracks
(:func:`~xvmatch.inference.tracks.tracking.track_pair`, CVMHAT Algorithm 1); the images are
closed at the end, also on an error. :func:`track_pictures` gives what the pictures of a run
show (``xvmatch track --draw``): each moment's pairs of boxes that share a track id. A caller
that needs the images' size before the run (to settle the horizontal image size and estimate the
offset, as ``xvmatch track`` does) opens them first with :func:`open_track_images` and passes
them in. Bad input raises ``ValueError`` with one line; the lines name the command-line options
that supply each input (``--model``, ``--cameras``).
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from xvmatch.cues.box_motion import jump_warning
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.formats.box_image_size import (
    UNKNOWN,
    check_boxes_in_image,
    runs_past_borders,
    unknown_size_error,
)
from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.formats.mot_boxes import FrameBoxes, align_frames, shift_frames
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.association_run import Note
from xvmatch.inference.matching.camera_check import CameraCheck, check_run_cameras
from xvmatch.inference.matching.camera_refinement import CameraRefinement, refine_run_cameras
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.inference.matching.learned_pipeline import (
    open_matcher_cameras,
    open_view_images,
    retimed,
)
from xvmatch.inference.matching.search_camera import upright_top_warning
from xvmatch.inference.tracks.track_costs import (
    FITTED_CAMERAS_W1,
    LEARNED_DUMMY_WEIGHT,
    TrackWeights,
)
from xvmatch.inference.tracks.track_ground import GroundChoice, ground_frame_pairs
from xvmatch.inference.tracks.tracking import (
    Progress,
    TrackConfig,
    TrackImages,
    TrackResult,
    learned_frame_evidence,
    track_pair,
)

__all__ = [
    "CROSS_VIEW_WEIGHTS",
    "OpenTrackImages",
    "TrackPictures",
    "TrackRun",
    "TrackRunOptions",
    "cross_view_weights",
    "open_track_images",
    "run_tracking",
    "track_pictures",
    "track_weights",
]

CROSS_VIEW_WEIGHTS = ("learned", "handcrafted")
"""Where the cross-view weights (Eq. 13) come from: the learned matcher's box-only costs, or the
spatial-distribution search's pairs."""


def cross_view_weights(weights: str | None, model: str | None, cameras: str | None,
                       images: bool) -> str:
    """The cross-view weights of a run: ``weights``, or by default ``learned`` with a ``model``
    (its name) and ``handcrafted`` without, after the checks of the combinations.

    Raises:
        ValueError: learned weights without a model, ``cameras`` without the learned weights,
            or a model with the handcrafted weights but no ``images`` (one line each).
    """
    weights = weights or ("learned" if model is not None else "handcrafted")
    if weights not in CROSS_VIEW_WEIGHTS:
        raise ValueError(f"weights must be one of {', '.join(CROSS_VIEW_WEIGHTS)}, got "
                         f"{weights!r}")
    if weights == "learned" and model is None:
        raise ValueError("--weights learned takes the learned matcher's costs: add --model "
                         "BUNDLE or --model default")
    if cameras is not None and weights != "learned":
        raise ValueError("--cameras feeds the learned matcher's cross-view weights: add --model "
                         "BUNDLE or --model default" if model is None else
                         "--cameras feeds the learned matcher's cross-view weights: drop "
                         "--weights handcrafted")
    if weights == "handcrafted" and model is not None and not images:
        raise ValueError("--model with --weights handcrafted gives the appearance network, which "
                         "needs the images: add --top-images and --hor-images, or drop --weights "
                         "handcrafted to take the cross-view weights from the matcher")
    return weights


def track_weights(weights: str, c0: float | None = None, w1: float | None = None,
                  w2: float | None = None, sigma: float | None = None) -> TrackWeights:
    """The edge weights of a run: those given, the others :class:`TrackWeights`' defaults but
    the dummy weight ``c0``, which with the learned cross-view weights is
    :data:`~xvmatch.inference.tracks.track_costs.LEARNED_DUMMY_WEIGHT`."""
    given = {k: v for k, v in (("c0", c0), ("w1", w1), ("w2", w2), ("sigma", sigma))
             if v is not None}
    if weights == "learned":
        given.setdefault("c0", LEARNED_DUMMY_WEIGHT)
    return TrackWeights(**given)


@dataclass(frozen=True)
class TrackRunOptions:
    """What a track run uses besides the boxes, the horizontal image size and the offset.

    Attributes:
        config: the tracker's settings (:class:`~xvmatch.inference.tracks.tracking.TrackConfig`;
            its weights from :func:`track_weights`).
        params: the spatial-distribution search's parameters (the frame association of the
            handcrafted weights).
        weights: the cross-view weights, one of :data:`CROSS_VIEW_WEIGHTS`
            (:func:`cross_view_weights`).
        model: the opened learned matcher, or None: its box-only costs give the learned
            weights; with images, its appearance network adds the cross-view term of Eq. 17
            and the over-time one of Eq. 18.
        model_name: how the user named the model (messages).
        top_images, hor_images: images of both views (a folder, a video, an image or a glob),
            both or neither.
        cameras: a camera file or folder with cameras ``top`` and ``ego``, per-frame files
            numbered by the horizontal frames; needs the learned weights.
        top_boxes, hor_boxes: the box files, named when a top box lies outside the top
            images and in the notes of the ground-map path.
        ground: the top view's geometry (no ``cameras``): where the top view is oblique (its
            people stand upright and calibrate it so, or forced), the frame association is
            ``associate``'s ground-map path frame by frame
            (:func:`~xvmatch.inference.tracks.track_ground.ground_frame_pairs`) instead of the
            nadir search, and the learned matcher's box-only costs are not used.
        appearance_check: with the model's network and the learned weights, judge the
            cross-view appearance cue on the video's own sure tracklet pairs.
        refine_top_camera: with cameras, turn a fixed top camera to fit the head rays when
            the fit is clear.
        camera_check: with cameras, judge them on the box-only matcher's sure pairs and leave
            them out when they fail.
        fit_w1: with images and refined cameras that fit the video, take ``w1`` at
            :data:`~xvmatch.inference.tracks.track_costs.FITTED_CAMERAS_W1` (False: keep the
            config's, as when ``--w1`` is given).
        workers: processes for the frame association (the same result for any number).
    """

    config: TrackConfig = field(default_factory=TrackConfig)
    params: SpatialParams = field(default_factory=SpatialParams)
    weights: str = "handcrafted"
    model: LearnedMatcher | None = None
    model_name: str = "the model"
    top_images: str | None = None
    hor_images: str | None = None
    cameras: str | None = None
    top_boxes: str = "the top-view boxes"
    hor_boxes: str = "the horizontal-view boxes"
    ground: GroundChoice = field(default_factory=GroundChoice)
    appearance_check: bool = True
    refine_top_camera: bool = True
    camera_check: bool = True
    fit_w1: bool = True
    workers: int = 1

    def __post_init__(self) -> None:
        cross_view_weights(self.weights, None if self.model is None else self.model_name,
                           self.cameras, self.top_images is not None)
        if (self.top_images is None) != (self.hor_images is None):
            raise ValueError("give --top-images and --hor-images together")
        if (self.top_images is not None and self.model is not None
                and self.model.bundle.manifest.appearance is None
                and self.weights == "handcrafted"):
            raise ValueError(f"{self.model_name}: a box-only matcher has no appearance network; "
                             "use a bundle with one (e.g. default), or drop --weights "
                             "handcrafted to take the cross-view weights from it")


class OpenTrackImages:
    """The open images of a run (:func:`open_track_images`); a context manager that closes them.

    Attributes:
        images: the :class:`~xvmatch.inference.tracks.tracking.TrackImages` of both views (and
            the model's appearance network when it has one), or None without images.
        sources: the open image sources, top first (empty without images).
    """

    def __init__(self, images: TrackImages | None, sources: list) -> None:
        self.images, self.sources = images, sources

    @property
    def top_size(self) -> tuple[int, int] | None:
        """``(W, H)`` of the top images, or None without images."""
        return tuple(self.sources[0].size) if self.sources else None

    @property
    def hor_size(self) -> tuple[int, int] | None:
        """``(W, H)`` of the horizontal images, or None without images."""
        return tuple(self.sources[1].size) if self.sources else None

    def close(self) -> None:
        """Close the image sources."""
        for source in self.sources:
            source.close()

    def __enter__(self) -> OpenTrackImages:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def open_track_images(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                      options: TrackRunOptions) -> OpenTrackImages:
    """Open the images of both views (:attr:`TrackRunOptions.top_images`), after the checks:
    each holds every frame its boxes list, and the top boxes lie inside the top images.

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view in its own timing (``ids`` = rows).
        options: the run's options.

    Returns:
        The open images (none without ``top_images``): a context manager.

    Raises:
        ValueError: a missing or unreadable frame, a top box outside the images (one line);
            nothing is left open.
    """
    if options.top_images is None:
        return OpenTrackImages(None, [])
    model = options.model
    embed = None
    if model is not None and model.bundle.manifest.appearance is not None:
        embed = model.descriptors
    sources = []
    try:
        for path, frames in ((options.top_images, top), (options.hor_images, hor)):
            sources.append(open_view_images(path, frames,
                                            [f for f in sorted(frames) if len(frames[f])]))
        check_boxes_in_image(top, tuple(sources[0].size), options.top_boxes,
                             f"the images {options.top_images}", ids=False,
                             past=runs_past_borders(top, hor))
    except BaseException:
        for source in sources:
            source.close()
        raise
    cross_cost = model.appearance_cost if embed is not None else None  # a site's adaptation
    cross_embed = None
    if embed is not None and model.cue_vector != "descriptors":  # one network run for both
        vectors = ("descriptors", model.cue_vector)

        def cross_embed(image, boxes):
            return tuple(model.bundle.embed_vectors(model.crops(image, boxes), vectors))
    images = TrackImages(sources[0], sources[1], embed, cross_cost, cross_embed)
    return OpenTrackImages(images, sources)


@dataclass(frozen=True, eq=False)
class TrackRun:
    """The result of a track run.

    Attributes:
        result: the tracks of both views (:class:`~xvmatch.inference.tracks.tracking.
            TrackResult`: input rows to track ids).
        config: the tracker's settings used (``w1`` fitted to the cameras, when it was).
        cameras: the cameras as refined, numbered by the horizontal frames, also when the
            camera check left them out (to write them), or None without cameras.
        refinement: what became of the top camera (``refine_top_camera``), or None.
        camera_checked: the camera check (``camera_check``), or None.
        checked: the appearance check (``appearance_check``), or None.
    """

    result: TrackResult
    config: TrackConfig
    cameras: CameraFrames | None = None
    refinement: CameraRefinement | None = None
    camera_checked: CameraCheck | None = None
    checked: AppearanceCheck | None = None

    def warning(self) -> str | None:
        """What to warn of, in one line: windows whose MIP spent its budget of work or time
        limit, or failed, and fell back to the best loop-free answer; None when none did."""
        result = self.result
        if not result.n_fallback:
            return None
        return (f"{result.n_fallback} of {result.n_windows} windows spent the MIP's budget of "
                f"work or time limit ({self.config.time_limit:g} s) or failed, and used the best "
                "loop-free answer found instead of the optimum")


def _open_cameras(top: Mapping, hor: Mapping, options: TrackRunOptions,
                  hor_size: tuple[tuple[int, int], str], offset: int, images: OpenTrackImages,
                  note: Note):
    """``(cameras, refinement)``: the cameras opened and checked for every horizontal frame
    ``f`` with boxes, and boxes in top frame ``f + offset``, each camera the size of its view's
    images (else of ``hor_size``); a fixed top camera refined on the boxes unless asked not to
    (the refinement is then None); ``(None, None)`` without cameras."""
    if options.cameras is None:
        return None, None
    wanted = {"hor": (tuple(hor_size[0]), hor_size[1])}
    if images.sources:
        wanted["top"] = (tuple(images.sources[0].size), f"the images {options.top_images}")
        wanted["hor"] = (tuple(images.sources[1].size), f"the images {options.hor_images}")
    frames = [f for f in hor if len(hor[f]) and len(top.get(f + offset, ()))]
    cameras = open_matcher_cameras(options.cameras, [(options.model, options.model_name)],
                                   frames, wanted)
    if not options.refine_top_camera:
        return cameras, None
    cameras, refinement = refine_run_cameras(cameras, top, hor, frames, offset)
    note(refinement.message, refinement.turned)
    return cameras, refinement


def _aligned(top: Mapping, hor: Mapping, images: TrackImages | None, cameras, offset: int):
    """The views (and their images and cameras) re-timed so that top frame ``t + offset`` and
    horizontal frame ``t`` are tracked as one moment (:func:`xvmatch.formats.mot_boxes.
    align_frames`); the cameras are numbered by the horizontal frames."""
    if not offset:
        return top, hor, images, cameras
    (top, hor), (s_top, s_hor) = align_frames([top, hor], [offset])
    if images is not None:  # aligned frame f shows the view's frame f - shift
        images = replace(images, top=retimed(images.top, -s_top), hor=retimed(images.hor, -s_hor))
    if cameras is not None:
        cameras = retimed(cameras, -s_hor)
    return top, hor, images, cameras


def _checked_cameras(top: Mapping, hor: Mapping, options: TrackRunOptions,
                     hor_size: tuple[int, int], cameras, refinement: CameraRefinement | None,
                     note: Note):
    """``(cameras, refinement, check)`` after the camera check (``top`` and ``hor`` aligned):
    the cameras as they are when the check is off or passes, None (and no refinement) when it
    fails: the cross-view weights then come from the boxes alone."""
    if cameras is None or not options.camera_check:
        return cameras, refinement, None
    model = options.model
    check = check_run_cameras(top, hor, sorted(hor), model, tuple(hor_size), cameras,
                              float(model.gamma),
                              None if refinement is None else refinement.fit_loss,
                              workers=options.workers,
                              moving=refinement is not None and refinement.moving)
    if check.to_tell(False):
        note(check.message(), check.to_tell(True))
    return (cameras, refinement, check) if check.trusted else (None, None, check)


def _fitted_config(options: TrackRunOptions, refinement: CameraRefinement | None,
                   images: TrackImages | None, note: Note) -> TrackConfig:
    """The config with Eq. 17's ``w1`` at :data:`~xvmatch.inference.tracks.track_costs.
    FITTED_CAMERAS_W1` when the images would enter the cross-view weights and the refined
    cameras fit the video (:attr:`~xvmatch.inference.matching.camera_refinement.
    CameraRefinement.fits`), unless ``fit_w1`` is off; says so."""
    config = options.config
    if not options.fit_w1 or images is None or refinement is None or not refinement.fits:
        return config
    note(f"track: the top camera fits the head rays, so the images serve over time only "
         f"(--w1 {FITTED_CAMERAS_W1:g}; give --w1 to choose)", False)
    return replace(config, weights=replace(config.weights, w1=FITTED_CAMERAS_W1))


def _ground_pairs(top: Mapping, hor: Mapping, options: TrackRunOptions,
                  hor_size: tuple[tuple[int, int], str], camera_rows, images: OpenTrackImages,
                  note: Note, calibration: object | None = None
                  ) -> dict[int, list[tuple[int, int]]] | None:
    """The frame association of the ground-map path where the top view is oblique and no
    cameras are given (``top`` and ``hor`` aligned;
    :func:`~xvmatch.inference.tracks.track_ground.ground_frame_pairs`; ``calibration``: the
    top camera already calibrated on these views), its lines told to ``note``; else None,
    with a warning where the top view's people stand upright all the same (the nadir search
    misreads them)."""
    if options.cameras is not None:
        return None
    pairs = ground_frame_pairs(top, hor, hor_size, options.ground, images.top_size, camera_rows,
                               (options.top_boxes, options.hor_boxes), options.workers, note,
                               calibration)
    if pairs is None:
        if hor_size[1] == UNKNOWN:  # guessed for this path only (the command's defer)
            raise unknown_size_error(hor, options.hor_boxes)
        if (said := upright_top_warning(
                top, "track's cross-view search", "its ids across the views",
                "give --cameras (the views' calibrated cameras, with --model), or --top-view "
                "oblique --top-image-size WxH to calibrate it from its people")) is not None:
            note(said, True)
    elif options.weights == "learned":
        with_images = " (its appearance network is, on the images)" if images.sources else ""
        note(f"track: {options.model_name}'s box-only costs are not used on the ground "
             f"maps{with_images}", False)
    return pairs


def _said_nowhere(line: str, always: bool) -> None:
    """A :data:`Note` that says nothing."""


def run_tracking(
    top: Mapping[int, FrameBoxes],
    hor: Mapping[int, FrameBoxes],
    options: TrackRunOptions,
    hor_size: tuple[tuple[int, int], str],
    offset: int = 0,
    camera_rows: Iterable[int] | np.ndarray | None = None,
    images: OpenTrackImages | None = None,
    progress: Progress | None = None,
    note: Note | None = None,
    calibration: object | None = None,
) -> TrackRun:
    """Track the people of both views with one id per person across the views.

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view in its own timing, ``ids`` = the
            detection rows (unique within a view).
        options: the run's options.
        hor_size: ``((W, H), where it comes from)``: the horizontal image size, settled
            (:func:`xvmatch.formats.box_image_size.resolve_size`).
        offset: top frame ``t + offset`` is shown with horizontal frame ``t`` (the rows, and so
            the tracks, keep their own frame numbers).
        camera_rows: top rows of the horizontal camera's wearer (O given), or None.
        images: the images opened by :func:`open_track_images` (left open: the caller closes
            them); None: opened here from the options and closed at the end.
        progress: optional ``progress(iterable, total, description)`` wrapper.
        note: told each line to say as the run goes (:data:`Note`), among them a warning for a
            view whose boxes jump like independent pictures'
            (:func:`~xvmatch.cues.box_motion.jump_warning`); None: said nowhere.
        calibration: the top camera as
            :func:`~xvmatch.inference.tracks.track_ground.oblique_track_top` calibrated it on
            ``top`` and ``hor`` as given, or None; taken at offset 0 (the views then as
            tracked) rather than calibrated again.

    Returns:
        The :class:`TrackRun`.

    Raises:
        ValueError: input that does not fit (one line).
    """
    if images is None:
        with open_track_images(top, hor, options) as opened:
            return run_tracking(top, hor, options, hor_size, offset, camera_rows, opened,
                                progress, note, calibration)
    note = note or _said_nowhere
    for view, frames in (("top", top), ("horizontal", hor)):
        if said := jump_warning(view, frames):
            note(said, True)
    cameras, refinement = _open_cameras(top, hor, options, hor_size, offset, images, note)
    refined = cameras, refinement  # to write: also when the check leaves them out
    top, hor, track_images, cameras = _aligned(top, hor, images.images, cameras, offset)
    frame_pairs = _ground_pairs(top, hor, options, hor_size, camera_rows, images, note,
                                None if offset else calibration)
    cameras, refinement, camera_checked = _checked_cameras(top, hor, options, hor_size[0],
                                                           cameras, refinement, note)
    config = _fitted_config(options, refinement, track_images, note)
    learned = None
    if options.weights == "learned" and frame_pairs is None:
        learned = learned_frame_evidence(top, hor, hor_size[0], options.model, camera_rows,
                                         options.workers, progress, cameras=cameras)
    checked: list[AppearanceCheck] = []
    result = track_pair(top, hor, float(hor_size[0][0]), options.params, config, camera_rows,
                        options.workers, progress, frame_pairs=frame_pairs,
                        images=track_images, learned=learned,
                        appearance_check=options.appearance_check, checked=checked)
    return TrackRun(result, config, *refined, camera_checked, checked[0] if checked else None)


@dataclass(frozen=True)
class TrackPictures:
    """What the pictures of a track run show, each moment under its horizontal frame number
    (the arguments of :func:`xvmatch.viz.match_pictures.write_match_pictures`).

    Attributes:
        top: ``{frame: FrameBoxes}`` of the top view re-timed by the offset: frame ``f`` holds
            top frame ``f + offset`` (``ids``: the rows).
        hor: ``{frame: FrameBoxes}`` of the horizontal view (``ids``: the rows).
        pairs: ``{frame: [(top row, horizontal row)]}``: the boxes of a moment that share a
            track id (the first box of each view where a track has two).
        frames: the frames with boxes in both views, ascending.
        tracks: ``({top row: track id}, {horizontal row: track id})``; rows the tracker
            dropped have none.
        sources: ``{"top": images, "hor": images}`` re-timed as ``top``, or None without
            images.
    """

    top: dict[int, FrameBoxes]
    hor: Mapping[int, FrameBoxes]
    pairs: dict[int, list[tuple[int, int]]]
    frames: list[int]
    tracks: tuple[dict[int, int], dict[int, int]]
    sources: dict | None = None


def track_pictures(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                   result: TrackResult, offset: int = 0,
                   images: OpenTrackImages | None = None) -> TrackPictures:
    """The :class:`TrackPictures` of a run's ``result`` on ``top`` and ``hor`` (each view in
    its own timing, ``ids`` = rows, as given to :func:`run_tracking`) at ``offset``, on the
    open ``images`` (None or none open: boxes only)."""
    shown = shift_frames(top, offset)
    pairs: dict[int, list[tuple[int, int]]] = {}
    for f, record in hor.items():
        if f not in shown:
            continue
        top_of: dict[int, int] = {}
        for row in shown[f].ids.tolist():
            if row in result.top_rows:
                top_of.setdefault(result.top_rows[row], row)
        pairs[f] = []
        for row in record.ids.tolist():
            track = result.hor_rows.get(row)
            if track in top_of:
                pairs[f].append((top_of.pop(track), row))
    frames = sorted(f for f in pairs if len(shown[f]) and len(hor[f]))
    sources = None
    if images is not None and images.sources:
        sources = {"top": retimed(images.sources[0], offset), "hor": images.sources[1]}
    return TrackPictures(shown, hor, pairs, frames, (dict(result.top_rows),
                                                     dict(result.hor_rows)), sources)
