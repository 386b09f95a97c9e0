"""The ``xvmatch associate`` command: pairs of the two views, frame by frame.

From boxes with the CVMHAT spatial-distribution search (Sec. 3.2), or with a learned matcher
(``--model``, :mod:`xvmatch.commands._model`) from boxes, images and cameras; ``--offset auto``
re-times the views first. The command reads and checks, builds one
:class:`~xvmatch.inference.matching.association_run.AssociationOptions`, calls
:func:`~xvmatch.inference.matching.association_run.run_association` (its notes on stderr as it
goes, its pictures drawn) and writes the pairs, the costs and the cameras.
"""

from __future__ import annotations

import argparse
import sys

from xvmatch.commands._cameras import add_top_view_arguments, check_top_view, line_printer
from xvmatch.commands._model import (
    DRAW_COMMAND,
    LEARNED_ONLY,
    ModelArgs,
    add_draw_arguments,
    add_model_arguments,
    check_write_cameras,
    draw_pictures,
    export_torch_file,
    horizontal_size,
    model_args,
    write_cameras,
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
from xvmatch.commands.offset import add_offset_options, max_offset_of, offset_progress
from xvmatch.core.output_paths import Input, Output, check_outputs, check_own_folder
from xvmatch.inference.matching.association_run import (
    AssociationHooks,
    AssociationOptions,
    AssociationPictures,
    AssociationRun,
    LearnedChoice,
)

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
                         help="processes for --offset auto, --model's features and an "
                         "oblique top view's lens candidates, 1..64 (default 1; the same "
                         "output for any K)")
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
    from xvmatch.cues.box_motion import is_video
    from xvmatch.inference.matching.association_run import run_association

    _keep_heap_memory()
    params = spatial_params(args)
    top = read_boxes(args.top, args.duplicates, box_reading(args))
    hor = read_boxes(args.hor, args.duplicates, box_reading(args))
    # --mode auto: video where both views' ids are track ids (every path keeps pairs along them)
    video = args.mode == "video" or (args.mode == "auto" and is_video(top, hor))
    if not video and (args.search or "exhaustive") != "exhaustive":
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
    learned = model_args(args)
    _check_outputs(args, learned)
    max_offset = max_offset_of(args, top, hor) if args.offset == "auto" else None
    hor_size = horizontal_size(learned, hor, defer=True, top=top)  # the ground path may guess
    options = _run_options(args, params, hor_size, max_offset, video)
    run = run_association(top, hor, options, _hooks(args, hor, hor_size))
    _write(args, learned, hor, run)
    return 0


def _check_outputs(args: argparse.Namespace, learned: ModelArgs) -> None:
    """Refuse outputs that would overwrite an input or a folder not ``associate``'s own."""
    from xvmatch.formats.offset_record import predictions_offset_path

    models = [m for m in args.model or () if m != "default"]
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


def _run_options(args: argparse.Namespace, params, hor_size, max_offset: int | None,
                 video: bool) -> AssociationOptions:
    """The run's :class:`~xvmatch.inference.matching.association_run.AssociationOptions`."""
    learned = None
    if args.model is not None:
        learned = LearnedChoice(
            names=tuple(args.model), threads=args.threads, precision=args.precision,
            top_images=args.top_images, hor_images=args.hor_images, cameras=args.cameras,
            gamma=args.gamma, mirror=bool(args.mirror),
            keep_costs=any(v is not None for v in (args.costs, args.draw, args.draw_video)),
            appearance_check=args.appearance_check == "on",
            refine_top_camera=args.refine_top_camera == "auto",
            camera_check=args.camera_check == "on")
    return AssociationOptions(
        hor_size=hor_size, params=params, offset=args.offset, max_offset=max_offset,
        video=video, video_by_auto=video and args.mode == "auto", search=args.search,
        camera_id=args.camera_id, workers=args.workers, top_boxes=args.top, hor_boxes=args.hor,
        top_view=args.top_view, top_image_size=args.top_image_size, hor_hfov=args.hor_hfov,
        fps=args.fps, learned=learned)


def _hooks(args: argparse.Namespace, hor: dict, hor_size) -> AssociationHooks:
    """Where the run's notes (stderr), progress bars and pictures (``--draw``) go."""
    from xvmatch.commands._box_reading import note_if_assumed

    def pictures(shown: AssociationPictures) -> None:
        draw_pictures(args.draw, args.draw_every, shown.top, shown.hor, shown.pairs,
                      shown.frames, shown.images, shown.hor_size, not args.no_labels,
                      truth=args.draw_truth, camera_id=args.camera_id, video=args.draw_video)

    return AssociationHooks(
        note=line_printer(args.quiet),
        size_assumed=lambda: note_if_assumed(hor_size, hor, args.hor, args.quiet),
        frames=lambda n: frame_progress(n, "associate", not args.quiet),
        clips=lambda: offset_progress("", not args.quiet),
        pictures=pictures if args.draw is not None or args.draw_video is not None else None,
        export=export_torch_file)


def _write(args: argparse.Namespace, learned: ModelArgs, hor: dict,
           run: AssociationRun) -> None:
    """The learned run's ``--costs`` and ``--write-cameras``, then the predictions and, when
    ``--offset`` was given, the offset applied beside them (``PRED.offset.json``, which
    ``evaluate`` reads; a record an earlier run left there is removed when this run applied
    none); the run's note said with the summary."""
    import os

    from xvmatch.formats.mot_boxes import write_predictions
    from xvmatch.formats.offset_record import predictions_offset_path, write_offset_record

    if (lr := run.learned) is not None:
        if args.costs is not None:
            from xvmatch.inference.matching.costs_record import write_costs_record

            write_costs_record(args.costs, run.top, hor, lr.costs, lr.gamma, lr.checked,
                               lr.camera_checked, lr.refinement)
        write_cameras(learned, run.refined_cameras, lr.refinement)
    write_predictions(args.out, run.pairs)
    record = predictions_offset_path(args.out)
    if args.offset != 0:
        write_offset_record(record, run.offset)
    elif os.path.isfile(record):
        os.unlink(record)
    if not args.quiet:
        if run.note:
            print(f"xvmatch: note: {run.note}", file=sys.stderr)
        print(f"wrote {sum(len(p) for p in run.pairs.values())} pairs over {len(run.frames)} "
              f"frames to {args.out}", file=sys.stderr)
