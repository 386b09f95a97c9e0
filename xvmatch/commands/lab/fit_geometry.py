"""The ``xvmatch fit-geometry`` command: train the box-only learned geometry model on
MOT-format top/horizontal box pairs (CVMHAT layout) and write a model file for ``xvmatch
associate --model`` (:mod:`xvmatch.commands._model`). Imports are lazy: only this command's run
loads torch. Bad input raises ``ValueError`` with a one-line message, which the main entry point
prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys

from xvmatch.commands._options import HOR_IMAGE_SIZE, add_command_parser
from xvmatch.commands._types import int_in, seed_value, thread_count, worker_count
from xvmatch.core.output_paths import Input, Output, check_outputs

__all__ = ["EXAMPLE", "add_fit_geometry_parser"]

EXAMPLE = ("xvmatch fit-geometry --cvmhat ../shared/data/cvmhat --out geometry.pt "
           "--sites canteen 55 --epochs 12 --seed 0")


def add_fit_geometry_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch fit-geometry`` on ``subparsers`` and return its parser."""
    help_text = (
        "Train the box-only learned geometry model on MOT-format top/horizontal box pairs "
        "(CVMHAT layout: NAME_top.txt + NAME_hor.txt, same id = same person) and write a model "
        "file for 'xvmatch associate --model'."
    )
    p = add_command_parser(subparsers, "fit-geometry", help_text, EXAMPLE)
    p.add_argument("--cvmhat", required=True, metavar="DIR",
                   help="folder of NAME_top.txt / NAME_hor.txt pairs")
    p.add_argument("--out", required=True, metavar="MODEL", help="model file to write")
    p.add_argument("--sites", nargs="+", default=None, metavar="SITE",
                   help="train on these sites only (the S_<site> part of the names; default all)")
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help="the horizontal camera's image size, 16:9, 8..65536 a side; boxes of "
                   "another size than 2688x1512 are scaled to it for training (default: "
                   "2688x1512 when the boxes reach beyond 60%% of its width, else an error)")
    p.add_argument("--epochs", default=12,
                   type=int_in(1, 1000, "a bound on the run's time: the default converges in "
                               "12"),
                   help="most epochs, 1..1000 (default 12)")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="random seed, 0..2**32-1 (default 0)")
    p.add_argument("--noise", default=2, metavar="COPIES",
                   type=int_in(0, 100, "copies of the training frames, all held in memory"),
                   help="detector-noise copies of the training frames, 0..100 (default 2; 0: "
                   "clean only)")
    p.add_argument("--sim-scenes", default=300, metavar="N",
                   type=int_in(0, 100_000, "simulated scenes, all held in memory"),
                   help="box-simulator scenes added to the training set as a regulariser, "
                   "0..100000 (default 300; 0: real data only)")
    p.add_argument("--no-sync", action="store_true",
                   help="keep every pair's files' timing (default: re-time a pair's top view "
                   "when 'associate --offset auto' would, so that same id means same moment; "
                   "estimated once per pair and cached)")
    # The multiple of 4 is checked by the command (one line, exit 2, before any work).
    p.add_argument("--width", default=64,
                   type=int_in(4, 1024, "the encoder's embedding size, a multiple of 4 (the "
                               "heads); the default is 64"),
                   help="encoder embedding size, 4..1024 and a multiple of 4, the heads "
                   "(default 64)")
    p.add_argument("--layers", default=2,
                   type=int_in(0, 16, "encoder rounds; the default is 2"),
                   help="encoder rounds of self/cross attention, 0..16 (default 2)")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="feature cache folder (default $XVMATCH_CACHE or ~/.cache/xvmatch)")
    p.add_argument("--run-dir", default=None, metavar="DIR",
                   help="checkpoints and CSV/TensorBoard logs (default MODEL.run)")
    p.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    p.add_argument("--workers", type=worker_count, default=1,
                   help="processes for feature extraction, 1..64 (default 1)")
    p.add_argument("--threads", type=thread_count, default=None,
                   help="torch threads for training, 1..64 (default: torch's choice; 1 is "
                   "often fastest on a busy machine)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=_cmd_fit_geometry)
    return p


def _cmd_fit_geometry(args: argparse.Namespace) -> int:
    from pathlib import Path

    folder = Path(args.cvmhat)
    if not folder.is_dir():
        raise ValueError(f"{args.cvmhat}: no such folder")
    if args.width % 4:
        raise ValueError(f"--width must be a multiple of 4 (the attention heads), got {args.width}")
    run_dir = args.run_dir if args.run_dir is not None else f"{args.out}.run"
    check_outputs(
        [Output("--out", args.out), Output("--run-dir", run_dir, folder=True),
         Output("--cache", args.cache, folder=True)],
        [Input("--cvmhat", args.cvmhat)],
    )
    import tempfile

    with tempfile.TemporaryDirectory(prefix="xvmatch-fit-") as scratch:
        data = _training_folder(folder, args.sites, args.image_size, scratch, args.quiet)
        result = _fit(args, data)
    if not args.quiet:
        score = "n/a" if result.best_score is None else f"{result.best_score:.1f}"
        print(
            f"wrote {result.model_path} (validation CVIDF1 {score}, {result.epochs} epochs, "
            f"{result.wall_time_s:.0f} s, peak memory {result.peak_memory_mb:.0f} MiB; "
            f"logs in {result.run_dir})",
            file=sys.stderr,
        )
    return 0


def _fit(args: argparse.Namespace, folder):
    from xvmatch.training.fit_geometry import fit_geometry_cvmhat

    return fit_geometry_cvmhat(
        folder,
        args.out,
        sites=args.sites,
        epochs=args.epochs,
        seed=args.seed,
        noise_copies=args.noise,
        sim_scenes=args.sim_scenes,
        cache_dir=args.cache,
        workers=args.workers,
        run_dir=args.run_dir,
        resume=args.resume,
        progress=not args.quiet,
        threads=args.threads,
        model_config={"width": args.width, "layers": args.layers},
        synchronise=not args.no_sync,
    )


def _training_folder(folder, sites, size, scratch: str, quiet: bool) -> object:
    """The folder fit-geometry trains from. It trains at CVMHAT's 2688x1512, so the horizontal
    boxes of the pairs it reads (``sites``) must be of that size
    (:mod:`xvmatch.commands._box_reading`): with ``size`` (``--image-size``) each box must lie in
    it, and boxes of another size are scaled to 2688 pixels wide into ``scratch`` (the features
    are resolution-free); without it the boxes must be consistent with 2688x1512. Else one error
    line."""
    import shutil
    import warnings
    from pathlib import Path

    from xvmatch.formats.box_image_size import (
        CVMHAT_SIZE,
        MIN_EXTENT,
        box_extent,
        check_boxes_in_image,
        consistent_with,
    )
    from xvmatch.formats.cvmhat import sequence_names, site_of
    from xvmatch.formats.mot_boxes import read_mot_boxes, scale_frames, write_mot_boxes

    if size is not None and abs(size[1] * CVMHAT_SIZE[0] / size[0] - CVMHAT_SIZE[1]) > 0.02 * \
            CVMHAT_SIZE[1]:
        raise ValueError(f"--image-size {size[0]}x{size[1]}: fit-geometry trains at CVMHAT's "
                         "16:9 (2688x1512); crop or pad the boxes to a 16:9 image first")
    source = "--image-size" if size is not None else "CVMHAT's size, fit-geometry's"
    want = tuple(size) if size is not None else CVMHAT_SIZE
    names, right, widest = [], 0.0, {}
    for name in sequence_names(folder):
        if sites and site_of(name) not in sites:
            continue
        path = Path(folder) / f"{name}_hor.txt"
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            hor = read_mot_boxes(path, duplicates="first")
        check_boxes_in_image(hor, want, path, source)
        names.append((name, hor))
        if box_extent(hor)[0] > right:
            right, widest = box_extent(hor)[0], hor
    if size is None and widest and not consistent_with(widest):
        raise ValueError(f"--cvmhat {folder}: the horizontal image size is unknown: pass "
                         f"--image-size WxH (fit-geometry trains at CVMHAT's 2688x1512 and "
                         f"these boxes reach only x {right:g}, not beyond {MIN_EXTENT:.0%} of "
                         "2688)")
    if size is None and widest and not quiet:
        print(f"xvmatch: note: assuming the horizontal images of {folder} are 2688x1512 (CVMHAT; "
              f"the boxes reach x {right:g}); pass --image-size WxH if not", file=sys.stderr)
    if want == CVMHAT_SIZE:
        return Path(folder)
    out = Path(scratch)
    for name, hor in names:
        shutil.copyfile(Path(folder) / f"{name}_top.txt", out / f"{name}_top.txt")
        write_mot_boxes(out / f"{name}_hor.txt", scale_frames(hor, CVMHAT_SIZE[0] / want[0]))
    return out
