"""``--top-view`` of ``xvmatch associate``: a nadir top camera (today's search and learned
matcher read its image as the ground) or an oblique one, calibrated from its people, with the
horizontal camera registered on its ground map
(:mod:`xvmatch.inference.matching.ground_association`); ``auto`` lets the top view's boxes
decide.
"""

from __future__ import annotations

import argparse
import sys

from xvmatch.commands._options import HOR_IMAGE_SIZE, UsageError
from xvmatch.commands._types import float_in

__all__ = ["add_top_view_arguments", "check_top_view", "oblique_pairs"]


def add_top_view_arguments(p: argparse.ArgumentParser) -> None:
    """``--top-view``, ``--top-image-size``, ``--hor-hfov``, ``--fps``."""
    p.add_argument(
        "--top-view", choices=("auto", "nadir", "oblique"), default="auto",
        help="the top camera: nadir (a drone looking straight down: its image is the ground), "
        "oblique (a camera on a building or a drone at an angle: calibrated from its people, "
        "the horizontal camera registered on its ground map frame by frame), or auto (the top "
        "view's boxes decide; it needs --top-image-size, else nadir; with --cameras, the "
        "cameras decide). Default auto")
    p.add_argument("--top-image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help="the top view's image size, 8..65536 a side, for --top-view auto / "
                   "oblique")
    p.add_argument("--hor-hfov", default=70.0, metavar="DEG",
                   type=float_in(20, 150, "a camera's horizontal field of view, degrees"),
                   help="the horizontal camera's field of view for --top-view oblique, degrees "
                   "in [20, 150] (default 70: a phone's, a drone's)")
    p.add_argument("--fps", default=30.0,
                   type=float_in(0.1, 1000, "a camera's frame rate, frames per second"),
                   help="frames per second of the frame numbers, for --top-view oblique's "
                   "registration over time, in [0.1, 1000] (default 30)")


def check_top_view(args: argparse.Namespace) -> None:
    """``--top-view`` and its options, before any work."""
    if args.top_view == "oblique":
        if args.top_image_size is None:
            raise UsageError("--top-view oblique calibrates the top camera from its people: "
                             "give --top-image-size WxH")
        if args.cameras is not None:
            raise UsageError("--top-view oblique estimates the cameras from the people: drop "
                             "--cameras, or use --top-view nadir with them")


def oblique_pairs(args: argparse.Namespace, top: dict, hor: dict,
                 hor_size: tuple[int, int]) -> dict | None:
    """The pairs of the ground-map association when the top view is oblique (forced, or found
    so by ``auto``), else None (today's path); prints the one line saying what was assumed."""
    if args.top_view == "nadir" or args.cameras is not None or args.top_image_size is None:
        return None
    from xvmatch.formats.box_image_size import check_boxes_in_image
    from xvmatch.inference.matching.ground_association import (
        GroundAssociationOptions,
        run_top_view,
    )

    check_boxes_in_image(top, args.top_image_size, args.top, "--top-image-size")
    options = GroundAssociationOptions(top_size=args.top_image_size, hor_size=hor_size,
                                       hor_hfov_deg=args.hor_hfov, fps=args.fps,
                                       consensus=args.mode == "video", seed=0)
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
