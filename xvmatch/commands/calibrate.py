"""The ``xvmatch calibrate`` command: a view's camera from the people in its boxes alone.

It parses, checks, calls :func:`~xvmatch.geometry.people_calibration.calibrate_from_people` and
writes the camera file (with its ``estimated`` record) and, with ``--draw``, the picture.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

from xvmatch.commands._cameras import FRAME_RATE
from xvmatch.commands._options import add_command_parser, read_boxes
from xvmatch.commands._types import image_size
from xvmatch.core.output_paths import Input, Output, check_outputs, plain_name

__all__ = ["EXAMPLE", "add_calibrate_parser"]

EXAMPLE = ("xvmatch calibrate --boxes drone.txt --image-size 1920x1080 --out drone_camera.json "
           "--draw drone_camera.png")

_HELP = ("estimate a view's camera (horizon, tilt, roll, field of view, height) from the "
         "people in its boxes alone")

_DESCRIPTION = f"""{_HELP}.

People stand on one floor and are about 1.72 m tall: how their boxes shrink towards the horizon
tells the camera. A clip of 10 s or more with 5 or more people walking at different distances is
enough for a static camera; the view's own track ids (the box file's ids) let each person keep
their own height. A camera looking straight down (a nadir drone) is recognised by its boxes'
shape and written as such. Where the boxes cannot tell (too few people, all at one distance),
the command says so and writes nothing; so it does where the camera's tilt changes over the
clip (a drone's gimbal: a tilt per 3 s window read from the people, --fps the frame numbers'
rate), since a camera file holds one camera. The camera file holds the camera in the view's own
ground frame (above the origin, looking along +x) and an "estimated" record of how it was found
(docs/formats.md); the picture (--draw) shows the horizon, a 2 m ground grid and the height of a
1.72 m person at each box's foot over one frame (--image, or a grey canvas)."""


def add_calibrate_parser(sub) -> None:
    """Register ``xvmatch calibrate``."""
    p = add_command_parser(sub, "calibrate", _HELP, EXAMPLE, description=_DESCRIPTION)
    p.add_argument("--boxes", required=True, help="the view's boxes (MOT format), a clip")
    p.add_argument("--image-size", type=image_size(16), default=None, metavar="WxH",
                   help="the view's image size in pixels (or give --image)")
    p.add_argument("--out", required=True, help="camera file to write (JSON)")
    p.add_argument("--name", default="top",
                   help="the camera's name in the file (default top; ego for a horizontal view)")
    p.add_argument("--hfov", type=float, default=None, metavar="DEG",
                   help="the horizontal field of view when known (degrees, 10-170); by default "
                   "it is estimated from the boxes, or taken as 70 where they cannot tell it")
    p.add_argument("--draw", default=None, metavar="PNG",
                   help="also write a picture of the calibration over one frame")
    p.add_argument("--image", default=None,
                   help="the frame to draw on (an image file of the view); its size is the "
                   "view's image size")
    p.add_argument("--frame", type=int, default=None,
                   help="the frame whose boxes are drawn (default: the one with most boxes)")
    p.add_argument("--fps", default="auto", type=FRAME_RATE,
                   help="the frame numbers' rate, in [0.1, 1000], or auto (default: 30 unless "
                   "the view's walkers say otherwise): the windows in which the tilt is read")
    p.add_argument("--seed", type=int, default=0,
                   help="seed of the resampling that measures the confidence (default 0)")
    p.add_argument("--duplicates", choices=("first", "error"), default="first",
                   help="a repeated (frame, id): keep the first box with a warning (default) "
                   "or stop with an error")
    p.set_defaults(func=_cmd_calibrate)


def _read_image(path: str) -> np.ndarray:
    """The frame to draw on, BGR; ValueError naming the file when it is not an image."""
    import cv2

    from xvmatch.core.input_files import read_input_bytes

    data = np.frombuffer(read_input_bytes(path, "--image"), dtype=np.uint8)
    image = cv2.imdecode(data, cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{path}: --image: not an image OpenCV can read")
    return image


def _options(args: argparse.Namespace) -> tuple[tuple[int, int], np.ndarray | None]:
    """The image size and the frame to draw on, checked."""
    plain_name(args.name, "--name")
    if args.hfov is not None and not 10.0 <= args.hfov <= 170.0:
        raise ValueError(f"--hfov {args.hfov:g}: the horizontal field of view must be 10-170 "
                         "degrees")
    if args.image is not None and args.draw is None:
        raise ValueError("--image is the frame --draw draws on; give --draw PNG too")
    image = _read_image(args.image) if args.image is not None else None
    size = args.image_size
    if image is not None:
        found = (image.shape[1], image.shape[0])
        if size is not None and size != found:
            raise ValueError(f"--image {args.image} is {found[0]}x{found[1]}, --image-size "
                             f"says {size[0]}x{size[1]}")
        size = found
    if size is None:
        raise ValueError("give the view's image size: --image-size WxH (or --image FRAME)")
    return size, image


def _summary(name: str, calib, out: str) -> str:
    """The one line the command prints."""
    if calib.kind == "nadir":
        return (f"{name}: looking straight down (its boxes are as wide as tall); about "
                f"{calib.camera_height:.0f} m up at a {calib.hfov_deg:.0f} degree field of view "
                f"({calib.focal_from}); {calib.n_boxes} boxes over {calib.n_frames} frames -> "
                f"{out}")
    where = ("above the image" if max(calib.horizon) < 0 else
             "below the image" if min(calib.horizon) > calib.height else "in the image")
    return (f"{name}: tilt {calib.tilt_deg:.1f} +- {calib.tilt_std_deg:.1f} degrees down, roll "
            f"{calib.roll_deg:.1f}, horizon at rows {calib.horizon[0]:.0f}..{calib.horizon[1]:.0f} "
            f"({where}), field of view {calib.hfov_deg:.0f} degrees (from the "
            f"{calib.focal_from}), {calib.camera_height:.1f} m up (people "
            f"{calib.person_height} m tall on average); {calib.n_boxes} boxes over "
            f"{calib.n_frames} frames -> {out}")


def _refuse_tilting(frames: dict, stacked: tuple, calib, fps: float | str, name: str) -> None:
    """CalibrationError where an oblique camera's tilt changes over the clip
    (:func:`~xvmatch.inference.matching.ground_association.tilting_top`)."""
    from xvmatch.geometry.people_calibration import CalibrationError
    from xvmatch.geometry.tilting_camera import WINDOW_S
    from xvmatch.inference.matching.ground_association import tilting_top, top_frame_rate

    if calib.kind != "oblique":
        return
    rate = top_frame_rate(frames, calib).fps if fps == "auto" else float(fps)
    tilt = tilting_top(*stacked, calib, rate)
    if tilt is not None:
        raise CalibrationError(
            f"{name}: the camera's tilt changes over the clip (from {tilt.tilts_deg[0]:.0f} to "
            f"{tilt.tilts_deg[-1]:.0f} degrees, a tilt per {WINDOW_S:g} s of its people at "
            f"{rate:g} frames a second) and a camera file holds one camera; give a clip over "
            "which it holds still (or --fps if the rate is not that), or its cameras with "
            "--cameras")


def _cmd_calibrate(args: argparse.Namespace) -> int:
    from xvmatch.core.atomic_files import atomic_write_bytes
    from xvmatch.formats.box_image_size import check_boxes_in_image
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.formats.mot_boxes import stack_frames
    from xvmatch.geometry.people_calibration import calibrate_from_people

    check_outputs([Output("--out", args.out), Output("--draw", args.draw)],
                  [Input("--boxes", args.boxes), Input("--image", args.image)])
    size, image = _options(args)
    frames = read_boxes(args.boxes, args.duplicates)
    check_boxes_in_image(frames, size, args.boxes, "--image-size" if args.image is None
                         else "--image")
    if args.frame is not None and args.frame not in frames:
        raise ValueError(f"--frame {args.frame}: {args.boxes} has no box in that frame")
    numbers, ids, boxes = stack_frames(frames)
    calib = calibrate_from_people(numbers, boxes, size, ids=ids, hfov_deg=args.hfov,
                                  seed=args.seed, name=os.fspath(args.boxes))
    _refuse_tilting(frames, (numbers, ids, boxes), calib, args.fps, os.fspath(args.boxes))
    save_cameras(args.out, {args.name: calib.camera}, estimated={args.name: calib.to_record()})
    if args.draw is not None:
        import cv2

        from xvmatch.viz.calibration_drawing import draw_calibration

        frame = args.frame if args.frame is not None else max(
            sorted(frames), key=lambda f: (len(frames[f].ids), -f))
        canvas = image if image is not None else np.full((size[1], size[0], 3), 96, np.uint8)
        shown = np.asarray(frames[frame].boxes, float).reshape(-1, 4)
        feet = calib.ground_points(np.column_stack([shown[:, 0] + 0.5 * shown[:, 2],
                                                    shown[:, 1] + shown[:, 3]]))
        picture = draw_calibration(canvas, calib.camera, shown, feet, calib.person_height)
        ok, png = cv2.imencode(".png", picture)
        if not ok:
            raise ValueError(f"--draw {args.draw}: OpenCV could not encode the picture")
        atomic_write_bytes(args.draw, png.tobytes())
    print(_summary(args.name, calib, args.out))
    return 0
