"""The ``xvmatch track`` command and ``xvmatch evaluate --tracks``: complementary-view tracking.

``track`` reads two box files as detections (their id column is ignored, except to find the
camera wearer with ``--camera-id``), tracks the people of both views with one id per person
across the views (:func:`xvmatch.inference.tracks.tracking.track_pair`, CVMHAT Algorithm 1), and
writes ``OUT/top.txt`` and ``OUT/hor.txt``: the input rows, text unchanged but the id field, which
holds the track id; rows the tracker dropped are absent. With the images of both views
(``--top-images``, ``--hor-images``: the forms ``xvmatch associate`` reads) the horizontal
tracklets link by IoU and colour and the over-time weights mix in colour similarity. ``--model``
gives the learned matcher: its box-only association makes the cross-view weights (``--weights
learned``, the default with ``--model``; ``--weights handcrafted`` keeps Eq. 13 on the spatial
search), and with images its appearance network adds the cross-view term and takes over the
over-time one (CVMHAT Sec. 3.3.2, 3.4.1, 4.1), unless ``--appearance-check`` finds its
cross-view cue too weak on the video's own sure tracklet pairs. ``--cameras`` gives the learned
matcher the calibrated cameras (a file, or per-frame files numbered by the horizontal frames).
``--offset N|auto`` tracks videos out of sync (top frame t + N with horizontal frame t), each
row still written under its own frame number; ``evaluate --tracks --offset N`` scores them. Bad
input raises ``ValueError`` with a one-line message, printed by the main entry point as
``xvmatch: error: ...`` with exit code 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Iterable
from dataclasses import replace
from pathlib import Path

from xvmatch.commands._model import (
    add_camera_check,
    add_refine_top_camera,
    add_write_cameras,
    check_write_cameras,
    model_args,
    note_camera_check,
    note_camera_refinement,
    write_cameras,
)
from xvmatch.commands._options import (
    HOR_IMAGE_SIZE,
    IMAGE_SIZE_HELP,
    add_command_parser,
    add_image_options,
    add_spatial_options,
    check_images_together,
    image_inputs,
    progress_bar,
    read_boxes,
    spatial_params,
)
from xvmatch.commands._types import box_id, float_in, int_in, seed_value, worker_count
from xvmatch.commands.offset import add_offset_options, max_offset_of, resolve_offset, wearer_marked
from xvmatch.core.output_paths import (
    Input,
    Output,
    check_outputs,
    check_own_folder,
    claim_folder,
)

__all__ = ["EXAMPLE", "OFFSET_FILE", "add_track_parser", "evaluate_tracks_command",
           "tracked_offset"]

OFFSET_FILE = "offset.json"
"""What ``track`` writes beside the tracks: ``{"offset": N}``, the offset it applied (0 when the
videos kept the files' timing), so that ``evaluate --tracks`` re-times the same way."""

TRACK_COMMAND = "xvmatch track"
"""The marker name of the command's output folders (it writes only into a folder it made)."""

EXAMPLE = (
    "xvmatch track --top seq_top.txt --hor seq_hor.txt --out tracks/\n"
    "  xvmatch track --top seq_top.txt --hor seq_hor.txt --model default --out tracks/\n"
    "  xvmatch evaluate --tracks tracks/ --top gt_top.txt --hor gt_hor.txt"
)

CLIP_LENGTH_TYPE = int_in(1, 1000, "frames per clip; each window's program grows with it")
MAX_GAP_TYPE = int_in(0, 1000, "frames; a clip is at most 1000 frames")
MIN_IOU_TYPE = float_in(0, 1, "an intersection over union", low_open=True)
C0_TYPE = float_in(0, 1, "edge weights are in [0, 1]; an edge pays off above 2 c0")
SIGMA_TYPE = float_in(0, 1000, "per box height of motion deviation", low_open=True)
SHARE_TYPE = float_in(0, 1, "a share of a linear combination")
TIME_LIMIT_TYPE = float_in(0.01, 600, "seconds per window before the MIP's fallback")


def _step_progress(enabled: bool):
    """``progress(iterable, total, description)``: a :func:`progress_bar` of steps."""

    def wrap(items: Iterable, total: int, desc: str) -> Iterable:
        return progress_bar(total, desc, "step", enabled, items)

    return wrap


def _cross_view_weights(args: argparse.Namespace) -> str:
    """``--weights``, its default (``learned`` with ``--model``, else ``handcrafted``) and the
    checks of its combinations with ``--model`` and the images."""
    weights = args.weights or ("learned" if args.model is not None else "handcrafted")
    if weights == "learned" and args.model is None:
        raise ValueError("--weights learned takes the learned matcher's costs: add --model "
                         "BUNDLE or --model default")
    if args.cameras is not None and weights != "learned":
        raise ValueError("--cameras feeds the learned matcher's cross-view weights: add --model "
                         "BUNDLE or --model default" if args.model is None else
                         "--cameras feeds the learned matcher's cross-view weights: drop "
                         "--weights handcrafted")
    if weights == "handcrafted" and args.model is not None and args.top_images is None:
        raise ValueError("--model with --weights handcrafted gives the appearance network, which "
                         "needs the images: add --top-images and --hor-images, or drop --weights "
                         "handcrafted to take the cross-view weights from the matcher")
    return weights


def _open_images(args: argparse.Namespace, top, hor, model, weights: str):
    """The image sources of both views, their horizontal size and the embedder (or None),
    after every check (images given together, the frames the boxes list, boxes inside the
    images, ``--image-size`` agreeing, a bundle with an appearance network unless the model
    gives the learned weights)."""
    from xvmatch.formats.box_image_size import check_boxes_in_image
    from xvmatch.inference.matching.learned_pipeline import open_view_images
    from xvmatch.inference.tracks.tracking import TrackImages

    check_images_together(args.top_images, args.hor_images)
    if args.top_images is None:
        return None, [], None
    embed = None
    if model is not None:
        if model.bundle.manifest.appearance is not None:
            embed = model.descriptors
        elif weights == "handcrafted":
            raise ValueError(f"{args.model}: a box-only matcher has no appearance network; "
                             "use a bundle with one (e.g. default), or drop --weights "
                             "handcrafted to take the cross-view weights from it")
    sources = []
    try:
        for path, frames in ((args.top_images, top), (args.hor_images, hor)):
            sources.append(open_view_images(path, frames,
                                            [f for f in sorted(frames) if len(frames[f])]))
        size = tuple(sources[1].size)
        check_boxes_in_image(top, tuple(sources[0].size), args.top,
                             f"the images {args.top_images}", ids=False)
    except BaseException:
        for source in sources:
            source.close()
        raise
    cross_cost = model.appearance_cost if embed is not None else None  # a site's adaptation
    cross_embed = None
    if embed is not None and model.cue_vector != "descriptors":  # one network run for both
        vectors = ("descriptors", model.cue_vector)

        def cross_embed(image, boxes):
            return tuple(model.bundle.embed_vectors(model.crops(image, boxes), vectors))
    return TrackImages(sources[0], sources[1], embed, cross_cost, cross_embed), sources, size


def _open_cameras(args: argparse.Namespace, model, top, hor, offset: int, resolved, sources):
    """``(cameras, refinement)``: ``--cameras`` opened and checked
    (:func:`~xvmatch.inference.matching.learned_pipeline.open_matcher_cameras`), or None: a file for
    every horizontal frame ``f`` with boxes, and boxes in top frame ``f + offset`` (the files are
    numbered by the horizontal frames, as ``associate`` reads them), each camera the size of its
    view's images (``sources``: the open top and horizontal images, or none; else the horizontal
    size ``resolved``); a fixed top camera refined on the boxes unless ``--refine-top-camera off``
    (:mod:`xvmatch.inference.matching.camera_refinement`; the refinement is None when off)."""
    if args.cameras is None:
        return None, None
    from xvmatch.inference.matching.learned_pipeline import open_matcher_cameras

    wanted = {"hor": (tuple(resolved[0]), resolved[1])}
    if sources:
        wanted["top"] = (tuple(sources[0].size), f"the images {args.top_images}")
        wanted["hor"] = (tuple(sources[1].size), f"the images {args.hor_images}")
    frames = [f for f in hor if len(hor[f]) and len(top.get(f + offset, ()))]
    cameras = open_matcher_cameras(args.cameras, [(model, args.model)], frames, wanted)
    if args.refine_top_camera == "off":
        return cameras, None
    from xvmatch.inference.matching.camera_refinement import refine_run_cameras

    cameras, refinement = refine_run_cameras(cameras, top, hor, frames, offset)
    note_camera_refinement(refinement, args.quiet)
    return cameras, refinement


def _checked_cameras(args: argparse.Namespace, model, top, hor, resolved, cameras, refinement):
    """``(cameras, refinement)`` after ``--camera-check`` (:mod:`xvmatch.inference.matching.
    camera_check`; ``top`` and ``hor`` aligned): as they are when the check is off or passes,
    ``(None, None)`` when it fails (the cross-view weights then come from the boxes alone)."""
    if cameras is None or args.camera_check == "off":
        return cameras, refinement
    from xvmatch.inference.matching.camera_check import check_run_cameras

    check = check_run_cameras(top, hor, sorted(hor), model, tuple(resolved[0]), cameras,
                              float(model.gamma),
                              None if refinement is None else refinement.fit_loss,
                              workers=args.workers,
                              moving=refinement is not None and refinement.moving)
    note_camera_check(check, args.quiet)
    return (cameras, refinement) if check.trusted else (None, None)


def _fitted_cameras_config(args: argparse.Namespace, config, refinement, images):
    """``config`` with Eq. 17's ``w1`` at :data:`~xvmatch.inference.tracks.track_costs.
    FITTED_CAMERAS_W1` when the images would enter the cross-view weights, ``--w1`` is not
    given and the refined cameras fit the video
    (:attr:`~xvmatch.inference.matching.camera_refinement.CameraRefinement.fits`); says so unless
    quiet."""
    if args.w1 is not None or images is None or refinement is None or not refinement.fits:
        return config
    from xvmatch.inference.tracks.track_costs import FITTED_CAMERAS_W1

    if not args.quiet:
        print(f"track: the top camera fits the head rays, so the images serve over time only "
              f"(--w1 {FITTED_CAMERAS_W1:g}; give --w1 to choose)", file=sys.stderr)
    return replace(config, weights=replace(config.weights, w1=FITTED_CAMERAS_W1))


def _aligned(top, hor, images, cameras, offset: int):
    """The views (and their images and cameras) re-timed so that top frame ``t + offset`` and
    horizontal frame ``t`` are tracked as one moment (:func:`xvmatch.formats.mot_boxes.
    align_frames`); the rows, and so the written tracks, keep their own frame numbers. The
    cameras are numbered by the horizontal frames."""
    if not offset:
        return top, hor, images, cameras
    from xvmatch.formats.mot_boxes import align_frames
    from xvmatch.inference.matching.learned_pipeline import retimed

    (top, hor), (s_top, s_hor) = align_frames([top, hor], [offset])
    if images is not None:  # aligned frame f shows the view's frame f - shift
        images = replace(images, top=retimed(images.top, -s_top), hor=retimed(images.hor, -s_hor))
    if cameras is not None:
        cameras = retimed(cameras, -s_hor)
    return top, hor, images, cameras


def add_track_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch track`` on ``subparsers`` and return its parser."""
    help_text = (
        "Track the people of a top-view and a horizontal-view box file with one id per person "
        "across both views (CVMHAT: tracklets in 10-frame clips, a four-cluster mixed-integer "
        "program per pair of clips, stitching). The input ids are ignored; writes OUT/top.txt "
        "and OUT/hor.txt, the input rows with the id replaced by the track id."
    )
    p = add_command_parser(subparsers, "track", help_text, EXAMPLE)
    p.add_argument("--top", required=True, help="top-view detections (MOT format, ids ignored)")
    p.add_argument("--hor", required=True,
                   help="horizontal-view detections (MOT format, ids ignored)")
    p.add_argument("--out", required=True, metavar="DIR",
                   help="output folder (created); top.txt, hor.txt and offset.json (the offset "
                   "applied, which evaluate --tracks reads) are written atomically")
    p.add_argument("--solver", choices=("mip", "spectral"), default="mip",
                   help="mip: Eqs. 1-4 with HiGHS (default); spectral: the spectral-clustering "
                   "baseline on the same weights")
    p.add_argument("--camera-id", type=box_id, default=None,
                   help="id (in the top file's id column) of the horizontal camera's wearer: O "
                   "given (|id| <= 2**53); without it O is searched among all top-view boxes")
    p.add_argument("--clip-length", type=CLIP_LENGTH_TYPE, default=10,
                   help="frames per clip, 1..1000 (default 10)")
    p.add_argument("--min-iou", type=MIN_IOU_TYPE, default=0.5,
                   help="IoU that links a box to the previous frame's, in (0, 1] (default 0.5)")
    p.add_argument("--max-gap", type=MAX_GAP_TYPE, default=3,
                   help="frames a tracklet may miss inside a clip and still continue, 0..1000 "
                   "(default 3)")
    p.add_argument("--c0", type=C0_TYPE, default=None,
                   help="dummy-node weight of Eq. 1, in [0, 1] (default 0.1, 0.02 with the "
                   "learned weights; the paper's 0.2)")
    p.add_argument("--sigma", type=SIGMA_TYPE, default=None,
                   help="motion deviation scale of Eq. 15 per box height (resolution-free), in "
                   "(0, 1000] (default 1)")
    p.add_argument("--time-limit", type=TIME_LIMIT_TYPE, default=30.0,
                   help="wall-time guard per window for the MIP, in [0.01, 600] (default 30; "
                   "its budget of work, the same on every CPU, is 64 added loops and 1000 "
                   "HiGHS nodes per program); past either the best loop-free answer found is "
                   "used and counted in a warning")
    p.add_argument("--seed", type=seed_value, default=0,
                   help="seed of the spectral baseline's k-means, 0..2**32-1 (default 0)")
    p.add_argument("--image-size", type=HOR_IMAGE_SIZE, default=None, metavar="WxH",
                   help=IMAGE_SIZE_HELP + "; with --hor-images it must agree with them")
    add_offset_options(p, "Tracks are written in each video's own frame numbers; score them "
                       "with 'xvmatch evaluate --tracks --offset N'", default="auto")
    p.add_argument("--workers", type=worker_count, default=1, metavar="K",
                   help="processes for the frame association and --offset auto's estimate, "
                   "1..64 (default 1; the same output for any K)")
    p.add_argument("--quiet", action="store_true", help="no progress bar or summary")
    _add_appearance_options(p)
    add_spatial_options(p)
    p.set_defaults(func=_cmd_track)
    return p


def _add_appearance_options(p: argparse.ArgumentParser) -> None:
    """``track``'s options of the appearance cue and the learned matcher (its images,
    ``--model``, ``--weights``, ``--cameras``, the weights of Eqs. 17 and 18)."""
    g = p.add_argument_group("appearance (with the images of both views)")
    add_image_options(g)
    g.add_argument("--model", default=None, metavar="BUNDLE",
                   help="a matcher bundle (xvmatch export), or 'default' for the shipped one: "
                   "its box-only association gives the cross-view weights (--weights learned); "
                   "with the images, its appearance network adds the cross-view term of Eq. 17 "
                   "and the over-time one of Eq. 18")
    g.add_argument("--weights", choices=("learned", "handcrafted"), default=None,
                   help="cross-view weights (Eq. 13): learned, from the --model's costs on the "
                   "boxes (default with --model), or handcrafted, from the spatial-distribution "
                   "search's pairs (default without)")
    g.add_argument("--cameras", default=None, metavar="CAMERAS",
                   help="calibrated cameras 'top' and 'ego' (a camera file, or a folder of "
                   "per-frame files numbered by the horizontal frames) for the --model's "
                   "cross-view weights: its camera cues and the rectified geometry, as "
                   "'associate --cameras' (an oblique overview camera wants them)")
    add_refine_top_camera(g)
    add_write_cameras(g)
    add_camera_check(g)
    g.add_argument("--w1", type=SHARE_TYPE, default=None,
                   help="share of the spatial term in a cross-view weight (Eq. 17), in [0, 1] "
                   "(default 0.3, or 1 when --cameras' top camera fits the video's head rays "
                   "after --refine-top-camera: the images then serve only over time)")
    g.add_argument("--w2", type=SHARE_TYPE, default=None,
                   help="share of the appearance term in an over-time weight (Eq. 18), in "
                   "[0, 1] (default 0.6)")
    g.add_argument("--min-colour", type=SHARE_TYPE, default=0.3,
                   help="colour-histogram similarity a horizontal box needs to extend a "
                   "tracklet, in [0, 1] (default 0.3)")
    g.add_argument("--time-appearance", choices=("network", "colour"), default="network",
                   help="over-time appearance term of Eq. 18: the --model's network (default; "
                   "colour without --model) or colour histograms (Eq. 14, the paper's)")
    g.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with --model's network and learned weights: judge the cross-view "
                   "appearance cue on the tracklet pairs the box-only matcher is sure of, and "
                   "leave it out of the cross-view weights when it is shown too weak to help "
                   "(default on; off: always use it; nothing to judge with --w1 1)")


def _track_config(args: argparse.Namespace, weights: str):
    """The tracker's :class:`~xvmatch.inference.tracks.tracking.TrackConfig` of the options (the
    dummy weight ``c0`` of the learned weights unless given)."""
    from xvmatch.inference.tracks.track_costs import LEARNED_DUMMY_WEIGHT, TrackWeights
    from xvmatch.inference.tracks.tracking import TrackConfig

    given = {k: v for k, v in (("c0", args.c0), ("w1", args.w1), ("w2", args.w2),
                               ("sigma", args.sigma)) if v is not None}
    if weights == "learned":
        given.setdefault("c0", LEARNED_DUMMY_WEIGHT)
    return TrackConfig(
        clip_length=args.clip_length,
        min_iou=args.min_iou,
        max_gap=args.max_gap,
        weights=TrackWeights(**given),
        solver=args.solver,
        time_limit=args.time_limit,
        seed=args.seed,
        min_colour=args.min_colour,
        time_appearance=args.time_appearance,
    )


def _read_checked(args: argparse.Namespace):
    """``(top, hor, camera_rows, out)``: the box files read, the wearer's rows (``--camera-id``,
    or None) and the output folder, after the checks of every input and output path."""
    from xvmatch.formats.detection_rows import read_detection_rows

    top = read_detection_rows(args.top)
    hor = read_detection_rows(args.hor)
    camera_rows = None
    if args.camera_id is not None:
        camera_rows = top.rows_with_id(args.camera_id)
        if camera_rows.size == 0:
            raise ValueError(f"{args.top}: no box has the --camera-id {args.camera_id}")
    out = Path(args.out)
    check_outputs(
        [Output("--out", out, folder=True, files=("top.txt", "hor.txt", OFFSET_FILE)),
         *check_write_cameras(model_args(args))],
        [Input("--top", args.top), Input("--hor", args.hor),
         *image_inputs(args), Input("--cameras", args.cameras),
         Input("--model", None if args.model == "default" else args.model)],
    )
    check_own_folder(out, TRACK_COMMAND)
    return top, hor, camera_rows, out


def _horizontal_size(args: argparse.Namespace, hor, size):
    """The horizontal image size and where it comes from: ``--image-size``, the images' ``size``
    (or None) or the ``--cameras``' ego camera, which must agree; said when assumed."""
    from xvmatch.commands._image_size import note_if_assumed
    from xvmatch.formats.box_image_size import resolve_size

    given = [] if args.image_size is None else [(args.image_size, "--image-size")]
    if size is not None:
        given.append((size, f"the horizontal images {args.hor_images}"))
    elif args.cameras is not None:  # with images, each camera is checked against them
        from xvmatch.commands._model import ego_camera_size

        given.append(ego_camera_size(args.cameras))
    resolved = resolve_size(hor.frames, args.hor, given, ids=False)
    note_if_assumed(resolved, hor.frames, args.hor, args.quiet)
    return resolved


def _run_tracks(args: argparse.Namespace, top, hor, camera_rows, params, config, weights: str,
                model, max_offset):
    """``(result, offset, refined, checked)``: the tracks of both views
    (:func:`~xvmatch.inference.tracks.tracking.track_pair`) on the views re-timed by the offset
    applied, the cameras as refined (for ``--write-cameras``) and the appearance check's
    verdict (a list of at most one)."""
    from xvmatch.inference.tracks.tracking import learned_frame_evidence, track_pair

    images, sources, size = _open_images(args, top.frames, hor.frames, model, weights)
    try:
        resolved = _horizontal_size(args, hor, size)
        width = resolved[0][0]
        positions = None if camera_rows is None else top.positions_of_id(args.camera_id)
        marked, wearer = wearer_marked(top.frames, positions)
        offset = resolve_offset(args, marked, hor.frames, width, params, max_offset, wearer)
        cameras, refinement = _open_cameras(args, model, top.frames, hor.frames, offset,
                                            resolved, sources)
        refined = (cameras, refinement)  # --write-cameras: also when the check drops them
        top_frames, hor_frames, images, cameras = _aligned(top.frames, hor.frames, images,
                                                           cameras, offset)
        cameras, refinement = _checked_cameras(args, model, top_frames, hor_frames, resolved,
                                               cameras, refinement)
        config = _fitted_cameras_config(args, config, refinement, images)
        progress = _step_progress(not args.quiet)
        learned = None
        if weights == "learned":
            learned = learned_frame_evidence(top_frames, hor_frames, resolved[0], model,
                                             camera_rows, args.workers, progress,
                                             cameras=cameras)
        checked = []
        result = track_pair(top_frames, hor_frames, float(width), params, config,
                            camera_rows, args.workers, progress, images=images,
                            learned=learned, appearance_check=args.appearance_check == "on",
                            checked=checked)
    finally:
        for source in sources:
            source.close()
    return result, offset, refined, checked


def _cmd_track(args: argparse.Namespace) -> int:
    from xvmatch.formats.detection_rows import write_track_rows
    from xvmatch.formats.offset_record import write_offset_record

    start = time.perf_counter()
    params = spatial_params(args)
    weights = _cross_view_weights(args)
    config = _track_config(args, weights)
    top, hor, camera_rows, out = _read_checked(args)
    max_offset = max_offset_of(args, top.frames, hor.frames) if args.offset == "auto" else None
    model = None
    if args.model is not None:
        from xvmatch.commands._model import open_models

        model = open_models([args.model])[0]
    result, offset, refined, checked = _run_tracks(args, top, hor, camera_rows, params, config,
                                                   weights, model, max_offset)
    claim_folder(out, TRACK_COMMAND)
    n_top = write_track_rows(out / "top.txt", top, result.top_rows)
    n_hor = write_track_rows(out / "hor.txt", hor, result.hor_rows)
    write_offset_record(out / OFFSET_FILE, offset)
    write_cameras(model_args(args), *refined)
    if result.n_fallback:
        print(f"xvmatch: warning: {result.n_fallback} of {result.n_windows} windows spent the "
              f"MIP's budget of work or time limit ({args.time_limit:g} s) or failed, and used "
              "the best loop-free answer found instead of the optimum", file=sys.stderr)
    if checked and checked[0].to_tell(args.quiet):
        print(checked[0].message(), file=sys.stderr)
    if not args.quiet:
        ids = set(result.top_rows.values()) | set(result.hor_rows.values())
        print(f"wrote {n_top} top and {n_hor} horizontal boxes, {len(ids)} tracks, to {out}/ "
              f"({time.perf_counter() - start:.1f} s)", file=sys.stderr)
    return 0


TRACKEVAL_MISSING = ("xvmatch: note: per-view IDF1, MOTA, MOTP and HOTA need the TrackEval "
                     "package: pip install --no-deps trackeval")
"""The line ``evaluate --tracks`` prints on stderr when TrackEval is not installed."""


def _trackeval_installed() -> bool:
    """Whether TrackEval's metrics import (its optional dataset readers' messages hidden)."""
    import contextlib
    import io

    try:
        with contextlib.redirect_stdout(io.StringIO()):
            import trackeval.metrics  # noqa: F401
    except ImportError:
        return False
    return True


def tracked_offset(folder: Path) -> int:
    """The offset ``track`` applied to the tracks in ``folder`` (its :data:`OFFSET_FILE`,
    checked as ``--offset`` is: :func:`~xvmatch.formats.offset_record.read_offset_record`; 0
    when absent, as in folders written before it existed)."""
    from xvmatch.commands._types import MAX_FRAME_OFFSET
    from xvmatch.formats.offset_record import read_offset_record

    path = folder / OFFSET_FILE
    if not path.exists():
        return 0
    return read_offset_record(path, MAX_FRAME_OFFSET)


def evaluate_tracks_command(args: argparse.Namespace) -> int:
    """``xvmatch evaluate --tracks DIR``: print the tracking scores of DIR/top.txt, DIR/hor.txt.

    Without TrackEval the cross-view scores are printed alone (JSON: ``top`` and ``hor`` are
    null), then one line on stderr naming the package the per-view metrics need; exit 0, as the
    cross-view scores asked for are given (issue 29, item 4)."""
    from dataclasses import asdict

    from xvmatch.formats.mot_boxes import read_mot_boxes
    from xvmatch.metrics.cross_view_metrics import format_table, summarize
    from xvmatch.metrics.track_metrics import (
        evaluate_tracks,
        format_track_table,
        track_pair_counts,
        track_scores_to_dict,
    )

    folder = Path(args.tracks)
    if not folder.is_dir():
        raise ValueError(f"--tracks {args.tracks}: not a folder (expected the --out of "
                         "xvmatch track, with top.txt and hor.txt)")
    tracks_top = read_mot_boxes(folder / "top.txt", allow_empty=True)
    tracks_hor = read_mot_boxes(folder / "hor.txt", allow_empty=True)
    gt_top = read_boxes(args.top, args.duplicates)
    gt_hor = read_boxes(args.hor, args.duplicates)
    offset = args.offset if args.offset is not None else tracked_offset(folder)
    if offset:  # tracked with --offset N: both files in their own videos' timing
        from xvmatch.formats.mot_boxes import align_views

        tracks_top, tracks_hor = align_views(tracks_top, tracks_hor, offset)
        gt_top, gt_hor = align_views(gt_top, gt_hor, offset)
    name = args.name or args.tracks
    if not _trackeval_installed():
        cross = summarize(track_pair_counts(tracks_top, tracks_hor, gt_top, gt_hor))
        if args.json:
            print(json.dumps({"cross_view": asdict(cross), "top": None, "hor": None}, indent=2))
        else:
            print(format_table([(name, cross)]))
        print(TRACKEVAL_MISSING, file=sys.stderr)
        return 0
    scores = evaluate_tracks(tracks_top, tracks_hor, gt_top, gt_hor)
    if args.json:
        print(json.dumps(track_scores_to_dict(scores), indent=2))
    else:
        print(format_track_table([(name, scores)]))
    return 0
