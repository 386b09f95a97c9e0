"""Command-line interface: ``xvmatch associate | evaluate | noise | offset | demo | ...``.

``synth``/``show``, ``baseline``, ``fit-geometry`` and ``train`` come from ``cli_synth``,
``cli_baseline``, ``cli_learn`` and ``cli_train``. Each command
imports only what it needs, so ``xvmatch associate`` starts fast and never imports torch. Bad
input ends with one line ``xvmatch: error: ...`` naming the file and line, exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Sequence

from xvmatch.cli_types import image_size, int_at_least, offset_value, positive_int
from xvmatch.geometry.spatial_search import AUTO_MAX_OFFSET

__all__ = ["main"]

EXAMPLES = {
    "associate": "xvmatch associate --top seq_top.txt --hor seq_hor.txt --out pred.csv",
    "evaluate": "xvmatch evaluate --pred pred.csv --top seq_top.txt --hor seq_hor.txt",
    "noise": "xvmatch noise --boxes seq_top.txt --view top --seed 1 --out noisy_top.txt",
    "offset": "xvmatch offset --top seq_top.txt --hor seq_hor.txt",
    "demo": "xvmatch demo --frames 150 --seed 0",
}


class UsageError(Exception):
    """A user mistake reported as one line, without a traceback."""


def _progress(total: int, desc: str, enabled: bool):
    """Wrap a frame iterator in a progress bar on stderr (only on a terminal, unless forced)."""

    def wrap(frames: Iterable[int]) -> Iterable[int]:
        from tqdm import tqdm

        return tqdm(
            frames,
            total=total,
            desc=desc,
            unit="frame",
            leave=False,
            file=sys.stderr,
            disable=None if enabled else True,
        )

    return wrap


def _add_spatial_options(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("spatial-distribution parameters (paper defaults)")
    g.add_argument("--rho", type=float, default=15.0, help="penalty base of Eq. 12 (default 15)")
    g.add_argument(
        "--lam", type=float, default=0.003, help="x/y balance lambda of Eq. 11 (default 0.003)"
    )
    g.add_argument(
        "--tau", type=float, default=2.0, help="occlusion tolerance, degrees (default 2)"
    )
    g.add_argument(
        "--dtheta", type=float, default=1.0, help="orientation step, degrees (default 1)"
    )
    g.add_argument(
        "--fov", type=float, default=90.0, help="horizontal camera field of view, degrees (90)"
    )


def _spatial_params(args: argparse.Namespace):
    from xvmatch.geometry.spatial_matching import SpatialParams

    return SpatialParams(
        rho=args.rho, lam=args.lam, tau_deg=args.tau, dtheta_deg=args.dtheta, fov_deg=args.fov
    )


def _read_boxes(path: str, duplicates: str):
    import warnings

    from xvmatch.datasets.mot_boxes import read_mot_boxes

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        frames = read_mot_boxes(path, duplicates=duplicates)
    for w in caught:
        print(f"xvmatch: warning: {w.message}", file=sys.stderr)
    return frames


def _keep_heap_memory() -> None:
    """Stop glibc returning large numpy temporaries to the OS after every frame.

    The search allocates and frees a few hundred-kilobyte arrays per frame; with glibc's default
    mmap threshold each one is a fresh mapping, and the page faults cost about 20% of the run.
    Process-wide, so only the CLI does it; a no-op where ``mallopt`` does not exist.
    """
    try:
        import ctypes

        libc = ctypes.CDLL(None)
        libc.mallopt(-3, 256 << 20)  # M_MMAP_THRESHOLD
        libc.mallopt(-1, 512 << 20)  # M_TRIM_THRESHOLD
    except (OSError, AttributeError):
        pass


def _cmd_associate(args: argparse.Namespace) -> int:
    from xvmatch.datasets.mot_boxes import write_predictions
    from xvmatch.geometry.spatial_search import associate_sequence

    _keep_heap_memory()
    params = _spatial_params(args)
    top = _read_boxes(args.top, args.duplicates)
    hor = _read_boxes(args.hor, args.duplicates)
    search = args.search or ("exhaustive" if args.mode == "frame" else "follow")
    if args.mode == "frame" and search != "exhaustive":
        raise UsageError("--search reduced/follow uses previous frames: it needs --mode video")
    if args.model is None and (args.mirror or args.gamma is not None):
        raise UsageError("--mirror and --gamma apply to a learned model: add --model")
    if args.offset == "auto":
        from xvmatch.geometry.spatial_search import OFFSET_TOLERANCE, estimate_offset

        est = estimate_offset(top, hor, hor_width=args.image_size[0], params=params,
                              max_offset=args.max_offset, camera_id=args.camera_id,
                              workers=args.workers)
        offset = est.applied
        if est.status == "unsupported":
            print(f"warning: offset {est.offset:+d} not applied ({_offset_summary(est)}): "
                  f"{_unsupported_reason(est, args.max_offset)}; keeping the files' timing; "
                  "pass --offset N if you know it", file=sys.stderr)
        elif not args.quiet:
            kept = (f" (within {OFFSET_TOLERANCE} frames of 0: keeping the files' timing)"
                    if est.offset and not offset else "")
            print(f"estimated offset {est.offset:+d} frames (top frame = horizontal frame "
                  f"{est.offset:+d}; {_offset_summary(est)}){kept}", file=sys.stderr)
    else:
        offset = args.offset
    if offset:
        from xvmatch.datasets.mot_boxes import shift_frames

        top = shift_frames(top, offset)
    frames = sorted(set(top) | set(hor))
    progress = _progress(len(frames), "associate", not args.quiet)
    if args.model is not None:
        from xvmatch.cli_learn import associate_with_model

        pairs = associate_with_model(args, top, hor, frames, progress)
    else:
        pairs = associate_sequence(
            top,
            hor,
            hor_width=args.image_size[0],
            params=params,
            search=search,
            camera_id=args.camera_id,
            frames=frames,
            progress=progress,
        )
    write_predictions(args.out, pairs)
    n_pairs = sum(len(p) for p in pairs.values())
    if not args.quiet:
        print(f"wrote {n_pairs} pairs over {len(frames)} frames to {args.out}", file=sys.stderr)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    from xvmatch.datasets.mot_boxes import read_predictions
    from xvmatch.evaluation.cross_view_metrics import (
        count_sequence,
        format_table,
        scores_to_dict,
        summarize,
    )

    top = _read_boxes(args.top, args.duplicates)
    hor = _read_boxes(args.hor, args.duplicates)
    pred = read_predictions(args.pred)
    if args.offset:
        from xvmatch.datasets.mot_boxes import shift_frames

        top = shift_frames(top, args.offset)
    try:
        counts = count_sequence(pred, top, hor)
    except ValueError as exc:
        raise UsageError(f"{args.pred}: {exc}") from None
    scores = summarize(counts)
    if args.json:
        print(json.dumps(scores_to_dict(scores), indent=2))
    else:
        print(format_table([(args.name or args.pred, scores)]))
    return 0


def _cmd_noise(args: argparse.Namespace) -> int:
    from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
    from xvmatch.datasets.mot_boxes import write_mot_boxes

    frames = _read_boxes(args.boxes, args.duplicates)
    noise = DetectorNoise(jitter=args.jitter, miss_rate=args.miss, false_per_frame=args.false)
    noisy = apply_detector_noise(
        frames, args.image_size, noise, seed=args.seed, view=args.view, keep_ids=args.keep_id
    )
    write_mot_boxes(args.out, noisy)
    return 0


def _offset_summary(est) -> str:
    """How strongly the clips back an :class:`OffsetEstimate`, in words."""
    import numpy as np

    n = int(np.isfinite(est.clip_costs).any(axis=1).sum())
    text = f"{round(est.support * n)} of {n} clips agree"
    return text + (f", evidence t = {est.evidence:.1f}" if est.offset and n > 1 else "")


def _unsupported_reason(est, max_offset: int) -> str:
    """Why an :class:`OffsetEstimate` was not applied, in words."""
    import numpy as np

    from xvmatch.geometry.spatial_search import MIN_OFFSET_EVIDENCE, OFFSET_ALPHA

    n = int(np.isfinite(est.clip_costs).any(axis=1).sum())
    if n < 2:
        return (f"only {n} clip fits videos this short for --max-offset {max_offset} and one "
                "clip cannot back an offset; try a smaller --max-offset")
    if est.evidence < MIN_OFFSET_EVIDENCE:
        return (f"the clips do not prefer {est.offset:+d} to 0 (evidence t = "
                f"{est.evidence:.1f} < {MIN_OFFSET_EVIDENCE})")
    return (f"too few clips agree on {est.offset:+d} ({round(est.support * n)} of {n}: chance "
            f"{est.chance:.2f} > {OFFSET_ALPHA})")


def _cmd_offset(args: argparse.Namespace) -> int:
    from xvmatch.geometry.spatial_search import OFFSET_TOLERANCE, estimate_offset

    top = _read_boxes(args.top, args.duplicates)
    hor = _read_boxes(args.hor, args.duplicates)
    est = estimate_offset(
        top,
        hor,
        hor_width=args.image_size[0],
        params=_spatial_params(args),
        clip_start=args.clip_start,
        clip_length=args.clip_length,
        max_offset=args.max_offset,
        camera_id=args.camera_id,
        n_clips=args.clips,
        workers=args.workers,
    )
    if args.json:
        print(
            json.dumps(
                {
                    "offset": est.offset,
                    "applied": est.applied,
                    "status": est.status,
                    "support": est.support,
                    "evidence": est.evidence if est.evidence != float("inf") else None,
                    "offsets": est.offsets.tolist(),
                    "costs": [c if c != float("inf") else None for c in est.costs.tolist()],
                }
            )
        )
    else:
        print(f"offset {est.offset:+d} frames (top frame = horizontal frame {est.offset:+d}; "
              f"{_offset_summary(est)})")
        if est.status == "unsupported":
            print(f"warning: {_unsupported_reason(est, args.max_offset)}: the estimate is "
                  "unreliable (detector noise, too few people, or an offset beyond "
                  "--max-offset); associate --offset auto keeps the files' timing",
                  file=sys.stderr)
        elif est.status == "within_tolerance" and est.offset:
            print(f"note: {est.offset:+d} is within the estimate's precision ({OFFSET_TOLERANCE} "
                  "frames) of 0: associate --offset auto keeps the files' timing; pass "
                  f"--offset {est.offset} to apply it", file=sys.stderr)
    return 0


def _cmd_demo(args: argparse.Namespace) -> int:
    from xvmatch.datasets.box_scene import SceneConfig, simulate_box_scene
    from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
    from xvmatch.evaluation.cross_view_metrics import count_sequence, format_table, summarize
    from xvmatch.geometry.spatial_matching import SpatialParams
    from xvmatch.geometry.spatial_search import associate_sequence

    config = SceneConfig()
    scene = simulate_box_scene(config, n_frames=args.frames, seed=args.seed)
    width = config.hor_size[0]
    print(
        f"simulated scene: {scene.people.n_people} people, {args.frames} frames, seed {args.seed} "
        f"(top {config.top_size[0]}x{config.top_size[1]}, "
        f"horizontal {config.hor_size[0]}x{config.hor_size[1]})"
    )
    noisy_top = apply_detector_noise(
        scene.top, config.top_size, DetectorNoise(), seed=args.seed, view="top", keep_ids=(0,)
    )
    noisy_hor = apply_detector_noise(
        scene.hor, config.hor_size, DetectorNoise(), seed=args.seed, view="hor"
    )
    runs = [
        ("frame, O searched", scene.top, scene.hor, "exhaustive", None),
        ("frame, O given", scene.top, scene.hor, "exhaustive", 0),
        ("video, theta reduced + O followed", scene.top, scene.hor, "follow", None),
        ("frame, O searched, detector noise", noisy_top, noisy_hor, "exhaustive", None),
    ]
    rows = []
    params = SpatialParams()
    for name, top, hor, search, cam in runs:
        frames = sorted(set(top) | set(hor))
        pred = associate_sequence(
            top,
            hor,
            width,
            params,
            search=search,
            camera_id=cam,
            frames=frames,
            progress=_progress(len(frames), name, True),
        )
        rows.append((name, summarize(count_sequence(pred, top, hor))))
    print(format_table(rows))
    return 0


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (also used to render the README's examples)."""
    from xvmatch import __version__

    parser = argparse.ArgumentParser(
        prog="xvmatch",
        description="Associate the same people across a top/overview view and a horizontal "
        "(egocentric) view.",
    )
    parser.add_argument("--version", action="version", version=f"xvmatch {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help_text: str) -> argparse.ArgumentParser:
        p = sub.add_parser(
            name,
            help=help_text,
            description=help_text,
            epilog=f"example:\n  {EXAMPLES[name]}",
            formatter_class=argparse.RawDescriptionHelpFormatter,
        )
        return p

    def box_inputs(p: argparse.ArgumentParser) -> None:
        p.add_argument("--top", required=True, help="top-view boxes (MOT format)")
        p.add_argument("--hor", required=True, help="horizontal-view boxes (MOT format)")
        p.add_argument(
            "--duplicates",
            choices=("first", "error"),
            default="first",
            help="a repeated (frame, id) in a box file: keep the first box with a warning "
            "(default; the real CVMHAT files have a few) or stop with an error",
        )

    p = command(
        "associate",
        "Associate people across the two views from boxes alone (CVMHAT spatial "
        "distribution, Sec. 3.2) and write frame,top_id,hor_id pairs.",
    )
    box_inputs(p)
    p.add_argument("--out", required=True, help="prediction CSV to write (atomically)")
    p.add_argument(
        "--camera-id",
        type=int,
        default=None,
        help="top-view id of the horizontal camera's wearer (the 'O given' setting); "
        "without it O is searched among all top-view people",
    )
    p.add_argument(
        "--mode",
        choices=("frame", "video"),
        default="frame",
        help="frame: each frame solved on its own (exhaustive search); video: uses previous "
        "frames (damped orientation window, O followed by its top-view track id)",
    )
    p.add_argument(
        "--search",
        choices=("exhaustive", "reduced", "follow"),
        default=None,
        help="video-mode search: reduced = orientation window only, follow = window + O "
        "followed (default in video mode)",
    )
    p.add_argument(
        "--image-size",
        type=image_size(),
        default=(2688, 1512),
        metavar="WxH",
        help="horizontal image size in pixels (default 2688x1512, CVMHAT)",
    )
    p.add_argument(
        "--offset",
        type=offset_value,
        default=0,
        metavar="N|auto",
        help="the videos are out of sync: top frame = horizontal frame + N (what "
        "'xvmatch offset' prints); 'auto' estimates it first from the boxes (about a "
        "minute per sequence on one core with the default --max-offset; see --workers) and "
        "shifts only when the clips "
        "back the estimate and it is more than 5 frames from 0. Pairs are written under the "
        "horizontal frame numbers (default 0: frame-locked videos)",
    )
    p.add_argument(
        "--max-offset",
        type=int_at_least(0),
        default=AUTO_MAX_OFFSET,
        help=f"largest |offset| tried by --offset auto (default {AUTO_MAX_OFFSET} frames)",
    )
    p.add_argument("--workers", type=positive_int, default=1, metavar="K",
                   help="processes for --offset auto's estimate and for --model's features "
                   "(default 1; the same output for any K)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    _add_spatial_options(p)
    from xvmatch.cli_learn import add_model_arguments

    add_model_arguments(p)
    p.set_defaults(func=_cmd_associate)

    p = command("evaluate", "Score predicted pairs: CVIDP, CVIDR, CVIDF1, CVMA, Eq. 9 accuracy.")
    box_inputs(p)
    p.add_argument("--pred", required=True, help="prediction CSV (frame,top_id,hor_id)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--name", default=None, help="row label in the table")
    p.add_argument("--offset", type=int, default=0, metavar="N",
                   help="score predictions made with 'associate --offset N': the top view is "
                   "re-timed the same way (top frame = horizontal frame + N) before scoring")
    p.set_defaults(func=_cmd_evaluate)

    p = command(
        "noise",
        "Apply detector-like noise (jitter, misses, false boxes) to a box file, seeded.",
    )
    p.add_argument("--boxes", required=True, help="input box file (MOT format)")
    p.add_argument("--out", required=True, help="output box file (written atomically)")
    p.add_argument("--view", choices=("top", "hor"), required=True, help="which view it is")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.add_argument("--jitter", type=float, default=0.05, help="box jitter fraction (0.05)")
    p.add_argument("--miss", type=float, default=0.10, help="miss probability (0.10)")
    p.add_argument("--false", type=float, default=0.3, help="false boxes per frame (0.3)")
    p.add_argument(
        "--keep-id", type=int, action="append", default=[], help="never drop this id (repeatable)"
    )
    p.add_argument(
        "--image-size", type=image_size(), default=(2688, 1512), metavar="WxH",
        help="image size (default 2688x1512)",
    )
    p.add_argument(
        "--duplicates", choices=("first", "error"), default="first",
        help="repeated (frame, id): keep the first with a warning (default) or stop",
    )
    p.set_defaults(func=_cmd_noise)

    p = command(
        "offset",
        "Estimate the temporal offset between the two videos by sliding clips (Fig. 5).",
    )
    box_inputs(p)
    p.add_argument("--camera-id", type=int, default=None, help="top-view id of the wearer")
    p.add_argument(
        "--clip-start",
        type=int,
        default=None,
        help="first horizontal frame of a single clip (the paper's setting); default: "
        "--clips clips spread over the video",
    )
    p.add_argument("--clips", type=int, default=9, help="clips to average (default 9)")
    p.add_argument("--clip-length", type=int, default=10, help="clip length (default 10)")
    p.add_argument(
        "--max-offset", type=int_at_least(0), default=AUTO_MAX_OFFSET,
        help=f"largest |offset| (default {AUTO_MAX_OFFSET}, as associate --offset auto)",
    )
    p.add_argument(
        "--image-size", type=image_size(), default=(2688, 1512), metavar="WxH",
        help="horizontal image size (default 2688x1512)",
    )
    p.add_argument("--json", action="store_true", help="print JSON (offset and cost per offset)")
    p.add_argument("--workers", type=positive_int, default=1, metavar="K",
                   help="processes sharing the clips (default 1; the estimate is the same "
                   "for any K)")
    _add_spatial_options(p)
    p.set_defaults(func=_cmd_offset)

    p = command("demo", "Simulate a scene, associate it in several modes and print the metrics.")
    p.add_argument("--frames", type=int, default=150, help="frames to simulate (default 150)")
    p.add_argument("--seed", type=int, default=0, help="random seed (default 0)")
    p.set_defaults(func=_cmd_demo)

    from xvmatch.cli_synth import add_show_parser, add_synth_parser

    add_synth_parser(sub)
    add_show_parser(sub)

    from xvmatch.cli_baseline import add_baseline_parser
    from xvmatch.cli_learn import add_fit_geometry_parser
    from xvmatch.cli_train import add_train_parser

    add_baseline_parser(sub)
    add_fit_geometry_parser(sub)
    add_train_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``xvmatch`` command."""
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args))
    except (UsageError, ValueError, OSError) as exc:
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        print(f"xvmatch: error: {message}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("xvmatch: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
