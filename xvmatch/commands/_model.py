"""The learned matcher on the command line (``xvmatch associate --model BUNDLE|default``): its
argument groups, one :class:`ModelArgs` record of the parsed options (:func:`model_args`, the one
place they are read, for ``associate``, ``adapt``, ``track``, ``associate-multi``), and the
matchers opened (:func:`open_models`, a torch matcher file exported first:
:func:`export_torch_file`). The cameras' options are in
:mod:`xvmatch.commands._cameras`, the pictures' in :mod:`xvmatch.commands._options` (both
re-exported here). The runs are imported lazily: only these code paths load onnxruntime."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from dataclasses import dataclass, fields

from xvmatch.commands._cameras import (
    add_camera_check,
    add_refine_top_camera,
    add_write_cameras,
    check_write_cameras,
    horizontal_size,
    note_camera_check,
    note_camera_refinement,
    write_cameras,
)
from xvmatch.commands._options import (
    DRAW_COMMAND,
    UsageError,
    add_draw_arguments,
    add_image_options,
    draw_pictures,
)
from xvmatch.commands._types import float_in, thread_count
from xvmatch.formats.camera_frames import ego_camera_size

__all__ = [
    "DRAW_COMMAND", "LEARNED_ONLY", "ModelArgs", "add_camera_check", "add_draw_arguments",
    "add_model_arguments", "add_refine_top_camera", "add_track_camera_arguments",
    "add_write_cameras", "check_precision", "check_write_cameras", "draw_pictures",
    "ego_camera_size", "export_torch_file", "horizontal_size", "model_args",
    "note_camera_check", "note_camera_refinement", "open_models", "write_cameras",
]

_gamma = float_in(0, 1, "the matcher's costs lie in [0, 1]", low_open=True)
"""``--gamma``: a non-association cost in (0, 1]."""


@dataclass(frozen=True)
class ModelArgs:
    """The learned matcher's options of a command line, read once by :func:`model_args`; one a
    command does not take keeps its default here (the option's own where a command takes it)."""

    model: str | list[str] | None = None
    """``--model``: one bundle (``track``, ``adapt``) or a list (``associate``), or None."""
    mode: str = "frame"
    top: str = "the top-view boxes"
    """``--top``, or how messages name the top boxes."""
    hor: str | list[str] | None = None
    """``--hor``: a box file, a list of them (``associate-multi``), or None."""
    top_images: str | None = None
    hor_images: str | list[str] | None = None
    cameras: str | list[str] | None = None
    write_cameras: str | list[str] | None = None
    refine_top_camera: str = "auto"
    camera_check: str = "on"
    appearance_check: str = "on"
    image_size: tuple[int, int] | None = None
    camera_id: int | None = None
    gamma: float | None = None
    mirror: bool = False
    workers: int = 1
    threads: int = 1
    precision: str | None = None
    costs: str | None = None
    draw: str | None = None
    draw_every: int = 1
    draw_video: str | None = None
    no_labels: bool = False
    draw_truth: bool = False
    quiet: bool = False


def model_args(args: argparse.Namespace) -> ModelArgs:
    """The :class:`ModelArgs` of parsed arguments: the options the namespace has, the record's
    defaults for those it lacks (the one place the learned matcher's options are read)."""
    given = vars(args)
    return ModelArgs(**{f.name: given[f.name] for f in fields(ModelArgs) if f.name in given})


def add_model_arguments(parser: argparse.ArgumentParser, common=None, cameras=None,
                        runtime=None, learned=None) -> None:
    """Add the learned matcher's options (``associate``) in ``learned`` (default: a group
    "learned matcher (--model)"), except those given a group of the caller's: ``common`` for
    ``--model``, the images and ``--cameras``; ``cameras`` for the cameras' refinement, check
    and writing; ``runtime`` for ``--costs``, ``--threads``, ``--precision``."""
    g = learned or parser.add_argument_group("learned matcher (--model)")
    common, cameras, runtime = common or g, cameras or g, runtime or g
    common.add_argument("--model", action="append", default=None, metavar="BUNDLE",
                        help="the learned matcher: 'default' (shipped), a bundle folder or a "
                        ".pt file; repeat to average several (default: the handcrafted search)")
    add_image_options(common, "top-view images (--model): a video, a folder of numbered "
                      "frames, one image or a quoted glob", "horizontal-view images (as above)")
    common.add_argument("--cameras", default=None, metavar="CAMERAS",
                        help="calibrated cameras 'top' and 'ego' (--model): a camera file, or "
                        "a folder of per-frame files named by frame number")
    g.add_argument("--gamma", type=_gamma, default=None,
                   help="non-association cost in (0, 1] (default: the model's own)")
    g.add_argument("--mirror", action="store_true",
                   help="also score the scene mirrored and average (twice the time; a few "
                   "tenths of CVIDF1)")
    g.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with images: match from the boxes alone where the images are shown "
                   "too weak to help (default on; off: always use the images)")
    add_refine_top_camera(cameras)
    add_write_cameras(cameras)
    add_camera_check(cameras)
    runtime.add_argument("--costs", default=None, metavar="JSON",
                         help="also write each frame's ids and cost matrix (--model)")
    runtime.add_argument("--threads", type=thread_count, default=1, metavar="K",
                         help="onnxruntime threads, 1..64 (default 1)")
    runtime.add_argument("--precision", choices=("fp32", "int8"), default=None,
                         help="the appearance network: int8 (a bundle exported with --int8) "
                         "or fp32 (default: int8 where the bundle and the CPU allow)")


def add_track_camera_arguments(g) -> None:
    """``track``'s ``--cameras`` with their refinement, writing and check, and the learned
    cross-view weights' ``--appearance-check``, on the argument group ``g``."""
    g.add_argument("--cameras", default=None, metavar="CAMERAS",
                   help="calibrated cameras 'top' and 'ego' (a file, or a folder of files "
                   "numbered by the horizontal frames) for the --model's cross-view weights, as "
                   "'associate --cameras' (an oblique overview camera wants them)")
    add_refine_top_camera(g)
    add_write_cameras(g)
    add_camera_check(g)
    g.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with --model's network and learned weights: leave the cross-view "
                   "appearance out where the tracklet pairs the boxes alone are sure of show it "
                   "too weak (default on; off: always use it; nothing to judge with --w1 1)")


LEARNED_ONLY = ("gamma", "mirror", "top_images", "hor_images", "cameras", "costs",
                "precision", "write_cameras")
"""Options of ``associate`` that need ``--model``."""


def export_torch_file(path: str, folder) -> None:
    """Export a torch matcher file's bundle into its cache ``folder``, once (the learn extra)."""
    try:
        from xvmatch.export.onnx_export import export_bundle
    except ImportError:
        raise ValueError(f"{path}: a torch matcher file; export it with 'xvmatch export' on "
                         "a machine with the learn extra, and pass the bundle folder") from None
    print(f"exporting {path} to {folder} (once)", file=sys.stderr)
    export_bundle(path, folder)


def open_models(names: Iterable[str], threads: int = 1, precision: str | None = None,
                recheck: bool = False) -> list:
    """Each ``--model``'s matcher (:func:`~xvmatch.inference.matching.run_inputs.open_matchers`;
    ``recheck``: ``associate`` re-checks INT8's near-tie frames in FP32)."""
    from xvmatch.inference.matching.run_inputs import open_matchers

    return open_matchers(names, threads, precision, recheck, export=export_torch_file)


def check_precision(precision: str | None, images: bool, models: Iterable = (),
                    names: Iterable[str] = ()) -> None:
    """Refuse ``--precision`` where no appearance network runs (:class:`UsageError`): call it
    before opening the models (``models`` empty) and after."""
    from xvmatch.inference.matching.run_inputs import precision_problem

    if (problem := precision_problem(precision, images, models, names)) is not None:
        raise UsageError(problem)
