"""The ``xvmatch synth`` command: render a labelled dataset
(:func:`xvmatch.datasets.synthetic_io.generate_dataset`).

``synth --cameras N`` writes one scene of N static cameras instead (the input of ``xvmatch
multicam``, :func:`xvmatch.datasets.synth_runs.synth_cameras`): rendered or, with
``--boxes-only``, from the box simulator, optionally with tracker-like noise.

:func:`add_synth_parser` registers the sub-command on the ``subparsers`` of the main parser; its
``func`` takes the parsed arguments and returns an exit code. Imports are lazy so that
other commands never load OpenCV. Bad input raises ``ValueError`` with a one-line message, which
the main entry point prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
import time

from xvmatch.commands._options import add_command_parser, progress_bar
from xvmatch.commands._types import float_in, image_size, int_in, seed_value, worker_count
from xvmatch.core.output_paths import Output, check_outputs

__all__ = ["EXAMPLE", "add_synth_parser"]

EXAMPLE = ("xvmatch synth --out data/synth --scenario drone --scenes 100 --frames 20 --seed 0 "
           "--workers 2\n  xvmatch synth --cameras 4 --frames 100 --out data/cams4")


MAX_PEOPLE = 60
"""Most people per scene: what the renderer places in a scene's area (``SynthConfig``)."""


def _people_range(text: str) -> tuple[int, int]:
    try:
        low, high = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN:MAX, e.g. 3:14; got {text!r}") from None
    if not 1 <= low <= high <= MAX_PEOPLE:
        raise argparse.ArgumentTypeError(
            f"need 1 <= MIN <= MAX <= {MAX_PEOPLE} (the renderer places at most {MAX_PEOPLE} "
            f"people in a scene), got {text!r}"
        )
    return low, high


MAX_FRAMES = 10_000
"""Most frames per scene (``synth --frames``)."""


def add_synth_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch synth`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers,
        "synth",
        "Render labelled image pairs (top/overview + egocentric views of walking people) with "
        "calibrated cameras: images/{top,ego}/SCENE_FRAME.jpg and annotations/SCENE.json.",
        EXAMPLE,
    )
    p.add_argument("--out", required=True, help="output folder (new, empty, or a previous "
                   "synth output)")
    p.add_argument("--scenario", choices=("drone", "overview"), default=None,
                   help="drone: nadir camera 20-60 m up + head-worn camera (CVMHAT); overview: "
                   "building camera 8-25 m up + hand-held camera (default drone)")
    p.add_argument("--scenes", default=None,
                   type=int_in(1, 100_000, "a bound on the run's time and disk: 100000 scenes "
                               "is ten times the largest training set"),
                   help="number of scenes, 1..100000 (default 10)")
    g = p.add_argument_group("several static cameras (one scene, the input of xvmatch multicam)")
    g.add_argument("--cameras", default=None, type=int_in(2, 8, "static cameras per scene"),
                   help="write one scene of N static calibrated cameras, 2..8: cameras.json, "
                   "boxes/NAME.txt (per-camera track ids), gt/NAME.txt (global ids), "
                   "ground_gt.csv, images/NAME/ (default people 12:12, --size 640x360)")
    g.add_argument("--boxes-only", action="store_true",
                   help="with --cameras: the box simulator, no images (fast)")
    g.add_argument("--tracker-noise", action="store_true",
                   help="with --cameras: tracker-like noise on boxes/ (jitter, misses, false "
                   "boxes, id switches, fragments; gt/ stays clean)")
    p.add_argument("--frames", default=10,
                   type=int_in(1, MAX_FRAMES, "frames per scene: a scene's walk is held in "
                               "memory"),
                   help=f"frames per scene, 1..{MAX_FRAMES}; people walk with turns and stops "
                   "(default 10)")
    p.add_argument("--seed", type=seed_value, default=0, help="random seed, 0..2**32-1 "
                   "(default 0); the output is identical for any --workers")
    p.add_argument("--people", type=_people_range, default=None, metavar="MIN:MAX",
                   help=f"people per scene, camera wearer included, 1 <= MIN <= MAX <= "
                   f"{MAX_PEOPLE} (default 3:14)")
    p.add_argument("--size", default=(640, 360), metavar="WxH",
                   type=image_size(8, 8192, "each image is held in memory: 8192x8192 is 200 "
                                   "MB; the renderer needs 8"),
                   help="image size of both views, 8..8192 a side (default 640x360)")
    p.add_argument("--difficulty", choices=("easy", "medium", "hard"), default="medium",
                   help="look-alike clothing and photometric degradation (default medium)")
    p.add_argument("--texture", default=0.0, metavar="D",
                   type=float_in(0, 1, "a depth of brightness modulation"),
                   help="photographic textures over the people, depth in [0, 1] (default 0: "
                   "none; image pairs only; needs pip install --no-deps scikit-image, whose "
                   "CC0 and public-domain images they are)")
    p.add_argument("--fps", default=10.0,
                   type=float_in(0.1, 1000, "a camera's frame rate, frames per second"),
                   help="frame rate of the walks, in [0.1, 1000] (default 10)")
    p.add_argument("--workers", type=worker_count, default=1,
                   help="rendering processes, 1..64 (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=_cmd_synth)
    return p


def _cmd_synth(args: argparse.Namespace) -> int:
    from xvmatch.datasets.render.image_render import Difficulty
    from xvmatch.datasets.synthetic_io import generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    if args.cameras is not None:
        return _synth_cameras(args)
    for option, given in (("--boxes-only", args.boxes_only),
                          ("--tracker-noise", args.tracker_noise)):
        if given:
            raise ValueError(f"{option} needs --cameras N (a scene of several static cameras)")
    args.scenario = args.scenario or "drone"
    args.scenes = 10 if args.scenes is None else args.scenes
    check_outputs([Output("--out", args.out, folder=True)])
    difficulty = Difficulty.preset(args.difficulty)
    if args.texture:
        from dataclasses import replace

        from xvmatch.datasets.render.person_textures import load_textures

        load_textures()  # a missing package is one line here, not an error in each worker
        difficulty = replace(difficulty, texture=args.texture)
    config = SynthConfig(scenario=args.scenario, n_people=args.people or (3, 14),
                         top_size=args.size, ego_size=args.size, fps=args.fps)
    total = args.scenes * args.frames
    start = time.perf_counter()
    with progress_bar(total, "synth", "pair", not args.quiet) as bar:
        manifest = generate_dataset(
            args.out, config, n_scenes=args.scenes, n_frames=args.frames, seed=args.seed,
            workers=args.workers, difficulty=difficulty, progress=bar.update,
        )
    elapsed = time.perf_counter() - start
    if not args.quiet:
        print(f"wrote {total} pairs ({args.scenes} scenes x {args.frames} frames, "
              f"{args.scenario}) to {manifest.parent} in {elapsed:.1f} s "
              f"({total / max(elapsed, 1e-9):.1f} pairs/s)", file=sys.stderr)
    return 0


def _synth_cameras(args: argparse.Namespace) -> int:
    """``synth --cameras N``: one multi-camera scene, rendered or box-only (issue 32)."""
    from xvmatch.datasets.multicam_scenes import MulticamConfig
    from xvmatch.datasets.synth_runs import CamerasSynthOptions, synth_cameras

    if args.texture:
        raise ValueError("--texture applies to image pairs, not to --cameras")
    for option, wrong in (("--scenario", args.scenario is not None),
                          ("--scenes", args.scenes not in (None, 1))):
        if wrong:
            raise ValueError(f"{option} does not apply to --cameras (one scene of static "
                             "cameras per run; run again with another --seed for more)")
    width, height = args.size
    if height != round(width * 9 / 16):
        raise ValueError(f"--size {width}x{height}: with --cameras every camera is 16:9; give "
                         f"{width}x{round(width * 9 / 16)}")
    if not args.boxes_only and not 8 <= width <= 4096:
        raise ValueError(f"--size: with --cameras the width must be in 8..4096, got {width}")
    check_outputs([Output("--out", args.out, folder=True)])
    options = CamerasSynthOptions(
        args.out, MulticamConfig(n_cameras=args.cameras, n_people=args.people or (12, 12),
                                 fps=args.fps),
        args.frames, args.seed, width=width, difficulty=args.difficulty,
        boxes_only=args.boxes_only, tracker_noise=args.tracker_noise)
    start = time.perf_counter()
    with progress_bar(1, "synth", "scene", not (args.quiet or args.boxes_only)) as bar:
        root, scene = synth_cameras(options, bar.update)
    if not args.quiet:
        kind = "box-only" if args.boxes_only else "rendered"
        print(f"wrote a {kind} scene of {args.cameras} static cameras x {args.frames} frames to "
              f"{root} in {time.perf_counter() - start:.1f} s; try: xvmatch multicam --boxes "
              + " ".join(f"{n}={root / 'boxes' / (n + '.txt')}" for n in scene.cameras)
              + f" --cameras {root / 'cameras.json'} --out OUT/", file=sys.stderr)
    return 0
