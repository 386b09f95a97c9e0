"""The cameras on the command line. ``--top-view`` of ``xvmatch associate``: a nadir top camera
(today's search and learned matcher read its image as the ground) or an oblique one, calibrated
from its people, with the horizontal camera registered on its ground map
(:func:`~xvmatch.inference.matching.association_run.oblique_pairs`); ``auto`` lets the top
view's boxes decide. With calibrated cameras (``--cameras``): the top camera's refinement, the
cameras' check and ``--write-cameras`` (``associate``, ``track``, ``adapt``,
``associate-multi``, read through :class:`~xvmatch.commands._model.ModelArgs`). And the
horizontal camera's image size a learned run's options give (:func:`horizontal_size`).
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING

from xvmatch.commands._options import HOR_IMAGE_SIZE, UsageError, check_images_together
from xvmatch.commands._types import float_in
from xvmatch.core.output_paths import Output, check_own_folder

if TYPE_CHECKING:
    from xvmatch.commands._model import ModelArgs

__all__ = ["CAMERAS_COMMAND", "add_camera_check", "add_refine_top_camera",
           "add_top_view_arguments", "add_write_cameras", "check_top_view",
           "check_write_cameras", "horizontal_size", "note_camera_check",
           "note_camera_refinement", "note_printer", "write_cameras"]


_HFOV_DEG = float_in(20, 150, "a camera's horizontal field of view, degrees")


def _or_auto(convert: Callable[[str], float]) -> Callable[[str], float | str]:
    """An argparse type taking ``auto`` as well as the numbers ``convert`` takes."""
    def parse(text: str) -> float | str:
        if text.strip().lower() == "auto":
            return "auto"
        try:
            return convert(text)
        except argparse.ArgumentTypeError as error:
            raise argparse.ArgumentTypeError(
                str(error).replace(", got ", " or auto, got ", 1)) from None

    return parse


_hor_hfov = _or_auto(_HFOV_DEG)
"""``--hor-hfov``: degrees in [20, 150], or ``auto`` (chosen from the people on the oblique
path, :func:`~xvmatch.cues.hor_lens.choose_hor_hfov`)."""

FRAME_RATE = _or_auto(float_in(0.1, 1000, "a camera's frame rate, frames per second"))
"""``--fps``: frames a second, or ``auto`` (30 unless the top view's walkers say otherwise,
:func:`~xvmatch.inference.matching.ground_association.top_frame_rate`)."""


def add_top_view_arguments(p: argparse._ActionsContainer) -> None:
    """``--top-view``, ``--top-image-size``, ``--hor-hfov``, ``--fps`` (on a parser or a group)."""
    p.add_argument(
        "--top-view", choices=("auto", "nadir", "oblique"), default="auto",
        help="nadir (looking straight down), oblique (at an angle; calibrated from its "
        "people) or auto (default: the boxes or --cameras decide)")
    p.add_argument("--top-image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help="the top view's image size, 8..65536 a side; oblique needs it, auto "
                   "reads it from the top boxes (their cut edges, else a common video size)")
    p.add_argument("--hor-hfov", default="auto", metavar="DEG", type=_hor_hfov,
                   help="oblique: the horizontal camera's field of view, degrees in [20, 150], "
                   "or auto (default: 70 unless its people pair clearly better at 90 or 110)")
    p.add_argument("--fps", default="auto", type=FRAME_RATE,
                   help="oblique: the frame numbers' rate, in [0.1, 1000], or auto (default: 30 "
                   "unless the top view's walkers say otherwise)")


def check_top_view(args: argparse.Namespace) -> None:
    """``--top-view`` and its options, before any work."""
    if args.top_view == "oblique":
        if args.top_image_size is None:
            raise UsageError("--top-view oblique calibrates the top camera from its people: "
                             "give --top-image-size WxH")
        if args.cameras is not None:
            raise UsageError("--top-view oblique estimates the cameras from the people: drop "
                             "--cameras, or use --top-view nadir with them")


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


def line_printer(quiet: bool) -> Callable[[str, bool], None]:
    """``note(line, always)``: prints the line on stderr unless ``quiet`` and not ``always``
    (a run's notes and warnings as a library run tells them)."""
    return lambda line, always: print(line, file=sys.stderr) if always or not quiet else None


def note_printer(quiet: bool) -> Callable[[str], None]:
    """``say(line)``: prints ``xvmatch: note: line`` on stderr unless quiet (a run's notes,
    e.g. the lenses ``--hor-hfov auto`` chose)."""
    def say(line: str) -> None:
        if not quiet:
            print(f"xvmatch: note: {line}", file=sys.stderr)

    return say


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


def horizontal_size(opts: ModelArgs, hor: Mapping, defer: bool = False,
                    top: Mapping | None = None) -> tuple[tuple[int, int], str]:
    """The horizontal image size and where it comes from: ``--image-size``, the
    ``--hor-images`` and the ``--cameras`` file's ego camera must agree when given
    (:func:`~xvmatch.formats.camera_frames.given_hor_sizes`); with none, CVMHAT's
    2688x1512 when the boxes are consistent with it (a note on stderr), else an error asking
    for ``--image-size`` (with ``defer``: a guess the run's path accepts or refuses,
    ``resolve_size``'s ``defer``). Every horizontal box must lie in it; with the run's ``top``
    view, whether boxes run on past the borders is read from both files."""
    from xvmatch.formats.box_image_size import resolve_size, runs_past_borders
    from xvmatch.formats.camera_frames import given_hor_sizes

    check_images_together(opts.top_images, opts.hor_images)
    learned = opts.model is not None
    given = given_hor_sizes(opts.image_size, opts.hor_images if learned else None,
                            opts.cameras if learned else None, sorted(hor))
    return resolve_size(hor, "the horizontal boxes" if opts.hor is None else opts.hor, given,
                        defer=defer, past=None if top is None else runs_past_borders(top, hor))
