"""The association run: the boxes of a top and a horizontal view to pairs, frame by frame, in one
call with its options in one typed record (what ``xvmatch associate`` does).

:func:`run_association` re-times the views (:func:`offset_to_apply`: a given offset, or ``auto``'s
estimate when the clips back it; the views must then share a frame with boxes), takes the
ground-map path when the top view is oblique (:func:`oblique_pairs`: forced, or found so by
``auto``, its size given or guessed from its boxes), else associates each frame with the learned
matchers (:class:`LearnedChoice`: opened here, run by
:func:`~xvmatch.inference.matching.learned_pipeline.open_learned_inputs`) or with the CVMHAT
spatial-distribution search (:func:`~xvmatch.cues.spatial_search.associate_sequence`, Sec. 3.2),
and in video mode keeps the pairs consistent along each view's track ids
(:func:`~xvmatch.inference.linking.pair_consensus.consistent_pairs`). What the run says, its
progress and its pictures go to the caller's :class:`AssociationHooks`, as the run goes; what it
writes (the pairs, the costs, the cameras as refined) the caller writes from the
:class:`AssociationRun`. Bad input raises ``ValueError`` with one line naming the option.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from xvmatch.cues.auto_offset import AutoOffsetOptions, auto_offset
from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.formats.mot_boxes import FrameBoxes, check_common_frames, shift_frames

if TYPE_CHECKING:
    from xvmatch.inference.matching.learned_pipeline import LearnedRun

__all__ = [
    "AUTO_VIDEO",
    "AssociationHooks",
    "AssociationOptions",
    "AssociationPictures",
    "AssociationRun",
    "LearnedChoice",
    "guessed_top_size",
    "oblique_pairs",
    "oblique_top",
    "offset_to_apply",
    "run_association",
]

Note = Callable[[str, bool], None]
"""``note(line, always)``: told each line a run has to say as it goes; ``always``: also with
``--quiet`` (a warning, a camera turned, cameras or images left out)."""
Pairs = dict[int, list[tuple[int, int]]]

AUTO_VIDEO = ("--mode video: each view's ids persist from frame to frame (track ids), so the "
              "pairs were kept consistent along them; --mode frame solves each frame alone")
"""The note of ``--mode auto`` taking video mode, said with the run's summary
(:attr:`AssociationRun.note`)."""


@dataclass(frozen=True)
class LearnedChoice:
    """The learned matchers a run asks for (``--model``) and how they run.

    Attributes:
        names: each matcher as named: a bundle folder, ``default`` or a torch matcher file
            (:func:`~xvmatch.inference.matching.run_inputs.open_matchers`; several: costs
            averaged).
        threads: onnxruntime threads.
        precision: the appearance network's ``fp32`` or ``int8`` (None: the bundle's choice).
        top_images, hor_images: images of both views, both or neither.
        cameras: a camera file or folder with cameras ``top`` and ``ego``, or None.
        gamma: non-association cost in (0, 1]; None: the model's own.
        mirror: also score the scene mirrored left-right and average.
        keep_costs: keep each frame's cost matrix (:attr:`AssociationRun.learned`).
        appearance_check, refine_top_camera, camera_check: as
            :class:`~xvmatch.inference.matching.learned_pipeline.LearnedRunOptions`.
    """

    names: tuple[str, ...]
    threads: int = 1
    precision: str | None = None
    top_images: str | None = None
    hor_images: str | None = None
    cameras: str | None = None
    gamma: float | None = None
    mirror: bool = False
    keep_costs: bool = False
    appearance_check: bool = True
    refine_top_camera: bool = True
    camera_check: bool = True


@dataclass(frozen=True)
class AssociationOptions:
    """What an association run uses besides the boxes.

    Attributes:
        hor_size: the horizontal image size ``(W, H)`` and where it comes from
            (:func:`~xvmatch.formats.box_image_size.resolve_size`).
        params: the spatial-distribution search's parameters (search and offset estimate).
        offset: frames to re-time the top view by (top frame = horizontal frame + offset), or
            ``"auto"``: estimated first.
        max_offset: the largest |offset| ``auto`` tries (needed with ``auto``).
        video: keep the pairs consistent along each view's track ids.
        video_by_auto: video mode was found by ``--mode auto`` (said with the summary).
        search: the handcrafted search's ``exhaustive``, ``reduced`` or ``follow``; None: as
            not given (``exhaustive``).
        camera_id: top-view id of the horizontal camera's wearer, or None.
        workers: processes for the offset estimate and the matcher's features.
        top_boxes, hor_boxes: the box files, as messages name them.
        top_view: ``auto``, ``nadir`` or ``oblique``.
        top_image_size: the top view's image size, or None (``auto`` may guess it).
        hor_hfov: the horizontal camera's field of view, degrees, or ``"auto"`` (the
            default, as ``--hor-hfov``): chosen from the people (the oblique path; in video
            mode :func:`~xvmatch.cues.hor_lens.pick_along_tracks`, frame by frame
            :func:`~xvmatch.cues.hor_lens.choose_hor_hfov`).
        fps: the frame rate of the frame numbers (the oblique path), or ``"auto"`` (the
            default, as ``--fps``): 30 unless the top view's walkers say otherwise.
        learned: the learned matchers, or None: the handcrafted search.
    """

    hor_size: tuple[tuple[int, int], str]
    params: SpatialParams = field(default_factory=SpatialParams)
    offset: int | str = 0
    max_offset: int | None = None
    video: bool = False
    video_by_auto: bool = False
    search: str | None = None
    camera_id: int | None = None
    workers: int = 1
    top_boxes: str = "the top-view boxes"
    hor_boxes: str = "the horizontal-view boxes"
    top_view: str = "auto"
    top_image_size: tuple[int, int] | None = None
    hor_hfov: float | str = "auto"
    fps: float | str = "auto"
    learned: LearnedChoice | None = None

    def __post_init__(self) -> None:
        if self.offset == "auto" and self.max_offset is None:
            raise ValueError("offset auto needs max_offset")
        if not self.video and (self.search or "exhaustive") != "exhaustive":
            raise ValueError(f"search {self.search} uses previous frames: it needs video")

    @property
    def cameras(self) -> str | None:
        """The calibrated cameras the learned matchers take, or None."""
        return None if self.learned is None else self.learned.cameras


@dataclass(frozen=True)
class AssociationPictures:
    """What the pictures of a run show: ``pairs`` over ``frames`` of ``top`` (re-timed) and
    ``hor``, the open ``images`` (``{"top": source, "hor": source}``, or None), of a horizontal
    view of ``hor_size``."""

    top: Mapping[int, FrameBoxes]
    hor: Mapping[int, FrameBoxes]
    pairs: Pairs
    frames: list[int]
    images: dict | None
    hor_size: tuple[int, int]


def _no_note(line: str, always: bool) -> None:
    """A note said nowhere."""


@dataclass(frozen=True)
class AssociationHooks:
    """Where a run tells what it does, as it goes (the command line's stderr); each optional.

    Attributes:
        note: :data:`Note`.
        size_assumed: said on the nadir path (the search, the learned matcher) once the checks
            have passed, as its work starts (the note of a horizontal size assumed); the
            ground-map path, which guesses the size from the boxes, says its own.
        frames: ``frames(n)`` wraps the iterator of the ``n`` frames associated (a progress bar).
        clips: ``clips()`` opens the offset search's ``progress(done, total)`` (a context
            manager).
        pictures: given the pictures to draw while the images are open; None: none drawn.
        export: ``export(torch_file, folder)`` writes a torch matcher file's bundle
            (:func:`~xvmatch.inference.matching.run_inputs.open_matchers`).
    """

    note: Note = _no_note
    size_assumed: Callable[[], None] = lambda: None
    frames: Callable[[int], Callable[[Iterable[int]], Iterable[int]]] | None = None
    clips: Callable[[], AbstractContextManager[Callable[[int, int], None] | None]] = nullcontext
    pictures: Callable[[AssociationPictures], None] | None = None
    export: Callable[[str, Path], None] | None = None


@dataclass(frozen=True, eq=False)
class AssociationRun:
    """The result of an association run.

    Attributes:
        pairs: ``{frame: [(top id, hor id)]}``, under the horizontal frame numbers.
        frames: every frame of either view (re-timed).
        offset: the offset applied (top frame = horizontal frame + offset).
        top: the top view re-timed by ``offset``.
        note: a line to say with the run's summary (:data:`AUTO_VIDEO`), or None.
        learned: the learned run (costs, checks, the top camera's refinement), or None.
        refined_cameras: the cameras as refined (``--write-cameras``), or None.
    """

    pairs: Pairs
    frames: list[int]
    offset: int
    top: Mapping[int, FrameBoxes]
    note: str | None = None
    learned: LearnedRun | None = None
    refined_cameras: object | None = None


def offset_to_apply(top: Mapping, hor: Mapping, value: int | str,
                    auto: AutoOffsetOptions | None = None,
                    names: tuple[str, str] = ("top", "horizontal"),
                    clips: Callable[[], AbstractContextManager] = nullcontext,
                    note: Note = _no_note) -> int:
    """The offset to apply: ``value`` when a number, or with ``auto`` the estimate when the
    clips back it (0 otherwise, with a warning told to ``note`` once the search is over;
    :func:`~xvmatch.cues.auto_offset.auto_offset` with ``auto``'s options, its progress told
    to what ``clips()`` opens). Views that then share no frame with boxes are refused (an empty
    result is no answer).

    Raises:
        ValueError: the views share no frame with boxes, naming both ``names`` and the offset.
    """
    if value == "auto":
        if auto is None:
            raise ValueError("offset auto needs its options")
        with clips() as progress:
            decided = auto_offset(top, hor, auto, progress)
        if decided.to_tell(False):
            note(decided.message, decided.to_tell(True))
        offset = decided.offset
    else:
        offset = int(value)
    check_common_frames(top, hor, offset, names, "nothing to match")
    return offset


def guessed_top_size(top: Mapping, note: Note = _no_note,
                     past: bool | None = None) -> tuple[int, int] | None:
    """The top view's size when none is given: where its people stand upright (an oblique
    camera, which the nadir search would misread), the size its boxes tell
    (:func:`~xvmatch.formats.box_image_size.guess_image_size`; ``past``: whether the run's
    boxes run on past the borders, None: as the top view's show), said in one line; None (the
    nadir path) for squat boxes, or boxes no size holds (a note saying what to give)."""
    from xvmatch.formats.box_image_size import size_guess_how, upright_size_guess

    if (guess := upright_size_guess(top, past)) is None:
        return None
    aspect, size = guess
    said = (f"took {size[0]}x{size[1]}, {size_guess_how(top, size, past)}, as its size; give "
            "--top-image-size WxH if not" if size is not None else
            "no common video size holds its boxes: give --top-image-size WxH to calibrate "
            "it from its people")
    note(f"xvmatch: note: the top view's people stand upright (boxes {aspect:.1f} times as "
         f"tall as wide): an oblique camera; {said}", False)
    return size


def _top_size(top: Mapping, options: AssociationOptions, note: Note = _no_note,
              past: bool | None = None) -> tuple[int, int] | None:
    """The top view's size for the ground-map path: ``--top-image-size``, else guessed from
    its boxes (:func:`guessed_top_size`, its line told to ``note``); None where that path is
    not taken (``nadir``, calibrated cameras, the learned matcher's top images, no guess)."""
    if options.top_view == "nadir" or options.cameras is not None:
        return None
    images = options.learned is not None and options.learned.top_images is not None
    return options.top_image_size or (None if images else guessed_top_size(top, note, past))


def oblique_top(top: Mapping, options: AssociationOptions, hor: Mapping) -> object | None:
    """The top camera calibrated from its people when the ground-map path would take it (its
    size given or guessed, as :func:`oblique_pairs` takes it with the handheld view ``hor``;
    the calibration oblique), else None; says nothing."""
    from xvmatch.formats.box_image_size import runs_past_borders

    if (top_size := _top_size(top, options, past=runs_past_borders(top, hor))) is None:
        return None
    from xvmatch.geometry.people_calibration import CalibrationError
    from xvmatch.inference.matching.ground_association import top_calibration

    try:
        calib = top_calibration(top, top_size, 0, options.top_boxes, options.video,
                                spread="later")  # its kind only: no spread
    except CalibrationError:
        return None
    return calib if calib.kind == "oblique" or options.top_view == "oblique" else None


def oblique_pairs(top: Mapping, hor: Mapping, options: AssociationOptions,
                  note: Note = _no_note, over_time: str | None = None,
                  calibration: object | None = None) -> Pairs | None:
    """The pairs of the ground-map association when the top view is oblique (forced, or found
    so by ``auto``), else None (the nadir path); tells ``note`` the one line saying what was
    assumed (and, with ``hor_hfov`` ``auto``, one saying the lens chosen). In video mode the
    pairs are made consistent along each view's tracks. Without ``--top-image-size`` the size
    is guessed from the boxes (not where the learned matcher reads the top images), and a top
    view too sparse to calibrate takes the nadir path; a horizontal size assumed to be CVMHAT's
    (or not known: boxes that do not fit it) is guessed from its boxes too
    (:func:`~xvmatch.formats.box_image_size.ground_path_hor_size`), with a note (the CVMHAT
    size kept, where its boxes fit it, said too). ``over_time``: how the caller keeps the
    pairs over time, said in place of the mode (``track``'s tracker); ``calibration``: the top
    camera as :func:`oblique_top` calibrated it on these views, not calibrated again."""
    from xvmatch.formats.box_image_size import (
        check_boxes_in_image,
        ground_path_hor_size,
        ground_path_size_note,
        runs_past_borders,
    )

    past = runs_past_borders(top, hor)  # the run's files, made by one tracker or tool
    if (top_size := _top_size(top, options, note, past)) is None:
        return None
    from xvmatch.geometry.people_calibration import CalibrationError
    from xvmatch.inference.matching.ground_association import (
        GroundAssociationOptions,
        run_top_view,
    )

    source = "--top-image-size" if options.top_image_size else "the top boxes' extent"
    check_boxes_in_image(top, top_size, options.top_boxes, source, past=past)
    guessed = ground_path_hor_size(hor, *options.hor_size, past)
    hor_size = guessed or options.hor_size[0]
    ground = GroundAssociationOptions(top_size=top_size, hor_size=hor_size,
                                      hor_hfov_deg=options.hor_hfov, fps=options.fps,
                                      consensus=options.video, seed=0,
                                      workers=options.workers, camera_id=options.camera_id)
    try:
        run = run_top_view(top, hor, ground, options.top_view, name=options.top_boxes,
                           calibration=calibration)
    except CalibrationError as error:
        if options.top_image_size:
            raise
        note("xvmatch: note: the top view cannot be calibrated from its people "
             f"({str(error).split(';')[0]}); associating as over a nadir drone", False)
        return None
    if run is None:
        note("xvmatch: note: top view: looking straight down (its boxes are as wide as "
             "tall); associating as over a nadir drone, which takes the handheld camera's "
             "wearer to be one of its people (if not: --top-view oblique)", False)
        return None
    unused = [name for name, given in (("--model", options.learned is not None),
                                       ("--search", options.search is not None)) if given]
    ignored = f" ({', '.join(unused)}: not used on this path)" if unused else ""
    mode = over_time or ("pairs made consistent over the clip with each view's track ids" if
                         ground.consensus else "each frame on its own (--mode video: "
                         "consistent over the clip)")
    note(f"xvmatch: note: {run.summary}; {mode}{ignored}", False)
    said = ground_path_size_note(options.hor_boxes, hor, guessed, options.hor_size[1], past)
    if said is not None:
        note(f"xvmatch: note: {said}", False)
    if run.lens is not None:
        from xvmatch.inference.matching.ground_association import lens_note

        note(f"xvmatch: note: {lens_note(run.lens)}", False)
    if run.frame_rate is not None:
        from xvmatch.inference.matching.frame_rate import frame_rate_note

        note(f"xvmatch: note: {frame_rate_note(run.frame_rate)}", False)
    return run.pairs


def _tell(note: Note, check) -> None:
    """Tell ``note`` a check's line (:meth:`message`) when it has one to say."""
    if check is not None and check.to_tell(False):
        note(check.message(), check.to_tell(True))


def _upright_note(top: Mapping, note: Note) -> None:
    """Tell ``note`` where the top view's people stand upright and its images keep the learned
    matcher (``--top-image-size`` not given): its geometry cue reads a nadir drone's view."""
    from xvmatch.inference.matching.search_camera import upright_top_warning

    if (said := upright_top_warning(
            top, "the learned matcher's geometry cue", "that cue",
            "its images' appearance weighs too; --top-image-size WxH (the top images' size) "
            "calibrates the top camera from its people and pairs on its ground map instead "
            "(boxes only)", level="note")) is not None:
        note(said, False)


def _learned_pairs(top: Mapping, hor: Mapping, frames: list[int], options: AssociationOptions,
                   offset: int, hooks: AssociationHooks) -> tuple[Pairs, LearnedRun, object]:
    """The learned matchers' pairs of ``frames`` (``top`` re-timed by ``offset``), after the
    checks of ``--precision`` before and after opening them; its notes told as it goes, its
    pictures drawn while the images are open. Returns the pairs, the learned run and the
    cameras as refined."""
    from xvmatch.inference.matching.learned_pipeline import LearnedRunOptions, open_learned_inputs
    from xvmatch.inference.matching.run_inputs import open_matchers, precision_problem

    choice = options.learned
    names, images = list(choice.names), choice.top_images is not None
    if (problem := precision_problem(choice.precision, images)) is not None:
        raise ValueError(problem)
    models = open_matchers(names, choice.threads, choice.precision, recheck=True,
                           export=hooks.export)
    if (problem := precision_problem(choice.precision, images, models, names)) is not None:
        raise ValueError(problem)
    run_options = LearnedRunOptions(
        models=tuple(models), hor_size=tuple(options.hor_size[0]),
        hor_size_source=options.hor_size[1], names=tuple(names), top_images=choice.top_images,
        hor_images=choice.hor_images, cameras=choice.cameras, top_boxes=options.top_boxes,
        hor_boxes=options.hor_boxes, camera_id=options.camera_id, gamma=choice.gamma,
        mirror=choice.mirror, workers=options.workers, top_offset=offset,
        keep_costs=choice.keep_costs, appearance_check=choice.appearance_check,
        refine_top_camera=choice.refine_top_camera, camera_check=choice.camera_check)
    note = hooks.note
    with open_learned_inputs(top, hor, frames, run_options) as inputs:
        hooks.size_assumed()
        if images and options.top_view != "nadir" and not (options.top_image_size
                                                           or choice.cameras):
            _upright_note(top, note)  # kept on this path: its images' size not given
        if (refinement := inputs.refinement) is not None:
            note(refinement.message, refinement.turned)
        _tell(note, inputs.camera_checked)
        run = inputs.associate(hooks.frames(len(frames)) if hooks.frames else None)
        if run.rechecked:
            both = sum(1 for f in frames if len(top.get(f, ())) and len(hor.get(f, ())))
            note(f"INT8 appearance network: {len(run.rechecked)} of {both} frames were near "
                 "ties, scored again with FP32", False)
        _tell(note, run.checked)
        if hooks.pictures is not None:
            hooks.pictures(AssociationPictures(top, hor, run.pairs, sorted(run.costs),
                                               inputs.images or None, run.hor_size))
    return run.pairs, run, inputs.refined_cameras


def _need_hor_size(hor: Mapping, options: AssociationOptions) -> None:
    """Refuse, on a path that reads the horizontal image size (the nadir search, the learned
    matcher), boxes alone whose size is not known (:data:`~xvmatch.formats.box_image_size.
    UNKNOWN`: they do not fit CVMHAT's and only the ground-map path guesses one)."""
    from xvmatch.formats.box_image_size import UNKNOWN, unknown_size_error

    if options.hor_size[1] == UNKNOWN:
        raise unknown_size_error(hor, options.hor_boxes)


def run_association(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes],
                    options: AssociationOptions,
                    hooks: AssociationHooks | None = None) -> AssociationRun:
    """Associate the two views' people frame by frame (see the module docstring).

    Args:
        top, hor: ``{frame: FrameBoxes}`` of each view, in its file's frame numbers.
        options: the run's options.
        hooks: where the run's notes, progress and pictures go (default: nowhere).

    Returns:
        The :class:`AssociationRun`.

    Raises:
        ValueError: input that does not fit (one line).
    """
    hooks = hooks or AssociationHooks()
    learned = options.learned
    auto = None
    if options.offset == "auto" and oblique_top(top, options, hor) is not None:
        raise ValueError("--offset auto estimates the offset with the nadir search; with an "
                         "oblique top view give it as a frame number (or 0)")
    if options.offset == "auto":
        _need_hor_size(hor, options)
        if learned is None:  # the nadir path (the search reads the size): said before it
            hooks.size_assumed()
        auto = AutoOffsetOptions(hor_width=options.hor_size[0][0], max_offset=options.max_offset,
                                 params=options.params, camera_id=options.camera_id,
                                 workers=options.workers)
    offset = offset_to_apply(top, hor, options.offset, auto,
                             (options.top_boxes, options.hor_boxes), hooks.clips, hooks.note)
    if offset:
        top = shift_frames(top, offset)
    frames = sorted(set(top) | set(hor))
    oblique = oblique_pairs(top, hor, options, hooks.note)
    if oblique is not None:  # the ground-map path keeps its own consensus
        _pictures(top, hor, oblique, frames, options, hooks)
        return AssociationRun(oblique, frames, offset, top)
    _need_hor_size(hor, options)
    if learned is None and options.offset != "auto":  # the learned run says it as it opens
        hooks.size_assumed()
    run = refined = None
    searched: dict[int, int] = {}  # each frame's row of the search's camera location O
    if learned is not None:
        pairs, run, refined = _learned_pairs(top, hor, frames, options, offset, hooks)
        searched = run.searched
    else:
        from xvmatch.cues.spatial_search import associate_sequence

        pairs = associate_sequence(top, hor, hor_width=options.hor_size[0][0],
                                   params=options.params, search=options.search or "exhaustive",
                                   camera_id=options.camera_id, frames=frames,
                                   progress=hooks.frames(len(frames)) if hooks.frames else None,
                                   cameras=searched)
    # The holder not named, no cameras: whether O stayed with one top-view person, followed by
    # the view's tracks (video) or its boxes linked (frame mode; search_camera).
    if options.camera_id is None and (learned is None or learned.cameras is None):
        from xvmatch.inference.matching.search_camera import (
            followed_cameras,
            wandering_camera_note,
        )

        followed = followed_cameras(top, searched, options.video)
        if followed is not None and (said := wandering_camera_note(followed)) is not None:
            hooks.note(f"xvmatch: warning: {said}", True)
    if options.video:
        from xvmatch.inference.linking.pair_consensus import consistent_pairs

        pairs = consistent_pairs(pairs, top, hor, frames)
    if learned is None:
        _pictures(top, hor, pairs, frames, options, hooks)
    return AssociationRun(pairs, frames, offset, top, AUTO_VIDEO if options.video_by_auto else None,
                          run, refined)


def _pictures(top: Mapping[int, FrameBoxes], hor: Mapping[int, FrameBoxes], pairs: Pairs,
              frames: list[int], options: AssociationOptions, hooks: AssociationHooks) -> None:
    """The run's pairs drawn on the frames where both views have boxes (``--draw``), for a
    path whose pictures have no costs (the search, the ground maps)."""
    if hooks.pictures is not None:
        both = [f for f in frames if len(top.get(f, ())) and len(hor.get(f, ()))]
        hooks.pictures(AssociationPictures(top, hor, pairs, both, None, options.hor_size[0]))
