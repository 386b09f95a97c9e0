"""The ``xvmatch synth`` and ``xvmatch show`` commands: render a labelled dataset, draw a pair.

``synth --cameras N`` writes one scene of N static cameras instead (the input of ``xvmatch
multicam``): rendered (:mod:`xvmatch.datasets.render.multicam_render`) or, with
``--boxes-only``, from the box simulator (:mod:`xvmatch.datasets.multicam_scenes`), optionally with
tracker-like noise.

Each ``add_*_parser`` registers one sub-command on the ``subparsers`` of the main parser; the
command's ``func`` takes the parsed arguments and returns an exit code. Imports are lazy so that
other commands never load OpenCV. Bad input raises ``ValueError`` with a one-line message, which
the main entry point prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    add_command_parser,
    progress_bar,
    read_boxes,
)
from xvmatch.commands._types import float_in, image_size, int_in, seed_value, worker_count
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLES", "add_show_parser", "add_synth_parser"]

EXAMPLES = {
    "synth": "xvmatch synth --out data/synth --scenario drone --scenes 100 --frames 20 "
    "--seed 0 --workers 2\n  xvmatch synth --cameras 4 --frames 100 --out data/cams4",
    "show": "xvmatch show data/synth/images/top/s00000_000001.jpg --out pair.png",
}


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
"""Most frames per scene (``synth --frames``, ``show --frame``)."""


def _parser(subparsers, name: str, help_text: str) -> argparse.ArgumentParser:
    return add_command_parser(subparsers, name, help_text, EXAMPLES[name])


def add_synth_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch synth`` on ``subparsers`` and return its parser."""
    p = _parser(
        subparsers,
        "synth",
        "Render labelled image pairs (top/overview + egocentric views of walking people) with "
        "calibrated cameras: images/{top,ego}/SCENE_FRAME.jpg and annotations/SCENE.json.",
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


SYNTH_CAMERAS = "synth --cameras"
"""The command name in the marker of a ``synth --cameras`` folder (it may replace only its own)."""


def _synth_cameras(args: argparse.Namespace) -> int:
    """``synth --cameras N``: one multi-camera scene, rendered or box-only (issue 32)."""
    from xvmatch.core.folder_marker import files_under, record_own_files, remove_own_files
    from xvmatch.core.output_paths import claim_folder
    from xvmatch.datasets.multicam_scenes import (
        MulticamConfig,
        TrackerNoise,
        add_tracker_noise,
        simulate_multicam_scene,
        write_multicam_scene,
    )
    from xvmatch.datasets.render.image_render import Difficulty
    from xvmatch.datasets.render.multicam_render import write_rendered_multicam_scene

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
    config = MulticamConfig(n_cameras=args.cameras, n_people=args.people or (12, 12),
                            fps=args.fps)
    start = time.perf_counter()
    root = claim_folder(args.out, SYNTH_CAMERAS)
    remove_own_files(root, SYNTH_CAMERAS)  # an earlier scene of this command: no stale camera
    kept = files_under(root)  # the user's: never removed, and not listed as written
    if args.boxes_only:
        scene = simulate_multicam_scene(config, args.frames, args.seed)
    else:
        with progress_bar(1, "synth", "scene", not args.quiet) as bar:
            scene, _ = write_rendered_multicam_scene(
                root, config, args.frames, args.seed, width=width,
                difficulty=Difficulty.preset(args.difficulty))
            bar.update(1)
    if args.tracker_noise:
        scene = add_tracker_noise(scene, TrackerNoise(), args.seed)
    if args.boxes_only or args.tracker_noise:
        write_multicam_scene(root, scene)
    record_own_files(root, SYNTH_CAMERAS, files_under(root) - kept)
    if not args.quiet:
        kind = "box-only" if args.boxes_only else "rendered"
        print(f"wrote a {kind} scene of {args.cameras} static cameras x {args.frames} frames to "
              f"{root} in {time.perf_counter() - start:.1f} s; try: xvmatch multicam --boxes "
              + " ".join(f"{n}={root / 'boxes' / (n + '.txt')}" for n in scene.cameras)
              + f" --cameras {root / 'cameras.json'} --out OUT/", file=sys.stderr)
    return 0


def add_show_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch show`` on ``subparsers`` and return its parser."""
    p = _parser(
        subparsers,
        "show",
        "Draw a labelled pair side by side with each person's box and id (one colour per "
        "person across the views; O marks the camera wearer) into a PNG; or a frame of your "
        "own box files (--top, --hor), matched by a prediction CSV or by their ids.",
    )
    p.add_argument("pair", metavar="PAIR", nargs="?", default=None,
                   help="an image of the pair (images/top/SCENE_FRAME.jpg or images/ego/...), "
                   "a scene file (annotations/SCENE.json), or a dataset folder")
    g = p.add_argument_group("box files instead of PAIR (drawn on blank canvases: the "
                             "horizontal view at its image size, the top view as a plan)")
    g.add_argument("--top", default=None, metavar="FILE", help="top-view boxes (MOT format)")
    g.add_argument("--hor", default=None, metavar="FILE",
                   help="horizontal-view boxes (MOT format)")
    g.add_argument("--pred", default=None, metavar="CSV",
                   help="pairs to draw, frame,top_id,hor_id (xvmatch associate --out); default: "
                   "the same id in both views (ground truth)")
    g.add_argument("--image-size", type=HOR_IMAGE_SIZE,
                   default=None, metavar="WxH", help=IMAGE_SIZE_HELP)
    g.add_argument("--no-labels", action="store_true", help="print no ids by the boxes")
    p.add_argument("--scene", default=None, help="scene name when PAIR is a dataset folder "
                   "(default: the first scene)")
    p.add_argument("--frame", default=None,
                   type=int_in(1, 2**53, "a frame number: frames are 1-based, exact to 2**53"),
                   help="frame number when PAIR is a scene file or folder (default 1), or of "
                   "the box files (default: the first with boxes in both views), 1..2**53")
    p.add_argument("--out", default="pair.png", help="picture to write (default pair.png)")
    p.add_argument("--full-boxes", action="store_true",
                   help="also draw the full (unoccluded) boxes, thin")
    p.add_argument("--bits", type=int, choices=range(1, 9), default=8, metavar="{1..8}",
                   help="colour bits per channel of the picture (default 8); 5 makes a PNG "
                   "about half as big, for documentation")
    p.set_defaults(func=_cmd_show)
    return p


def _resolve_pair(spec: str, scene: str | None, frame: int | None):
    """The (scene file, dataset root, frame) that ``spec`` designates."""
    path = Path(spec)
    if path.is_dir():
        from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset

        if not (path / MANIFEST).is_file():
            raise ValueError(f"{spec}: folder has no {MANIFEST}; is it an xvmatch synth output?")
        dataset = SyntheticDataset(path)
        names = dataset.scene_names
        name = scene or (names[0] if names else None)
        if name not in names:
            raise ValueError(f"{spec}: no scene {name!r} (have {', '.join(names[:5])}...)")
        return path / "annotations" / f"{name}.json", path, frame or 1
    if not path.is_file():
        raise ValueError(f"{spec}: no such file or folder")
    if path.suffix == ".json":
        return path, path.resolve().parent.parent, frame or 1
    stem = path.stem
    if path.parent.name not in ("top", "ego") or "_" not in stem:
        raise ValueError(f"{spec}: expected ROOT/images/top|ego/SCENE_FRAME.jpg")
    name, _, number = stem.rpartition("_")
    if not number.isdigit():
        raise ValueError(f"{spec}: file name must end in _FRAME (digits), got {path.name!r}")
    root = path.resolve().parent.parent.parent
    return root / "annotations" / f"{name}.json", root, frame or int(number)


def _show_boxes(args: argparse.Namespace) -> int:
    """``show --top T --hor H``: one frame of box files, pairs from ``--pred`` or equal ids."""
    import numpy as np

    from xvmatch.commands._image_size import note_if_assumed
    from xvmatch.formats.box_image_size import resolve_size
    from xvmatch.formats.mot_boxes import read_predictions
    from xvmatch.viz.box_canvas import blank_view, top_plan
    from xvmatch.viz.match_drawing import draw_matches, write_match_picture

    if args.pair is not None or args.top is None or args.hor is None:
        raise ValueError("give either PAIR (a synthetic pair) or --top and --hor (box files)")
    if args.full_boxes:
        raise ValueError("--full-boxes applies to a synthetic PAIR (box files hold one box)")
    out = Path(args.out)
    check_outputs([Output("--out", out)], [Input("--top", args.top), Input("--hor", args.hor),
                                           Input("--pred", args.pred)])
    top, hor = read_boxes(args.top, "first"), read_boxes(args.hor, "first")
    both = [f for f in sorted(set(top) & set(hor)) if len(top[f]) and len(hor[f])]
    frame = args.frame if args.frame is not None else (both[0] if both else None)
    if frame not in both:
        raise ValueError(f"--frame {frame}: {args.top} and {args.hor} have no boxes in both "
                         f"views there (frames with both: {both[0]}..{both[-1]})" if both else
                         f"{args.top} and {args.hor} share no frame with boxes in both views")
    resolved = resolve_size(hor, args.hor, [] if args.image_size is None else
                            [(args.image_size, "--image-size")])
    t_ids, h_ids = top[frame].ids.tolist(), hor[frame].ids.tolist()
    if args.pred is not None:
        pairs = read_predictions(args.pred).get(frame, [])
        for a, b in pairs:
            if a not in t_ids or b not in h_ids:
                raise ValueError(f"{args.pred}: frame {frame}: pair ({a}, {b}) names a box "
                                 "that is not in the box files")
        what = f"{len(pairs)} pairs of {args.pred}"
    else:
        pairs = [(i, i) for i in t_ids if i in h_ids]
        what = f"{len(pairs)} people with the same id in both views"
    rows = [(t_ids.index(a), h_ids.index(b)) for a, b in pairs]
    plan = top_plan(top)
    picture = draw_matches(
        plan.image, blank_view(resolved[0]), plan.place(top[frame].boxes), hor[frame].boxes,
        np.array(rows, dtype=np.int64).reshape(-1, 2),
        None if args.no_labels else t_ids, None if args.no_labels else h_ids,
        title=f"frame {frame}: {what} (same colour: same person; grey: unmatched; top view as "
        "a plan)")
    note_if_assumed(resolved, hor, args.hor)
    write_match_picture(out, picture)
    print(f"wrote {out} ({picture.shape[1]}x{picture.shape[0]})", file=sys.stderr)
    return 0


def _cmd_show(args: argparse.Namespace) -> int:
    import cv2

    if args.top is not None or args.hor is not None or args.pair is None:
        return _show_boxes(args)
    for option in ("pred", "image_size"):
        if getattr(args, option) is not None:
            raise ValueError(f"--{option.replace('_', '-')} applies to box files (--top, --hor)")

    from xvmatch.core.atomic_files import atomic_write_bytes
    from xvmatch.datasets.synthetic_io import draw_pair, read_scene

    annotation, root, frame = _resolve_pair(args.pair, args.scene, args.frame)
    record = read_scene(annotation, root)
    if not 1 <= frame <= len(record.pairs):
        raise ValueError(f"{annotation}: frame {frame} out of range 1..{len(record.pairs)}")
    out = Path(args.out)
    if out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise ValueError(f"--out {args.out}: use a .png or .jpg file name")
    pair = record.pairs[frame - 1]
    from xvmatch.datasets.synthetic_io import MANIFEST

    # the whole data set is input: never write over another pair's image or annotation
    dataset = root if (Path(root) / MANIFEST).is_file() else None
    check_outputs([Output("--out", out)],
                  [Input("PAIR", args.pair), Input("PAIR", annotation), Input("PAIR", dataset),
                   Input("PAIR", pair.top.image_path), Input("PAIR", pair.ego.image_path)])
    picture = draw_pair(pair, full_boxes=args.full_boxes)
    if args.bits < 8:
        drop = 8 - args.bits
        picture = ((picture >> drop) << drop) + ((1 << drop) >> 1)
    ok, buf = cv2.imencode(out.suffix.lower(), picture, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:  # pragma: no cover
        raise OSError(f"could not encode {out}")
    # A temporary file of an unpredictable name, made exclusively beside the output, then
    # renamed over it; removed on any failure.
    atomic_write_bytes(out, buf.tobytes(), fsync=False)
    print(f"wrote {out} ({picture.shape[1]}x{picture.shape[0]})", file=sys.stderr)
    return 0
