"""The ``xvmatch noise`` command: detector-like noise (jitter, misses, false boxes) on a box
file, seeded."""

from __future__ import annotations

import argparse

from xvmatch.commands._options import HOR_IMAGE_SIZE, add_command_parser, read_boxes
from xvmatch.commands._types import box_id, float_in, seed_value
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLE", "add_noise_parser"]

EXAMPLE = "xvmatch noise --boxes seq_top.txt --view top --seed 1 --out noisy_top.txt"


def add_noise_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch noise`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers,
        "noise",
        "Apply detector-like noise (jitter, misses, false boxes) to a box file, seeded.",
        EXAMPLE,
    )
    p.add_argument("--boxes", required=True, help="input box file (MOT format)")
    p.add_argument("--out", required=True, help="output box file (written atomically)")
    p.add_argument("--view", choices=("top", "hor"), required=True, help="which view it is")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="random seed, 0..2**32-1 (default 0)")
    p.add_argument("--jitter", default=0.05,
                   type=float_in(0, 1, "a fraction of the box size: 1 moves a box by its size"),
                   help="box jitter fraction, in [0, 1] (default 0.05)")
    p.add_argument("--miss", default=0.10, type=float_in(0, 1, "a probability"),
                   help="miss probability, in [0, 1] (default 0.10)")
    p.add_argument("--false", default=0.3,
                   type=float_in(0, 500, "false boxes per frame, each held in memory; 500 is "
                                 "far beyond any detector"),
                   help="false boxes per frame (Poisson mean), in [0, 500] (default 0.3)")
    p.add_argument(
        "--keep-id", type=box_id, action="append", default=[],
        help="never drop this id (repeatable; |id| <= 2**53)",
    )
    p.add_argument(
        "--image-size", type=HOR_IMAGE_SIZE,
        default=None, metavar="WxH",
        help="image size, 8..65536 a side, where false boxes are placed (default: --view top "
        "2688x1512; --view hor as associate: 2688x1512 only when the boxes reach beyond 60%% "
        "of its width, else an error asking for it)",
    )
    p.add_argument(
        "--duplicates", choices=("first", "error"), default="first",
        help="repeated (frame, id): keep the first with a warning (default) or stop",
    )
    p.set_defaults(func=_cmd_noise)
    return p


def _cmd_noise(args: argparse.Namespace) -> int:
    from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
    from xvmatch.formats.mot_boxes import write_mot_boxes

    check_outputs([Output("--out", args.out)], [Input("--boxes", args.boxes)])
    frames = read_boxes(args.boxes, args.duplicates)
    size = args.image_size
    if args.view == "hor":  # false boxes land in this image: the associate rule's size
        from xvmatch.commands._box_reading import note_if_assumed
        from xvmatch.formats.box_image_size import resolve_size

        resolved = resolve_size(frames, args.boxes, [] if size is None else
                                [(size, "--image-size")])
        note_if_assumed(resolved, frames, args.boxes)
        size = resolved[0]
    elif size is None:
        size = (2688, 1512)
    noise = DetectorNoise(jitter=args.jitter, miss_rate=args.miss, false_per_frame=args.false)
    noisy = apply_detector_noise(
        frames, size, noise, seed=args.seed, view=args.view, keep_ids=args.keep_id
    )
    write_mot_boxes(args.out, noisy)
    return 0
