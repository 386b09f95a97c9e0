"""Command-line interface: ``xvmatch associate | evaluate | noise | offset | demo | ...``.

``synth``/``show``, ``baseline``, ``fit-geometry`` and ``train`` come from ``cli_synth``,
``cli_baseline``, ``cli_learn`` and ``cli_train``. Each command
imports only what it needs, so ``xvmatch associate`` starts fast and never imports torch. Bad
input ends with one line ``xvmatch: error: ...`` naming the file and line, exit code 2. Every
size or count option has a range, given in its help and checked while the arguments are parsed
(:mod:`xvmatch.cli_types`), before any work starts; so is every output path
(:mod:`xvmatch.output_paths`: no FIFO, device or folder where a file goes, no input overwritten,
no two outputs on one path, a writable folder).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Iterable, Sequence

from xvmatch.cli_demo import EXAMPLES as DEMO_EXAMPLES
from xvmatch.cli_types import (
    box_id,
    float_in,
    frame_offset,
    image_size,
    int_in,
    offset_value,
    seed_value,
    worker_count,
)
from xvmatch.geometry.offset_estimation import AUTO_MAX_OFFSET
from xvmatch.output_paths import Input, Output, check_outputs

__all__ = ["main"]

EXAMPLES = {
    "associate": "xvmatch associate --top seq_top.txt --hor seq_hor.txt --out pred.csv",
    "evaluate": "xvmatch evaluate --pred pred.csv --top seq_top.txt --hor seq_hor.txt",
    "noise": "xvmatch noise --boxes seq_top.txt --view top --seed 1 --out noisy_top.txt",
    "offset": "xvmatch offset --top seq_top.txt --hor seq_hor.txt",
    **DEMO_EXAMPLES,
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


MAX_OFFSET_LIMIT = 10_000
"""Largest ``--max-offset``: each clip is compared at 2 * max_offset + 1 offsets."""

MAX_OFFSET_TYPE = int_in(0, MAX_OFFSET_LIMIT, "each clip is compared at 2 * max_offset + 1 "
                         "offsets")
"""``--max-offset``: 0..10000 frames (and at most the videos' length: :func:`_max_offset`)."""

HOR_IMAGE_SIZE = image_size(8, 65536, "pixels of a camera image")
"""``--image-size`` of the horizontal view: 8..65536 pixels a side."""

IMAGE_SIZE_HELP = (
    "the horizontal camera's image size in pixels, 8..65536 a side; needed with boxes only "
    "(default: the images' or the cameras' size; else 2688x1512, CVMHAT's, only when the boxes "
    "reach beyond 60%% of its width, with a note; a box more than 10%% past the image's border "
    "is an error)")
"""The help of every ``--image-size`` of the horizontal view (:mod:`xvmatch.cli_image_size`)."""


def _add_spatial_options(parser: argparse.ArgumentParser) -> None:
    g = parser.add_argument_group("spatial-distribution parameters (paper defaults)")
    # rho > 1 is checked with the other parameters by SpatialParams (one line, exit 2, before
    # any work): the parser bounds only its size.
    g.add_argument(
        "--rho", default=15.0,
        type=float_in(None, 1e6, "Eq. 12's penalty base, in (1, 1e6]; the paper uses 15"),
        help="penalty base of Eq. 12, in (1, 1e6] (default 15)",
    )
    g.add_argument(
        "--lam", default=0.003,
        type=float_in(0, 1e6, "Eq. 11's x/y balance is positive; the paper uses 0.003",
                      low_open=True),
        help="x/y balance lambda of Eq. 11, in (0, 1e6] (default 0.003)",
    )
    g.add_argument(
        "--tau", default=2.0,
        type=float_in(0, 90, "an angle between two people seen from the camera, degrees"),
        help="occlusion tolerance, degrees in [0, 90] (default 2)",
    )
    g.add_argument(
        "--dtheta", default=1.0,
        type=float_in(0.01, 360, "the search tries 360 / dtheta orientations"),
        help="orientation step, degrees in [0.01, 360]: the search tries 360 / dtheta "
        "orientations (default 1)",
    )
    g.add_argument(
        "--fov", default=90.0,
        type=float_in(0, 180, "a pinhole camera's horizontal field of view, degrees",
                      low_open=True, high_open=True),
        help="horizontal camera field of view, degrees in (0, 180) (default 90)",
    )


def _max_offset(args: argparse.Namespace, top, hor) -> int:
    """``--max-offset``, the default when not given; a given one must not exceed the number of
    frames the two box files span (no larger offset aligns any frame of the two)."""
    if args.max_offset is None:
        return AUTO_MAX_OFFSET
    frames = [*top, *hor]
    if frames:
        first, last = min(frames), max(frames)
        span = last - first + 1
        if args.max_offset > span:
            raise UsageError(
                f"--max-offset {args.max_offset} is more than the videos' length: the box files "
                f"span {span} frames ({first}..{last}) and no larger offset aligns any frame; "
                f"use at most {span}"
            )
    return args.max_offset


def _spatial_params(args: argparse.Namespace):
    from xvmatch.geometry.spatial_matching import SpatialParams

    return SpatialParams(
        rho=args.rho, lam=args.lam, tau_deg=args.tau, dtheta_deg=args.dtheta, fov_deg=args.fov
    )


def _check_camera_id(camera_id: int | None, top, path: str) -> None:
    """``--camera-id`` must name a person of the top view in at least one frame."""
    if camera_id is None:
        return
    if not any(camera_id in rec.ids for rec in top.values()):
        raise UsageError(f"--camera-id {camera_id}: no box of {path} has this id (the id of "
                         "the horizontal camera's wearer in the top-view file)")


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
    if args.model is None:
        from xvmatch.cli_learn import LEARNED_ONLY

        given = [f"--{k.replace('_', '-')}" for k in LEARNED_ONLY
                 if getattr(args, k) not in (None, False)]
        if given:
            raise UsageError(f"{', '.join(given)} apply to a learned matcher: add --model "
                             "default (or a bundle)")
    _check_camera_id(args.camera_id, top, args.top)
    models = [m for m in args.model or () if m != "default"]
    check_outputs(
        [Output("--out", args.out), Output("--costs", args.costs),
         Output("--draw", args.draw, folder=True)],
        [Input("--top", args.top), Input("--hor", args.hor),
         Input("--top-images", args.top_images), Input("--hor-images", args.hor_images),
         Input("--cameras", args.cameras), *(Input("--model", m) for m in models)],
    )
    if args.draw is not None:
        from xvmatch.cli_learn import DRAW_COMMAND
        from xvmatch.output_paths import check_own_folder

        check_own_folder(args.draw, DRAW_COMMAND, "--draw")
    from xvmatch.cli_learn import horizontal_size

    max_offset = _max_offset(args, top, hor) if args.offset == "auto" else None
    hor_size = horizontal_size(args, hor)
    hor_width = hor_size[0][0]
    if args.model is None:
        from xvmatch.cli_image_size import note_if_assumed

        note_if_assumed(hor_size, hor, args.hor, args.quiet)
    if args.offset == "auto":
        from xvmatch.geometry.offset_estimation import OFFSET_TOLERANCE, estimate_offset

        est = estimate_offset(top, hor, hor_width=hor_width, params=params,
                              max_offset=max_offset, camera_id=args.camera_id,
                              workers=args.workers)
        offset = est.applied
        if est.status == "unsupported":
            print(f"warning: offset {est.offset:+d} not applied ({_offset_summary(est)}): "
                  f"{_unsupported_reason(est, max_offset)}; keeping the files' timing; "
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

        pairs = associate_with_model(args, top, hor, frames, progress, top_offset=offset,
                                     hor_size=hor_size)
    else:
        pairs = associate_sequence(
            top,
            hor,
            hor_width=hor_width,
            params=params,
            search=search,
            camera_id=args.camera_id,
            frames=frames,
            progress=progress,
        )
        if args.draw is not None:
            from xvmatch.cli_learn import draw_pictures

            both = [f for f in frames if len(top.get(f, ())) and len(hor.get(f, ()))]
            draw_pictures(args.draw, args.draw_every, top, hor, pairs, both, None, hor_size[0],
                          not args.no_labels)
    write_predictions(args.out, pairs)
    n_pairs = sum(len(p) for p in pairs.values())
    if not args.quiet:
        print(f"wrote {n_pairs} pairs over {len(frames)} frames to {args.out}", file=sys.stderr)
    return 0


def _cmd_evaluate(args: argparse.Namespace) -> int:
    if args.tracks is not None:
        from xvmatch.cli_track import evaluate_tracks_command

        return evaluate_tracks_command(args, _read_boxes)
    from xvmatch.datasets.mot_boxes import read_predictions
    from xvmatch.inference.cross_view_metrics import (
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
    _check_common_frames(top, hor, args)
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


def _check_common_frames(top, hor, args: argparse.Namespace) -> None:
    """Scores need a frame with boxes in both views: without one every score is empty."""
    common = {f for f, rec in top.items() if len(rec)} & {f for f, rec in hor.items() if len(rec)}
    if common:
        return

    def span(frames) -> str:
        used = [f for f, rec in frames.items() if len(rec)]
        return f"{min(used)}..{max(used)}" if used else "none"

    shifted = f" after --offset {args.offset}" if args.offset else ""
    raise UsageError(f"nothing to score: {args.top} and {args.hor} share no frame with boxes in "
                     f"both views{shifted} (top frames {span(top)}, horizontal frames "
                     f"{span(hor)}); check the files and --offset")


def _cmd_noise(args: argparse.Namespace) -> int:
    from xvmatch.datasets.detector_noise import DetectorNoise, apply_detector_noise
    from xvmatch.datasets.mot_boxes import write_mot_boxes

    check_outputs([Output("--out", args.out)], [Input("--boxes", args.boxes)])
    frames = _read_boxes(args.boxes, args.duplicates)
    size = args.image_size
    if args.view == "hor":  # false boxes land in this image: the associate rule's size
        from xvmatch.cli_image_size import note_if_assumed, resolve_size

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


def _offset_summary(est) -> str:
    """How strongly the clips back an :class:`OffsetEstimate`, in words."""
    import numpy as np

    n = int(np.isfinite(est.clip_costs).any(axis=1).sum())
    text = f"{round(est.support * n)} of {n} clips agree"
    return text + (f", evidence t = {est.evidence:.1f}" if est.offset and n > 1 else "")


def _unsupported_reason(est, max_offset: int, one_clip_asked: bool = False) -> str:
    """Why an :class:`OffsetEstimate` was not applied, in words (``one_clip_asked``: the user
    asked for a single clip with --clips 1 or --clip-start)."""
    import numpy as np

    from xvmatch.geometry.offset_estimation import MIN_OFFSET_EVIDENCE, OFFSET_ALPHA

    n = int(np.isfinite(est.clip_costs).any(axis=1).sum())
    if n < 2 and one_clip_asked:
        return ("one clip (--clips 1 or --clip-start) cannot back an offset: at least 2 clips "
                "must agree; use --clips 3 or more, or pass --offset N if you trust it")
    if n < 2:
        return (f"only {n} clip fits videos this short for --max-offset {max_offset} and one "
                "clip cannot back an offset; try a smaller --max-offset")
    if est.evidence < MIN_OFFSET_EVIDENCE:
        return (f"the clips do not prefer {est.offset:+d} to 0 (evidence t = "
                f"{est.evidence:.1f} < {MIN_OFFSET_EVIDENCE})")
    return (f"too few clips agree on {est.offset:+d} ({round(est.support * n)} of {n}: chance "
            f"{est.chance:.2f} > {OFFSET_ALPHA})")


def _cmd_offset(args: argparse.Namespace) -> int:
    from xvmatch.geometry.offset_estimation import OFFSET_TOLERANCE, estimate_offset

    params = _spatial_params(args)
    top = _read_boxes(args.top, args.duplicates)
    hor = _read_boxes(args.hor, args.duplicates)
    max_offset = _max_offset(args, top, hor)
    _check_camera_id(args.camera_id, top, args.top)
    if args.clip_length < 1:  # before the size note: a refused run prints one line
        raise UsageError(f"--clip-length {args.clip_length}: need clip_length >= 1 (frames per "
                         "clip)")
    from xvmatch.cli_image_size import note_if_assumed, resolve_size

    given = [] if args.image_size is None else [(args.image_size, "--image-size")]
    resolved = resolve_size(hor, args.hor, given)
    hor_width = resolved[0][0]
    note_if_assumed(resolved, hor, args.hor)
    est = estimate_offset(
        top,
        hor,
        hor_width=hor_width,
        params=params,
        clip_start=args.clip_start,
        clip_length=args.clip_length,
        max_offset=max_offset,
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
            one_clip = args.clip_start is not None or args.clips == 1
            print(f"warning: {_unsupported_reason(est, max_offset, one_clip)}: the estimate is "
                  "unreliable (detector noise, too few people, or an offset beyond "
                  "--max-offset); associate --offset auto keeps the files' timing",
                  file=sys.stderr)
        elif est.status == "within_tolerance" and est.offset:
            print(f"note: {est.offset:+d} is within the estimate's precision ({OFFSET_TOLERANCE} "
                  "frames) of 0: associate --offset auto keeps the files' timing; pass "
                  f"--offset {est.offset} to apply it", file=sys.stderr)
    return 0


def version_text() -> str:
    """``xvmatch --version``: the package and every on-disk format it reads and writes."""
    from xvmatch import __version__
    from xvmatch.datasets.synthetic_io import SCHEMA_VERSION
    from xvmatch.geometry.camera_io import FORMAT_VERSION as CAMERA_VERSION
    from xvmatch.geometry.spatial_features import FEATURE_VERSION
    from xvmatch.inference.bundle import BUNDLE_FORMAT_VERSION, OPSET

    try:  # the training file format needs torch (the learn extra)
        from xvmatch.models.matcher_file import MATCHER_FORMAT_VERSION as MATCHER
    except ImportError:
        MATCHER = "(needs the learn extra)"
    return (f"xvmatch {__version__}\n"
            f"  geometry features: version {FEATURE_VERSION}\n"
            f"  matcher bundle: format {BUNDLE_FORMAT_VERSION} (ONNX opset {OPSET})\n"
            f"  matcher file (.pt): format {MATCHER}\n"
            f"  camera file: version {CAMERA_VERSION}\n"
            f"  synthetic dataset: schema {SCHEMA_VERSION}")


class _VersionAction(argparse.Action):
    """``--version``, computed only when asked (it may import torch)."""

    def __call__(self, parser, namespace, values, option_string=None) -> None:
        print(version_text())
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The argument parser of every command (also used to render the README's examples)."""
    parser = argparse.ArgumentParser(
        prog="xvmatch",
        description="Associate the same people across a top/overview view and a horizontal "
        "(egocentric) view.",
    )
    parser.add_argument("--version", action=_VersionAction, nargs=0,
                        help="print the version of xvmatch and of its file formats")
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

    # In the order a user needs them: try it, match, score, synchronise, data, the baseline,
    # training, deployment, utilities.
    from xvmatch.cli_ablate import add_ablate_parser
    from xvmatch.cli_baseline import add_baseline_parser
    from xvmatch.cli_demo import add_demo_parser
    from xvmatch.cli_learn import add_export_parser, add_fit_geometry_parser
    from xvmatch.cli_multi_ego import add_multi_ego_parser
    from xvmatch.cli_synth import add_show_parser, add_synth_parser
    from xvmatch.cli_track import add_track_parser
    from xvmatch.cli_train import add_train_parser

    add_demo_parser(sub)

    p = command(
        "associate",
        "Associate people across the two views and write frame,top_id,hor_id pairs: from "
        "boxes with the CVMHAT spatial-distribution search (Sec. 3.2), or with a learned "
        "matcher (--model) from boxes, images and cameras.",
    )
    box_inputs(p)
    p.add_argument("--out", required=True, help="prediction CSV to write (atomically)")
    p.add_argument(
        "--camera-id",
        type=box_id,
        default=None,
        help="top-view id of the horizontal camera's wearer (the 'O given' setting; any id a "
        "box file holds, |id| <= 2**53); without it O is searched among all top-view people",
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
        type=HOR_IMAGE_SIZE,
        default=None,
        metavar="WxH",
        help=IMAGE_SIZE_HELP + "; with --hor-images or --cameras it must agree with them",
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
        "horizontal frame numbers; |N| <= 100000 (default 0: frame-locked videos)",
    )
    p.add_argument(
        "--max-offset",
        type=MAX_OFFSET_TYPE,
        default=None,
        help=f"largest |offset| tried by --offset auto, 0..{MAX_OFFSET_LIMIT} frames and at "
        f"most the frames the box files span (default {AUTO_MAX_OFFSET})",
    )
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for --offset auto's estimate and for --model's features, "
                   "1..64 (default 1; the same output for any K)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    _add_spatial_options(p)
    from xvmatch.cli_learn import add_draw_arguments, add_model_arguments

    add_model_arguments(p)
    add_draw_arguments(p)
    p.set_defaults(func=_cmd_associate)

    p = command("evaluate", "Score predicted pairs: CVIDP, CVIDR, CVIDF1, CVMA, Eq. 9 accuracy; "
                "or tracks (--tracks): CVIDF1 and CVMA across views, IDF1, MOTA, MOTP and HOTA "
                "per view.")
    box_inputs(p)
    scored = p.add_mutually_exclusive_group(required=True)
    scored.add_argument("--pred", help="prediction CSV (frame,top_id,hor_id)")
    scored.add_argument("--tracks", metavar="DIR",
                        help="tracks of xvmatch track (DIR/top.txt, DIR/hor.txt); per-view "
                        "metrics need TrackEval (pip install --no-deps trackeval; without it "
                        "the cross-view scores alone, with a note)")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--name", default=None, help="row label in the table")
    p.add_argument("--offset", type=frame_offset, default=0, metavar="N",
                   help="score predictions made with 'associate --offset N': the top view is "
                   "re-timed the same way (top frame = horizontal frame + N) before scoring; "
                   "|N| <= 100000")
    p.set_defaults(func=_cmd_evaluate)
    add_track_parser(sub)
    add_multi_ego_parser(sub)

    p = command(
        "offset",
        "Estimate the temporal offset between the two videos by sliding clips (Fig. 5).",
    )
    box_inputs(p)
    p.add_argument("--camera-id", type=box_id, default=None,
                   help="top-view id of the wearer (|id| <= 2**53)")
    p.add_argument(
        "--clip-start",
        type=int_in(1, 2**53, "a frame number: frames are 1-based, exact to 2**53"),
        default=None,
        help="first horizontal frame of a single clip (the paper's setting), 1..2**53; "
        "default: --clips clips spread over the video",
    )
    p.add_argument("--clips", default=9,
                   type=int_in(1, 100, "each clip is one more search over every offset"),
                   help="clips to average, 1..100 (default 9)")
    # clip_length >= 1 is checked by estimate_offset with the other clip settings (one line,
    # exit 2, before any search): the parser bounds only its size.
    p.add_argument("--clip-length", default=10,
                   type=int_in(None, 1000, "frames per clip, in [1, 1000]: each is searched at "
                               "every offset"),
                   help="clip length in frames, 1..1000 (default 10)")
    p.add_argument(
        "--max-offset", type=MAX_OFFSET_TYPE, default=None,
        help=f"largest |offset|, 0..{MAX_OFFSET_LIMIT} frames and at most the frames the box "
        f"files span (default {AUTO_MAX_OFFSET}, as associate --offset auto)",
    )
    p.add_argument(
        "--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
        help=IMAGE_SIZE_HELP,
    )
    p.add_argument("--json", action="store_true", help="print JSON (offset and cost per offset)")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes sharing the clips, 1..64 (default 1; the estimate is the "
                   "same for any K)")
    _add_spatial_options(p)
    p.set_defaults(func=_cmd_offset)

    add_synth_parser(sub)
    add_show_parser(sub)
    add_baseline_parser(sub)
    add_ablate_parser(sub)
    add_fit_geometry_parser(sub)
    add_train_parser(sub)
    add_export_parser(sub)

    p = command(
        "noise",
        "Apply detector-like noise (jitter, misses, false boxes) to a box file, seeded.",
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
        "--image-size", type=image_size(8, 65536, "pixels of a camera image"),
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
    except MemoryError:
        print(f"xvmatch: error: out of memory running {args.command}: the input or the options "
              "need more memory than this machine has (try smaller inputs or fewer --workers)",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("xvmatch: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
