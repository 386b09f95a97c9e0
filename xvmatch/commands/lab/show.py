"""The ``xvmatch show`` command: draw a labelled pair, or one frame of two box files.

A synthetic pair (an image, a scene file or a dataset folder of ``xvmatch synth``) is found by
:func:`xvmatch.datasets.synthetic_io.resolve_pair` and drawn by
:func:`~xvmatch.datasets.synthetic_io.draw_pair`; a frame of box files by
:func:`xvmatch.viz.box_canvas.draw_box_frame`. Imports are lazy so that other commands never load
OpenCV. Bad input raises ``ValueError`` with a one-line message, which the main entry point
prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    add_command_parser,
    read_boxes,
)
from xvmatch.commands._types import int_in
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLE", "add_show_parser"]

EXAMPLE = "xvmatch show data/synth/images/top/s00000_000001.jpg --out pair.png"


def add_show_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch show`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers,
        "show",
        "Draw a labelled pair side by side with each person's box and id (one colour per "
        "person across the views; O marks the camera wearer) into a PNG; or a frame of your "
        "own box files (--top, --hor), matched by a prediction CSV or by their ids.",
        EXAMPLE,
    )
    p.add_argument("pair", metavar="PAIR", nargs="?", default=None,
                   help="an image of the pair (images/top/SCENE_FRAME.jpg or images/ego/...), "
                   "a scene file (annotations/SCENE.json), or a dataset folder")
    g = p.add_argument_group("box files instead of PAIR (drawn on blank canvases: the "
                             "horizontal view at its image size, the top view as a plan)")
    g.add_argument("--top", default=None, metavar="FILE", help="top-view boxes (MOT format)")
    g.add_argument("--hor", default=None, metavar="FILE",
                   help="horizontal-view boxes (MOT format)")
    g.add_argument("--pred", default=None, metavar="CSV",
                   help="pairs to draw, frame,top_id,hor_id (xvmatch associate --out); default: "
                   "the same id in both views (ground truth)")
    g.add_argument("--image-size", type=HOR_IMAGE_SIZE,
                   default=None, metavar="WxH", help=IMAGE_SIZE_HELP)
    g.add_argument("--no-labels", action="store_true", help="print no ids by the boxes")
    p.add_argument("--scene", default=None, help="scene name when PAIR is a dataset folder "
                   "(default: the first scene)")
    p.add_argument("--frame", default=None,
                   type=int_in(1, 2**53, "a frame number: frames are 1-based, exact to 2**53"),
                   help="frame number when PAIR is a scene file or folder (default 1), or of "
                   "the box files (default: the first with boxes in both views), 1..2**53")
    p.add_argument("--out", default="pair.png", help="picture to write (default pair.png)")
    p.add_argument("--full-boxes", action="store_true",
                   help="also draw the full (unoccluded) boxes, thin")
    p.add_argument("--bits", type=int, choices=range(1, 9), default=8, metavar="{1..8}",
                   help="colour bits per channel of the picture (default 8); 5 makes a PNG "
                   "about half as big, for documentation")
    p.set_defaults(func=_cmd_show)
    return p


def _show_boxes(args: argparse.Namespace) -> int:
    """``show --top T --hor H``: one frame of box files, pairs from ``--pred`` or equal ids."""
    from xvmatch.commands._box_reading import note_if_assumed
    from xvmatch.formats.box_image_size import resolve_size
    from xvmatch.formats.mot_boxes import read_predictions
    from xvmatch.viz.box_canvas import draw_box_frame
    from xvmatch.viz.match_drawing import write_match_picture

    if args.pair is not None or args.top is None or args.hor is None:
        raise ValueError("give either PAIR (a synthetic pair) or --top and --hor (box files)")
    if args.full_boxes:
        raise ValueError("--full-boxes applies to a synthetic PAIR (box files hold one box)")
    out = Path(args.out)
    check_outputs([Output("--out", out)], [Input("--top", args.top), Input("--hor", args.hor),
                                           Input("--pred", args.pred)])
    top, hor = read_boxes(args.top, "first"), read_boxes(args.hor, "first")
    both = [f for f in sorted(set(top) & set(hor)) if len(top[f]) and len(hor[f])]
    frame = args.frame if args.frame is not None else (both[0] if both else None)
    if frame not in both:
        raise ValueError(f"--frame {frame}: {args.top} and {args.hor} have no boxes in both "
                         f"views there (frames with both: {both[0]}..{both[-1]})" if both else
                         f"{args.top} and {args.hor} share no frame with boxes in both views")
    resolved = resolve_size(hor, args.hor, [] if args.image_size is None else
                            [(args.image_size, "--image-size")])
    pairs = None if args.pred is None else read_predictions(args.pred).get(frame, [])
    picture = draw_box_frame(top, hor, frame, resolved[0], pairs, labels=not args.no_labels,
                             source=args.pred or "pairs")
    note_if_assumed(resolved, hor, args.hor)
    write_match_picture(out, picture)
    print(f"wrote {out} ({picture.shape[1]}x{picture.shape[0]})", file=sys.stderr)
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    import cv2

    from xvmatch.core.atomic_files import atomic_write_bytes
    from xvmatch.datasets.synthetic_io import MANIFEST, draw_pair, read_scene, resolve_pair

    if args.top is not None or args.hor is not None or args.pair is None:
        return _show_boxes(args)
    for option, value in (("--pred", args.pred), ("--image-size", args.image_size)):
        if value is not None:
            raise ValueError(f"{option} applies to box files (--top, --hor)")
    annotation, root, frame = resolve_pair(args.pair, args.scene, args.frame)
    record = read_scene(annotation, root)
    if not 1 <= frame <= len(record.pairs):
        raise ValueError(f"{annotation}: frame {frame} out of range 1..{len(record.pairs)}")
    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"--out {args.out}: use a .png or .jpg file name")
    pair = record.pairs[frame - 1]
    # the whole data set is input: never write over another pair's image or annotation
    dataset = root if (Path(root) / MANIFEST).is_file() else None
    check_outputs([Output("--out", out)],
                  [Input("PAIR", args.pair), Input("PAIR", annotation), Input("PAIR", dataset),
                   Input("PAIR", pair.top.image_path), Input("PAIR", pair.ego.image_path)])
    picture = draw_pair(pair, full_boxes=args.full_boxes)
    if args.bits < 8:
        drop = 8 - args.bits
        picture = ((picture >> drop) << drop) + ((1 << drop) >> 1)
    ok, buf = cv2.imencode(out.suffix.lower(), picture, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover
        raise OSError(f"could not encode {out}")
    # A temporary file of an unpredictable name, made exclusively beside the output, then
    # renamed over it; removed on any failure.
    atomic_write_bytes(out, buf.tobytes(), fsync=False)
    print(f"wrote {out} ({picture.shape[1]}x{picture.shape[0]})", file=sys.stderr)
    return 0
