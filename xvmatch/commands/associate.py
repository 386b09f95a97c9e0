"""The ``xvmatch associate`` command: pairs of the two views, frame by frame.

From boxes with the CVMHAT spatial-distribution search (Sec. 3.2), or with a learned matcher
(``--model``, :mod:`xvmatch.commands._model`) from boxes, images and cameras; ``--offset auto``
re-times the views first (:mod:`xvmatch.commands.offset`).
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace

from xvmatch.commands._cameras import add_top_view_arguments, check_top_view, oblique_pairs
from xvmatch.commands._model import (
    DRAW_COMMAND,
    LEARNED_ONLY,
    add_draw_arguments,
    add_model_arguments,
    associate_with_model,
    check_write_cameras,
    draw_pictures,
    horizontal_size,
    model_args,
)
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    UsageError,
    add_box_inputs,
    add_command_parser,
    add_spatial_options,
    box_reading,
    check_camera_id,
    frame_progress,
    image_inputs,
    read_boxes,
    short_offset_help,
    spatial_params,
)
from xvmatch.commands._types import box_id, worker_count
from xvmatch.commands.offset import add_offset_options, max_offset_of, resolve_offset
from xvmatch.core.output_paths import Input, Output, check_outputs, check_own_folder

__all__ = ["EXAMPLE", "add_associate_parser"]

EXAMPLE = "xvmatch associate --top seq_top.txt --hor seq_hor.txt --out pred.csv"


def add_associate_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch associate`` on ``subparsers`` and return its parser: the options most
    runs need first (the parser's own group), then one group per topic."""
    p = add_command_parser(
        subparsers,
        "associate",
        "Associate people across the two views and write frame,top_id,hor_id pairs: from "
        "boxes with the CVMHAT spatial-distribution search (Sec. 3.2), or with a learned "
        "matcher (--model) from boxes, images and cameras.",
        EXAMPLE,
        usage="%(prog)s --top TOP --hor HOR --out OUT [--model BUNDLE] [options]",
    )
    search = p.add_argument_group("the handcrafted search (without --model)")
    learned = p.add_argument_group("learned matcher (--model)")
    cameras = p.add_argument_group("calibrated cameras (--cameras)")
    top_view = p.add_argument_group("an oblique top view (without --cameras)")
    detector = p.add_argument_group("box files from a detector")
    runtime = p.add_argument_group("output and run time")
    add_box_inputs(p, reading=True, detector=detector)
    p.add_argument("--out", required=True, help="prediction CSV to write: frame,top_id,hor_id")
    add_model_arguments(p, common=p, cameras=cameras, runtime=runtime, learned=learned)
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help="the horizontal images' size, 8..65536 a side (default: the images' or "
                   "cameras'; else CVMHAT's 2688x1512, with a note)")
    add_offset_options(p, "Pairs are written under the horizontal frame numbers, "
                       "the offset in OUT.offset.json")
    short_offset_help(p, "OUT.offset.json", "0")
    p.add_argument(
        "--mode", choices=("auto", "frame", "video"), default="auto",
        help="video: pairs kept consistent along each view's track ids; frame: each frame "
        "alone; auto (default): video when both views' ids persist")
    add_draw_arguments(p, common=p, more=runtime, video=True)
    search.add_argument(
        "--camera-id", type=box_id, default=None, metavar="ID",
        help="top-view id of the camera's wearer (either method; |id| <= 2**53; default: "
        "searched among all top-view people)")
    search.add_argument(
        "--search", choices=("exhaustive", "reduced", "follow"), default=None,
        help="exhaustive (default), or in video mode reduced (orientation window) or follow "
        "(window + the wearer followed by its track id)")
    add_spatial_options(p, group=search)
    add_top_view_arguments(top_view)
    runtime.add_argument("--workers", type=worker_count, default=1, metavar="K",
                         help="processes for --offset auto and --model's features, 1..64 "
                         "(default 1; the same output for any K)")
    runtime.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=_cmd_associate)
    return p


def _keep_heap_memory() -> None:
    """Stop glibc returning large numpy temporaries to the OS after every frame.

    The search allocates and frees a few hundred-kilobyte arrays per frame; with glibc's default
    mmap threshold each one is a fresh mapping, and the page faults cost about 20% of the run.
    Process-wide, so only the CLI does it; a no-op where ``mallopt`` does not exist.
    """
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.mallopt(-3, 256 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 512 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


def _cmd_associate(args: argparse.Namespace) -> int:
    from xvmatch.cues.spatial_search import associate_sequence

    _keep_heap_memory()
    params = spatial_params(args)
    top = read_boxes(args.top, args.duplicates, box_reading(args))
    hor = read_boxes(args.hor, args.duplicates, box_reading(args))
    video = _video_mode(args, top, hor)
    search = args.search or "exhaustive"
    if not video and search != "exhaustive":
        raise UsageError("--search reduced/follow uses previous frames: it needs --mode video"
                         + (" (auto found no track ids: ids that persist from frame to frame)"
                            if args.mode == "auto" else ""))
    if args.model is None:
        given = [f"--{k.replace('_', '-')}" for k in LEARNED_ONLY
                 if getattr(args, k) not in (None, False)]
        if given:
            raise UsageError(f"{', '.join(given)} apply to a learned matcher: add --model "
                             "default (or a bundle)")
    check_camera_id(args.camera_id, top, args.top)
    check_top_view(args)
    learned = replace(model_args(args), mode="frame")  # video: its pairs made consistent
    models = [m for m in args.model or () if m != "default"]
    from xvmatch.formats.offset_record import predictions_offset_path

    check_outputs(
        [Output("--out", args.out), Output("--offset", predictions_offset_path(args.out)),
         Output("--costs", args.costs),
         Output("--draw", args.draw, folder=True), Output("--draw-video", args.draw_video),
         *check_write_cameras(learned)],
        [Input("--top", args.top), Input("--hor", args.hor), *image_inputs(args),
         Input("--cameras", args.cameras), *(Input("--model", m) for m in models)],
    )
    if args.draw is not None:
        check_own_folder(args.draw, DRAW_COMMAND, "--draw")
    if args.draw_video is not None and not args.draw_video.lower().endswith(".mp4"):
        raise UsageError(f"--draw-video {args.draw_video}: an mp4 file (FILE.mp4) is written")
    max_offset = max_offset_of(args, top, hor) if args.offset == "auto" else None
    hor_size = horizontal_size(learned, hor)
    hor_width = hor_size[0][0]
    if args.model is None:
        from xvmatch.commands._box_reading import note_if_assumed

        note_if_assumed(hor_size, hor, args.hor, args.quiet)
    offset = resolve_offset(args, top, hor, hor_width, params, max_offset, args.camera_id)
    if offset:
        from xvmatch.formats.mot_boxes import shift_frames

        top = shift_frames(top, offset)
    frames = sorted(set(top) | set(hor))
    oblique = oblique_pairs(args, top, hor, hor_size[0], video)
    if oblique is not None:
        pairs = oblique
        _write(args, pairs, frames, offset)
        return 0
    progress = frame_progress(len(frames), "associate", not args.quiet)
    if args.model is not None:
        pairs = associate_with_model(learned, top, hor, frames, progress, top_offset=offset,
                                     hor_size=hor_size)
    else:
        pairs = associate_sequence(
            top,
            hor,
            hor_width=hor_width,
            params=params,
            search=search,
            camera_id=args.camera_id,
            frames=frames,
            progress=progress,
        )
    if video:
        from xvmatch.inference.linking.pair_consensus import consistent_pairs

        pairs = consistent_pairs(pairs, top, hor, frames)
    if args.model is None and (args.draw is not None or args.draw_video is not None):
        both = [f for f in frames if len(top.get(f, ())) and len(hor.get(f, ()))]
        draw_pictures(args.draw, args.draw_every, top, hor, pairs, both, None, hor_size[0],
                      not args.no_labels, truth=args.draw_truth, camera_id=args.camera_id,
                      video=args.draw_video)
    _write(args, pairs, frames, offset, _AUTO_VIDEO if video and args.mode == "auto" else None)
    return 0


_AUTO_VIDEO = ("--mode video: each view's ids persist from frame to frame (track ids), so the "
               "pairs were kept consistent along them; --mode frame solves each frame alone")
"""The note of ``--mode auto`` taking video mode, said with the run's summary."""


def _video_mode(args: argparse.Namespace, top: dict, hor: dict) -> bool:
    """``--mode``: video or frame; ``auto`` takes video where both views' ids are track ids
    (:func:`~xvmatch.cues.box_motion.is_video`): every path then keeps its pairs consistent
    along them."""
    if args.mode != "auto":
        return args.mode == "video"
    from xvmatch.cues.box_motion import is_video

    return is_video(top, hor)


def _write(args: argparse.Namespace, pairs: dict, frames: list[int], offset: int,
           note: str | None = None) -> None:
    """The predictions and, when ``--offset`` was given, the offset applied beside them
    (``PRED.offset.json``, which ``evaluate`` reads); a record an earlier run left there for
    these predictions is removed when this run applied none. ``note``: a line said with the
    summary, once the run has succeeded."""
    import os

    from xvmatch.formats.mot_boxes import write_predictions
    from xvmatch.formats.offset_record import predictions_offset_path, write_offset_record

    write_predictions(args.out, pairs)
    record = predictions_offset_path(args.out)
    if args.offset != 0:
        write_offset_record(record, offset)
    elif os.path.isfile(record):
        os.unlink(record)
    n_pairs = sum(len(p) for p in pairs.values())
    if not args.quiet:
        if note:
            print(f"xvmatch: note: {note}", file=sys.stderr)
        print(f"wrote {n_pairs} pairs over {len(frames)} frames to {args.out}", file=sys.stderr)
