"""The ``xvmatch multicam`` command: one global id per person across several static cameras and
each person's path on the ground (issue 32; the run is
:func:`xvmatch.inference.views.multicam_run.run_multicam`), and
``--fit-homography`` to make ``H`` cameras from image/ground point pairs.

Everything is read and checked, and the answer computed, before anything is written; the outputs
are written atomically into a folder the command owns
(:func:`xvmatch.core.output_paths.claim_folder`).
"""

from __future__ import annotations

import argparse
import os
import sys

from xvmatch.commands._box_reading import add_box_reading_options, box_reading
from xvmatch.commands._options import UsageError, add_command_parser, progress_bar, read_boxes
from xvmatch.commands._types import float_in, image_size, int_in
from xvmatch.core.output_paths import Input, Output, check_outputs, claim_folder, plain_name

__all__ = ["COMMAND", "EXAMPLE", "add_multicam_parser", "named_paths"]

EXAMPLE = ("xvmatch multicam --boxes cam1=cam1.txt cam2=cam2.txt cam3=cam3.txt "
           "--cameras cameras.json --out multicam_out/")
COMMAND = "xvmatch multicam"
"""The marker name of the command's output folders."""

_CAMERA_SIZE = image_size(8, 65536, "pixels of a camera image")
_PIECE = int_in(0, 100000, "frames of a track piece, or auto")
_DEFAULT_WEIGHT = 4.0  # MulticamOptions().appearance_weight, without importing numpy here


def named_paths(values: list[str] | None, option: str) -> dict[str, str]:
    """``NAME=PATH`` arguments as ``{name: path}``; a malformed or repeated name is an error
    naming the option."""
    out: dict[str, str] = {}
    for text in values or []:
        name, sep, path = text.partition("=")
        if not sep or not name or not path:
            raise UsageError(f"{option} {text}: expected NAME=FILE, NAME a camera of the "
                             "cameras file")
        plain_name(name, f"{option} {text}")
        if name in out:
            raise UsageError(f"{option}: camera {name} given twice")
        out[name] = path
    return out


def add_multicam_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch multicam`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers, "multicam",
        "Several static cameras: one global id per person across all cameras (trajectory "
        "association on the ground plane) and each person's ground path.",
        EXAMPLE,
        description="Associate people across 2 or more static, partly overlapping cameras "
        "(calibrated, or calibrated here from their people) from each camera's boxes and "
        "track ids (ids are never compared across cameras). Writes OUT/NAME.txt (the input "
        "rows, the id replaced by a global id), "
        "OUT/tracks.csv (camera,track_id,first_frame,last_frame,global_id), OUT/ground.csv "
        "(frame,global_id,X,Y in metres) and OUT/birdseye.png. Lens distortion must be "
        "removed beforehand. With --fit-homography, fits H cameras from point pairs instead.",
    )
    p.add_argument("--boxes", nargs="+", metavar="NAME=FILE",
                   help="each camera's MOT box file with its own track ids; NAME is a camera "
                   "of --cameras")
    p.add_argument("--cameras", metavar="FILE",
                   help="camera JSON (version 1): per camera K, R, c, width, height or H, "
                   "width, height (H maps pixels to the ground in metres); without it the "
                   "cameras are calibrated and registered from their people (give "
                   "--image-size) and written to OUT/cameras.json")
    p.add_argument("--method", choices=("ours", "dtw"), default="ours",
                   help="ours: the trajectory-correspondence paper's features, reprojection "
                   "conflicts, fusion and linkage; dtw: its DTW baseline (M1)")
    p.add_argument("--split-frames", type=lambda t: t if t == "auto" else _PIECE(t),
                   default=None, metavar="auto|L",
                   help="auto: cut a track only where the other cameras show its id switched, "
                   "or in pieces of 20 frames where many do (a tracker's output); L: every "
                   "track in pieces of L frames, rejoined unless the other cameras disagree; "
                   "0: whole tracks, as the paper (default auto with --method ours, 0 with "
                   "dtw: the paper's M1)")
    p.add_argument("--localise", choices=("foot", "two-best", "all"), default="foot",
                   help="ground.csv from: foot, the fused foot points (default); two-best, "
                   "the VRL paper's two most visible views (principal axes along the "
                   "vertical, K R c cameras); all, every view's axes")
    p.add_argument("--out", metavar="DIR",
                   help="output folder (new, empty, or an earlier multicam's); with "
                   "--fit-homography the camera JSON to write")
    p.add_argument("--fit-homography", metavar="POINTS.csv", default=None,
                   help="fit each camera's H with OpenCV from a CSV 'camera,u,v,X,Y' (pixels, "
                   "ground metres; 4 or more points per camera) and write the cameras file "
                   "to --out; give each camera's --image-size")
    p.add_argument("--image-size", nargs="+", metavar="NAME=WxH", default=None,
                   help="each camera's image size: without --cameras, or with "
                   "--fit-homography")
    p.add_argument("--duplicates", choices=("first", "error"), default="first",
                   help="a repeated (frame, id) in a box file: keep the first box with a "
                   "warning (default) or stop")
    add_box_reading_options(p)
    p.add_argument("--above-horizon", choices=("error", "drop"), default="error",
                   help="a box whose foot point lies at or above its camera's horizon (no "
                   "person stands there: a false detection or a wrong calibration): stop with "
                   "its file and line (default; drop without --cameras), or leave it out of "
                   "the association with a warning (it keeps a global id of its own)")
    p.add_argument("--images", nargs="+", metavar="NAME=PATH", default=None,
                   help="optional: a camera's images (a folder of numbered frames, a quoted "
                   "glob pattern or a video; its size the camera's), for any of the cameras "
                   "of --boxes: an appearance cost (the --model's appearance network) between "
                   "trajectories of two cameras with images joins the geometry where "
                   "conflicts are resolved (--method ours)")
    p.add_argument("--model", metavar="default|BUNDLE", default=None,
                   help="with --images: the bundle whose appearance network embeds the boxes "
                   "(default: the shipped one); a site bundle's adaptation (xvmatch adapt) is "
                   "for top/horizontal pairs and is not used here: raw descriptors")
    p.add_argument("--appearance-weight", type=float_in(0.0, 100.0, "weight"), default=None,
                   metavar="W",
                   help="with --images: weight of the appearance cost |a-b|/2 added to the "
                   "reprojection distance in box heights (default "
                   f"{_DEFAULT_WEIGHT:g}, chosen on rendered scenes; 0: off)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_multicam)
    return p


def _cmd_multicam(args: argparse.Namespace) -> int:
    if args.out is None:
        raise UsageError("--out is required")
    if args.fit_homography is not None:
        return _fit_homographies(args)
    if args.boxes is None:
        raise UsageError("give --boxes NAME=FILE ... (or --fit-homography)")
    from xvmatch.formats.camera_io import load_ground_cameras, save_cameras
    from xvmatch.formats.multicam_files import write_multicam_outputs
    from xvmatch.inference.views.multicam_run import (
        check_box_cameras,
        check_image_sizes,
        run_multicam,
    )
    from xvmatch.viz.birdseye import draw_birdseye

    options = _run_options(args)
    files = options.box_files
    if args.cameras is not None:
        cameras = load_ground_cameras(args.cameras)
        check_box_cameras(files, cameras, args.cameras)
    else:
        cameras = None  # estimated by the run from the people
        check_image_sizes(files, options)  # before the boxes are read
    reading = box_reading(args)
    boxes = {name: read_boxes(path, args.duplicates, reading) for name, path in files.items()}
    run = run_multicam(cameras, boxes, options,
                       progress=lambda n: progress_bar(n, "camera pairs", "pair", not args.quiet),
                       warn=lambda m: print(f"xvmatch: warning: {m}", file=sys.stderr),
                       note=None if args.quiet else
                       lambda m: print(f"xvmatch: note: {m}", file=sys.stderr))
    picture = draw_birdseye(run.result.ground, run.cameras)
    out = claim_folder(args.out, COMMAND)
    write_multicam_outputs(out, boxes, run.relabelled, run.result.ground, picture)
    if run.estimated is not None:
        save_cameras(out / "cameras.json", run.estimated.cameras, run.estimated.records())
    if not args.quiet:  # said once written: a run or a write that fails claims nothing
        if run.estimated is not None:
            print(f"xvmatch: note: {run.estimated.summary()}; wrote them to "
                  f"{os.fspath(out / 'cameras.json')}", file=sys.stderr)
        n_people = len(run.result.ground)
        print(f"{n_people} global ids over {len(files)} cameras; wrote {os.fspath(out)}/")
    return 0


def _run_options(args: argparse.Namespace):
    """The run's options, after every check of the options and of the input and output paths."""
    from xvmatch.core.output_paths import check_own_folder
    from xvmatch.inference.views.multicam_run import MulticamRunOptions, association_options

    files = named_paths(args.boxes, "--boxes")
    if len(files) < 2:
        raise UsageError(f"--boxes: multicam needs at least two cameras, got {len(files)}")
    images = named_paths(args.images, "--images")
    for name, path in images.items():
        if name not in files:
            raise UsageError(f"--images {name}={path}: camera {name} has no --boxes (it has "
                             f"{', '.join(files)}); give --boxes {name}=FILE or drop its images")
    if not images and (args.model is not None or args.appearance_weight is not None):
        raise UsageError("--model and --appearance-weight need --images")
    if images and args.method != "ours":
        raise UsageError("--images needs --method ours (dtw has no appearance term)")
    outputs = (*(f"{n}.txt" for n in files), "tracks.csv", "ground.csv", "birdseye.png",
               *(("cameras.json",) if args.cameras is None else ()))
    check_outputs([Output("--out", args.out, folder=True, files=outputs)],
                  [Input("--cameras", args.cameras),
                   *(Input("--boxes", f) for f in files.values()),
                   *(Input("--images", f) for f in images.values())])
    check_own_folder(args.out, COMMAND)
    association = association_options(args.method, args.split_frames, args.appearance_weight)
    above = "drop" if args.cameras is None else args.above_horizon  # estimated: a horizon off
    sizes = {n: s for n, s in _sizes(args).items() if n in files} if args.cameras is None else {}
    return MulticamRunOptions(association, files, args.cameras or "", above,
                              args.localise, images, args.model or "default", sizes)


def _sizes(args: argparse.Namespace) -> dict[str, tuple[int, int]]:
    """``--image-size NAME=WxH ...`` as ``{name: (width, height)}``."""
    sizes = {}
    for name, text in named_paths(args.image_size, "--image-size").items():
        try:
            sizes[name] = _CAMERA_SIZE(text)
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"--image-size {name}={text}: {exc}") from None
    return sizes


def _fit_homographies(args: argparse.Namespace) -> int:
    """``--fit-homography POINTS.csv``: one H per camera, written as a cameras file."""
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.formats.multicam_files import read_point_pairs
    from xvmatch.inference.views.multicam_run import fit_ground_cameras

    check_outputs([Output("--out", args.out)], [Input("--fit-homography", args.fit_homography)])
    sizes = _sizes(args)  # its names checked before anything is read
    points = read_point_pairs(args.fit_homography)
    cams = fit_ground_cameras(points, sizes, args.fit_homography)
    save_cameras(args.out, cams)
    if not args.quiet:
        print(f"fitted {len(cams)} camera(s); wrote {args.out}")
    return 0
