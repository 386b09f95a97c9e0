"""The ``xvmatch synth`` command: a labelled dataset
(:func:`xvmatch.datasets.synthetic_io.generate_dataset`), or one scene of the runs of
:mod:`xvmatch.datasets.synth_runs`: ``--video`` (a smooth clip), ``--egos K`` (K egocentric
views), ``--cameras N`` (N static cameras, rendered or box-only). Each mode ends by printing the
commands that run on what it wrote. Imports are lazy so that other commands never load OpenCV;
bad input raises ``ValueError`` with a one-line message (``xvmatch: error: ...``).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from xvmatch.commands._options import add_command_parser, progress_bar
from xvmatch.commands._types import (
    MAX_PEOPLE,
    float_in,
    image_size,
    int_in,
    people_range,
    seed_value,
    worker_count,
)
from xvmatch.commands.lab._next_steps import print_commands, print_multi_commands
from xvmatch.core.output_paths import Output, check_outputs

__all__ = ["EXAMPLE", "add_synth_parser"]

EXAMPLE = ("xvmatch synth --out data/synth --scenario drone --scenes 100 --frames 20 --seed 0 "
           "--workers 2\n  xvmatch synth --video --frames 200 --out data/clip\n  "
           "xvmatch synth --cameras 4 --frames 100 --out data/cams4")
FPS = {"pairs": 10.0, "video": 25.0}
"""Default ``--fps``: pairs and ``--cameras`` scenes at 10, a ``--video`` clip at 25 (a video's)."""

MAX_FRAMES = 10_000  # most frames per scene (--frames)


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
    p.add_argument("--video", action="store_true",
                   help="write one smooth clip instead: --frames consecutive frames of one scene "
                   "(people walking, the worn camera turning smoothly; what track and associate "
                   "--mode video read) as top.txt, hor.txt (MOT, ground-truth ids), top/, hor/ "
                   "(PNG frames), cameras/ (default --fps 25)")
    p.add_argument("--egos", default=None, metavar="K",
                   type=int_in(2, 3, "head-worn cameras besides the top one: associate-multi "
                               "reads 1 to 3 horizontal views"),
                   help="write one drone scene seen by the top camera and K head-worn cameras, "
                   "2..3 (what associate-multi reads): top.txt, hor1.txt, ... (MOT, "
                   "ground-truth ids), images/VIEW/, cameras/horK/ (default people 6:12)")
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
    p.add_argument("--people", type=people_range, default=None, metavar="MIN:MAX",
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
    p.add_argument("--fps", default=None,
                   type=float_in(0.1, 1000, "a camera's frame rate, frames per second"),
                   help="frame rate of the walks, in [0.1, 1000] (default 10; 25 with --video)")
    p.add_argument("--workers", type=worker_count, default=1,
                   help="rendering processes, 1..64 (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=_cmd_synth)
    return p


def _refuse(mode: str, why: str, *checks: tuple[str, bool]) -> None:
    """Refuse the first option of ``checks`` given where it does not apply (``mode``)."""
    wrong = [option for option, given in checks if given]
    if wrong:
        raise ValueError(f"{wrong[0]} does not apply to {mode} ({why}; run again with another "
                         "--seed for more)")


def _cmd_synth(args: argparse.Namespace) -> int:
    from xvmatch.datasets.synth_runs import synth_difficulty
    from xvmatch.datasets.synthetic_io import MOT_FOLDER, generate_dataset, scene_name
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    modes = [m for m, on in (("--video", args.video), ("--cameras", args.cameras is not None),
                             ("--egos", args.egos is not None)) if on]
    if len(modes) > 1:
        raise ValueError(f"{' and '.join(modes)} are different modes; give one")
    if args.cameras is not None:
        return _synth_cameras(args)
    for option, given in (("--boxes-only", args.boxes_only),
                          ("--tracker-noise", args.tracker_noise)):
        if given:
            raise ValueError(f"{option} needs --cameras N (a scene of several static cameras)")
    if args.video:
        return _synth_video(args)
    if args.egos is not None:
        return _synth_egos(args)
    args.scenario = args.scenario or "drone"
    args.scenes = 10 if args.scenes is None else args.scenes
    check_outputs([Output("--out", args.out, folder=True)])
    difficulty = synth_difficulty(args.difficulty, args.texture)
    config = SynthConfig(scenario=args.scenario, n_people=args.people or (3, 14),
                         top_size=args.size, ego_size=args.size, fps=args.fps or FPS["pairs"])
    total = args.scenes * args.frames
    start = time.perf_counter()
    with progress_bar(total, "synth", "pair", not args.quiet) as bar:
        manifest = generate_dataset(
            args.out, config, n_scenes=args.scenes, n_frames=args.frames, seed=args.seed,
            workers=args.workers, difficulty=difficulty, progress=bar.update, mot_boxes=True,
        )
    elapsed = time.perf_counter() - start
    if not args.quiet:
        root, name = manifest.parent, scene_name(0)
        print(f"wrote {total} pairs ({args.scenes} scenes x {args.frames} frames, "
              f"{args.scenario}) to {root} in {elapsed:.1f} s "
              f"({total / max(elapsed, 1e-9):.1f} pairs/s); each scene also as MOT boxes and "
              f"cameras in {root / MOT_FOLDER}/SCENE/. Match and score scene {name}:",
              file=sys.stderr)
        print_commands(root / MOT_FOLDER / name, Path("pred.csv"),
                       (root / "images" / "top" / f"{name}_*.jpg",
                        root / "images" / "ego" / f"{name}_*.jpg"),
                       root / MOT_FOLDER / name / "cameras")
    return 0


def _synth_video(args: argparse.Namespace) -> int:
    """``synth --video``: one clip of consecutive frames, written as a user's data (issue 69)."""
    from xvmatch.datasets.synth_runs import VideoSynthOptions, synth_difficulty, synth_video
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    _refuse("--video", "one clip, rendered frame after frame",
            ("--scenes", args.scenes not in (None, 1)), ("--workers", args.workers != 1))
    check_outputs([Output("--out", args.out, folder=True)])
    scenario, fps = args.scenario or "drone", args.fps or FPS["video"]
    config = SynthConfig(scenario=scenario, n_people=args.people or (3, 14),
                         top_size=args.size, ego_size=args.size, fps=fps)
    options = VideoSynthOptions(args.out, config, args.frames, args.seed,
                                synth_difficulty(args.difficulty, args.texture))
    start = time.perf_counter()
    with progress_bar(args.frames, "synth", "frame", not args.quiet) as bar:
        paths = synth_video(options, lambda _: bar.update(1))
    if not args.quiet:
        root = paths["top"].parent
        print(f"wrote a {scenario} clip of {args.frames} frames at {fps:g} fps to {root} in "
              f"{time.perf_counter() - start:.1f} s. Track, match and score it:",
              file=sys.stderr)
        size = "{}x{}".format(*args.size)
        print_commands(root, root / "pred.csv", (paths["top_images"], paths["hor_images"]),
                       paths["cameras"],
                       ["--image-size", size, "--offset", "0", "--out", root / "tracks"])
    return 0


def _synth_egos(args: argparse.Namespace) -> int:
    """``synth --egos K``: one scene of a top and K egocentric views (issue 69, item 5)."""
    from xvmatch.datasets.synth_runs import EgosSynthOptions, synth_difficulty, synth_egos

    _refuse("--egos", "one drone scene of head-worn cameras", ("--scenes", args.scenes not in
            (None, 1)), ("--workers", args.workers != 1), ("--scenario", args.scenario not in
                                                           (None, "drone")))
    if args.people is not None and args.people[0] < args.egos + 1:
        raise ValueError(f"--people {args.people[0]}:{args.people[1]}: --egos {args.egos} needs "
                         f"at least {args.egos + 1} people (the wearers and one more)")
    check_outputs([Output("--out", args.out, folder=True)])
    start = time.perf_counter()
    inputs = synth_egos(EgosSynthOptions(
        args.out, args.egos, args.frames, args.seed, args.size, args.fps or FPS["pairs"],
        args.people, synth_difficulty(args.difficulty, args.texture)))
    if not args.quiet:
        root = inputs.boxes[0].parent
        print(f"wrote a scene of a top and {args.egos} egocentric views x {args.frames} frames "
              f"to {root} in {time.perf_counter() - start:.1f} s. Match them all at once:",
              file=sys.stderr)
        print_multi_commands(inputs.boxes, inputs.images, inputs.cameras, root / "multi")
    return 0


def _synth_cameras(args: argparse.Namespace) -> int:
    """``synth --cameras N``: one multi-camera scene, rendered or box-only (issue 32)."""
    from xvmatch.datasets.multicam_scenes import MulticamConfig
    from xvmatch.datasets.synth_runs import CamerasSynthOptions, synth_cameras

    if args.texture:
        raise ValueError("--texture applies to image pairs, not to --cameras")
    _refuse("--cameras", "one scene of static cameras per run",
            ("--scenario", args.scenario is not None), ("--scenes", args.scenes not in (None, 1)))
    width, height = args.size
    if height != round(width * 9 / 16):
        raise ValueError(f"--size {width}x{height}: with --cameras every camera is 16:9; give "
                         f"{width}x{round(width * 9 / 16)}")
    if not args.boxes_only and not 8 <= width <= 4096:
        raise ValueError(f"--size: with --cameras the width must be in 8..4096, got {width}")
    check_outputs([Output("--out", args.out, folder=True)])
    options = CamerasSynthOptions(
        args.out, MulticamConfig(n_cameras=args.cameras, n_people=args.people or (12, 12),
                                 fps=args.fps or FPS["pairs"]),
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
