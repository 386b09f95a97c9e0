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

from xvmatch.cli_options import (
    HOR_IMAGE_SIZE,
    add_command_parser,
    add_image_options,
    check_images_together,
)
from xvmatch.cli_types import (
    float_in,
    int_in,
    seed_value,
    thread_count,
    worker_count,
)
from xvmatch.output_paths import Input, Output, check_outputs, check_own_folder

__all__ = [
    "EXAMPLES",
    "add_draw_arguments",
    "add_export_parser",
    "add_fit_geometry_parser",
    "add_model_arguments",
    "associate_with_model",
    "draw_pictures",
]

EXAMPLES = {
    "export": "xvmatch export --model geometry.pt --out geometry_bundle/",
    "fit-geometry": "xvmatch fit-geometry --cvmhat ../shared/data/cvmhat --out geometry.pt "
    "--sites canteen 55 --epochs 12 --seed 0",
}


_gamma = float_in(0, 1, "the matcher's costs lie in [0, 1]", low_open=True)
"""``--gamma``: a non-association cost in (0, 1]."""


def add_fit_geometry_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch fit-geometry`` on ``subparsers`` and return its parser."""
    help_text = (
        "Train the box-only learned geometry model on MOT-format top/horizontal box pairs "
        "(CVMHAT layout: NAME_top.txt + NAME_hor.txt, same id = same person) and write a model "
        "file for 'xvmatch associate --model'."
    )
    p = add_command_parser(subparsers, "fit-geometry", help_text, EXAMPLES["fit-geometry"])
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
    boxes of the pairs it reads (``sites``) must be of that size (:mod:`xvmatch.cli_image_size`):
    with ``size`` (``--image-size``) each box must lie in it, and boxes of another size are
    scaled to 2688 pixels wide into ``scratch`` (the features are resolution-free); without it
    the boxes must be consistent with 2688x1512. Else one error line."""
    import re
    import shutil
    import warnings
    from pathlib import Path

    from xvmatch.cli_image_size import (
        CVMHAT_SIZE,
        MIN_EXTENT,
        box_extent,
        check_boxes_in_image,
        consistent_with,
    )
    from xvmatch.datasets.cvmhat import sequence_names
    from xvmatch.datasets.mot_boxes import read_mot_boxes, scale_frames, write_mot_boxes

    if size is not None and abs(size[1] * CVMHAT_SIZE[0] / size[0] - CVMHAT_SIZE[1]) > 0.02 * \
            CVMHAT_SIZE[1]:
        raise ValueError(f"--image-size {size[0]}x{size[1]}: fit-geometry trains at CVMHAT's "
                         "16:9 (2688x1512); crop or pad the boxes to a 16:9 image first")
    source = "--image-size" if size is not None else "CVMHAT's size, fit-geometry's"
    want = tuple(size) if size is not None else CVMHAT_SIZE
    names, right, widest = [], 0.0, {}
    for name in sequence_names(folder):
        site = re.search(r"S_([A-Za-z0-9]+)", name)
        if sites and (site is None or site.group(1) not in sites):
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


def add_export_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch export`` on ``subparsers`` and return its parser."""
    help_text = (
        "Export a trained matcher file to a deployable bundle folder: the appearance network "
        "and the matcher as ONNX, and manifest.json (preprocessing, gamma, sha256, the parity "
        "figures). Fails, writing nothing, unless onnxruntime reproduces the torch costs within "
        "1e-4 and the same assignments on held-out synthetic frames."
    )
    p = add_command_parser(subparsers, "export", help_text, EXAMPLES["export"])
    p.add_argument("--model", required=True, metavar="MODEL",
                   help="matcher file (.pt from fit-geometry or the matcher training), or "
                   "'default' (models/default_matcher.pt)")
    p.add_argument("--out", required=True, metavar="BUNDLE", help="bundle folder to write")
    p.add_argument("--parity-data", default=None, metavar="DIR",
                   help="synthetic dataset (xvmatch synth) for the parity check (default: "
                   "render a small held-out one)")
    p.add_argument("--int8", action="store_true",
                   help="also write a static INT8 (QDQ) appearance network, which the runtime "
                   "then uses (needs --calibration)")
    p.add_argument("--calibration", default=None, metavar="DATA",
                   help="with --int8: synthetic dataset (xvmatch synth, 2+ scenes): even "
                   "scenes calibrate, odd scenes measure the accuracy kept")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_export)
    return p


def _cmd_export(args: argparse.Namespace) -> int:
    try:
        from xvmatch.export.onnx_export import ExportError, check_replaceable, export_bundle
    except ImportError as exc:
        raise ValueError(f"xvmatch export needs the learn extra (torch, onnx): {exc}") from None

    def say(line: str) -> None:
        if not args.quiet:
            print(line, file=sys.stderr)

    if args.int8 != (args.calibration is not None):
        raise ValueError("--int8 and --calibration DATA go together")
    check_outputs(
        [Output("--out", args.out, folder=True)],
        [Input("--model", None if args.model == "default" else args.model),
         Input("--parity-data", args.parity_data), Input("--calibration", args.calibration)],
    )
    try:
        check_replaceable(args.out)  # only a bundle of an earlier export is replaced
    except ExportError as exc:
        raise ValueError(f"--out {exc}") from None
    manifest = export_bundle(args.model, args.out, parity_data=args.parity_data,
                             int8_calibration=args.calibration, progress=say)
    if not args.quiet:
        for setting, p in manifest["parity"].items():
            if isinstance(p, dict) and "frames" in p:
                say(f"parity {setting}: {p['frames']} frames, max |cost diff| "
                    f"{p['max_abs_cost_diff']:.1e}, identical assignments "
                    f"{p['assignments_identical']}/{p['frames']}")
        int8 = (manifest.get("appearance") or {}).get("int8")
        if int8:
            acc = int8["accuracy"]
            say(f"INT8 appearance ({int8['calibration']['method']} calibration): Eq. 9 accuracy "
                f"with images {acc['int8']['images']['acc9']:.1f} against FP32 "
                f"{acc['fp32']['images']['acc9']:.1f} on held-out scenes")
        say(f"wrote {args.out} (cues: {', '.join(manifest['cues']) or 'none, box-only'})")
    return 0


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the learned matcher's options to a parser (``associate``): ``--model``, ``--gamma``,
    ``--mirror``, the image and camera inputs, ``--costs``, ``--threads`` and ``--precision``."""
    g = parser.add_argument_group("learned matcher (--model)")
    g.add_argument(
        "--model", action="append", default=None, metavar="BUNDLE",
        help="a matcher bundle folder (xvmatch export), 'default' for the shipped one, or a "
        "torch matcher file (.pt, exported once into the cache; needs the learn extra); "
        "replaces the handcrafted search (frame mode). Repeat it to average the costs of "
        "several models (an ensemble)",
    )
    g.add_argument(
        "--gamma", type=_gamma, default=None,
        help="non-association cost in (0, 1] (default: the model's own)",
    )
    g.add_argument(
        "--mirror", action="store_true",
        help="also score the scene mirrored left-right and average the costs (test-time "
        "augmentation: twice the search; a few tenths of CVIDF1 on CVMHAT)",
    )
    add_image_options(g)
    g.add_argument(
        "--cameras", default=None, metavar="CAMERAS",
        help="calibrated cameras 'top' and 'ego': a camera file (both fixed) or a folder of "
        "per-frame camera files named by frame number",
    )
    g.add_argument("--costs", default=None, metavar="JSON",
                   help="also write each frame's ids and cost matrix (written atomically)")
    g.add_argument("--threads", type=thread_count, default=1, metavar="K",
                   help="onnxruntime threads, 1..64 (default 1)")
    g.add_argument("--precision", choices=("fp32", "int8"), default=None,
                   help="appearance network to run: int8 (needs a bundle exported with --int8) "
                   "or fp32 (default: int8 when the bundle has it and the CPU has 8-bit "
                   "dot-product instructions, VNNI; else fp32)")


def add_draw_arguments(parser: argparse.ArgumentParser) -> None:
    """Add ``--draw``, ``--draw-every`` and ``--no-labels`` (both methods of ``associate``)."""
    g = parser.add_argument_group("pictures (both methods)")
    g.add_argument("--draw", default=None, metavar="DIR",
                   help="write a side-by-side picture of each frame's matches, "
                   "DIR/frame_000212.jpg (JPEG), into DIR: a new or empty folder, or one an "
                   "earlier --draw wrote. Without images the boxes are drawn on a blank canvas "
                   "of the horizontal image size and the top view as a plan")
    g.add_argument("--draw-every", default=1, metavar="K",
                   type=int_in(1, 100_000, "a frame step: 100000 is over an hour at 25 fps"),
                   help="with --draw: every K-th frame only, 1..100000 (default 1)")
    g.add_argument("--no-labels", action="store_true",
                   help="with --draw: print no ids by the boxes (colours alone show the pairs)")


DRAW_COMMAND = "xvmatch associate --draw"
"""The owner of a ``--draw`` folder: pictures are written only into a new or empty folder or one
an earlier ``--draw`` made (:func:`xvmatch.output_paths.claim_folder`)."""

LEARNED_ONLY = ("gamma", "mirror", "top_images", "hor_images", "cameras", "costs",
                "precision")
"""Options of ``associate`` that need ``--model``."""


def _torch_file_bundle(path: str, threads: int, precision: str | None):
    """The bundle of a torch matcher file, exported once into the cache."""
    import hashlib
    from pathlib import Path

    from xvmatch.datasets.feature_cache import default_cache_dir
    from xvmatch.inference.learned_association import load_matcher_bundle

    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()[:20]
    folder = default_cache_dir() / "bundles" / digest
    if not (folder / "manifest.json").is_file():
        try:
            from xvmatch.export.onnx_export import export_bundle
        except ImportError:
            raise ValueError(f"{path}: a torch matcher file; export it with 'xvmatch export' on "
                             "a machine with the learn extra, and pass the bundle folder"
                             ) from None
        print(f"exporting {path} to {folder} (once)", file=sys.stderr)
        export_bundle(path, folder)
    return load_matcher_bundle(folder, threads, precision)


def open_models(names: Iterable[str], threads: int = 1, precision: str | None = None) -> list:
    """:class:`~xvmatch.inference.learned_association.LearnedMatcher` of each ``--model``."""
    import os

    from xvmatch.inference.learned_association import load_matcher_bundle

    models = []
    for name in names:
        if name != "default" and os.path.isfile(name):
            models.append(_torch_file_bundle(name, threads, precision))
        else:
            models.append(load_matcher_bundle(name, threads, precision))
    return models


class _Shifted:
    """An image source re-timed like the boxes: frame ``f`` is the source's ``f + shift``."""

    def __init__(self, source, shift: int) -> None:
        self.source, self.shift = source, int(shift)

    def get(self, frame: int):
        return self.source.get(int(frame) + self.shift)

    def close(self) -> None:
        self.source.close()


def _check_boxes_inside(frames: Mapping, size: tuple[int, int], where: str,
                        source: str = "the images") -> None:
    """Every box must lie in its image (:func:`xvmatch.cli_image_size.check_boxes_in_image`:
    at most 10% past a border), else the images and boxes do not belong together."""
    from xvmatch.cli_image_size import check_boxes_in_image

    check_boxes_in_image(frames, size, where, source)


def _check_camera_sizes(cameras, sizes: dict[str, tuple[tuple[int, int], str]]) -> None:
    """Every camera's image size must be its view's image size (``sizes``: view -> (size,
    where that size comes from))."""
    for where, cams in cameras.all():
        for view, cam in (("top", cams.top), ("hor", cams.hor)):
            if view not in sizes:
                continue
            want, source = sizes[view]
            if tuple(cam.image_size) != tuple(want):
                name = "ego" if view == "hor" else "top"
                label = "horizontal" if view == "hor" else "top"
                raise ValueError(f"{where}: camera {name!r} is {cam.width}x{cam.height} but the "
                                 f"{label} image size is {want[0]}x{want[1]} (from {source})")


def horizontal_size(args: argparse.Namespace, hor: Mapping) -> tuple[tuple[int, int], str]:
    """The horizontal image size and where it comes from (:mod:`xvmatch.cli_image_size`):
    ``--image-size``, the ``--hor-images`` and the ``--cameras`` file's ego camera must agree
    when given; with none, CVMHAT's 2688x1512 when the boxes are consistent with it (a note on
    stderr), else an error asking for ``--image-size``. Every horizontal box must lie in it."""
    from xvmatch.cli_image_size import resolve_size

    check_images_together(args)
    given = []
    if getattr(args, "image_size", None) is not None:
        given.append((tuple(args.image_size), "--image-size"))
    if getattr(args, "model", None) is not None and getattr(args, "hor_images", None):
        from xvmatch.datasets.frame_sources import open_frames

        with open_frames(args.hor_images, box_frames=sorted(hor)) as source:
            given.append((tuple(source.size), f"the horizontal images {args.hor_images}"))
    elif getattr(args, "model", None) is not None and getattr(args, "cameras", None):
        # with images, each camera file is checked against them (:func:`_check_camera_sizes`)
        from xvmatch.datasets.camera_frames import open_cameras

        sizes = {tuple(c.hor.image_size) for _, c in open_cameras(args.cameras).all()}
        if len(sizes) != 1:
            raise ValueError(f"{args.cameras}: the ego cameras have several image sizes "
                             f"({', '.join(f'{w}x{h}' for w, h in sorted(sizes))}); pass "
                             "--image-size")
        given.append((sizes.pop(), f"the camera files {args.cameras}"))
    return resolve_size(hor, getattr(args, "hor", "the horizontal boxes"), given)


def associate_with_model(
    args: argparse.Namespace,
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    progress: Callable[[Iterable[int]], Iterable[int]] | None,
    top_offset: int = 0,
    hor_size: tuple[tuple[int, int], str] | None = None,
) -> dict[int, list[tuple[int, int]]]:
    """Associate with ``args.model`` (bundles, ``default`` or torch files); ``{frame: [(top,
    hor)]}``. Also writes ``--costs`` and ``--draw`` when asked. ``top`` is already re-timed by
    ``top_offset`` (``--offset``); the top images are re-timed the same way. ``hor_size``:
    :func:`horizontal_size` when the caller has it already (else it is worked out here).

    Reads ``args.model``, ``args.image_size`` (W, H, or None: from the images, else CVMHAT's),
    ``args.camera_id``, and when present ``args.mode`` (must be ``frame``), ``args.gamma``,
    ``args.mirror``, ``args.workers``, ``args.threads``, ``args.top_images``,
    ``args.hor_images``, ``args.cameras``, ``args.costs``, ``args.draw``, ``args.draw_every``.
    Every input is checked before any work starts; outputs are written only at the end.
    """
    from xvmatch.inference.learned_association import associate_sequence_learned

    if getattr(args, "mode", "frame") != "frame":
        raise ValueError("--model solves each frame on its own: use --mode frame")
    top_path, hor_path = getattr(args, "top_images", None), getattr(args, "hor_images", None)
    check_images_together(args)
    draw = getattr(args, "draw", None)
    if draw is not None:
        check_own_folder(draw, DRAW_COMMAND, "--draw")
    names = [args.model] if isinstance(args.model, str) else list(args.model)
    models = open_models(names, getattr(args, "threads", 1), getattr(args, "precision", None))
    frames = list(frames)
    both = [f for f in frames if f in top and f in hor and len(top[f]) and len(hor[f])]
    sources = {}
    sizes: dict[str, tuple[int, int]] = {}
    if top_path is not None:
        from xvmatch.datasets.frame_sources import check_frames, open_frames

        for m, name in zip(models, names, strict=True):
            if m.bundle.manifest.appearance is None:
                raise ValueError(f"{name}: a box-only matcher cannot use images; drop "
                                 "--top-images/--hor-images or use a bundle with an "
                                 "appearance network (e.g. default)")
        for view, path, boxes, shift in (("top", top_path, top, top_offset),
                                         ("hor", hor_path, hor, 0)):
            source = open_frames(path, box_frames=sorted(f + shift for f in boxes))
            check_frames(source, [f + shift for f in both])
            sources[view] = _Shifted(source, shift) if shift else source
            sizes[view] = tuple(source.size)
        _check_boxes_inside(top, sizes["top"], args.top)
    (width, height), said = hor_size or horizontal_size(args, hor)
    cameras = None
    if getattr(args, "cameras", None) is not None:
        from xvmatch.datasets.camera_frames import open_cameras

        for m, name in zip(models, names, strict=True):
            if not m.bundle.manifest.uses_cameras:
                raise ValueError(f"{name}: this matcher takes no camera cues; drop --cameras or "
                                 "use a bundle trained with cameras (e.g. default)")
        cameras = open_cameras(args.cameras, both)
        wanted = {"hor": ((width, height), "the images" if sizes else said)}
        if "top" in sizes:
            wanted["top"] = (sizes["top"], "the images")
        _check_camera_sizes(cameras, wanted)
    from xvmatch.cli_image_size import note_if_assumed

    note_if_assumed(((width, height), said), hor, getattr(args, "hor", "the horizontal boxes"),
                    bool(getattr(args, "quiet", False)))
    want_costs = getattr(args, "costs", None) is not None or draw is not None
    costs: dict | None = {} if want_costs else None
    try:
        pairs = associate_sequence_learned(
            top,
            hor,
            hor_width=width,
            model=models,
            camera_id=getattr(args, "camera_id", None),
            gamma=getattr(args, "gamma", None),
            progress=progress,
            hor_height=height,
            frames=frames,
            mirror=bool(getattr(args, "mirror", False)),
            workers=getattr(args, "workers", 1),
            top_images=sources.get("top"),
            hor_images=sources.get("hor"),
            cameras=cameras,
            costs_out=costs,
        )
        if draw is not None:
            draw_pictures(draw, getattr(args, "draw_every", 1), top, hor, pairs, sorted(costs),
                          sources or None, (width, height),
                          not getattr(args, "no_labels", False))
    finally:
        for source in sources.values():
            source.close()
    if getattr(args, "costs", None) is not None:
        _write_costs(args.costs, top, hor, costs, getattr(args, "gamma", None) or
                     models[0].gamma)
    return pairs


def _write_costs(path: str, top: Mapping, hor: Mapping, costs: dict, gamma: float) -> None:
    import json

    from xvmatch.geometry.atomic_files import atomic_write_text

    record = {
        "version": 1,
        "gamma": gamma,
        "frames": {
            str(f): {"top_ids": [int(i) for i in top[f].ids],
                     "hor_ids": [int(i) for i in hor[f].ids],
                     "cost": [[round(float(v), 6) for v in row] for row in c]}
            for f, c in sorted(costs.items())
        },
    }
    atomic_write_text(path, json.dumps(record) + "\n")


def draw_pictures(folder: str, every: int, top: Mapping, hor: Mapping, pairs: Mapping,
                  frames: list[int], sources: dict | None, hor_size: tuple[int, int],
                  labels: bool = True) -> None:
    """``--draw``: the pictures of every ``every``-th of ``frames``, written into a temporary
    folder and moved into ``folder`` only once all are made.

    Args:
        folder: the ``--draw`` folder.
        every: ``--draw-every``.
        top, hor: ``{frame: FrameBoxes}`` of each view (the top one re-timed as the pairs).
        pairs: ``{frame: [(top id, hor id)]}``.
        frames: the frames that may be drawn (those with boxes in both views).
        sources: ``{"top": source, "hor": source}`` of the images; None: boxes only, drawn on a
            blank canvas of ``hor_size`` and the top view as a plan
            (:mod:`xvmatch.inference.box_canvas`).
        hor_size: the horizontal image size.
        labels: print each box's id (``--no-labels``: none).
    """
    import shutil
    import tempfile
    from pathlib import Path

    import numpy as np

    from xvmatch.inference.box_canvas import blank_view, top_plan
    from xvmatch.inference.match_drawing import (
        draw_matches,
        frames_to_draw,
        picture_path,
        write_match_picture,
    )
    from xvmatch.output_paths import claim_folder

    out = claim_folder(folder, DRAW_COMMAND, "--draw")
    tmp = Path(tempfile.mkdtemp(prefix=".draw-", dir=out))
    plan = hor_canvas = None
    if sources is None:
        plan, hor_canvas = top_plan(top), blank_view(hor_size)
    legend = "same colour: same person; grey: unmatched"
    if sources is None:
        legend += "; boxes only: top view as a plan, horizontal view blank"
    try:
        written = []
        for f in frames_to_draw(frames, every):
            t_ids, h_ids = list(top[f].ids), list(hor[f].ids)
            rows = np.array([(t_ids.index(a), h_ids.index(b)) for a, b in pairs.get(f, [])],
                            dtype=np.int64).reshape(-1, 2)
            if sources is None:
                images = (plan.image, hor_canvas)
                boxes = (plan.place(top[f].boxes), hor[f].boxes)
            else:
                images = (sources["top"].get(f), sources["hor"].get(f))
                boxes = (top[f].boxes, hor[f].boxes)
            picture = draw_matches(*images, *boxes, rows, top[f].ids if labels else None,
                                   hor[f].ids if labels else None,
                                   title=f"frame {f}: {len(rows)} matches ({legend})")
            path = picture_path(tmp, f)
            write_match_picture(path, picture)
            written.append(path)
        for path in written:
            path.replace(out / path.name)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
