"""The multi-view run: one top view and several egocentric views to person ids, with its options in
one typed record.

In two steps, so that a caller can settle each horizontal view's image size and offset between
them (as :func:`~xvmatch.inference.matching.learned_pipeline.open_learned_inputs` does for one
pair): :func:`open_multi_ego` opens and checks the images and the cameras of every view (the
top boxes inside the top images, each ego camera the size of its view's images), and
:func:`run_multi_ego` refines the shared top camera, re-times the views by their offsets, leaves
out a view's cameras that fail the camera check, builds every frame's cost matrices of every view
pair (:func:`~xvmatch.inference.views.multi_view_costs.multi_view_costs`) and solves them
(:func:`~xvmatch.inference.views.multi_view_people.assign_people`).
:func:`multi_ego_sizes` is the image size rule of each horizontal view. The models come opened,
so that this module needs neither torch nor the command line. Bad input raises ``ValueError``
with one line; the lines name the command-line options that supply each input.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xvmatch.cues.spatial_matching import SpatialParams
from xvmatch.formats.box_image_size import (
    UNKNOWN,
    check_boxes_in_image,
    resolve_size,
    runs_past_borders,
    unknown_size_error,
)
from xvmatch.formats.camera_frames import open_cameras
from xvmatch.formats.mot_boxes import FrameBoxes, align_frames, shift_frames
from xvmatch.inference.matching.appearance_check import AppearanceCheck
from xvmatch.inference.matching.camera_check import CameraCheck, check_run_cameras
from xvmatch.inference.matching.camera_refinement import CameraRefinement, refine_views_cameras
from xvmatch.inference.matching.learned_association import LearnedMatcher
from xvmatch.inference.matching.learned_pipeline import open_view_images, retimed
from xvmatch.inference.views.multi_view_costs import multi_view_costs
from xvmatch.inference.views.multi_view_people import PeopleOptions, ViewPeople, assign_people

__all__ = ["MultiEgoInputs", "MultiEgoRun", "MultiEgoRunOptions", "check_view_inputs",
           "multi_ego_sizes", "open_multi_ego", "pair_pictures", "per_view_offsets",
           "run_multi_ego", "wearer_rows"]

Views = list[Mapping[int, object]]
"""Per view, top first, ``{frame: record}`` with ``ids`` and ``boxes``."""


@dataclass(frozen=True)
class MultiEgoRunOptions:
    """What a multi-view run uses besides the boxes and the opened matcher.

    Attributes:
        box_files: the box files, top first (named in messages).
        model: how the matcher was named by the user (messages).
        top_images, hor_images: images of the top view and of each horizontal view, all or
            none (:func:`~xvmatch.inference.matching.learned_pipeline.open_view_images`); they
            need a matcher with an appearance network.
        cameras: per horizontal view, a camera file or folder with cameras ``top`` and ``ego``;
            they need a matcher that takes camera cues.
        image_size: ``(W, H)`` of every horizontal view's images, or None (from the images, the
            cameras or the boxes: :func:`multi_ego_sizes`).
        refine_top_camera: fit the top camera shared by the views' camera files on their boxes.
        camera_check: leave out a view's cameras that the boxes show wrong.
        appearance_check: judge each view's top-ego appearance cue on the pairs the box-only
            matcher is sure of, and use its boxes alone when its images are too weak to help.
        params: the spatial search's parameters (no matcher).
        workers: processes for the learned matcher's features (the same result for any number).
        people: how every frame's program is solved (:class:`PeopleOptions`).
    """

    box_files: tuple[str, ...]
    model: str | None = None
    top_images: str | None = None
    hor_images: tuple[str, ...] | None = None
    cameras: tuple[str, ...] | None = None
    image_size: tuple[int, int] | None = None
    refine_top_camera: bool = True
    camera_check: bool = True
    appearance_check: bool = True
    params: SpatialParams | None = None
    workers: int = 1
    people: PeopleOptions = field(default_factory=PeopleOptions)


@dataclass
class MultiEgoInputs:
    """The opened inputs of a run (:func:`open_multi_ego`); ``close`` them (or use ``with``).

    Attributes:
        views: per view, top first, ``{frame: record}``, in their own files' timing.
        images: per view (top first) an open image source, or None without images.
        cameras: per horizontal view its camera source, or None without cameras.
        given: per horizontal view, ``[(size, where it comes from)]`` of the sizes the inputs
            give (empty: none does).
        sources: the open image sources, closed by :meth:`close`.
    """

    views: Views
    images: list | None = None
    cameras: list | None = None
    given: list[list[tuple[tuple[int, int], str]]] = field(default_factory=list)
    sources: list = field(default_factory=list)

    def close(self) -> None:
        """Close every image source."""
        for source in self.sources:
            source.close()

    def __enter__(self) -> MultiEgoInputs:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class MultiEgoRun:
    """The answer of a multi-view run.

    Attributes:
        people: every box's person id (:class:`ViewPeople`, per view top first).
        frames: the frames solved (the views' timing once re-timed).
        refined: the cameras as refined (for ``--write-cameras``), or None.
        refinement: what became of the top camera, or None without refinement.
    """

    people: ViewPeople
    frames: list[int]
    refined: list | None
    refinement: CameraRefinement | None


def wearer_rows(top, camera_ids: Sequence[int] | None) -> list[dict[int, int]] | None:
    """Per horizontal view, ``{frame: row within the frame's record}`` of the top box with its
    ``--camera-id`` (``top``: a :class:`~xvmatch.formats.detection_rows.DetectionRows`); None
    without ids."""
    if camera_ids is None:
        return None
    out = []
    for camera_id in camera_ids:
        positions = top.positions_of_id(camera_id)
        if not positions:
            raise ValueError(f"{top.path}: no box has the --camera-id {camera_id}")
        out.append(positions)
    return out


def check_view_inputs(paths: Sequence[str], per_view: Mapping[str, Sequence | None],
                      most: int) -> None:
    """The box files (top first) and the options given once per horizontal view, checked: 1 to
    ``most`` horizontal files, no file named twice, each option of ``per_view`` (``{dest:
    values or None}``, ``hor_images`` for ``--hor-images``) one value per horizontal file."""
    n_hor = len(paths) - 1
    if not 1 <= n_hor <= most:
        raise ValueError(f"--hor: give 1 to {most} horizontal box files, got {n_hor}")
    for option, values in per_view.items():
        if values is not None and len(values) != n_hor:
            flag = "--" + option.replace("_", "-")
            raise ValueError(f"{flag}: give one per --hor file ({n_hor}), got {len(values)}")
    if len(set(map(str, map(Path, paths)))) != len(paths):
        raise ValueError("--top and --hor name the same file twice")


def per_view_offsets(values: Sequence, n_hor: int) -> list:
    """``--offset``: one value per horizontal view (a single one is for all)."""
    values = list(values)
    if len(values) == 1:
        return values * n_hor
    if len(values) != n_hor:
        raise ValueError(f"--offset: give one per --hor file ({n_hor}) or one for all, got "
                         f"{len(values)}")
    return values


def open_multi_ego(views: Views, matcher: LearnedMatcher | None,
                   options: MultiEgoRunOptions) -> MultiEgoInputs:
    """Open the images and the cameras of every view and check them (the top boxes inside the
    top images, each ego camera the size of its view's images); nothing is left open on an
    error."""
    n_hor = len(views) - 1
    given: list[list] = [[] for _ in range(n_hor)]
    if options.image_size is not None:
        given = [[(tuple(options.image_size), "--image-size")] for _ in range(n_hor)]
    inputs = MultiEgoInputs(views, given=given)
    try:
        if options.top_images is not None:
            inputs.images = _open_images(options, matcher, views, given, inputs.sources)
        if options.cameras is not None:
            inputs.cameras = _open_cameras(options, matcher, views, given)
    except BaseException:
        inputs.close()
        raise
    return inputs


def multi_ego_sizes(inputs: MultiEgoInputs, options: MultiEgoRunOptions
                    ) -> list[tuple[tuple[int, int], str]]:
    """Each horizontal view's image size and where it comes from
    (:func:`~xvmatch.formats.box_image_size.resolve_size`: given, else read from its boxes;
    boxes that do not fit the CVMHAT size are left to :func:`path_sizes`)."""
    views, paths = inputs.views, options.box_files
    past = runs_past_borders(*views)  # the run's files, made by one tracker or tool
    return [resolve_size(views[k + 1], paths[k + 1], inputs.given[k], ids=False, defer=True,
                         past=past) for k in range(len(views) - 1)]


def path_sizes(resolved: Sequence[tuple[tuple[int, int], str]], views: Views,
               paths: Sequence[str], ground: bool) -> list[tuple[int, int]]:
    """Each horizontal view's size for the path taken (``resolved`` by
    :func:`multi_ego_sizes`): a size not known (boxes alone that do not fit CVMHAT's) is
    refused unless the path is the ``ground``-map one, which guesses it."""
    if not ground:
        for k, (_, source) in enumerate(resolved):
            if source == UNKNOWN:
                raise unknown_size_error(views[k + 1], paths[k + 1])
    return [tuple(size) for size, _ in resolved]


def _open_images(options: MultiEgoRunOptions, matcher, views: Views, given, sources: list):
    """The images of every view (``sources``, top first, each added as it opens so that the
    caller closes them), their sizes added to ``given``; the top boxes checked against theirs."""
    if matcher.bundle.manifest.appearance is None:
        raise ValueError(f"{options.model}: a box-only matcher cannot use images; drop "
                         "the images or use a bundle with an appearance network")
    for v, path in enumerate([options.top_images, *options.hor_images]):
        source = open_view_images(path, views[v],
                                  [f for f in sorted(views[v]) if len(views[v][f])])
        sources.append(source)
        if v:
            given[v - 1].append((tuple(source.size), f"the horizontal images {path}"))
        else:
            check_boxes_in_image(views[0], tuple(source.size), options.box_files[0],
                                 f"the images {path}", ids=False, past=runs_past_borders(*views))
    return sources


def _open_cameras(options: MultiEgoRunOptions, matcher, views: Views, given) -> list:
    """The cameras of every horizontal view, each ego camera the size ``given`` names (else
    its size added to ``given``)."""
    if not matcher.bundle.manifest.uses_cameras:
        raise ValueError(f"{options.model}: this matcher takes no camera cues; drop "
                         "--cameras")
    paths = options.box_files
    cameras = []
    for k, path in enumerate(options.cameras):
        cams = open_cameras(path, sorted(views[k + 1]))
        for where, pair in cams.all():
            size = tuple(pair.hor.image_size)
            if given[k] and tuple(given[k][0][0]) != size:
                want = given[k][0][0]
                raise ValueError(f"{where}: camera 'ego' is {size[0]}x{size[1]} but "
                                 f"{paths[k + 1]}'s images are {want[0]}x{want[1]} "
                                 f"(from {given[k][0][1]})")
            if not given[k]:
                given[k].append((size, f"the camera files {path}"))
        cameras.append(cams)
    return cameras


def run_multi_ego(
    inputs: MultiEgoInputs,
    matcher: LearnedMatcher | None,
    sizes: Sequence[tuple[int, int]],
    offsets: Sequence[int],
    camera_rows: Sequence[Mapping[int, int]] | None,
    options: MultiEgoRunOptions,
    progress: Callable[[int], Callable[[Iterable[int]], Iterable[int]]] | None = None,
    on_refinement: Callable[[CameraRefinement], None] | None = None,
    on_camera_check: Callable[[int, CameraCheck], None] | None = None,
    on_appearance_check: Callable[[int, AppearanceCheck], None] | None = None,
    tracks: Sequence[Mapping[int, int]] | None = None,
    on_wandering: Callable[[int, str], None] | None = None,
) -> MultiEgoRun:
    """Person ids for every box of the opened views.

    Args:
        inputs: the opened views (:func:`open_multi_ego`).
        matcher: the learned top-ego matcher, or None (the spatial search).
        sizes: each horizontal view's image size (:func:`multi_ego_sizes`).
        offsets: each horizontal view's offset: top frame ``t + N_k`` shows the moment of its
            frame ``t``; the rows keep their own frame numbers.
        camera_rows: per horizontal view, ``{frame: row of its wearer in the top record}`` (in
            the top file's timing), or None.
        options: :class:`MultiEgoRunOptions`.
        progress: ``progress(n_frames)`` wraps the frames whose costs are built.
        on_refinement: told what became of the top camera.
        on_camera_check: told each view's camera check (``view`` counts from 1, top 0).
        on_appearance_check: told each view's appearance check, in the order of the views.
        tracks: per view (top first) ``{row id: track id}`` for video mode
            (:func:`~xvmatch.inference.views.multi_ego_video.video_people`), or None.
        on_wandering: in video mode, told ``(view, line)`` for each horizontal view (its wearer
            not given, no cameras) whose search put its camera at one top-view track in too few
            frames (:func:`~xvmatch.inference.matching.search_camera.wandering_camera_note`).
    """
    views, images, cameras = inputs.views, inputs.images, inputs.cameras
    frames = sorted(set().union(*views))
    refinement = None
    if cameras is not None and options.refine_top_camera:
        cameras, refinement = refine_views_cameras(
            cameras, views[0], views[1:], [sorted(v) for v in views[1:]], offsets)
        if on_refinement is not None:
            on_refinement(refinement)
    refined = cameras
    if any(offsets):
        views, images, cameras, camera_rows, frames = _aligned(views, offsets, images, cameras,
                                                               camera_rows)
    if refinement is not None and options.camera_check:
        cameras = _checked_cameras(matcher, views, sizes, cameras, refinement, options,
                                   on_camera_check)
    checked: dict = {}
    searched: dict[int, dict[int, int]] | None = (
        {} if tracks is not None and on_wandering is not None else None)
    problems = multi_view_costs(
        views, sizes, frames, matcher=matcher,
        appearance=matcher if images is not None else None, images=images,
        cameras=cameras, camera_rows=camera_rows, params=options.params,
        workers=options.workers, progress=progress(len(frames)) if progress else None,
        appearance_check=options.appearance_check, checked=checked, searched=searched,
    )
    if searched:  # each view's O followed by the top view's tracks (search_camera)
        from xvmatch.inference.matching.search_camera import (
            followed_cameras,
            wandering_camera_note,
        )

        for k, found in sorted(searched.items()):
            if cameras is not None and cameras[k - 1] is not None:
                continue
            ids = followed_cameras(views[0], found, video=True)  # rows' ids, then their tracks
            said = wandering_camera_note({f: tracks[0].get(i, i) for f, i in ids.items()})
            if said is not None:
                on_wandering(k, said)
    for k, check in sorted(checked.items()):
        if on_appearance_check is not None:
            on_appearance_check(k, check)
    if tracks is not None:
        from xvmatch.inference.views.multi_ego_video import video_people

        people = video_people(views, problems, frames, tracks, options.people)
    else:
        people = assign_people(views, problems, frames, options.people)
    return MultiEgoRun(people, frames, refined, refinement)


def _aligned(views, offsets, images, cameras, camera_rows):
    """Every view (and its images and cameras) re-timed so that top frame ``t + N_k`` and frame
    ``t`` of horizontal view ``k`` share a number (:func:`xvmatch.formats.mot_boxes.
    align_frames`); the rows keep their own frame numbers in the output."""
    views, shifts = align_frames(views, offsets)
    if images is not None:  # aligned frame f shows the source's frame f - shift
        images = [retimed(x, -m) for x, m in zip(images, shifts, strict=True)]
    if cameras is not None:
        cameras = [retimed(x, -m) for x, m in zip(cameras, shifts[1:], strict=True)]
    if camera_rows is not None:
        camera_rows = [{f + shifts[0]: r for f, r in rows.items()} for rows in camera_rows]
    return views, images, cameras, camera_rows, sorted(set().union(*views))


def _checked_cameras(matcher, views, sizes, cameras, refinement: CameraRefinement,
                     options: MultiEgoRunOptions, on_camera_check) -> list:
    """The cameras after the camera check (``views`` aligned): a view whose cameras fail is
    matched without them (None)."""
    cameras = list(cameras)
    for k in range(len(views) - 1):
        check = check_run_cameras(views[0], views[k + 1], sorted(views[k + 1]),
                                  matcher, tuple(sizes[k]), cameras[k],
                                  float(matcher.gamma), refinement.fit_loss,
                                  workers=options.workers, moving=refinement.moving)
        if on_camera_check is not None:
            on_camera_check(k + 1, check)
        if not check.trusted:
            cameras[k] = None
    return cameras


def pair_pictures(inputs: MultiEgoInputs, people: ViewPeople, offsets: Sequence[int]) -> list:
    """What :func:`~xvmatch.viz.match_pictures.write_match_pictures` draws of each (top,
    horizontal view) pair (``associate-multi --draw``): per horizontal view ``k``, ``(top, hor,
    pairs, frames, sources)`` on view ``k``'s own frame numbers (the top view re-timed by its
    offset, as ``associate --draw`` draws), each record's ids the boxes' person ids (so the
    labels name the people, one number in every view) and the pairs ``(id, id)`` of the people
    both views hold; ``sources`` the images (the top ones re-timed) or None."""
    views, images = inputs.views, inputs.images
    named = [{f: FrameBoxes(f, np.array([people.person[v].get(r, -1) for r in rec.ids.tolist()],
                                        dtype=np.int64), rec.boxes) for f, rec in view.items()}
             for v, view in enumerate(views)]
    out = []
    for k in range(1, len(views)):
        top, hor = shift_frames(named[0], offsets[k - 1]), named[k]
        frames = sorted(f for f in set(top) & set(hor) if len(top[f].ids) and len(hor[f].ids))
        pairs = {f: [(p, p) for p in sorted(set(top[f].ids.tolist()) & set(hor[f].ids.tolist()))
                     if p >= 0] for f in frames}
        sources = (None if images is None else
                   {"top": retimed(images[0], int(offsets[k - 1])), "hor": images[k]})
        out.append((top, hor, pairs, frames, sources))
    return out
