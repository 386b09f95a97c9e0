"""The ``xvmatch adapt`` command: a site bundle fitted on the user's own unlabelled videos.

Reads a video pair (images and box files of both views, no ids across views; optionally the
cameras), mines pairs (:mod:`xvmatch.inference.adaptation.adaptation_pairs`), fits the adaptation of
the appearance cue (:mod:`xvmatch.inference.adaptation.site_adaptation`) and writes a site bundle
(:mod:`xvmatch.inference.matching.site_bundle`) that ``associate --model SITE/`` uses. Torch-free:
runs in the base install.
"""

from __future__ import annotations

import argparse
import math
import sys

from xvmatch.commands._model import add_camera_check, add_refine_top_camera
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    UsageError,
    add_box_inputs,
    add_command_parser,
    add_image_options,
    check_camera_id,
    image_inputs,
    progress_bar,
    read_boxes,
)
from xvmatch.commands._types import box_id, int_in, thread_count, worker_count
from xvmatch.core.output_paths import Input, Output, check_outputs, check_own_folder

__all__ = ["ADAPT_COMMAND", "EXAMPLE", "add_adapt_parser", "refusal_message"]

EXAMPLE = ("xvmatch adapt --top top.txt --hor hor.txt --top-images top.mp4 --hor-images hor.mp4 "
           "--out site/\n  xvmatch associate --model site/ --top top.txt --hor hor.txt "
           "--top-images top.mp4 --hor-images hor.mp4 --out pred.csv")

ADAPT_COMMAND = "xvmatch adapt"
"""The owner of a site bundle folder (:func:`xvmatch.core.output_paths.claim_folder`)."""


def add_adapt_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch adapt`` on ``subparsers`` and return its parser."""
    p = add_command_parser(
        subparsers,
        "adapt",
        "Adapt the learned matcher's appearance cue to your cameras from your own unlabelled "
        "video pair (boxes and images of both views, no ids across views): writes a site "
        "bundle for associate --model SITE/. The video's last block is held out: the site bundle "
        "must make better pairs there than the unadapted one (the box-only matcher's sure "
        "pairs kept, fewer partners switched along tracklets), else it is refused and nothing "
        "is written.",
        EXAMPLE,
    )
    add_box_inputs(p)
    add_image_options(p)
    p.add_argument("--out", required=True, metavar="SITE",
                   help="the site bundle folder to write: new, empty, or one adapt wrote")
    p.add_argument("--model", default="default", metavar="BUNDLE",
                   help="the bundle to adapt (with an appearance network; default: the shipped "
                   "one); its files are copied unchanged")
    p.add_argument("--cameras", default=None, metavar="CAMERAS",
                   help="calibrated cameras 'top' and 'ego' (a file or a folder of per-frame "
                   "files), as associate takes them: the box-only matcher that mines the "
                   "cross-view pairs then uses them")
    add_refine_top_camera(p)
    add_camera_check(p)
    p.add_argument("--camera-id", type=box_id, default=None,
                   help="top-view id of the horizontal camera's wearer, when known")
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help=IMAGE_SIZE_HELP + "; it must agree with the horizontal images")
    p.add_argument("--max-frames", default=1500, metavar="N",
                   type=int_in(10, 1_000_000, "frames scored by the box-only matcher"),
                   help="most frames read, in bursts spread over the whole video, 10..1000000 "
                   "(default 1500, whatever the video's length)")
    p.add_argument("--burst", default=10, metavar="K",
                   type=int_in(3, 100, "consecutive frames whose matches must agree"),
                   help="consecutive frames per burst, 3..100 (default 10)")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for the geometry features, 1..64 (default 1; same output)")
    p.add_argument("--threads", type=thread_count, default=1, metavar="K",
                   help="onnxruntime threads, 1..64 (default 1)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    p.set_defaults(func=_cmd_adapt)
    return p


def refusal_message(run, model: str) -> str:
    """The one line ``adapt`` ends with when no fit was accepted (a
    :class:`~xvmatch.inference.matching.site_bundle.SiteRun`): each vector's reason, then what to
    do. When the network's own cue (its descriptors, unadapted) is not above chance on the held-out
    pairs either, images would only add noise to the boxes: the advice is to leave them out,
    unless the box-only matcher whose pairs judged them is often wrong (docs/adaptation.md)."""
    from xvmatch.inference.adaptation.site_adaptation import auc_standard_error, better_than_chance

    fit = run.fit
    reasons = "; ".join(f"{v}: {f.reason}" for v, f in run.fits.items()) or fit.reason
    raw = run.fits.get("descriptors", fit)
    if math.isfinite(raw.auc_before) and not better_than_chance(raw.auc_before, raw.heldout_pairs):
        se = auc_standard_error(raw.auc_before, *raw.heldout_pairs)
        advice = (f"nor is the network's own appearance cue shown better than chance at this "
                  f"site (held-out AUC {raw.auc_before:.3f} +/- {se:.3f}): images would add "
                  "noise to the boxes, so match from the boxes alone (associate without "
                  "--top-images and --hor-images), unless the box-only matcher is often wrong "
                  "here (its sure pairs were the yardstick; an oblique overview camera without "
                  "--cameras): then score both on a few frames you label")
    else:
        advice = f"keep using --model {model}"
    return f"adaptation refused, nothing written: {reasons}; {advice}"


def _cmd_adapt(args: argparse.Namespace) -> int:
    from xvmatch import __version__
    from xvmatch.commands._model import (
        horizontal_size,
        model_args,
        note_camera_check,
        note_camera_refinement,
        open_models,
    )
    from xvmatch.core.output_paths import claim_folder
    from xvmatch.formats.mot_boxes import check_common_frames
    from xvmatch.inference.adaptation.adaptation_pairs import MiningConfig
    from xvmatch.inference.matching.learned_pipeline import LearnedRunOptions, open_learned_inputs
    from xvmatch.inference.matching.site_bundle import adapt_to_site, write_site_bundle

    if args.top_images is None or args.hor_images is None:
        raise UsageError("adapt learns from the images: give --top-images and --hor-images")
    top = read_boxes(args.top, args.duplicates)
    hor = read_boxes(args.hor, args.duplicates)
    check_common_frames(top, hor, 0, (args.top, args.hor), "nothing to adapt on")
    check_camera_id(args.camera_id, top, args.top)
    check_outputs([Output("--out", args.out, folder=True)],
                  [Input("--top", args.top), Input("--hor", args.hor), *image_inputs(args),
                   Input("--cameras", args.cameras),
                   Input("--model", None if args.model == "default" else args.model)])
    check_own_folder(args.out, ADAPT_COMMAND)
    config = MiningConfig(burst=args.burst, max_frames=max(args.max_frames, args.burst),
                          agree=3)
    model = open_models([args.model], args.threads)[0]
    if model.bundle.manifest.appearance is None:
        raise UsageError(f"--model {args.model}: a box-only matcher has no appearance network "
                         "to adapt; use a bundle with one (e.g. default)")
    hor_size = horizontal_size(model_args(args), hor)
    both = [f for f in sorted(set(top) & set(hor)) if len(top[f].ids) and len(hor[f].ids)]
    options = LearnedRunOptions(models=(model,), hor_size=tuple(hor_size[0]),
                                hor_size_source=hor_size[1], names=(args.model,),
                                top_images=args.top_images, hor_images=args.hor_images,
                                cameras=args.cameras, top_boxes=args.top,
                                camera_id=args.camera_id, workers=args.workers,
                                refine_top_camera=args.refine_top_camera == "auto",
                                camera_check=args.camera_check == "on")

    def progress(items, total, what):
        return progress_bar(total, what, "frame", not args.quiet, items)

    with open_learned_inputs(top, hor, both, options) as inputs:
        note_camera_refinement(inputs.refinement, args.quiet)
        note_camera_check(inputs.camera_checked, args.quiet)
        run = adapt_to_site(top, hor, model, inputs.images["top"], inputs.images["hor"],
                            tuple(hor_size[0]), inputs.cameras, args.camera_id, config,
                            progress, args.workers)
        mined_with_cameras = inputs.cameras is not None  # not when the camera check failed
    fit = run.fit
    if not fit.accepted:
        raise UsageError(refusal_message(run, args.model))
    if not run.accepted:
        raise UsageError(f"adaptation refused, nothing written: {run.judgement.message()}; "
                         f"keep using --model {args.model}")
    out = claim_folder(args.out, ADAPT_COMMAND)
    roles = {"top": args.top, "hor": args.hor, "top_images": args.top_images,
             "hor_images": args.hor_images}
    if mined_with_cameras:
        roles["cameras"] = args.cameras
    write_site_bundle(model.bundle.manifest.folder, out, run, roles, __version__)
    if not args.quiet:
        print(f"adapted the network's {fit.adaptation.vector} on {run.frames_scored} frames "
              f"({len(run.mined.embed_frames)} embedded): "
              f"{run.counts['cross_pos']} cross-view pseudo-matches; rank "
              f"{fit.adaptation.rank}; held-out AUC {fit.auc_before:.3f} -> {fit.auc_after:.3f}"
              + "".join(f" ({v}: {f.auc_before:.3f} -> {f.auc_after:.3f}"
                        f"{'' if f.accepted else ', refused'})"
                        for v, f in run.fits.items() if f is not fit)
              + f"; {run.judgement.message()}"
              + f"; wrote {out}/ (use: xvmatch associate --model {out} ...)", file=sys.stderr)
    return 0
