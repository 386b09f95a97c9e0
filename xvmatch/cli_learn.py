"""The learned geometry model on the command line: ``xvmatch fit-geometry`` and the
``xvmatch associate --model MODEL|default`` path.

``add_fit_geometry_parser`` registers the training sub-command; ``add_model_arguments`` adds
``--model`` / ``--gamma`` to a parser (``associate``), and ``associate_with_model`` runs the
association with a model file. Imports are lazy: only these code paths load torch. Bad input
raises ``ValueError`` with a one-line message, which the main entry point prints as
``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterable, Mapping

from xvmatch.cli_types import non_negative_int, positive_int

__all__ = [
    "EXAMPLES",
    "add_fit_geometry_parser",
    "add_model_arguments",
    "associate_with_model",
]

EXAMPLES = {
    "fit-geometry": "xvmatch fit-geometry --cvmhat ../shared/data/cvmhat --out geometry.pt "
    "--sites canteen 55 --epochs 12 --seed 0",
}


def _gamma(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number in (0, 1], got {text!r}") from None
    if not 0.0 < value <= 1.0:
        raise argparse.ArgumentTypeError(f"gamma must be in (0, 1], got {text!r}")
    return value


def add_fit_geometry_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch fit-geometry`` on ``subparsers`` and return its parser."""
    help_text = (
        "Train the box-only learned geometry model on MOT-format top/horizontal box pairs "
        "(CVMHAT layout: NAME_top.txt + NAME_hor.txt, same id = same person) and write a model "
        "file for 'xvmatch associate --model'."
    )
    p = subparsers.add_parser(
        "fit-geometry",
        help=help_text,
        description=help_text,
        epilog=f"example:\n  {EXAMPLES['fit-geometry']}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--cvmhat", required=True, metavar="DIR",
                   help="folder of NAME_top.txt / NAME_hor.txt pairs")
    p.add_argument("--out", required=True, metavar="MODEL", help="model file to write")
    p.add_argument("--sites", nargs="+", default=None, metavar="SITE",
                   help="train on these sites only (the S_<site> part of the names; default all)")
    p.add_argument("--epochs", type=positive_int, default=12, help="most epochs (default 12)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--noise", type=non_negative_int, default=2, metavar="COPIES",
                   help="detector-noise copies of the training frames (default 2; 0: clean only)")
    p.add_argument("--sim-scenes", type=non_negative_int, default=300, metavar="N",
                   help="box-simulator scenes added to the training set as a regulariser "
                   "(default 300; 0: real data only)")
    p.add_argument("--no-sync", action="store_true",
                   help="keep every pair's files' timing (default: re-time a pair's top view "
                   "when 'associate --offset auto' would, so that same id means same moment; "
                   "estimated once per pair and cached)")
    p.add_argument("--width", type=positive_int, default=64,
                   help="encoder embedding size (default 64; a multiple of 4, the heads)")
    p.add_argument("--layers", type=non_negative_int, default=2,
                   help="encoder rounds of self/cross attention (default 2)")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="feature cache folder (default $XVMATCH_CACHE or ~/.cache/xvmatch)")
    p.add_argument("--run-dir", default=None, metavar="DIR",
                   help="checkpoints and CSV/TensorBoard logs (default MODEL.run)")
    p.add_argument("--resume", action="store_true", help="continue from the last checkpoint")
    p.add_argument("--workers", type=positive_int, default=1,
                   help="processes for feature extraction (default 1)")
    p.add_argument("--threads", type=positive_int, default=None,
                   help="torch threads for training (default: torch's choice; 1 is often "
                   "fastest on a busy machine)")
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
    from xvmatch.training.fit_geometry import fit_geometry_cvmhat

    result = fit_geometry_cvmhat(
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
    if not args.quiet:
        score = "n/a" if result.best_score is None else f"{result.best_score:.1f}"
        print(
            f"wrote {result.model_path} (validation CVIDF1 {score}, {result.epochs} epochs, "
            f"{result.wall_time_s:.0f} s, peak memory {result.peak_memory_mb:.0f} MiB; "
            f"logs in {result.run_dir})",
            file=sys.stderr,
        )
    return 0


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--model MODEL|default`` and ``--gamma`` to a parser (e.g. ``associate``)."""
    parser.add_argument(
        "--model", action="append", default=None, metavar="MODEL",
        help="learned geometry model file, or 'default' for the shipped simulator-trained one; "
        "replaces the handcrafted cost (frame mode only). Repeat it to average the costs of "
        "several models (an ensemble, e.g. --model site.pt --model default)",
    )
    parser.add_argument(
        "--gamma", type=_gamma, default=None,
        help="with --model: non-association cost in (0, 1] (default: the model's own, 0.5)",
    )
    parser.add_argument(
        "--mirror", action="store_true",
        help="with --model: also run the model on both views mirrored left-right and average "
        "the costs (test-time augmentation: twice the time, a few tenths to about one point "
        "of CVIDF1 better on CVMHAT)",
    )


def associate_with_model(
    args: argparse.Namespace,
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    progress: Callable[[Iterable[int]], Iterable[int]] | None,
) -> dict[int, list[tuple[int, int]]]:
    """Associate with ``args.model`` (a model file or ``default``); ``{frame: [(top, hor)]}``.

    Reads ``args.model``, ``args.image_size`` (W, H), ``args.camera_id``, and when present
    ``args.mode`` (must be ``frame``), ``args.gamma``, ``args.mirror`` and ``args.workers``.
    The model uses the search parameters it was trained with, not ``--rho`` / ``--lam`` / ...
    """
    from xvmatch.inference.learned_association import (
        associate_sequence_learned,
        load_geometry_model,
    )

    if getattr(args, "mode", "frame") != "frame":
        raise ValueError("--model solves each frame on its own: use --mode frame")
    names = [args.model] if isinstance(args.model, str) else list(args.model)
    model = [load_geometry_model(name) for name in names]
    width, height = args.image_size
    return associate_sequence_learned(
        top,
        hor,
        hor_width=width,
        model=model,
        camera_id=getattr(args, "camera_id", None),
        gamma=getattr(args, "gamma", None),
        progress=progress,
        hor_height=height,
        frames=frames,
        mirror=bool(getattr(args, "mirror", False)),
        workers=getattr(args, "workers", 1),
    )
