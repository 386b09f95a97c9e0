"""The ``xvmatch associate-multi`` command: one top view and several egocentric views at once.

Reads a top-view box file and 1..3 horizontal (egocentric) box files as detections (their id
columns are read only as each view's track ids in video mode, ``--mode``, and to find each
wearer with ``--camera-id``), settles each view's image size and ``--offset`` (``auto``:
estimated), and runs :func:`xvmatch.inference.views.multi_ego_run.run_multi_ego`: every frame's
cost matrices of every view pair and the joint cycle-consistent program of every frame (with
``--tracks`` the ids carry over frames; in video mode the pairs follow each view's tracks,
:mod:`xvmatch.inference.views.multi_ego_video`). Writes ``OUT/top.txt``, ``OUT/hor1.txt``, ...:
the input rows, text unchanged but the id field, which holds a person id; the same id in two
views of a frame is the same person. ``--draw DIR``: pictures of each (top, horizontal) pair.
Bad input raises ``ValueError`` with one line, printed as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from xvmatch.commands._box_reading import add_box_reading_options
from xvmatch.commands._cameras import add_top_view_arguments, check_top_view, note_printer
from xvmatch.commands._model import (
    add_camera_check,
    add_refine_top_camera,
    add_write_cameras,
    check_write_cameras,
    model_args,
    note_camera_check,
    note_camera_refinement,
    write_cameras,
)
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    add_command_parser,
    add_image_options,
    add_spatial_options,
    check_images_together,
    frame_progress,
    image_inputs,
    spatial_params,
)
from xvmatch.commands._types import box_id, float_in, int_in, thread_count, worker_count
from xvmatch.commands.offset import add_offset_options, max_offset_of, resolve_offset, wearer_marked
from xvmatch.core.output_paths import Input, Output, check_outputs, check_own_folder, claim_folder

__all__ = ["EXAMPLE", "add_multi_ego_parser"]

MULTI_COMMAND = "xvmatch associate-multi"
"""The marker name of the command's output folders (it writes only into a folder it made)."""

EXAMPLE = ("xvmatch associate-multi --model default --top top.txt --hor hor1.txt hor2.txt "
           "hor3.txt --out people/")

MAX_HOR = 3  # most horizontal views (issue 17: one top view and two or three horizontal ones)

TIME_LIMIT_TYPE = float_in(0.01, 600, "seconds per frame before the MIP's fallback")
CLIP_TYPE = int_in(1, 1000, "frames per clip of tracklets")
DRAW_OWNER = "xvmatch associate-multi --draw"


def add_multi_ego_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch associate-multi`` on ``subparsers`` and return its parser."""
    help_text = (
        "Associate the people of one top view and 1-3 horizontal (egocentric) views at once: "
        "a joint assignment over every view pair with cycle consistency (a person matched "
        "hor1-top and top-hor2 is the same in hor1-hor2), solved with HiGHS. Ids are never "
        "compared across views (video mode reads each view's as track ids); writes OUT/top.txt, "
        "OUT/hor1.txt, ...: the rows with a person id shared across the views of a frame."
    )
    p = add_command_parser(subparsers, "associate-multi", help_text, EXAMPLE)
    p.add_argument("--top", required=True, help="top-view boxes (MOT format)")
    p.add_argument("--hor", required=True, nargs="+", metavar="H",
                   help="1 to 3 horizontal-view box files (MOT format)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (created); top.txt, hor1.txt, ... written atomically")
    p.add_argument("--model", default=None, metavar="BUNDLE",
                   help="learned top-ego matcher: a bundle folder or 'default'; without it the "
                   "handcrafted spatial-distribution search (boxes only)")
    add_image_options(p, top_help="images of the top view (as associate; needs --model)",
                      hor_help="images of each horizontal view, in the order of --hor (needs "
                      "--model; its appearance network also scores the hor-hor pairs)",
                      several_hor=True)
    p.add_argument("--cameras", default=None, nargs="+", metavar="CAMERAS",
                   help="per horizontal view, a camera file or folder with cameras 'top' and "
                   "'ego' (as associate; needs --model)")
    add_refine_top_camera(p)
    add_write_cameras(p, several=True)
    add_camera_check(p)
    p.add_argument("--camera-id", default=None, nargs="+", type=box_id, metavar="ID",
                   help="per horizontal view, the top-file id of its wearer (O given; "
                   "|id| <= 2**53); without it O is searched")
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help=IMAGE_SIZE_HELP + " (every horizontal view); with images or cameras it "
                   "must agree with them")
    p.add_argument("--solver", choices=("mip", "greedy"), default="mip",
                   help="mip: the joint program with HiGHS (default); greedy: pairwise "
                   "Hungarian made consistent (the MIP's fallback)")
    p.add_argument("--time-limit", type=TIME_LIMIT_TYPE, default=30.0, metavar="S",
                   help="wall-time guard per frame for the MIP, in [0.01, 600] (default 30); past "
                   "it or its budget (96 added triangles and 1000 HiGHS nodes per program) the "
                   "best consistent answer found is used and counted in a warning")
    p.add_argument("--tracks", action="store_true",
                   help="follow people over time: tracklets per view smooth the costs and "
                   "carry the ids over frames")
    p.add_argument("--clip-length", type=CLIP_TYPE, default=10, metavar="N",
                   help="with --tracks, frames per clip of tracklets, 1..1000 (default 10)")
    p.add_argument("--mode", choices=("auto", "frame", "video"), default="auto",
                   help="video: pairs kept consistent along each view's track ids; frame: "
                   "each frame alone; auto (default): video when every view's ids persist")
    p.add_argument("--draw", default=None, metavar="DIR",
                   help="pictures of each frame's pairs into DIR/hor1/, DIR/hor2/, ...")
    p.add_argument("--draw-every", default=1, metavar="K", type=int_in(1, 100_000, "a step"),
                   help="with --draw: every K-th frame only, 1..100000 (default 1)")
    add_offset_options(p, "Each view is associated at its moment, every row written under "
                       "its own file's frame number", several=True)
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for the learned matcher's features, --offset auto's "
                   "estimates and an oblique top view's lens candidates, 1..64 (default 1; the "
                   "same output for any K)")
    p.add_argument("--threads", type=thread_count, default=1, metavar="K",
                   help="onnxruntime threads, 1..64 (default 1)")
    p.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with images of a video: use a horizontal view's boxes alone where the "
                   "pairs the box-only matcher is sure of show its images too weak to help "
                   "(as associate; default on)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    add_box_reading_options(p)
    add_spatial_options(p)
    add_top_view_arguments(p)
    p.set_defaults(func=_cmd_associate_multi)
    return p


def _run_options(args: argparse.Namespace):
    """``(out, options)`` after every check of the arguments and the output paths: the output
    folder and the run's :class:`~xvmatch.inference.views.multi_ego_run.MultiEgoRunOptions`."""
    from xvmatch.inference.views.multi_ego_run import MultiEgoRunOptions, check_view_inputs
    from xvmatch.inference.views.multi_view_people import PeopleOptions

    n_hor, paths = len(args.hor), [args.top, *args.hor]
    check_view_inputs(paths, {k: getattr(args, k) for k in ("hor_images", "cameras",
                                                              "camera_id")}, MAX_HOR)
    check_top_view(args)
    check_images_together(args.top_images, args.hor_images)
    if args.model is None and (args.top_images or args.cameras):
        raise ValueError("--top-images, --hor-images and --cameras feed a learned matcher: add "
                         "--model default (or a bundle)")
    params = spatial_params(args)
    out = Path(args.out)
    check_outputs(
        [Output("--out", out, folder=True,
                files=("top.txt", *(f"hor{k}.txt" for k in range(1, n_hor + 1)))),
         Output("--draw", args.draw, folder=True),
         *check_write_cameras(model_args(args))],
        [Input("--top", args.top), *(Input("--hor", h) for h in args.hor),
         *image_inputs(args), *(Input("--cameras", c) for c in args.cameras or ()),
         Input("--model", None if args.model == "default" else args.model)],
    )
    check_own_folder(out, MULTI_COMMAND)
    if args.draw is not None:
        check_own_folder(args.draw, DRAW_OWNER, "--draw")
    return out, MultiEgoRunOptions(
        tuple(paths), args.model, args.top_images, tuple(args.hor_images or ()) or None,
        tuple(args.cameras or ()) or None, args.image_size and tuple(args.image_size),
        args.refine_top_camera == "auto", args.camera_check == "on",
        args.appearance_check == "on", params, args.workers,
        PeopleOptions(solver=args.solver, time_limit=args.time_limit, tracks=args.tracks,
                      clip_length=args.clip_length))


def _cmd_associate_multi(args: argparse.Namespace) -> int:
    from xvmatch.commands._box_reading import box_reading, note_if_assumed, read_detections
    from xvmatch.formats.detection_rows import write_track_rows
    from xvmatch.inference.views import multi_ego_run as mer
    from xvmatch.inference.views import multi_ground
    from xvmatch.inference.views.multi_ego_video import AUTO_VIDEO, video_track_ids

    start = time.perf_counter()
    out, options = _run_options(args)
    paths, quiet, n_hor = options.box_files, args.quiet, len(options.box_files) - 1
    say = note_printer(quiet)
    offsets = mer.per_view_offsets(args.offset, n_hor)
    rows = [read_detections(p, box_reading(args)) for p in paths]
    views = [r.frames for r in rows]
    tracks = video_track_ids(views, [r.file_ids for r in rows], args.mode, paths)
    max_offset = (max_offset_of(args, views[0], set().union(*views[1:]))
                  if "auto" in offsets else None)
    camera_rows = mer.wearer_rows(rows[0], args.camera_id)
    matcher = None
    if args.model is not None:
        from xvmatch.commands._model import open_models

        matcher = open_models([args.model], args.threads)[0]
    with mer.open_multi_ego(views, matcher, options) as inputs:
        resolved = mer.multi_ego_sizes(inputs, options)
        calib, note = multi_ground.oblique_top(  # calib None: the nadir path
            views[0], "nadir" if args.cameras else args.top_view, args.top_image_size, paths[0],
            offsets, top_tracks=None if tracks is None else tracks[0], hors=views[1:])
        sizes = mer.path_sizes(resolved, views, paths, ground=calib is not None)
        if note:
            say(note)
        for k, r in enumerate(resolved if calib is None else ()):  # the ground path: its own
            note_if_assumed(r, views[k + 1], paths[k + 1], quiet)
        for k, value in enumerate(offsets):
            marked, wearer = wearer_marked(views[0], camera_rows[k] if camera_rows else None)
            offsets[k] = resolve_offset(args, marked, views[k + 1], sizes[k][0], options.params,
                                        max_offset, wearer, value,
                                        f"--hor {paths[k + 1]}: " if n_hor > 1 else "",
                                        hor_path=paths[k + 1])
        ground = calib and multi_ground.run_multi_ground(
            views, offsets, calib, multi_ground.ground_options(
                views, resolved, paths, args.hor_hfov, args.fps, say, args.workers, camera_rows),
            options.people, tracks, say)
        run = ground or mer.run_multi_ego(
            inputs, matcher, sizes, offsets, camera_rows, options,
            progress=lambda n: frame_progress(n, "costs", not quiet),
            on_refinement=lambda r: note_camera_refinement(r, quiet),
            on_camera_check=lambda v, c: note_camera_check(c, quiet, f"--hor {paths[v]}: "),
            on_appearance_check=lambda v, c: note_camera_check(c, quiet, f"--hor {paths[v]}: "),
            tracks=tracks, on_wandering=lambda v, line: print(
                f"xvmatch: warning: --hor {paths[v]}: {line}", file=sys.stderr))
        if args.draw is not None:  # each (top, horizontal view) pair in DIR/horK/
            from xvmatch.viz.match_pictures import write_match_pictures

            claim_folder(args.draw, DRAW_OWNER, "--draw")
            for k, (t, h, pairs, frames, sources) in enumerate(
                    mer.pair_pictures(inputs, run.people, offsets), 1):
                write_match_pictures(Path(args.draw) / f"hor{k}", args.draw_every, t, h, pairs,
                                     frames, sources, tuple(sizes[k - 1]), owner=DRAW_OWNER,
                                     option="--draw")
    claim_folder(out, MULTI_COMMAND)
    names = ["top", *(f"hor{k}" for k in range(1, n_hor + 1))]
    written = [write_track_rows(out / f"{name}.txt", r, p)
               for name, r, p in zip(names, rows, run.people.person, strict=True)]
    write_cameras(model_args(args), run.refined, run.refinement)
    if run.people.n_fallback:
        print(f"xvmatch: warning: {run.people.n_fallback} of {len(run.frames)} frames spent the "
              f"MIP's budget of work or time limit ({args.time_limit:g} s) or failed, and used "
              "the best consistent answer found instead of the optimum", file=sys.stderr)
    if not quiet:
        if tracks is not None and args.mode == "auto":
            print(f"xvmatch: note: {AUTO_VIDEO}", file=sys.stderr)
        print(f"wrote {sum(written)} boxes of {len(paths)} views, {run.people.n_people} people "
              f"over {len(run.frames)} frames, to {out}/ ({time.perf_counter() - start:.1f} s)",
              file=sys.stderr)
    return 0

