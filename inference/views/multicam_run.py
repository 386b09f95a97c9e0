"""The multicam run: several static cameras' boxes to one global id per person and each person's
ground path, in one call with its options in one typed record.

:func:`run_multicam` estimates the cameras from their people when none are given
(:func:`~xvmatch.inference.views.multicam_from_people.estimate_cameras`), checks the boxes
against their cameras (a box entirely outside its image, a foot point above the horizon: the
file and its line), leaves out the boxes above the horizon when
asked (each keeps a global id of its own), opens the images of the cameras that have them and
embeds their boxes with a bundle's appearance network, runs
:func:`~xvmatch.inference.views.multicam.associate_cameras`, relabels the boxes and localises the
people (foot points, or :func:`~xvmatch.inference.views.multicam_localisation.localise`); the
image sources are closed, also on an error. :func:`fit_ground_cameras` makes ``H`` cameras from
image/ground point pairs. Bad input raises ``ValueError`` with one line; the lines name the
command-line options that supply each input (``--images``, ``--model``).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from contextlib import AbstractContextManager, nullcontext
from dataclasses import dataclass, field, replace

import numpy as np

from xvmatch.formats.box_image_size import box_line
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera, fit_homography, foot_points
from xvmatch.inference.matching.learned_association import LearnedMatcher, load_matcher_bundle
from xvmatch.inference.matching.learned_pipeline import open_view_images
from xvmatch.inference.views.multicam import (
    BoxEmbedder,
    MulticamInputError,
    MulticamOptions,
    MulticamResult,
    associate_cameras,
    relabel,
)
from xvmatch.inference.views.multicam_from_people import EstimatedCameras, estimate_cameras
from xvmatch.inference.views.multicam_localisation import LocalisationOptions, localise

__all__ = [
    "MANY_IDS_RATIO",
    "SHORT_FRAMES",
    "MulticamRun",
    "MulticamRunOptions",
    "association_options",
    "check_box_cameras",
    "check_image_sizes",
    "fit_ground_cameras",
    "many_ids_note",
    "run_multicam",
]

Boxes = Mapping[str, Mapping[int, FrameBoxes]]
"""``{camera: {frame: FrameBoxes}}``: each camera's boxes with its own track ids."""


@dataclass(frozen=True)
class MulticamRunOptions:
    """What a multicam run uses besides the cameras and the boxes.

    Attributes:
        association: the association's parameters (:class:`MulticamOptions`).
        box_files: ``{camera: box file}``, named with the line of a box at fault.
        cameras_file: the cameras file, named when a camera's images are of another size.
        above_horizon: ``"error"``: a box whose foot point lies at or above its camera's
            horizon is an error; ``"drop"``: it takes no part (a warning per camera) and its
            track gets a global id of its own.
        localise: ground positions from ``"foot"`` (the fused foot points), ``"two-best"``
            or ``"all"`` views (:func:`~xvmatch.inference.views.multicam_localisation.localise`).
        images: ``{camera: images}`` (a folder, a glob or a video, the camera's size) of the
            cameras whose boxes are also compared by appearance; empty: geometry only.
        model: the bundle whose appearance network embeds the boxes of ``images``.
        image_sizes: ``{camera: (width, height)}`` of each camera's images, needed when the
            run estimates the cameras from their people (:func:`run_multicam` without
            cameras).
    """

    association: MulticamOptions = field(default_factory=MulticamOptions)
    box_files: Mapping[str, str] = field(default_factory=dict)
    cameras_file: str = ""
    above_horizon: str = "error"
    localise: str = "foot"
    images: Mapping[str, str] = field(default_factory=dict)
    model: str = "default"
    image_sizes: Mapping[str, tuple[int, int]] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.above_horizon not in ("error", "drop"):
            raise ValueError(f"above_horizon must be 'error' or 'drop', got "
                             f"{self.above_horizon!r}")
        if self.localise not in ("foot", "two-best", "all"):
            raise ValueError(f"localise must be 'foot', 'two-best' or 'all', got "
                             f"{self.localise!r}")


def association_options(method: str = "ours", split_frames: int | str | None = None,
                        appearance_weight: float | None = None) -> MulticamOptions:
    """The association's options of the command line's ``--method``, ``--split-frames``
    (``"auto"``: split on evidence, probing with pieces of 20 frames; ``L``: fixed pieces of
    ``L`` frames, 0 whole tracks; None: ``"auto"`` with ``ours``, 0 with ``dtw``, the paper's
    M1) and ``--appearance-weight`` (None: the default)."""
    if split_frames is None:
        split_frames = 0 if method == "dtw" else "auto"
    options = MulticamOptions(method=method, split="evidence") if split_frames == "auto" else \
        MulticamOptions(method=method, split_frames=int(split_frames), split="fixed")
    if appearance_weight is not None:
        options = replace(options, appearance_weight=appearance_weight)
    return options


def check_box_cameras(files: Mapping[str, str], cameras: Mapping[str, GroundCamera],
                      cameras_file: str) -> None:
    """Every camera of the box files ``{camera: path}`` is one of ``cameras`` (read from
    ``cameras_file``); else ``ValueError`` naming ``--boxes NAME=FILE``."""
    for name, path in files.items():
        if name not in cameras:
            raise ValueError(f"--boxes {name}={path}: camera {name} is not in {cameras_file} "
                             f"(it has {', '.join(cameras)})")


@dataclass(frozen=True)
class MulticamRun:
    """The answer of a multicam run.

    Attributes:
        result: the association (global ids, each person's ground path in ``result.ground``).
        relabelled: every input box in its place, the track id replaced by its global id.
        cameras: the cameras the association ran on (given, or estimated).
        estimated: the cameras' estimate from their people (its ``summary()`` and
            ``records()``), None when they were given.
    """

    result: MulticamResult
    relabelled: dict[str, dict[int, FrameBoxes]]
    cameras: Mapping[str, GroundCamera] = field(default_factory=dict)
    estimated: EstimatedCameras | None = None


def check_image_sizes(names: Iterable[str], options: MulticamRunOptions) -> None:
    """Without cameras each camera is calibrated from its people and needs its image size:
    raise ``ValueError`` naming the cameras of ``names`` that have none in ``options``."""
    missing = [n for n in names if n not in options.image_sizes]
    if missing:
        raise ValueError("without --cameras each camera is calibrated from its people: give "
                         "--image-size NAME=WxH for " + ", ".join(missing))


def run_multicam(cameras: Mapping[str, GroundCamera] | None, boxes: Boxes,
                 options: MulticamRunOptions,
                 progress: Callable[[int], AbstractContextManager] | None = None,
                 warn: Callable[[str], None] | None = None,
                 note: Callable[[str], None] | None = None) -> MulticamRun:
    """One global id per person across the cameras, and each person's ground path.

    Args:
        cameras: ``{name: GroundCamera}``, one for each camera of ``boxes``; None: each
            camera calibrated from its people and the cameras registered to one another
            (:func:`~xvmatch.inference.views.multicam_from_people.estimate_cameras`, each
            camera's size from ``options.image_sizes``), the estimate in the answer.
        boxes: each camera's boxes, at least two cameras.
        options: :class:`MulticamRunOptions`.
        progress: ``progress(n_pairs)``: a context (a progress bar) whose ``update(1)`` is
            called after each camera pair, entered for the association only.
        warn: told each camera's boxes left out above its horizon (``above_horizon="drop"``).
        note: told that a site bundle's adaptation is not used, and when the global ids are
            many more than the people any camera sees at once (:func:`many_ids_note`; None:
            said nowhere).

    Raises:
        ValueError: a box outside its image or above its horizon (the file and its line),
            images of another size than their camera or lacking a frame, a box-only bundle;
            without cameras, a camera without an image size, or cameras that cannot be
            estimated from their people
            (:class:`~xvmatch.inference.views.multicam_from_people.RegistrationError`).
    """
    estimated = None
    if cameras is None:
        check_image_sizes(boxes, options)
        estimated = estimate_cameras(boxes, {n: options.image_sizes[n] for n in boxes})
        cameras = estimated.cameras
    for name, frames in boxes.items():
        _check_inside(options.box_files.get(name, name), frames, cameras[name])
    kept, above = boxes, {}
    if options.above_horizon == "drop":
        kept, above = _drop_above_horizon(boxes, cameras, options.box_files, warn)
    sources, embedders = _open_images(options, kept, cameras, note)
    try:
        n_pairs = len(boxes) * (len(boxes) - 1) // 2
        try:
            with progress(n_pairs) if progress is not None else nullcontext() as bar:
                result = associate_cameras(cameras, kept, options.association,
                                           progress=bar.update if bar is not None else None,
                                           appearance=embedders or None)
        except MulticamInputError as exc:
            path = options.box_files.get(exc.camera, exc.camera)
            line = box_line(path, exc.frame, exc.box) if exc.box is not None else None
            raise ValueError(f"{path}{'' if line is None else f':{line}'}: {exc}") from None
    finally:
        for source in sources:
            source.close()
    relabelled = relabel(kept, result)
    if above:
        relabelled = _put_back(boxes, relabelled, above, max(result.ground, default=0))
    if options.localise != "foot":
        method = "two_best" if options.localise == "two-best" else "all"
        ground = localise(cameras, relabelled, result.ground, LocalisationOptions(method))
        result = replace(result, ground=ground)
    if note is not None and (line := many_ids_note(result.ground, boxes)):
        note(line)
    return MulticamRun(result, relabelled, cameras, estimated)


MANY_IDS_RATIO = 2.0
"""Global ids above this many times the most boxes any camera holds in one frame earn a note:
a person seen by some camera gets one id, so many more ids than people seen at once means
people's tracks did not join (simulated scenes of 7 cameras, 20 people: 25-30 ids for at most
20 boxes a frame with clean tracks; 836 with ``xvmatch noise``'s defaults, 808 of them under
10 frames)."""

SHORT_FRAMES = 10
"""A global id seen on fewer ground frames than this is counted as short in the note."""


def many_ids_note(ground: Mapping[int, tuple[np.ndarray, np.ndarray]], boxes: Boxes) -> str:
    """A one-line note when the global ids of ``ground`` (``{global_id: (frames, xy)}``) are
    many more (:data:`MANY_IDS_RATIO`) than the most boxes one camera holds in one frame, else
    ``""``.

    Why: with false boxes or a tracker's broken tracks every short track that no other camera
    confirms keeps a global id of its own, and a count such as "550 global ids" for 16 people
    reads as a result rather than as a symptom.
    """
    most = max((len(rec.ids) for frames in boxes.values() for rec in frames.values()),
               default=0)
    if most == 0 or len(ground) <= MANY_IDS_RATIO * most:
        return ""
    short = sum(len(frames) < SHORT_FRAMES for frames, _xy in ground.values())
    return (f"{len(ground)} global ids ({short} of them on fewer than {SHORT_FRAMES} frames), "
            f"while no camera sees more than {most} people at once: likely false boxes or a "
            "tracker's broken tracks (a short track that no other camera confirms keeps an id "
            "of its own); leave short tracks out of the box files, or use a tracker that keeps "
            "ids longer")


def _check_inside(path: str, frames: Mapping[int, FrameBoxes], camera: GroundCamera) -> None:
    """A box entirely outside its camera's image is an error (the boxes and the camera's
    ``width`` and ``height`` do not belong together). Boxes past a border only in part are
    kept: a jittered detection of a near person at the border is one (the two-view rule 3 of
    docs/formats.md, 10% past a border, refuses some of ``xvmatch noise``'s output here)."""
    W, H = camera.width, camera.height
    for f in sorted(frames):
        b = frames[f].boxes
        bad = (b[:, 0] >= W) | (b[:, 1] >= H) | (b[:, 0] + b[:, 2] <= 0) | \
            (b[:, 1] + b[:, 3] <= 0)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            line = box_line(path, f, b[k])
            raise ValueError(f"{path}{'' if line is None else f':{line}'}: frame {f}, id "
                             f"{frames[f].ids[k]}: the box lies entirely outside the camera's "
                             f"{W}x{H} image; check the camera's width and height")


def _drop_above_horizon(boxes: Boxes, cameras: Mapping[str, GroundCamera],
                        files: Mapping[str, str], warn: Callable[[str], None] | None):
    """Each camera's boxes without those whose foot point lies at or above its horizon, and
    ``{camera: {frame: mask of the dropped}}``; one warning per camera."""
    kept: dict[str, dict[int, FrameBoxes]] = {}
    above: dict[str, dict[int, np.ndarray]] = {}
    for name, frames in boxes.items():
        kept[name], above[name], n = {}, {}, 0
        for f, rec in frames.items():
            _, ok = cameras[name].to_ground(foot_points(rec.boxes))
            kept[name][f] = FrameBoxes(f, rec.ids[ok], rec.boxes[ok])
            above[name][f] = ~ok
            n += int((~ok).sum())
        if n and warn is not None:
            warn(f"{files.get(name, name)}: {n} box(es) whose foot point lies above camera "
                 f"{name}'s horizon take no part (each gets a global id of its own)")
    return kept, above


def _put_back(boxes: Boxes, relabelled: Mapping[str, Mapping[int, FrameBoxes]],
              above: Mapping[str, Mapping[int, np.ndarray]], last_id: int
              ) -> dict[str, dict[int, FrameBoxes]]:
    """The dropped boxes back in their places, a new global id per (camera, track id)."""
    out: dict[str, dict[int, FrameBoxes]] = {}
    fresh: dict[tuple[str, int], int] = {}
    for name, frames in boxes.items():
        out[name] = {}
        for f, rec in frames.items():
            ids = np.empty(len(rec), dtype=np.int64)
            mask = above[name][f]
            ids[~mask] = relabelled[name][f].ids
            for k in np.flatnonzero(mask):
                key = (name, int(rec.ids[k]))
                if key not in fresh:
                    fresh[key] = last_id + 1 + len(fresh)
                ids[k] = fresh[key]
            out[name][f] = FrameBoxes(f, ids, rec.boxes)
    return out


def _open_images(options: MulticamRunOptions, boxes: Boxes,
                 cameras: Mapping[str, GroundCamera], note: Callable[[str], None] | None):
    """Each camera of ``options.images``: its open image source (every frame with boxes
    checked, its size the camera's) and embedder ``(frame, boxes) -> descriptors`` with the
    model's appearance network; nothing without images."""
    if not options.images:
        return [], {}
    matcher = load_matcher_bundle(options.model)
    if matcher.bundle.manifest.appearance is None:
        raise ValueError(f"--model {options.model}: a box-only bundle has no appearance "
                         "network; use one with images (e.g. default)")
    if matcher.bundle.adaptation is not None and note is not None:
        note(f"--model {options.model}: its site adaptation is for top/horizontal view pairs; "
             "multicam compares raw descriptors")
    sources, embedders = [], {}
    try:
        for name, path in options.images.items():
            frames = boxes[name]
            source = open_view_images(path, frames, [f for f in sorted(frames) if len(frames[f])])
            sources.append(source)
            cam = cameras[name]
            if tuple(source.size) != (cam.width, cam.height):
                raise ValueError(f"--images {name}={path}: the images are "
                                 f"{source.size[0]}x{source.size[1]} but camera {name} is "
                                 f"{cam.width}x{cam.height} in "
                                 f"{options.cameras_file or '--image-size'}")
            embedders[name] = _embedder(source, matcher)
    except BaseException:
        for source in sources:
            source.close()
        raise
    return sources, embedders


def _embedder(source, matcher: LearnedMatcher) -> BoxEmbedder:
    """``embed(frame, boxes)``: the matcher's descriptors of the boxes on the source's image of
    the frame (the last image read is kept: the association asks frame by frame)."""
    last: dict = {}

    def embed(frame: int, boxes: np.ndarray) -> np.ndarray:
        if last.get("frame") != frame:
            last["frame"], last["image"] = frame, source.get(frame)
        return matcher.descriptors(last["image"], boxes)

    return embed


def fit_ground_cameras(points: Mapping[str, np.ndarray],
                       sizes: Mapping[str, tuple[int, int]], path: str | os.PathLike
                       ) -> dict[str, GroundCamera]:
    """One ``H`` camera per camera of ``points`` (``{camera: (N, 4) u, v, X, Y}``, pixels and
    ground metres, 4 or more pairs), fitted with OpenCV; ``sizes`` gives each camera's image
    size, ``path`` the points' file named in messages.

    Raises:
        ValueError: a camera without a size, too few pairs, points in line, a horizon across
            them (one line each, naming the camera).
    """
    cams = {}
    for name, arr in points.items():
        if name not in sizes:
            raise ValueError(f"--image-size: camera {name} of {path} has no size; give "
                             f"--image-size {name}=WxH")
        try:
            cams[name] = GroundCamera(fit_homography(arr[:, :2], arr[:, 2:], *sizes[name]),
                                      *sizes[name])
        except ValueError as exc:
            raise ValueError(f"{path}: camera {name}: {exc}") from None
    return cams
