"""Options and helpers shared by the ``xvmatch`` commands (every ``cli_*`` module uses them).

Each option is defined here once: the box inputs (``--top``, ``--hor``, ``--duplicates``, and
how box files are read, ``--min-score`` and ``--first-frame``, live in
:mod:`xvmatch.commands._box_reading` and are re-exported here), the spatial-distribution
parameters (``--rho --lam --tau --dtheta --fov``, read back by :func:`spatial_params`), the
image inputs (``--top-images``, ``--hor-images``, checked together by
:func:`check_images_together`), the horizontal ``--image-size``'s type and help, and the
pictures (``--draw`` and its companions: :func:`add_draw_arguments`, :func:`draw_pictures`).
With them come the sub-command parser (:func:`add_command_parser`), the progress bar
(:func:`progress_bar`), the box readers that print the reader's notes and warnings
(:func:`read_boxes`, :func:`read_detections`) and :class:`UsageError`. Output paths are checked
by :mod:`xvmatch.core.output_paths`; :func:`image_inputs` lists the images as its inputs.

Nothing here imports :mod:`xvmatch.cli` (the root imports the command modules, never the
reverse), and nothing heavy is imported until a command runs.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Mapping

from xvmatch.commands._box_reading import (
    BoxReading,
    add_box_inputs,
    add_box_reading_options,
    box_reading,
    check_camera_id,
    read_boxes,
    read_detections,
)
from xvmatch.commands._types import float_in, image_size, int_in
from xvmatch.core.output_paths import Input

__all__ = [
    "DRAW_COMMAND",
    "HOR_IMAGE_SIZE",
    "IMAGE_SIZE_HELP",
    "BoxReading",
    "UsageError",
    "add_box_inputs",
    "add_box_reading_options",
    "add_command_parser",
    "add_draw_arguments",
    "add_image_options",
    "add_spatial_options",
    "box_reading",
    "check_camera_id",
    "check_images_together",
    "draw_pictures",
    "frame_progress",
    "image_inputs",
    "progress_bar",
    "read_boxes",
    "read_detections",
    "short_offset_help",
    "spatial_params",
]


class UsageError(Exception):
    """A user mistake reported as one line, without a traceback."""


def add_command_parser(subparsers, name: str, help_text: str, example: str,
                       description: str | None = None,
                       usage: str | None = None) -> argparse.ArgumentParser:
    """Register the sub-command ``name`` on ``subparsers``: ``help_text`` in the command list
    and as its description (unless ``description`` is given), ``example`` as its epilog;
    ``usage``: a short usage line instead of argparse's list of every option (``associate``,
    whose options are grouped with the common ones first)."""
    return subparsers.add_parser(
        name,
        help=help_text,
        description=help_text if description is None else description,
        epilog=f"example:\n  {example}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        usage=usage,
    )


def add_spatial_options(parser: argparse.ArgumentParser,
                        group: argparse._ActionsContainer | None = None) -> None:
    """The spatial-distribution parameters of the CVMHAT search (Eqs. 11-12), in a group:
    ``--rho --lam --tau --dtheta --fov`` (:func:`spatial_params` reads them back); ``group``:
    the caller's group (``associate``'s handcrafted search), else one of their own."""
    g = group if group is not None else parser.add_argument_group(
        "spatial-distribution parameters (paper defaults)")
    # rho > 1 is checked with the other parameters by SpatialParams (one line, exit 2, before
    # any work): the parser bounds only its size.
    g.add_argument(
        "--rho", default=15.0,
        type=float_in(None, 1e6, "Eq. 12's penalty base, in (1, 1e6]; the paper uses 15"),
        help="penalty base of Eq. 12, in (1, 1e6] (default 15)",
    )
    g.add_argument(
        "--lam", default=0.003,
        type=float_in(0, 1e6, "Eq. 11's x/y balance is positive; the paper uses 0.003",
                      low_open=True),
        help="x/y balance lambda of Eq. 11, in (0, 1e6] (default 0.003)",
    )
    g.add_argument(
        "--tau", default=2.0,
        type=float_in(0, 90, "an angle between two people seen from the camera, degrees"),
        help="occlusion tolerance, degrees in [0, 90] (default 2)",
    )
    g.add_argument(
        "--dtheta", default=1.0,
        type=float_in(0.01, 360, "the search tries 360 / dtheta orientations"),
        help="orientation step, degrees in [0.01, 360]: the search tries 360 / dtheta "
        "orientations (default 1)",
    )
    g.add_argument(
        "--fov", default=90.0,
        type=float_in(0, 180, "a pinhole camera's horizontal field of view, degrees",
                      low_open=True, high_open=True),
        help="horizontal camera field of view, degrees in (0, 180) (default 90)",
    )


def spatial_params(args: argparse.Namespace):
    """The :class:`~xvmatch.cues.spatial_matching.SpatialParams` of the options of
    :func:`add_spatial_options` (checked there: one line, exit 2, before any work)."""
    from xvmatch.cues.spatial_matching import SpatialParams

    return SpatialParams(
        rho=args.rho, lam=args.lam, tau_deg=args.tau, dtheta_deg=args.dtheta, fov_deg=args.fov
    )


HOR_IMAGE_SIZE = image_size(8, 65536, "pixels of a camera image")
"""``--image-size`` of a camera image: 8..65536 pixels a side."""

IMAGE_SIZE_HELP = (
    "the horizontal camera's image size in pixels, 8..65536 a side; needed with boxes only "
    "(default: the images' or the cameras' size; else 2688x1512, CVMHAT's, only when the boxes "
    "reach beyond 60%% of its width, with a note; a box more than 10%% past the image's border "
    "is an error)")
"""The help of every ``--image-size`` of the horizontal view
(:mod:`xvmatch.commands._box_reading`)."""

TOP_IMAGES_HELP = (
    "images of the top view: one image, a folder of frames whose names end in the frame number "
    "(0212.jpg, frame_000212.png), a quoted glob pattern, or a video file")
HOR_IMAGES_HELP = "images of the horizontal view (as --top-images)"


def add_image_options(group, top_help: str = TOP_IMAGES_HELP, hor_help: str = HOR_IMAGES_HELP,
                      several_hor: bool = False) -> None:
    """``--top-images`` and ``--hor-images`` (given together: :func:`check_images_together`)
    on a parser or an argument group; ``several_hor``: one ``--hor-images`` per horizontal
    view (``associate-multi``)."""
    group.add_argument("--top-images", default=None, metavar="PATH", help=top_help)
    group.add_argument("--hor-images", default=None, nargs="+" if several_hor else None,
                       metavar="PATH", help=hor_help)


def check_images_together(top_images: str | None, hor_images: str | list[str] | None) -> None:
    """``--top-images`` and ``--hor-images`` come together or not at all."""
    if (top_images is None) != (hor_images is None):
        raise ValueError("give --top-images and --hor-images together")


def image_inputs(args: argparse.Namespace) -> list[Input]:
    """The images of :func:`add_image_options` as inputs of the output-path check
    (:func:`xvmatch.core.output_paths.check_outputs`)."""
    hor = args.hor_images
    return [Input("--top-images", args.top_images),
            *(Input("--hor-images", h) for h in (hor if isinstance(hor, list) else [hor]))]


def progress_bar(total: int, desc: str, unit: str, enabled: bool, items: Iterable | None = None,
                 leave: bool = False, initial: int = 0):
    """A tqdm progress bar on stderr over ``items`` (or updated by hand): shown only on a
    terminal, never when not ``enabled`` (``--quiet``)."""
    from tqdm import tqdm

    return tqdm(items, total=total, desc=desc, unit=unit, initial=initial, leave=leave,
                file=sys.stderr, disable=None if enabled else True)


def frame_progress(total: int, desc: str, enabled: bool
                   ) -> Callable[[Iterable[int]], Iterable[int]]:
    """``progress(frames)``: wraps a frame iterator in a :func:`progress_bar`."""

    def wrap(frames: Iterable[int]) -> Iterable[int]:
        return progress_bar(total, desc, "frame", enabled, frames)

    return wrap


def step_progress(enabled: bool) -> Callable[[Iterable, int, str], Iterable]:
    """``progress(items, total, description)``: wraps the steps of a run in a
    :func:`progress_bar` (the tracker's ``progress``)."""
    return lambda items, total, desc: progress_bar(total, desc, "step", enabled, items)


DRAW_COMMAND = "xvmatch associate --draw"
"""The owner of ``associate``'s ``--draw`` folder: pictures are written only into a new or empty
folder or one an earlier ``--draw`` of the same command made
(:func:`xvmatch.core.output_paths.claim_folder`; ``track``'s has its own owner)."""


def add_draw_arguments(parser: argparse.ArgumentParser, common=None, more=None,
                       video: bool = False) -> None:
    """Add ``--draw`` (to ``common`` when given), ``--draw-every``, ``--no-labels`` and
    ``--draw-truth`` (to ``more``, default a group "pictures"); with ``video``,
    ``--draw-video`` too (``track``)."""
    g = more or parser.add_argument_group("pictures")
    (common or g).add_argument(
        "--draw", default=None, metavar="DIR",
        help="write a picture of each frame's pairs into DIR (new, empty or an earlier --draw's)")
    if video:
        g.add_argument("--draw-video", default=None, metavar="FILE.mp4",
                       help="write the same pictures as an mp4 video (mp4v, 10 frames a "
                       "second), with or without --draw")
    g.add_argument("--draw-every", default=1, metavar="K",
                   type=int_in(1, 100_000, "a frame step: 100000 is over an hour at 25 fps"),
                   help="with --draw: every K-th frame only, 1..100000 (default 1)")
    g.add_argument("--no-labels", action="store_true",
                   help="with --draw: print no ids by the boxes (colours alone show the pairs)")
    g.add_argument("--draw-truth", action="store_true",
                   help="with --draw: pairs green where the files' ids agree, red where not, "
                   "--camera-id's wearer marked (pictures only: the pairs are the same)")


def draw_pictures(folder, every: int, top: Mapping, hor: Mapping, *more,
                  owner: str = DRAW_COMMAND, truth: bool = False, camera_id: int | None = None,
                  row_ids: tuple | None = None, **kwargs) -> None:
    """:func:`~xvmatch.viz.match_pictures.write_match_pictures` into ``--draw``'s folder (that
    of ``owner``: ``DRAW_COMMAND`` or ``track``'s); with ``truth`` (``--draw-truth``), the
    colours and wearer mark of :func:`~xvmatch.viz.match_pictures.truth_marks` (``row_ids``:
    each view's true id per row, where the boxes' ids are rows)."""
    from xvmatch.viz.match_pictures import truth_marks, write_match_pictures

    if truth:
        kwargs.update(truth_marks(top, hor, camera_id, *(row_ids or (None, None))))
    write_match_pictures(folder, every, top, hor, *more, owner=owner, option="--draw", **kwargs)


def short_offset_help(parser: argparse.ArgumentParser, record: str, default: str) -> None:
    """``--offset``'s help in two or three lines: what N means, its range, where the offset
    applied is recorded (``record``) and the ``default``; docs/offset.md has the rest."""
    action = next(a for a in parser._actions if "--offset" in a.option_strings)
    action.help = ("top frame = horizontal frame + N for unsynced videos, |N| <= 100000; auto: "
                   f"N from the boxes (default {default}; applied N in {record}; docs/offset.md)")
