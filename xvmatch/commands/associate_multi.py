"""The ``xvmatch associate-multi`` command: one top view and several egocentric views at once.

Reads a top-view box file and 1..3 horizontal (egocentric) box files as detections (their id
columns are ignored, except to find each wearer with ``--camera-id``), builds the cost matrices
of every view pair frame by frame
(:func:`xvmatch.inference.views.multi_view_costs.multi_view_costs`: the learned matcher or the
handcrafted search for top-ego, the appearance network for ego-ego), solves the joint
cycle-consistent program of every frame
(:func:`xvmatch.inference.views.multi_view_people.assign_people`), and writes
``OUT/top.txt``, ``OUT/hor1.txt``, ...: the input rows, text unchanged but the id field, which holds
a person id; the same id in two views of a frame is the same person (ids are unique over the whole
output and do not carry over frames). With ``--tracks`` the ids carry over frames
(:func:`xvmatch.inference.views.multi_ego_tracking.track_multi_view`: tracklets per view smooth the
costs, every frame is solved with the cycle constraints, ids follow the tracklets). ``--offset N1 N2
...|auto`` re-times each horizontal view against the top view (cameras not started together); rows
keep their own frame numbers. Bad input raises ``ValueError`` with one line, printed by the main
entry point as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

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
from xvmatch.core.output_paths import (
    Input,
    Output,
    check_outputs,
    check_own_folder,
    claim_folder,
)

__all__ = ["EXAMPLE", "add_multi_ego_parser"]

MULTI_COMMAND = "xvmatch associate-multi"
"""The marker name of the command's output folders (it writes only into a folder it made)."""

EXAMPLE = ("xvmatch associate-multi --model default --top top.txt --hor hor1.txt hor2.txt "
           "hor3.txt --out people/")

MAX_HOR = 3
"""Most horizontal views (issue 17: one top view and two or three horizontal ones)."""

TIME_LIMIT_TYPE = float_in(0.01, 600, "seconds per frame before the MIP's fallback")
CLIP_TYPE = int_in(1, 1000, "frames per clip of tracklets")


def add_multi_ego_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch associate-multi`` on ``subparsers`` and return its parser."""
    help_text = (
        "Associate the people of one top view and 1-3 horizontal (egocentric) views at once: "
        "a joint assignment over every view pair with cycle consistency (a person matched "
        "hor1-top and top-hor2 is the same in hor1-hor2), solved with HiGHS. The input ids "
        "are ignored; writes OUT/top.txt, OUT/hor1.txt, ...: the input rows with the id "
        "replaced by a person id shared across the views of a frame."
    )
    p = add_command_parser(subparsers, "associate-multi", help_text, EXAMPLE)
    p.add_argument("--top", required=True, help="top-view boxes (MOT format, ids ignored)")
    p.add_argument("--hor", required=True, nargs="+", metavar="H",
                   help="1 to 3 horizontal-view box files (MOT format, ids ignored)")
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
                   help="wall-time guard per frame for the MIP, in [0.01, 600] (default 30; its "
                   "budget of work, the same on every CPU, is 96 added triangles and 1000 "
                   "HiGHS nodes per program); past either the best consistent answer found is "
                   "used and counted in a warning")
    p.add_argument("--tracks", action="store_true",
                   help="follow people over time: tracklets per view smooth the costs and "
                   "carry the ids over frames (still one box per view and person on a frame)")
    p.add_argument("--clip-length", type=CLIP_TYPE, default=10, metavar="N",
                   help="with --tracks, frames per clip of tracklets, 1..1000 (default 10)")
    add_offset_options(p, "Each view is associated at its moment, every row written under "
                       "its own file's frame number", several=True)
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for the learned matcher's features and --offset auto's "
                   "estimates, 1..64 (default 1)")
    p.add_argument("--threads", type=thread_count, default=1, metavar="K",
                   help="onnxruntime threads, 1..64 (default 1)")
    p.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with images of a video: judge each horizontal view's top-ego "
                   "appearance cue on the pairs the box-only matcher is sure of over "
                   "consecutive frames, and use that view's boxes alone when its images are "
                   "shown too weak to help (as associate; default on)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    add_spatial_options(p)
    p.set_defaults(func=_cmd_associate_multi)
    return p


def _per_view(values: list | None, n_hor: int, option: str) -> None:
    if values is not None and len(values) != n_hor:
        raise ValueError(f"{option}: give one per --hor file ({n_hor}), got {len(values)}")


def _wearer_rows(top, camera_id: int) -> dict[int, int]:
    """``{frame: row within the frame's record}`` of the top box with ``camera_id``."""
    positions = top.positions_of_id(camera_id)
    if not positions:
        raise ValueError(f"{top.path}: no box has the --camera-id {camera_id}")
    return positions


def _offsets(args: argparse.Namespace, n_hor: int) -> list:
    """``--offset``: one value per horizontal view (a single one is for all)."""
    values = list(args.offset)
    if len(values) == 1:
        return values * n_hor
    if len(values) != n_hor:
        raise ValueError(f"--offset: give one per --hor file ({n_hor}) or one for all, got "
                         f"{len(values)}")
    return values


def _aligned(views, offsets, images, cameras, camera_rows):
    """Every view (and its images and cameras) re-timed so that top frame ``t + N_k`` and frame
    ``t`` of horizontal view ``k`` share a number (:func:`xvmatch.formats.mot_boxes.
    align_frames`); the rows keep their own frame numbers in the output."""
    from xvmatch.formats.mot_boxes import align_frames
    from xvmatch.inference.matching.learned_pipeline import retimed

    views, shifts = align_frames(views, offsets)
    if images is not None:  # aligned frame f shows the source's frame f - shift
        images = [retimed(x, -m) for x, m in zip(images, shifts, strict=True)]
    if cameras is not None:
        cameras = [retimed(x, -m) for x, m in zip(cameras, shifts[1:], strict=True)]
    if camera_rows is not None:
        camera_rows = [{f + shifts[0]: r for f, r in rows.items()} for rows in camera_rows]
    return views, images, cameras, camera_rows, sorted(set().union(*views))


def _checked_args(args: argparse.Namespace):
    """``(out, paths, params)`` after every check of the arguments and the output paths: the
    output folder, the box files (top first) and the spatial options."""
    n_hor = len(args.hor)
    if not 1 <= n_hor <= MAX_HOR:
        raise ValueError(f"--hor: give 1 to {MAX_HOR} horizontal box files, got {n_hor}")
    for option in ("hor_images", "cameras", "camera_id"):
        _per_view(getattr(args, option), n_hor, "--" + option.replace("_", "-"))
    check_images_together(args.top_images, args.hor_images)
    if args.model is None and (args.top_images or args.cameras):
        raise ValueError("--top-images, --hor-images and --cameras feed a learned matcher: add "
                         "--model default (or a bundle)")
    params = spatial_params(args)
    paths = [args.top, *args.hor]
    if len(set(map(str, map(Path, paths)))) != len(paths):
        raise ValueError("--top and --hor name the same file twice")
    out = Path(args.out)
    check_outputs(
        [Output("--out", out, folder=True,
                files=("top.txt", *(f"hor{k}.txt" for k in range(1, n_hor + 1)))),
         *check_write_cameras(model_args(args))],
        [Input("--top", args.top), *(Input("--hor", h) for h in args.hor),
         *image_inputs(args),
         *(Input("--cameras", c) for c in args.cameras or ()),
         Input("--model", None if args.model == "default" else args.model)],
    )
    check_own_folder(out, MULTI_COMMAND)
    return out, paths, params


def _open_images(args: argparse.Namespace, matcher, views, paths, given, sources: list):
    """The images of every view (``sources``, top first, each added as it opens so that the
    caller closes them), their sizes added to ``given``; the top boxes checked against theirs."""
    from xvmatch.formats.box_image_size import check_boxes_in_image
    from xvmatch.inference.matching.learned_pipeline import open_view_images

    if matcher.bundle.manifest.appearance is None:
        raise ValueError(f"{args.model}: a box-only matcher cannot use images; drop "
                         "the images or use a bundle with an appearance network")
    for v, path in enumerate([args.top_images, *args.hor_images]):
        source = open_view_images(path, views[v],
                                  [f for f in sorted(views[v]) if len(views[v][f])])
        sources.append(source)
        if v:
            given[v - 1].append((tuple(source.size), f"the horizontal images {path}"))
        else:
            check_boxes_in_image(views[0], tuple(source.size), paths[0],
                                 f"the images {path}", ids=False)
    return sources


def _open_cameras(args: argparse.Namespace, matcher, views, paths, given) -> list:
    """``--cameras`` of every horizontal view, each ego camera the size ``given`` names (else
    its size added to ``given``)."""
    from xvmatch.formats.camera_frames import open_cameras

    if not matcher.bundle.manifest.uses_cameras:
        raise ValueError(f"{args.model}: this matcher takes no camera cues; drop "
                         "--cameras")
    cameras = []
    for k, path in enumerate(args.cameras):
        cams = open_cameras(path, sorted(views[k + 1]))
        for where, pair in cams.all():
            size = tuple(pair.hor.image_size)
            if given[k] and tuple(given[k][0][0]) != size:
                want = given[k][0][0]
                raise ValueError(f"{where}: camera 'ego' is {size[0]}x{size[1]} but "
                                 f"{paths[k + 1]}'s images are {want[0]}x{want[1]} "
                                 f"(from {given[k][0][1]})")
            if not given[k]:
                given[k].append((size, f"the camera files {path}"))
        cameras.append(cams)
    return cameras


def _sizes_and_offsets(args: argparse.Namespace, views, paths, given, offsets, camera_rows,
                       params, max_offset):
    """``(sizes, offsets)``: each horizontal view's image size (said when assumed) and its
    offset against the top view (``--offset``, estimated where ``auto``)."""
    from xvmatch.commands._image_size import note_if_assumed
    from xvmatch.formats.box_image_size import resolve_size

    n_hor = len(paths) - 1
    resolved = [resolve_size(views[k + 1], paths[k + 1], given[k], ids=False)
                for k in range(n_hor)]
    for k, r in enumerate(resolved):
        note_if_assumed(r, views[k + 1], paths[k + 1], args.quiet)
    sizes = [r[0] for r in resolved]
    for k, value in enumerate(offsets):
        marked, wearer = wearer_marked(views[0], camera_rows[k] if camera_rows else None)
        offsets[k] = resolve_offset(args, marked, views[k + 1], sizes[k][0], params,
                                    max_offset, wearer, value,
                                    f"--hor {paths[k + 1]}: " if n_hor > 1 else "",
                                    hor_path=paths[k + 1])
    return sizes, offsets


def _checked_cameras(args: argparse.Namespace, matcher, views, paths, sizes, cameras,
                     refinement):
    """The cameras after ``--camera-check`` (``views`` aligned): a view whose cameras fail is
    matched without them (None)."""
    if refinement is None or args.camera_check != "on":
        return cameras
    from xvmatch.inference.matching.camera_check import check_run_cameras

    cameras = list(cameras)
    for k in range(len(paths) - 1):
        check = check_run_cameras(views[0], views[k + 1], sorted(views[k + 1]),
                                  matcher, tuple(sizes[k]), cameras[k],
                                  float(matcher.gamma), refinement.fit_loss,
                                  workers=args.workers, moving=refinement.moving)
        note_camera_check(check, args.quiet, f"--hor {paths[k + 1]}: ")
        if not check.trusted:
            cameras[k] = None
    return cameras


def _costs(args: argparse.Namespace, rows, paths, params, offsets, max_offset, camera_rows):
    """``(views, frames, problems, refined, refinement)``: every frame's cost matrices of every
    view pair (:func:`~xvmatch.inference.views.multi_view_costs.multi_view_costs`) on the views
    re-timed by their offsets, and the cameras as refined for ``--write-cameras``."""
    from xvmatch.inference.views.multi_view_costs import multi_view_costs

    n_hor = len(paths) - 1
    views = [r.frames for r in rows]
    frames = sorted(set().union(*views))
    matcher = images = cameras = None
    given: list[list] = [[] for _ in range(n_hor)]  # per horizontal view: [(size, source)]
    if args.image_size is not None:
        given = [[(tuple(args.image_size), "--image-size")] for _ in range(n_hor)]
    sources: list = []
    try:
        if args.model is not None:
            from xvmatch.commands._model import open_models

            matcher = open_models([args.model], args.threads)[0]
        if args.top_images is not None:
            images = _open_images(args, matcher, views, paths, given, sources)
        if args.cameras is not None:
            cameras = _open_cameras(args, matcher, views, paths, given)
        sizes, offsets = _sizes_and_offsets(args, views, paths, given, offsets, camera_rows,
                                            params, max_offset)
        refinement = None
        if cameras is not None and args.refine_top_camera == "auto":
            from xvmatch.inference.matching.camera_refinement import refine_views_cameras

            cameras, refinement = refine_views_cameras(
                cameras, views[0], views[1:], [sorted(v) for v in views[1:]], offsets)
            note_camera_refinement(refinement, args.quiet)
        refined = cameras
        if any(offsets):
            views, images, cameras, camera_rows, frames = _aligned(views, offsets, images,
                                                                   cameras, camera_rows)
        cameras = _checked_cameras(args, matcher, views, paths, sizes, cameras, refinement)
        checked: dict = {}
        problems = multi_view_costs(
            views, sizes, frames, matcher=matcher,
            appearance=matcher if images is not None else None, images=images,
            cameras=cameras, camera_rows=camera_rows, params=params, workers=args.workers,
            progress=frame_progress(len(frames), "costs", not args.quiet),
            appearance_check=args.appearance_check == "on", checked=checked,
        )
        for k, check in sorted(checked.items()):
            if check.to_tell(args.quiet):
                print(f"--hor {paths[k]}: {check.message()}", file=sys.stderr)
    finally:
        for source in sources:
            source.close()
    return views, frames, problems, refined, refinement


def _cmd_associate_multi(args: argparse.Namespace) -> int:
    from xvmatch.formats.detection_rows import read_detection_rows, write_track_rows
    from xvmatch.inference.views.multi_view_people import PeopleOptions, assign_people

    start = time.perf_counter()
    out, paths, params = _checked_args(args)
    n_hor = len(paths) - 1
    offsets = _offsets(args, n_hor)
    rows = [read_detection_rows(p) for p in paths]
    views = [r.frames for r in rows]
    max_offset = (max_offset_of(args, views[0], set().union(*views[1:]))
                  if "auto" in offsets else None)
    camera_rows = ([_wearer_rows(rows[0], c) for c in args.camera_id]
                   if args.camera_id is not None else None)
    views, frames, problems, refined, refinement = _costs(args, rows, paths, params, offsets,
                                                          max_offset, camera_rows)
    people = assign_people(views, problems, frames, PeopleOptions(
        solver=args.solver, time_limit=args.time_limit, tracks=args.tracks,
        clip_length=args.clip_length))
    claim_folder(out, MULTI_COMMAND)
    names = ["top", *(f"hor{k}" for k in range(1, n_hor + 1))]
    written = [write_track_rows(out / f"{name}.txt", r, p)
               for name, r, p in zip(names, rows, people.person, strict=True)]
    write_cameras(model_args(args), refined, refinement)
    if people.n_fallback:
        print(f"xvmatch: warning: {people.n_fallback} of {len(frames)} frames spent the MIP's "
              f"budget of work or time limit ({args.time_limit:g} s) or failed, and used the "
              "best consistent answer found instead of the optimum", file=sys.stderr)
    if not args.quiet:
        print(f"wrote {sum(written)} boxes of {len(paths)} views, {people.n_people} people over "
              f"{len(frames)} frames, to {out}/ ({time.perf_counter() - start:.1f} s)",
              file=sys.stderr)
    return 0
