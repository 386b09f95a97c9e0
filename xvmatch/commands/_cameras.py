"""The cameras on the command line. ``--top-view`` of ``xvmatch associate``: a nadir top camera
(today's search and learned matcher read its image as the ground) or an oblique one, calibrated
from its people, with the horizontal camera registered on its ground map
(:mod:`xvmatch.inference.matching.ground_association`); ``auto`` lets the top view's boxes
decide. With calibrated cameras (``--cameras``): the top camera's refinement, the cameras' check
and ``--write-cameras`` (``associate``, ``track``, ``adapt``, ``associate-multi``, read through
:class:`~xvmatch.commands._model.ModelArgs`). And the horizontal camera's image size a learned
run's options give (:func:`horizontal_size`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np

from xvmatch.commands._options import HOR_IMAGE_SIZE, UsageError, check_images_together
from xvmatch.commands._types import float_in
from xvmatch.core.output_paths import Output, check_own_folder

if TYPE_CHECKING:
    from xvmatch.commands._model import ModelArgs

__all__ = ["CAMERAS_COMMAND", "add_camera_check", "add_refine_top_camera",
           "add_top_view_arguments", "add_write_cameras", "check_top_view",
           "check_write_cameras", "horizontal_size", "note_camera_check",
           "note_camera_refinement", "oblique_pairs", "write_cameras"]


def add_top_view_arguments(p: argparse._ActionsContainer) -> None:
    """``--top-view``, ``--top-image-size``, ``--hor-hfov``, ``--fps`` (on a parser or a group)."""
    p.add_argument(
        "--top-view", choices=("auto", "nadir", "oblique"), default="auto",
        help="nadir (looking straight down), oblique (at an angle; calibrated from its "
        "people) or auto (default: the boxes or --cameras decide)")
    p.add_argument("--top-image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help="the top view's image size, 8..65536 a side; oblique needs it, auto "
                   "takes the smallest common video size holding the top boxes")
    p.add_argument("--hor-hfov", default=70.0, metavar="DEG",
                   type=float_in(20, 150, "a camera's horizontal field of view, degrees"),
                   help="oblique: the horizontal camera's field of view, degrees in [20, 150] "
                   "(default 70: a phone's, a drone's)")
    p.add_argument("--fps", default=30.0,
                   type=float_in(0.1, 1000, "a camera's frame rate, frames per second"),
                   help="oblique: the frame rate, in [0.1, 1000] (default 30)")


def check_top_view(args: argparse.Namespace) -> None:
    """``--top-view`` and its options, before any work."""
    if args.top_view == "oblique":
        if args.top_image_size is None:
            raise UsageError("--top-view oblique calibrates the top camera from its people: "
                             "give --top-image-size WxH")
        if args.cameras is not None:
            raise UsageError("--top-view oblique estimates the cameras from the people: drop "
                             "--cameras, or use --top-view nadir with them")


def _guessed_top_size(args: argparse.Namespace, top: dict) -> tuple[int, int] | None:
    """The top view's size when ``--top-image-size`` is not given: where its people stand
    upright (an oblique camera, which the nadir search would misread), the smallest common video
    size holding its boxes, said in one line; None (today's nadir path) for squat boxes, or
    boxes no common size holds (a note saying what to give)."""
    from xvmatch.formats.box_image_size import common_size_holding
    from xvmatch.formats.mot_boxes import stack_frames
    from xvmatch.geometry.people_calibration import STEEP_ASPECT

    boxes = stack_frames(top)[2]
    if not len(boxes):
        return None
    aspect = float(np.median(boxes[:, 3] / np.maximum(boxes[:, 2], 1e-9)))
    if aspect < STEEP_ASPECT:
        return None
    size = common_size_holding(top)
    if not args.quiet:
        said = (f"took {size[0]}x{size[1]}, the smallest common video size holding its boxes, as"
                " its size; give --top-image-size WxH if not" if size is not None else
                "no common video size holds its boxes: give --top-image-size WxH to calibrate "
                "it from its people")
        print(f"xvmatch: note: the top view's people stand upright (boxes {aspect:.1f} times as "
              f"tall as wide): an oblique camera; {said}", file=sys.stderr)
    return size


def oblique_pairs(args: argparse.Namespace, top: dict, hor: dict,
                  hor_size: tuple[int, int], video: bool) -> dict | None:
    """The pairs of the ground-map association when the top view is oblique (forced, or found
    so by ``auto``), else None (today's path); prints the one line saying what was assumed.
    ``video``: the pairs are made consistent along each view's tracks."""
    if args.top_view == "nadir" or args.cameras is not None:
        return None
    top_size = args.top_image_size or _guessed_top_size(args, top)
    if top_size is None:
        return None
    from xvmatch.formats.box_image_size import check_boxes_in_image
    from xvmatch.inference.matching.ground_association import (
        GroundAssociationOptions,
        run_top_view,
    )

    source = "--top-image-size" if args.top_image_size else "the top boxes' extent"
    check_boxes_in_image(top, top_size, args.top, source)
    options = GroundAssociationOptions(top_size=top_size, hor_size=hor_size,
                                       hor_hfov_deg=args.hor_hfov, fps=args.fps,
                                       consensus=video, seed=0)
    run = run_top_view(top, hor, options, args.top_view, name=args.top)
    if run is None:
        if not args.quiet:
            print("xvmatch: note: top view: looking straight down (its boxes are as wide as "
                  "tall); associating as over a nadir drone", file=sys.stderr)
        return None
    if not args.quiet:
        unused = [name for name, given in (("--model", args.model is not None),
                                           ("--camera-id", args.camera_id is not None),
                                           ("--search", args.search is not None)) if given]
        ignored = f" ({', '.join(unused)}: not used on this path)" if unused else ""
        mode = ("pairs made consistent over the clip with each view's track ids" if
                options.consensus else "each frame on its own (--mode video: consistent over "
                "the clip)")
        print(f"xvmatch: note: {run.summary}; {mode}{ignored}", file=sys.stderr)
    return run.pairs


def add_refine_top_camera(group) -> None:
    """Add ``--refine-top-camera`` (``associate``, ``track``, ``adapt``)."""
    group.add_argument(
        "--refine-top-camera", choices=("auto", "off"), default="auto",
        help="with --cameras: turn the top camera so both views' people line up, when clear, "
        "saying so (default auto; off: as given)")


CAMERAS_COMMAND = "xvmatch --write-cameras"
"""The marker of a camera folder ``--write-cameras`` made (it replaces only its own)."""


def add_write_cameras(group, several: bool = False) -> None:
    """Add ``--write-cameras`` (``associate``, ``track``; ``several``: one per ``--cameras``,
    ``associate-multi``)."""
    group.add_argument(
        "--write-cameras", default=None, metavar="PATH", nargs="+" if several else None,
        help=("with --cameras: also write them as refined, in --cameras' form (a file, or a "
              "new, empty or earlier --write-cameras folder)")
        + ("; one per --cameras, in their order" if several else ""))


def _listed(value) -> list:
    """An option's value as a list: ``[]`` for None, one item for a single value."""
    return [] if value is None else list(value) if isinstance(value, list) else [value]


def check_write_cameras(opts: ModelArgs) -> list[Output]:
    """``--write-cameras``' outputs for :func:`~xvmatch.core.output_paths.check_outputs`,
    after refusing them without ``--cameras``, not one per ``--cameras``, or with
    ``--refine-top-camera off``, and a folder that is neither new, empty nor its own."""
    paths = _listed(opts.write_cameras)
    given = _listed(opts.cameras)
    if not paths:
        return []
    if not given:
        raise UsageError("--write-cameras writes the cameras of --cameras as refined: give "
                         "--cameras")
    if len(paths) != len(given):
        raise UsageError(f"--write-cameras: one path per --cameras ({len(given)}), got "
                         f"{len(paths)}")
    if opts.refine_top_camera == "off":
        raise UsageError("--write-cameras writes the cameras as refined: drop "
                         "--refine-top-camera off (else they are --cameras as given)")
    outputs = []
    for path, cameras in zip(paths, given, strict=True):
        folder = os.path.isdir(cameras)
        if folder:
            check_own_folder(path, CAMERAS_COMMAND, "--write-cameras")
        outputs.append(Output("--write-cameras", path, folder=folder))
    return outputs


def add_camera_check(group) -> None:
    """Add ``--camera-check`` (``associate``, ``track``, ``adapt``, ``associate-multi``)."""
    group.add_argument(
        "--camera-check", choices=("on", "off"), default="on",
        help="with --cameras that fit poorly: drop them if they contradict the pairs the boxes "
        "alone are sure of (6 s+ videos; default on)")


def note_camera_check(check, quiet: bool, prefix: str = "") -> None:
    """Print the camera check's line: when it had a run of frames to judge on, and with
    ``quiet`` only when the cameras were left out."""
    if check is not None and check.to_tell(quiet):
        print(f"{prefix}{check.message()}", file=sys.stderr)


def note_camera_refinement(refinement, quiet: bool) -> None:
    """Print what became of the top camera: always when it was turned, else unless quiet."""
    if refinement is not None and (refinement.turned or not quiet):
        print(refinement.message, file=sys.stderr)


def write_cameras(opts: ModelArgs, cameras, refinement) -> None:
    """Write ``--write-cameras`` (when given): ``cameras``, the run's
    :class:`~xvmatch.formats.camera_frames.CameraFrames` as refined (a list, one per path,
    for ``associate-multi``), in ``--cameras``' form
    (:func:`~xvmatch.formats.camera_frames.write_camera_frames`); say what they hold unless
    quiet."""
    from xvmatch.formats.camera_frames import write_camera_frames

    paths = _listed(opts.write_cameras)
    if not paths:
        return
    counts = []
    for path, cams in zip(paths, _listed(cameras), strict=True):
        written = write_camera_frames(cams, path, CAMERAS_COMMAND, "--write-cameras")
        if written is not None:
            counts.append(f"{path}: {written} camera files, one per frame of its --cameras")
    if not opts.quiet:
        turned = refinement is not None and refinement.turned
        what = (f"the {'moving ' if refinement.moving else ''}top camera turned "
                f"{refinement.fit.angle_deg:.2f} degrees" if turned
                else "the top camera as given")
        print(f"cameras: wrote {', '.join(map(str, paths))} ({what})"
              + "".join(f"; {c}" for c in counts), file=sys.stderr)


def horizontal_size(opts: ModelArgs, hor: Mapping) -> tuple[tuple[int, int], str]:
    """The horizontal image size and where it comes from: ``--image-size``, the
    ``--hor-images`` and the ``--cameras`` file's ego camera must agree when given
    (:func:`~xvmatch.formats.camera_frames.given_hor_sizes`); with none, CVMHAT's
    2688x1512 when the boxes are consistent with it (a note on stderr), else an error asking
    for ``--image-size``. Every horizontal box must lie in it."""
    from xvmatch.formats.box_image_size import resolve_size
    from xvmatch.formats.camera_frames import given_hor_sizes

    check_images_together(opts.top_images, opts.hor_images)
    learned = opts.model is not None
    given = given_hor_sizes(opts.image_size, opts.hor_images if learned else None,
                            opts.cameras if learned else None, sorted(hor))
    return resolve_size(hor, "the horizontal boxes" if opts.hor is None else opts.hor, given)
