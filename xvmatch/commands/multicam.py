"""The ``xvmatch multicam`` command: one global id per person across several static cameras and
each person's path on the ground (issue 32; :mod:`xvmatch.inference.views.multicam`), and
``--fit-homography`` to make ``H`` cameras from image/ground point pairs.

Everything is read and checked, and the answer computed, before anything is written; the outputs
are written atomically into a folder the command owns
(:func:`xvmatch.core.output_paths.claim_folder`).
"""

from __future__ import annotations

import argparse
import os

from xvmatch.commands._options import UsageError, add_command_parser, progress_bar, read_boxes
from xvmatch.commands._types import float_in, image_size, int_in
from xvmatch.core.output_paths import Input, Output, check_outputs, claim_folder, plain_name

__all__ = ["COMMAND", "EXAMPLE", "add_multicam_parser", "evaluate_multicam_command", "named_paths",
           "read_ground_csv"]

EXAMPLE = ("xvmatch multicam --boxes cam1=cam1.txt cam2=cam2.txt cam3=cam3.txt "
           "--cameras cameras.json --out multicam_out/")
COMMAND = "xvmatch multicam"
"""The marker name of the command's output folders."""

_CAMERA_SIZE = image_size(8, 65536, "pixels of a camera image")
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
        description="Associate people across 2 or more static, calibrated, partly overlapping "
        "cameras from each camera's boxes and track ids (ids are never compared across "
        "cameras). Writes OUT/NAME.txt (the input rows, the id replaced by a global id), "
        "OUT/tracks.csv (camera,track_id,first_frame,last_frame,global_id), OUT/ground.csv "
        "(frame,global_id,X,Y in metres) and OUT/birdseye.png. Lens distortion must be "
        "removed beforehand. With --fit-homography, fits H cameras from point pairs instead.",
    )
    p.add_argument("--boxes", nargs="+", metavar="NAME=FILE",
                   help="each camera's MOT box file with its own track ids; NAME is a camera "
                   "of --cameras")
    p.add_argument("--cameras", metavar="FILE",
                   help="camera JSON (version 1): per camera K, R, c, width, height or H, "
                   "width, height (H maps pixels to the ground in metres)")
    p.add_argument("--method", choices=("ours", "dtw"), default="ours",
                   help="ours: the trajectory-correspondence paper's features, reprojection "
                   "conflicts, fusion and linkage; dtw: its DTW baseline (M1)")
    p.add_argument("--split-frames", type=int_in(0, 100000, "frames of a track piece"),
                   default=None, metavar="L",
                   help="associate each track in pieces of L frames, rejoined unless the other "
                   "cameras disagree (a tracker's id switch); 0: whole tracks, as the paper "
                   "(default 20 with --method ours, 0 with dtw: the paper's M1)")
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
                   help="with --fit-homography: each camera's image size")
    p.add_argument("--duplicates", choices=("first", "error"), default="first",
                   help="a repeated (frame, id) in a box file: keep the first box with a "
                   "warning (default) or stop")
    p.add_argument("--above-horizon", choices=("error", "drop"), default="error",
                   help="a box whose foot point lies at or above its camera's horizon (no "
                   "person stands there: a false detection or a wrong calibration): stop with "
                   "its file and line (default), or leave it out of the association with a "
                   "warning (it keeps a global id of its own)")
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
    if args.boxes is None or args.cameras is None:
        raise UsageError("give --boxes NAME=FILE ... and --cameras (or --fit-homography)")
    from xvmatch.formats.camera_io import load_ground_cameras
    from xvmatch.inference.views.multicam import (
        MulticamInputError,
        MulticamOptions,
        associate_cameras,
        relabel,
    )

    files, images = _checked_inputs(args)
    names = list(files)
    cameras = load_ground_cameras(args.cameras)
    for name, path in files.items():
        if name not in cameras:
            raise UsageError(f"--boxes {name}={path}: camera {name} is not in {args.cameras} "
                             f"(it has {', '.join(cameras)})")
    boxes = {name: read_boxes(path, args.duplicates) for name, path in files.items()}
    for name, frames in boxes.items():
        _check_inside(files[name], frames, cameras[name])
    kept, above = boxes, {}
    if args.above_horizon == "drop":
        kept, above = _drop_above_horizon(boxes, cameras, files)
    options = MulticamOptions(method=args.method, split_frames=_split_frames(args))
    if args.appearance_weight is not None:
        from dataclasses import replace

        options = replace(options, appearance_weight=args.appearance_weight)
    sources, embedders = _open_images(args, images, kept, cameras)
    n_pairs = len(names) * (len(names) - 1) // 2
    try:
        with progress_bar(n_pairs, "camera pairs", "pair", not args.quiet) as bar:
            try:
                result = associate_cameras(cameras, kept, options, progress=bar.update,
                                           appearance=embedders or None)
            except MulticamInputError as exc:
                path = files[exc.camera]
                raise UsageError(f"{path}{_line_of(path, str(exc))}: {exc}") from None
    finally:
        for source in sources:
            source.close()
    relabelled = relabel(kept, result)
    if above:
        relabelled = _put_back(boxes, relabelled, above, max(result.ground, default=0))
    if args.localise != "foot":
        result = _localised(args.localise, cameras, relabelled, result)
    picture = _birdseye(result, cameras)
    out = claim_folder(args.out, COMMAND)
    _write_outputs(out, boxes, relabelled, result, picture)
    if not args.quiet:
        n_people = len(result.ground)
        print(f"{n_people} global ids over {len(names)} cameras; wrote {os.fspath(out)}/")
    return 0


def _checked_inputs(args: argparse.Namespace) -> tuple[dict[str, str], dict[str, str]]:
    """``(files, images)``: ``--boxes`` and ``--images`` by camera name, after the checks of
    the options and of every input and output path."""
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
    outputs = (*(f"{n}.txt" for n in files), "tracks.csv", "ground.csv", "birdseye.png")
    check_outputs([Output("--out", args.out, folder=True, files=outputs)],
                  [Input("--cameras", args.cameras),
                   *(Input("--boxes", f) for f in files.values()),
                   *(Input("--images", f) for f in images.values())])
    from xvmatch.core.output_paths import check_own_folder

    check_own_folder(args.out, COMMAND)
    return files, images


def _localised(localise_option: str, cameras, relabelled, result):
    """``result`` with each person's ground positions from ``--localise`` (``two-best`` or
    ``all`` cameras' boxes) instead of the foot points."""
    from dataclasses import replace

    from xvmatch.inference.views.multicam_localisation import LocalisationOptions, localise

    method = "two_best" if localise_option == "two-best" else "all"
    ground = localise(cameras, relabelled, result.ground, LocalisationOptions(method))
    return replace(result, ground=ground)


def _open_images(args: argparse.Namespace, images: dict[str, str], boxes, cameras):
    """``--images``: each camera's open image source (every frame with boxes checked, its size
    the camera's) and embedder ``(frame, boxes) -> descriptors`` with the ``--model``'s
    appearance network; nothing without ``--images``."""
    import sys

    if not images:
        return [], {}
    from xvmatch.inference.matching.learned_association import load_matcher_bundle
    from xvmatch.inference.matching.learned_pipeline import open_view_images

    model_name = args.model or "default"
    matcher = load_matcher_bundle(model_name)
    if matcher.bundle.manifest.appearance is None:
        raise UsageError(f"--model {model_name}: a box-only bundle has no appearance network; "
                         "use one with images (e.g. default)")
    if matcher.bundle.adaptation is not None and not args.quiet:
        print(f"xvmatch: note: --model {model_name}: its site adaptation is for top/horizontal "
              "view pairs; multicam compares raw descriptors", file=sys.stderr)
    sources, embedders = [], {}
    try:
        for name, path in images.items():
            frames = boxes[name]
            source = open_view_images(path, frames, [f for f in sorted(frames) if len(frames[f])])
            sources.append(source)
            cam = cameras[name]
            if tuple(source.size) != (cam.width, cam.height):
                raise UsageError(f"--images {name}={path}: the images are "
                                 f"{source.size[0]}x{source.size[1]} but camera {name} is "
                                 f"{cam.width}x{cam.height} in {args.cameras}")
            embedders[name] = _embedder(source, matcher)
    except BaseException:
        for source in sources:
            source.close()
        raise
    return sources, embedders


def _embedder(source, matcher):
    """``embed(frame, boxes)``: the matcher's descriptors of the boxes on the source's image of
    the frame (the last image read is kept: the association asks frame by frame)."""
    last: dict = {}

    def embed(frame: int, boxes):
        if last.get("frame") != frame:
            last["frame"], last["image"] = frame, source.get(frame)
        return matcher.descriptors(last["image"], boxes)

    return embed


def _drop_above_horizon(boxes, cameras, files):
    """``--above-horizon drop``: each camera's boxes without those whose foot point lies at or
    above its horizon, and ``{camera: {frame: mask of the dropped}}``; one warning per camera."""
    import sys

    from xvmatch.formats.mot_boxes import FrameBoxes
    from xvmatch.geometry.ground_plane import foot_points

    kept, above = {}, {}
    for name, frames in boxes.items():
        kept[name], above[name], n = {}, {}, 0
        for f, rec in frames.items():
            _, ok = cameras[name].to_ground(foot_points(rec.boxes))
            kept[name][f] = FrameBoxes(f, rec.ids[ok], rec.boxes[ok])
            above[name][f] = ~ok
            n += int((~ok).sum())
        if n:
            print(f"xvmatch: warning: {files[name]}: {n} box(es) whose foot point lies above "
                  f"camera {name}'s horizon take no part (each gets a global id of its own)",
                  file=sys.stderr)
    return kept, above


def _put_back(boxes, relabelled, above, last_id: int):
    """The dropped boxes back in their places, a new global id per (camera, track id)."""
    import numpy as np

    from xvmatch.formats.mot_boxes import FrameBoxes

    out, fresh = {}, {}
    for name, frames in boxes.items():
        out[name] = {}
        for f, rec in frames.items():
            ids = np.empty(len(rec), dtype=np.int64)
            mask = above[name][f]
            ids[~mask] = relabelled[name][f].ids
            for k in np.flatnonzero(mask):
                key = (name, int(rec.ids[k]))
                if key not in fresh:
                    fresh[key] = last_id + 1 + len(fresh)
                ids[k] = fresh[key]
            out[name][f] = FrameBoxes(f, ids, rec.boxes)
    return out


def _split_frames(args: argparse.Namespace) -> int:
    """``--split-frames``, or its default for the method (20 for ours, 0 for dtw)."""
    if args.split_frames is not None:
        return args.split_frames
    return 0 if args.method == "dtw" else 20


def _check_inside(path: str, frames, camera) -> None:
    """A box entirely outside its camera's image is an error (the boxes and the camera's
    ``width`` and ``height`` do not belong together). Boxes past a border only in part are
    kept: a jittered detection of a near person at the border is one (the two-view rule 3 of
    docs/formats.md, 10% past a border, refuses some of ``xvmatch noise``'s output here)."""
    import numpy as np

    W, H = camera.width, camera.height
    for f in sorted(frames):
        b = frames[f].boxes
        bad = (b[:, 0] >= W) | (b[:, 1] >= H) | (b[:, 0] + b[:, 2] <= 0) | \
            (b[:, 1] + b[:, 3] <= 0)
        if bad.any():
            k = int(np.flatnonzero(bad)[0])
            where = _line_of(path, f"frame {f}, id {frames[f].ids[k]}")
            raise UsageError(f"{path}{where}: frame {f}, id {frames[f].ids[k]}: the box lies "
                             f"entirely outside the camera's {W}x{H} image; check the camera's "
                             "width and height")


def _line_of(path: str, message: str) -> str:
    """``:LINE`` of the first line of ``path`` holding the frame and id a message names."""
    import re

    m = re.search(r"frame (\d+), id (-?\d+)", message)
    if not m:
        return ""
    frame, ident = int(m.group(1)), int(m.group(2))
    try:
        with open(path, encoding="utf-8") as fh:
            for lineno, line in enumerate(fh, 1):
                fields = line.split(",")
                try:
                    if int(float(fields[0])) == frame and int(float(fields[1])) == ident:
                        return f":{lineno}"
                except (ValueError, IndexError):
                    continue
    except OSError:
        pass
    return ""


def _write_outputs(out, boxes, relabelled, result, picture: bytes) -> None:
    """Every output file, each atomically."""
    from xvmatch.core.atomic_files import atomic_write_bytes, atomic_write_text
    from xvmatch.formats.mot_boxes import write_mot_boxes

    for name, frames in relabelled.items():
        write_mot_boxes(out / f"{name}.txt", frames)
    rows = ["camera,track_id,first_frame,last_frame,global_id"]
    for name, frames in relabelled.items():  # one line per stretch of a track under one id
        spans: list[list[int]] = []
        open_span: dict[int, list[int]] = {}
        for f in sorted(frames):
            for t, g in zip(boxes[name][f].ids.tolist(), frames[f].ids.tolist(), strict=True):
                span = open_span.get(t)
                if span is None or span[3] != g:
                    span = [t, f, f, g]
                    open_span[t] = span
                    spans.append(span)
                span[2] = f
        rows += [f"{name},{t},{a},{b},{g}" for t, a, b, g in sorted(spans)]
    atomic_write_text(out / "tracks.csv", "\n".join(rows) + "\n")
    lines = ["frame,global_id,X,Y"]
    points = [(int(f), g, x, y) for g, (fr, xy) in result.ground.items()
              for f, (x, y) in zip(fr.tolist(), xy.tolist(), strict=True)]
    points.sort()
    lines += [f"{f},{g},{x:.4f},{y:.4f}" for f, g, x, y in points]
    atomic_write_text(out / "ground.csv", "\n".join(lines) + "\n")
    atomic_write_bytes(out / "birdseye.png", picture)


def _colour(k: int) -> tuple[int, int, int]:
    """A distinct BGR colour for index ``k`` (golden-ratio hues)."""
    import colorsys

    r, g, b = colorsys.hsv_to_rgb((k * 0.618034) % 1.0, 0.85, 0.9)
    return int(255 * b), int(255 * g), int(255 * r)


def _birdseye(result, cameras, size: int = 1000) -> bytes:
    """PNG of the global trajectories on the ground, each camera's field of view outlined."""
    import cv2
    import numpy as np

    paths = [xy for _fr, xy in result.ground.values() if len(xy)]
    pts = np.concatenate(paths) if paths else np.zeros((1, 2))
    lo, hi = np.percentile(pts, 0.5, axis=0) - 3.0, np.percentile(pts, 99.5, axis=0) + 3.0
    centres = [c.camera.c[:2] for c in cameras.values() if c.camera is not None]
    if centres:
        lo = np.minimum(lo, np.min(centres, axis=0) - 1.0)
        hi = np.maximum(hi, np.max(centres, axis=0) + 1.0)
    scale = (size - 40) / max(float((hi - lo).max()), 1e-6)
    canvas = np.full((size, size, 3), 255, np.uint8)

    def px(xy):
        xy = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.stack([20 + (xy[:, 0] - lo[0]) * scale,
                         size - 20 - (xy[:, 1] - lo[1]) * scale], 1).round().astype(np.int32)

    step = 5.0
    for x in np.arange(np.floor(lo[0] / step) * step, hi[0] + step, step):
        cv2.line(canvas, tuple(px([x, lo[1]])[0]), tuple(px([x, hi[1]])[0]), (235, 235, 235), 1)
    for y in np.arange(np.floor(lo[1] / step) * step, hi[1] + step, step):
        cv2.line(canvas, tuple(px([lo[0], y])[0]), tuple(px([hi[0], y])[0]), (235, 235, 235), 1)
    reach = float((hi - lo).max())
    for i, cam in enumerate(cameras.values()):  # fields of view, lightly filled
        overlay = canvas.copy()
        cv2.fillPoly(overlay, [px(cam.ground_footprint(max_range=reach))],
                     _colour(1000 + i), cv2.LINE_AA)
        canvas = cv2.addWeighted(overlay, 0.08, canvas, 0.92, 0.0)
    for i, (name, cam) in enumerate(cameras.items()):
        colour = tuple(int(0.6 * v + 100) for v in _colour(1000 + i))
        poly = px(cam.ground_footprint(max_range=reach))
        cv2.polylines(canvas, [poly], True, colour, 1, cv2.LINE_AA)
        anchor = px(cam.camera.c[:2])[0] if cam.camera is not None else poly.mean(0).astype(int)
        cv2.circle(canvas, tuple(int(v) for v in anchor), 6, colour, -1, cv2.LINE_AA)
        cv2.putText(canvas, name, (int(anchor[0]) + 8, int(anchor[1]) - 8),
                    cv2.FONT_HERSHEY_SIMPLEX, 0.5, (60, 60, 60), 1, cv2.LINE_AA)
    for g, (_fr, xy) in result.ground.items():
        if len(xy) < 2:
            continue
        line = px(xy)
        cv2.polylines(canvas, [line], False, _colour(g), 2, cv2.LINE_AA)
        cv2.putText(canvas, str(g), tuple(int(v) for v in line[-1]), cv2.FONT_HERSHEY_SIMPLEX,
                    0.4, _colour(g), 1, cv2.LINE_AA)
    cv2.putText(canvas, f"grid {step:g} m; {len(result.ground)} global ids", (20, 20),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    ok, png = cv2.imencode(".png", canvas)
    if not ok:
        raise OSError("could not encode birdseye.png")
    return png.tobytes()


def _fit_homographies(args: argparse.Namespace) -> int:
    """``--fit-homography POINTS.csv``: one H per camera, written as a cameras file."""
    import numpy as np

    from xvmatch.core.input_files import read_input_text
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.geometry.ground_plane import GroundCamera, fit_homography

    check_outputs([Output("--out", args.out)], [Input("--fit-homography", args.fit_homography)])
    sizes = {}
    for name, text in named_paths(args.image_size, "--image-size").items():
        try:
            sizes[name] = _CAMERA_SIZE(text)
        except argparse.ArgumentTypeError as exc:
            raise UsageError(f"--image-size {name}={text}: {exc}") from None
    path = args.fit_homography
    points: dict[str, list[tuple[float, float, float, float]]] = {}
    lines = read_input_text(path, "--fit-homography").split("\n")
    header = [h.strip() for h in lines[0].split(",")] if lines else []
    if header != ["camera", "u", "v", "X", "Y"]:
        raise UsageError(f"{path}:1: expected the header camera,u,v,X,Y")
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        fields = [f.strip() for f in line.split(",")]
        if len(fields) != 5:
            raise UsageError(f"{path}:{lineno}: expected 5 fields camera,u,v,X,Y")
        try:
            values = tuple(float(v) for v in fields[1:])
        except ValueError:
            raise UsageError(f"{path}:{lineno}: u, v, X, Y must be numbers") from None
        if not np.isfinite(values).all():
            raise UsageError(f"{path}:{lineno}: u, v, X, Y must be finite")
        points.setdefault(fields[0], []).append(values)
    if not points:
        raise UsageError(f"{path}: no point pairs")
    cams = {}
    for name, rows in points.items():
        if name not in sizes:
            raise UsageError(f"--image-size: camera {name} of {path} has no size; give "
                             f"--image-size {name}=WxH")
        arr = np.array(rows)
        try:  # too few pairs, points in line, a horizon across them: one line each
            cams[name] = GroundCamera(fit_homography(arr[:, :2], arr[:, 2:], *sizes[name]),
                                      *sizes[name])
        except ValueError as exc:
            raise UsageError(f"{path}: camera {name}: {exc}") from None
    save_cameras(args.out, cams)
    if not args.quiet:
        print(f"fitted {len(cams)} camera(s); wrote {args.out}")
    return 0


def read_ground_csv(path: str) -> dict:
    """``{global_id: (frames, (J, 2) xy)}`` of a CSV ``frame,global_id,X,Y`` (ground.csv or
    true positions); a bad line is an error naming the file and the line."""
    import numpy as np

    try:
        with open(path, encoding="utf-8") as fh:
            lines = fh.read().split("\n")
    except UnicodeDecodeError:
        raise UsageError(f"{path}: not UTF-8 text") from None
    if not lines or [h.strip() for h in lines[0].split(",")] != ["frame", "global_id", "X",
                                                                   "Y"]:
        raise UsageError(f"{path}:1: expected the header frame,global_id,X,Y")
    rows: dict[int, list[tuple[int, float, float]]] = {}
    for lineno, line in enumerate(lines[1:], 2):
        if not line.strip():
            continue
        fields = line.split(",")
        try:
            if len(fields) != 4:
                raise ValueError
            frame, gid = int(fields[0]), int(fields[1])
            x, y = float(fields[2]), float(fields[3])
            if not (np.isfinite(x) and np.isfinite(y)):
                raise ValueError
        except ValueError:
            raise UsageError(f"{path}:{lineno}: expected frame,global_id,X,Y (integers, then "
                             "finite numbers)") from None
        rows.setdefault(gid, []).append((frame, x, y))
    out = {}
    for gid, pts in rows.items():
        pts.sort()
        arr = np.array(pts, dtype=float)
        out[gid] = (arr[:, 0].astype(np.int64), arr[:, 1:])
    return out


def evaluate_multicam_command(args: argparse.Namespace) -> int:
    """``xvmatch evaluate --multicam OUT --gt NAME=FILE ... [--ground-gt FILE]``, or with
    ``--pred NAME=FILE ...`` (one MOT box file per camera, ids global) instead of ``--multicam``:
    trajectory P/R, box pairs, global IDF1, CVIDP/CVIDR/CVIDF1/CVMA over every camera pair and,
    with TrackEval, MOTA/IDF1/HOTA per camera."""
    import json

    from xvmatch.metrics.multicam_cross_view import (
        cross_view_scores,
        format_cross_view,
        view_tracking_scores,
    )
    from xvmatch.metrics.multicam_metrics import format_multicam, multicam_scores

    gt_files = named_paths(args.gt, "--gt")
    if len(gt_files) < 2:
        raise UsageError("--gt: give the ground truth of at least two cameras, NAME=FILE")
    pred_files, folder = _predicted_files(args, gt_files)
    pred = {name: read_boxes(path, args.duplicates) for name, path in pred_files.items()}
    gt = {name: read_boxes(path, args.duplicates) for name, path in gt_files.items()}
    ground_pred = ground_gt = None
    if args.ground_gt is not None:
        if folder is None:
            raise UsageError("--ground-gt: needs --multicam DIR (its ground.csv); with --pred "
                             "there are no predicted ground positions")
        ground_gt = read_ground_csv(args.ground_gt)
        ground_pred = read_ground_csv(os.path.join(folder, "ground.csv"))
    scores = multicam_scores(pred, gt, ground_pred, ground_gt)
    scores["cross_view"] = cross_view_scores(pred, gt)
    tracking = view_tracking_scores(pred, gt)
    scores["views"] = tracking
    if args.json:
        print(json.dumps(scores, indent=2))
    else:
        label = args.name or (folder if folder is not None else "multicam tracks")
        print(format_multicam(scores, label))
        print(format_cross_view(scores["cross_view"], tracking))
    return 0


def _predicted_files(args: argparse.Namespace, gt_files: dict[str, str]
                     ) -> tuple[dict[str, str], str | None]:
    """Each camera's predicted box file, in the order of ``--gt``, and the ``--multicam``
    folder (None with ``--pred``)."""
    from pathlib import Path

    if args.multicam is None:
        pred_files = named_paths(args.pred, "--pred")
        if set(pred_files) != set(gt_files):
            raise UsageError(f"--pred names the cameras {', '.join(pred_files)} but --gt "
                             f"{', '.join(gt_files)}; give both for the same cameras")
        return {name: pred_files[name] for name in gt_files}, None
    folder = Path(args.multicam)
    if not folder.is_dir():
        raise UsageError(f"--multicam {args.multicam}: no such folder (the --out of xvmatch "
                         "multicam)")
    written = sorted(p.stem for p in folder.glob("*.txt"))
    out = {}
    for name, path in gt_files.items():
        mine = folder / f"{name}.txt"
        if not mine.is_file():
            raise UsageError(f"--gt {name}={path}: {mine} does not exist (multicam wrote "
                             f"{', '.join(written) or 'no box file'} there)")
        out[name] = str(mine)
    return out, os.fspath(folder)
