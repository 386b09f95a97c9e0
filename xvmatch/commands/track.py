"""The ``xvmatch track`` command: parses and checks the options, settles the horizontal image size
and the offset, runs :func:`xvmatch.inference.tracks.track_run.run_tracking` (CVMHAT Algorithm 1;
the module says what each option feeds) and writes ``OUT/top.txt`` and ``OUT/hor.txt`` (the
input rows, the id field holding the track id; rows dropped are absent), ``OUT/offset.json``
(the offset applied, read by ``evaluate --tracks``) and with ``--draw`` or ``--draw-video`` the
pictures of the pairs. Bad input raises ``ValueError`` with one line (exit code 2).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from xvmatch.commands._box_reading import box_reading, read_detections, settled_hor_size
from xvmatch.commands._cameras import add_top_view_arguments, check_top_view, line_printer
from xvmatch.commands._model import (
    add_track_camera_arguments,
    check_write_cameras,
    model_args,
    open_models,
    write_cameras,
)
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    add_box_reading_options,
    add_command_parser,
    add_draw_arguments,
    add_image_options,
    add_spatial_options,
    draw_pictures,
    image_inputs,
    short_offset_help,
    spatial_params,
    step_progress,
)
from xvmatch.commands._types import box_id, float_in, int_in, seed_value, worker_count
from xvmatch.commands.offset import add_offset_options, max_offset_of, resolve_offset, wearer_marked
from xvmatch.core.output_paths import Input, Output, check_outputs, check_own_folder, claim_folder

__all__ = ["EXAMPLE", "OFFSET_FILE", "add_track_parser"]

OFFSET_FILE = "offset.json"
"""What ``track`` writes beside the tracks: ``{"offset": N}``, the offset it applied (0 when the
videos kept the files' timing), so that ``evaluate --tracks`` re-times the same way."""

TRACK_COMMAND = "xvmatch track"
"""The marker name of the command's output folders (it writes only into a folder it made); its
``--draw`` folders are marked ``xvmatch track --draw``."""

EXAMPLE = (
    "xvmatch track --top seq_top.txt --hor seq_hor.txt --out tracks/\n"
    "  xvmatch track --top seq_top.txt --hor seq_hor.txt --model default --out tracks/\n"
    "  xvmatch track --top drone.txt --hor phone.txt --top-image-size 1920x1080 --out tracks/\n"
    "  xvmatch evaluate --tracks tracks/ --top gt_top.txt --hor gt_hor.txt"
)

CLIP_LENGTH_TYPE = int_in(1, 1000, "frames per clip; each window's program grows with it")
MAX_GAP_TYPE = int_in(0, 1000, "frames; a clip is at most 1000 frames")
MIN_IOU_TYPE = float_in(0, 1, "an intersection over union", low_open=True)
C0_TYPE = float_in(0, 1, "edge weights are in [0, 1]; an edge pays off above 2 c0")
SIGMA_TYPE = float_in(0, 1000, "per box height of motion deviation", low_open=True)
SHARE_TYPE = float_in(0, 1, "a share of a linear combination")
TIME_LIMIT_TYPE = float_in(0.01, 600, "seconds per window before the MIP's fallback")


def add_track_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch track`` on ``subparsers`` and return its parser."""
    help_text = (
        "Track the people of a top-view and a horizontal-view box file with one id per person "
        "across both views (CVMHAT: tracklets in 10-frame clips, a four-cluster mixed-integer "
        "program per pair of clips, stitching). The input ids are ignored; writes OUT/top.txt "
        "and OUT/hor.txt, the input rows with the id replaced by the track id."
    )
    p = add_command_parser(subparsers, "track", help_text, EXAMPLE)
    p.add_argument("--top", required=True, help="top-view detections (MOT format, ids ignored)")
    p.add_argument("--hor", required=True, help="horizontal-view detections (MOT, ids ignored)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (created): top.txt, hor.txt and offset.json (the offset "
                   "applied, read by evaluate --tracks), each written atomically")
    p.add_argument("--solver", choices=("mip", "spectral"), default="mip",
                   help="mip: Eqs. 1-4 with HiGHS (default); spectral: the spectral-clustering "
                   "baseline on the same weights")
    p.add_argument("--camera-id", type=box_id, default=None,
                   help="top-file id of the horizontal camera's wearer (O given), |id| <= 2**53 "
                   "(default: O searched among all top-view boxes)")
    p.add_argument("--clip-length", type=CLIP_LENGTH_TYPE, default=10,
                   help="frames per clip, 1..1000 (default 10)")
    p.add_argument("--min-iou", type=MIN_IOU_TYPE, default=0.5,
                   help="IoU that links a box to the previous frame's, in (0, 1] (default 0.5)")
    p.add_argument("--max-gap", type=MAX_GAP_TYPE, default=3, help="frames a tracklet may miss "
                   "inside a clip and still continue, 0..1000 (default 3)")
    p.add_argument("--c0", type=C0_TYPE, default=None,
                   help="dummy-node weight of Eq. 1, in [0, 1] (default 0.1, 0.02 with the "
                   "learned weights; the paper's 0.2)")
    p.add_argument("--sigma", type=SIGMA_TYPE, default=None, help="motion deviation scale of "
                   "Eq. 15 per box height (resolution-free), in (0, 1000] (default 1)")
    p.add_argument("--time-limit", type=TIME_LIMIT_TYPE, default=30.0,
                   help="wall-time guard per window for the MIP, in [0.01, 600] (default 30); "
                   "past it or its budget (64 added loops and 1000 HiGHS nodes a program) the "
                   "best loop-free answer found is used, with a warning")
    p.add_argument("--seed", type=seed_value, default=0, help="seed of the spectral baseline's "
                   "k-means, 0..2**32-1 (default 0)")
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help=IMAGE_SIZE_HELP + "; with --hor-images it must agree with them")
    add_offset_options(p, "", default="auto")
    short_offset_help(p, "OUT/offset.json", "auto")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for the frame association and --offset auto's estimate, "
                   "1..64 (default 1; the same output for any K)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    add_box_reading_options(p)
    _add_appearance_options(p)
    add_draw_arguments(p, video=True)
    add_spatial_options(p)
    add_top_view_arguments(p.add_argument_group("an oblique top view (without --cameras)"))
    p.set_defaults(func=_cmd_track)
    return p


def _add_appearance_options(p: argparse.ArgumentParser) -> None:
    """``track``'s options of the appearance cue and the learned matcher (its images,
    ``--model``, ``--weights``, ``--cameras``, the weights of Eqs. 17 and 18)."""
    g = p.add_argument_group("appearance (with the images of both views)")
    add_image_options(g)
    g.add_argument("--model", default=None, metavar="BUNDLE",
                   help="a matcher bundle (xvmatch export) or 'default' (shipped): its box-only "
                   "costs give the cross-view weights (--weights learned); with the images, its "
                   "appearance network adds the terms of Eqs. 17 and 18")
    g.add_argument("--weights", choices=("learned", "handcrafted"), default=None,
                   help="cross-view weights (Eq. 13): learned, from the --model's costs on the "
                   "boxes (default with --model), or handcrafted, from the spatial-distribution "
                   "search's pairs (default without)")
    g.add_argument("--w1", type=SHARE_TYPE, default=None,
                   help="share of the spatial term in a cross-view weight (Eq. 17), in [0, 1] "
                   "(default 0.3, or 1 when --cameras' top camera fits the video's head rays "
                   "after --refine-top-camera: the images then serve only over time)")
    g.add_argument("--w2", type=SHARE_TYPE, default=None,
                   help="share of the appearance term in an over-time weight (Eq. 18), in "
                   "[0, 1] (default 0.6)")
    g.add_argument("--min-colour", type=SHARE_TYPE, default=0.3,
                   help="colour-histogram similarity a horizontal box needs to extend a "
                   "tracklet, in [0, 1] (default 0.3)")
    g.add_argument("--time-appearance", choices=("network", "colour"), default="network",
                   help="over-time appearance term of Eq. 18: the --model's network (default; "
                   "colour without --model) or colour histograms (Eq. 14, the paper's)")
    add_track_camera_arguments(g)


def _read_checked(args: argparse.Namespace):
    """``(top, hor, camera_rows, out)``: the boxes, wearer's rows and output folder, all checked."""
    top, hor = (read_detections(path, box_reading(args)) for path in (args.top, args.hor))
    camera_rows = None
    if args.camera_id is not None:
        camera_rows = top.rows_with_id(args.camera_id)
        if camera_rows.size == 0:
            raise ValueError(f"{args.top}: no box has the --camera-id {args.camera_id}")
    out = Path(args.out)
    if args.draw_video is not None and not args.draw_video.lower().endswith(".mp4"):
        raise ValueError(f"--draw-video {args.draw_video}: an mp4 file (FILE.mp4) is written")
    check_outputs(
        [Output("--out", out, folder=True, files=("top.txt", "hor.txt", OFFSET_FILE)),
         Output("--draw", args.draw, folder=True), Output("--draw-video", args.draw_video),
         *check_write_cameras(model_args(args))],
        [Input("--top", args.top), Input("--hor", args.hor), *image_inputs(args),
         Input("--cameras", args.cameras), Input("--model", None if args.model == "default"
                                                 else args.model)],
    )
    check_own_folder(out, TRACK_COMMAND)
    if args.draw is not None:
        check_own_folder(args.draw, f"{TRACK_COMMAND} --draw", "--draw")
    return top, hor, camera_rows, out


def _run_options(args: argparse.Namespace, params, weights: str, model):
    """The :class:`~xvmatch.inference.tracks.track_run.TrackRunOptions` of the options, for the
    search's ``params``, the cross-view ``weights`` settled and the ``model`` opened (or None)."""
    from xvmatch.inference.tracks.track_ground import GroundChoice
    from xvmatch.inference.tracks.track_run import TrackRunOptions, track_weights
    from xvmatch.inference.tracks.tracking import TrackConfig

    given = ("clip_length", "min_iou", "max_gap", "solver", "time_limit", "seed", "min_colour",
             "time_appearance")
    config = TrackConfig(**{k: getattr(args, k) for k in given},
                         weights=track_weights(weights, args.c0, args.w1, args.w2, args.sigma))
    return TrackRunOptions(
        config=config, params=params, weights=weights, model=model,
        model_name=str(args.model), top_images=args.top_images, hor_images=args.hor_images,
        cameras=args.cameras, top_boxes=args.top, hor_boxes=args.hor, ground=GroundChoice(
            args.top_view, args.top_image_size, args.hor_hfov, args.fps),
        appearance_check=args.appearance_check == "on",
        refine_top_camera=args.refine_top_camera != "off",
        camera_check=args.camera_check != "off", fit_w1=args.w1 is None, workers=args.workers)


def _cmd_track(args: argparse.Namespace) -> int:
    from xvmatch.formats.detection_rows import write_track_rows
    from xvmatch.formats.offset_record import write_offset_record
    from xvmatch.inference.tracks import track_run
    from xvmatch.inference.tracks.track_ground import OBLIQUE_OFFSET, oblique_track_top

    start = time.perf_counter()
    check_top_view(args)
    params = spatial_params(args)
    weights = track_run.cross_view_weights(args.weights, args.model, args.cameras,
                                           args.top_images is not None)
    top, hor, camera_rows, out = _read_checked(args)
    max_offset = max_offset_of(args, top.frames, hor.frames) if args.offset == "auto" else None
    model = open_models([args.model])[0] if args.model is not None else None
    options = _run_options(args, params, weights, model)
    with track_run.open_track_images(top.frames, hor.frames, options) as images:
        calib = None if args.cameras else oblique_track_top(  # the ground path's top camera
            top.frames, hor.frames, options.ground, images.top_size, args.top)
        oblique = calib is not None  # the ground path says its own size, and may guess it
        resolved = settled_hor_size(hor.frames, args.hor, args.image_size, images.hor_size,
                                    args.hor_images, args.cameras, args.quiet or oblique, False,
                                    top.frames, oblique)
        positions = None if camera_rows is None else top.positions_of_id(args.camera_id)
        marked, wearer = wearer_marked(top.frames, positions)
        if auto := oblique and args.offset == "auto":  # the nadir search's estimate misleads
            print(f"xvmatch: warning: {OBLIQUE_OFFSET}", file=sys.stderr)
        offset = resolve_offset(args, marked, hor.frames, resolved[0][0], params, max_offset,
                                wearer, 0 if auto else None)
        run = track_run.run_tracking(top.frames, hor.frames, options, resolved, offset,
                                     camera_rows, images, step_progress(not args.quiet),
                                     line_printer(args.quiet), calib)
        if args.draw is not None or args.draw_video is not None:
            shown = track_run.track_pictures(top.frames, hor.frames, run.result, offset, images)
            draw_pictures(args.draw, args.draw_every, shown.top, shown.hor, shown.pairs,
                          shown.frames, shown.sources, resolved[0], not args.no_labels,
                          owner=f"{TRACK_COMMAND} --draw", truth=args.draw_truth,
                          camera_id=args.camera_id, row_ids=(top.file_ids, hor.file_ids),
                          tracks=shown.tracks, video=args.draw_video)
    claim_folder(out, TRACK_COMMAND)
    result = run.result
    n_top = write_track_rows(out / "top.txt", top, result.top_rows)
    n_hor = write_track_rows(out / "hor.txt", hor, result.hor_rows)
    write_offset_record(out / OFFSET_FILE, offset)
    write_cameras(model_args(args), run.cameras, run.refinement)
    if run.warning() is not None:
        print(f"xvmatch: warning: {run.warning()}", file=sys.stderr)
    if run.checked is not None and run.checked.to_tell(args.quiet):
        print(run.checked.message(), file=sys.stderr)
    if not args.quiet:
        ids = set(result.top_rows.values()) | set(result.hor_rows.values())
        print(f"wrote {n_top} top and {n_hor} horizontal boxes, {len(ids)} tracks, to {out}/ "
              f"({time.perf_counter() - start:.1f} s)", file=sys.stderr)
    return 0
