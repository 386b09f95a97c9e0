"""The learned matcher on the command line: ``xvmatch associate --model BUNDLE|default``.

``add_model_arguments`` adds ``--model``, ``--gamma``, the images, the cameras and the other
learned-matcher options to ``associate``'s parser, ``add_draw_arguments`` its ``--draw``
pictures; :func:`model_args` reads these options from the parsed arguments into one
:class:`ModelArgs` record (the one place they are read), which the others take:
``associate_with_model`` runs the association with the models
(:func:`xvmatch.inference.matching.learned_pipeline.run_learned_association`'s steps, with the
options :func:`learned_run_options` builds from the record), ``open_models`` opens them (also for
``track`` and ``associate-multi``), ``horizontal_size`` works out the horizontal image size.
Imports are lazy: only these code paths load onnxruntime (torch only to export a .pt file
once). Bad input raises ``ValueError`` with a one-line message, which the main entry
point prints as ``xvmatch: error: ...``.
"""

from __future__ import annotations

import argparse
import os
import sys
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, fields

from xvmatch.commands._options import UsageError, add_image_options, check_images_together
from xvmatch.commands._types import float_in, int_in, thread_count
from xvmatch.core.output_paths import Output, check_own_folder

__all__ = [
    "CAMERAS_COMMAND",
    "DRAW_COMMAND",
    "LEARNED_ONLY",
    "ModelArgs",
    "add_camera_check",
    "add_draw_arguments",
    "add_model_arguments",
    "add_refine_top_camera",
    "add_write_cameras",
    "associate_with_model",
    "check_precision",
    "check_write_cameras",
    "draw_pictures",
    "ego_camera_size",
    "horizontal_size",
    "learned_run_options",
    "model_args",
    "note_camera_check",
    "note_camera_refinement",
    "open_models",
    "write_cameras",
]

_gamma = float_in(0, 1, "the matcher's costs lie in [0, 1]", low_open=True)
"""``--gamma``: a non-association cost in (0, 1]."""


@dataclass(frozen=True)
class ModelArgs:
    """The learned matcher's options of a command line (``associate``, ``adapt``, ``track``,
    ``associate-multi``), read once by :func:`model_args`. An option a command does not take
    keeps the default here, which is the default of the option where a command takes it."""

    model: str | list[str] | None = None
    """``--model``: one bundle (``track``, ``adapt``) or a list (``associate``), or None."""
    mode: str = "frame"
    top: str = "the top-view boxes"
    """``--top``, or how messages name the top boxes."""
    hor: str | list[str] | None = None
    """``--hor``: a box file, a list of them (``associate-multi``), or None."""
    top_images: str | None = None
    hor_images: str | list[str] | None = None
    cameras: str | list[str] | None = None
    write_cameras: str | list[str] | None = None
    refine_top_camera: str = "auto"
    camera_check: str = "on"
    appearance_check: str = "on"
    image_size: tuple[int, int] | None = None
    camera_id: int | None = None
    gamma: float | None = None
    mirror: bool = False
    workers: int = 1
    threads: int = 1
    precision: str | None = None
    costs: str | None = None
    draw: str | None = None
    draw_every: int = 1
    no_labels: bool = False
    quiet: bool = False


def model_args(args: argparse.Namespace) -> ModelArgs:
    """The :class:`ModelArgs` of parsed arguments: the options the namespace has, the record's
    defaults for those it lacks (the one place the learned matcher's options are read)."""
    given = vars(args)
    return ModelArgs(**{f.name: given[f.name] for f in fields(ModelArgs) if f.name in given})


def add_model_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the learned matcher's options to a parser (``associate``): ``--model``, ``--gamma``,
    ``--mirror``, the image and camera inputs, ``--costs``, ``--threads``, ``--precision`` and
    ``--appearance-check``."""
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
    add_refine_top_camera(g)
    add_write_cameras(g)
    add_camera_check(g)
    g.add_argument("--costs", default=None, metavar="JSON",
                   help="also write each frame's ids and cost matrix (written atomically)")
    g.add_argument("--threads", type=thread_count, default=1, metavar="K",
                   help="onnxruntime threads, 1..64 (default 1)")
    g.add_argument("--precision", choices=("fp32", "int8"), default=None,
                   help="appearance network to run: int8 (needs a bundle exported with --int8; "
                   "near-tie frames are scored again with fp32) or fp32 (default: int8 when "
                   "the bundle has it, kept fp32's matches at export and the CPU has 8-bit "
                   "dot-product instructions, VNNI; else fp32)")
    g.add_argument("--appearance-check", choices=("on", "off"), default="on",
                   help="with images of a video: judge the appearance cue on the pairs the "
                   "box-only matcher is sure of over consecutive frames, and match from the "
                   "boxes alone when the images are shown too weak to help; with no run of "
                   "consecutive frames (single image pairs), judge each frame by the bundle's "
                   "frame check (default on; off: always use the images)")


def add_refine_top_camera(group) -> None:
    """Add ``--refine-top-camera`` (``associate``, ``track``, ``adapt``)."""
    group.add_argument(
        "--refine-top-camera", choices=("auto", "off"), default="auto",
        help="with --cameras: turn the top camera to fit the video's head rays when the fit "
        "is clear (10 or more frames with boxes in both views; a degree of calibration error "
        "costs the matcher more than the cameras give; a top camera that moves, per-frame "
        "files from a drone's telemetry, has its constant error turned away, in its own frame "
        "or the world), and say so (default auto; off: use it as given)")


CAMERAS_COMMAND = "xvmatch --write-cameras"
"""The marker of a camera folder ``--write-cameras`` made (it replaces only its own)."""


def add_write_cameras(group, several: bool = False) -> None:
    """Add ``--write-cameras`` (``associate``, ``track``; ``several``: one per ``--cameras``,
    ``associate-multi``)."""
    group.add_argument(
        "--write-cameras", default=None, metavar="PATH", nargs="+" if several else None,
        help=("with --cameras: also write them as refined (the top camera turned to fit the "
              "head rays, else as given), in --cameras' form: a camera file, or a folder of "
              "per-frame files under the same names (a new or empty folder, or one an earlier "
              "--write-cameras made); give it as --cameras with --refine-top-camera off next "
              "time") + ("; one per --cameras, in their order" if several else ""))


def _listed(value) -> list:
    """An option's value as a list: ``[]`` for None, one item for a single value."""
    return [] if value is None else list(value) if isinstance(value, list) else [value]


def check_write_cameras(opts: ModelArgs) -> list[Output]:
    """``--write-cameras``' outputs for :func:`~xvmatch.core.output_paths.check_outputs`,
    after refusing them without ``--cameras``, not one per ``--cameras``, or with
    ``--refine-top-camera off``, and a folder that is neither new, empty nor its own."""
    paths = _listed(opts.write_cameras)
    given = _listed(opts.cameras)
    if not paths:
        return []
    if not given:
        raise UsageError("--write-cameras writes the cameras of --cameras as refined: give "
                         "--cameras")
    if len(paths) != len(given):
        raise UsageError(f"--write-cameras: one path per --cameras ({len(given)}), got "
                         f"{len(paths)}")
    if opts.refine_top_camera == "off":
        raise UsageError("--write-cameras writes the cameras as refined: drop "
                         "--refine-top-camera off (else they are --cameras as given)")
    outputs = []
    for path, cameras in zip(paths, given, strict=True):
        folder = os.path.isdir(cameras)
        if folder:
            check_own_folder(path, CAMERAS_COMMAND, "--write-cameras")
        outputs.append(Output("--write-cameras", path, folder=folder))
    return outputs


def write_cameras(opts: ModelArgs, cameras, refinement) -> None:
    """Write ``--write-cameras`` (when given): ``cameras``, the run's
    :class:`~xvmatch.formats.camera_frames.CameraFrames` as refined (a list, one per path,
    for ``associate-multi``), in ``--cameras``' form (a folder it made before loses the camera
    files it wrote of frames this run has not: they would be read with the new ones; a file the
    user put there is kept); say what they hold unless quiet."""
    from xvmatch.core.folder_marker import record_own_files, remove_own_files
    from xvmatch.core.output_paths import claim_folder
    from xvmatch.formats.camera_frames import save_camera_frames

    paths = _listed(opts.write_cameras)
    if not paths:
        return
    counts = []
    for path, cams in zip(paths, _listed(cameras), strict=True):
        if cams.static is not None:
            save_camera_frames(cams, path)
            continue
        folder = claim_folder(path, CAMERAS_COMMAND, "--write-cameras")
        written = [p.name for p in save_camera_frames(cams, folder)]
        # an earlier run's other frames would be read with these: remove them, and only them
        remove_own_files(folder, CAMERAS_COMMAND, keep=written)
        record_own_files(folder, CAMERAS_COMMAND, written)
        counts.append(f"{path}: {len(written)} camera files, one per frame of its --cameras")
    if not opts.quiet:
        turned = refinement is not None and refinement.turned
        what = (f"the {'moving ' if refinement.moving else ''}top camera turned "
                f"{refinement.fit.angle_deg:.2f} degrees" if turned
                else "the top camera as given")
        print(f"cameras: wrote {', '.join(map(str, paths))} ({what})"
              + "".join(f"; {c}" for c in counts), file=sys.stderr)


def add_camera_check(group) -> None:
    """Add ``--camera-check`` (``associate``, ``track``, ``adapt``, ``associate-multi``)."""
    group.add_argument(
        "--camera-check", choices=("on", "off"), default="on",
        help="with --cameras: when even the refined top camera fits the video's head rays "
        "poorly, or the top camera moves (only its constant error refined), judge the cameras "
        "on the pairs the "
        "box-only matcher is sure of over consecutive frames, and match without them when "
        "they re-pair too many of those "
        "(cameras calibrated far off); only on videos of 6 s or more where those pairs are "
        "steady (default on; off: always use them)")


def note_camera_check(check, quiet: bool, prefix: str = "") -> None:
    """Print the camera check's line: when it had a run of frames to judge on, and with
    ``quiet`` only when the cameras were left out."""
    if check is not None and check.to_tell(quiet):
        print(f"{prefix}{check.message()}", file=sys.stderr)


def note_camera_refinement(refinement, quiet: bool) -> None:
    """Print what became of the top camera: always when it was turned, else unless quiet."""
    if refinement is not None and (refinement.turned or not quiet):
        print(refinement.message, file=sys.stderr)


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
an earlier ``--draw`` made (:func:`xvmatch.core.output_paths.claim_folder`)."""

LEARNED_ONLY = ("gamma", "mirror", "top_images", "hor_images", "cameras", "costs",
                "precision", "write_cameras")
"""Options of ``associate`` that need ``--model``."""


def _torch_file_bundle(path: str, threads: int, precision: str | None, recheck: bool):
    """The bundle of a torch matcher file, exported once into the cache."""
    import hashlib
    from pathlib import Path

    from xvmatch.datasets.feature_cache import default_cache_dir
    from xvmatch.inference.matching.learned_association import load_matcher_bundle

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
    return load_matcher_bundle(folder, threads, precision, recheck)


def open_models(names: Iterable[str], threads: int = 1, precision: str | None = None,
                recheck: bool = False) -> list:
    """:class:`~xvmatch.inference.matching.learned_association.LearnedMatcher` of each ``--model``
    (``recheck``: for ``associate``, which re-checks INT8's near-tie frames in FP32)."""
    import os

    from xvmatch.inference.matching.learned_association import load_matcher_bundle

    models = []
    for name in names:
        if name != "default" and os.path.isfile(name):
            models.append(_torch_file_bundle(name, threads, precision, recheck))
        else:
            models.append(load_matcher_bundle(name, threads, precision, recheck))
    return models


def check_precision(precision: str | None, images: bool, models: Iterable = (),
                    names: Iterable[str] = ()) -> None:
    """Refuse ``--precision`` where no appearance network runs: without images (the run
    matches boxes alone), or when none of ``models`` (opened from ``names``) has one (a
    box-only bundle). Call it once before opening the models (``models`` empty) and once
    after.

    Raises:
        UsageError: one line naming ``--precision`` and what to do.
    """
    if precision is None:
        return
    if not images:
        raise UsageError(f"--precision {precision} chooses the appearance network, which runs "
                         "only on images: give --top-images and --hor-images, or leave "
                         "--precision out")
    models, names = list(models), list(names)
    if models and all(m.bundle.manifest.appearance is None for m in models):
        which = ", ".join(names) or "the model"
        raise UsageError(f"--precision {precision}: --model {which} has no appearance network "
                         "(a box-only matcher) for it to choose; leave --precision out")


def horizontal_size(opts: ModelArgs, hor: Mapping) -> tuple[tuple[int, int], str]:
    """The horizontal image size and where it comes from (:mod:`xvmatch.commands._image_size`):
    ``--image-size``, the ``--hor-images`` and the ``--cameras`` file's ego camera must agree
    when given; with none, CVMHAT's 2688x1512 when the boxes are consistent with it (a note on
    stderr), else an error asking for ``--image-size``. Every horizontal box must lie in it."""
    from xvmatch.formats.box_image_size import resolve_size

    check_images_together(opts.top_images, opts.hor_images)
    given = []
    if opts.image_size is not None:
        given.append((tuple(opts.image_size), "--image-size"))
    if opts.model is not None and opts.hor_images:
        from xvmatch.formats.frame_sources import open_frames

        with open_frames(opts.hor_images, box_frames=sorted(hor)) as source:
            given.append((tuple(source.size), f"the horizontal images {opts.hor_images}"))
    elif opts.model is not None and opts.cameras:
        # with images, each camera file is checked against them
        # (inference/matching/learned_pipeline.py)
        given.append(ego_camera_size(opts.cameras))
    return resolve_size(hor, _hor_name(opts, "the horizontal boxes"), given)


def _hor_name(opts: ModelArgs, unnamed: str) -> str | list[str]:
    """``--hor``, or ``unnamed`` when the command has none."""
    return unnamed if opts.hor is None else opts.hor


def ego_camera_size(cameras: str) -> tuple[tuple[int, int], str]:
    """The horizontal image size that ``--cameras``' ego cameras give, and where it comes
    from (for :func:`~xvmatch.formats.box_image_size.resolve_size`); one size for all of
    them, or an error asking for ``--image-size``."""
    from xvmatch.formats.camera_frames import open_cameras

    sizes = {tuple(c.hor.image_size) for _, c in open_cameras(cameras).all()}
    if len(sizes) != 1:
        raise ValueError(f"{cameras}: the ego cameras have several image sizes "
                         f"({', '.join(f'{w}x{h}' for w, h in sorted(sizes))}); pass "
                         "--image-size")
    return sizes.pop(), f"the camera files {cameras}"


def learned_run_options(
    opts: ModelArgs,
    models: list,
    names: list[str],
    hor_size: tuple[tuple[int, int], str],
    top_offset: int = 0,
):
    """The :class:`~xvmatch.inference.matching.learned_pipeline.LearnedRunOptions` of
    ``associate``'s options, for ``models`` already opened (:func:`open_models`) from ``names``
    and the horizontal size :func:`horizontal_size` resolved. Costs are kept when ``--costs``
    or ``--draw`` asks for them (the pictures are of the frames that have costs)."""
    from xvmatch.inference.matching.learned_pipeline import LearnedRunOptions

    (width, height), said = hor_size
    return LearnedRunOptions(
        models=tuple(models),
        hor_size=(width, height),
        hor_size_source=said,
        names=tuple(names),
        top_images=opts.top_images,
        hor_images=opts.hor_images,
        cameras=opts.cameras,
        top_boxes=opts.top,
        hor_boxes=opts.hor if isinstance(opts.hor, str) else "the horizontal-view boxes",
        camera_id=opts.camera_id,
        gamma=opts.gamma,
        mirror=bool(opts.mirror),
        workers=opts.workers,
        top_offset=top_offset,
        keep_costs=opts.costs is not None or opts.draw is not None,
        appearance_check=opts.appearance_check == "on",
        refine_top_camera=opts.refine_top_camera == "auto",
        camera_check=opts.camera_check == "on",
    )


def associate_with_model(
    opts: ModelArgs,
    top: Mapping,
    hor: Mapping,
    frames: Iterable[int],
    progress: Callable[[Iterable[int]], Iterable[int]] | None,
    top_offset: int = 0,
    hor_size: tuple[tuple[int, int], str] | None = None,
) -> dict[int, list[tuple[int, int]]]:
    """Associate with ``opts.model`` (bundles, ``default`` or torch files); ``{frame: [(top,
    hor)]}``. The command line's side of :mod:`xvmatch.inference.matching.learned_pipeline`: checks
    the options, opens the models, builds the run's options (:func:`learned_run_options`),
    prints the note of an assumed image size, runs it, and writes ``--costs`` and ``--draw``.
    ``top`` is already re-timed by ``top_offset`` (``--offset``); the top images are re-timed
    the same way. ``hor_size``: :func:`horizontal_size` when the caller has it already (else it
    is worked out here).

    Reads ``opts.model``, ``opts.mode`` (must be ``frame``), ``opts.threads``,
    ``opts.precision``, ``opts.draw``, ``opts.draw_every``, ``opts.no_labels``, ``opts.costs``,
    ``opts.quiet``, ``opts.hor`` and what :func:`learned_run_options` reads. Every input is
    checked before any work starts; outputs are written only at the end.
    """
    from xvmatch.commands._image_size import note_if_assumed
    from xvmatch.inference.matching.learned_pipeline import open_learned_inputs

    if opts.mode != "frame":
        raise ValueError("--model solves each frame on its own: use --mode frame")
    check_images_together(opts.top_images, opts.hor_images)
    draw = opts.draw
    if draw is not None:
        check_own_folder(draw, DRAW_COMMAND, "--draw")
    names = [opts.model] if isinstance(opts.model, str) else list(opts.model)
    precision = opts.precision
    images = opts.top_images is not None
    check_precision(precision, images)
    models = open_models(names, opts.threads, precision, recheck=True)
    check_precision(precision, images, models, names)
    hor_size = hor_size or horizontal_size(opts, hor)
    options = learned_run_options(opts, models, names, hor_size, top_offset)
    hor_path = _hor_name(opts, "the horizontal boxes")
    quiet = bool(opts.quiet)
    with open_learned_inputs(top, hor, frames, options) as inputs:
        note_if_assumed(hor_size, hor, hor_path, quiet)
        note_camera_refinement(inputs.refinement, quiet)
        note_camera_check(inputs.camera_checked, quiet)
        run = inputs.associate(progress)
        if run.rechecked and not opts.quiet:
            both = sum(1 for f in frames if len(top.get(f, ())) and len(hor.get(f, ())))
            print(f"INT8 appearance network: {len(run.rechecked)} of {both} frames were near "
                  "ties, scored again with FP32", file=sys.stderr)
        if run.checked is not None and run.checked.to_tell(opts.quiet):
            print(run.checked.message(), file=sys.stderr)
        if draw is not None:
            draw_pictures(draw, opts.draw_every, top, hor, run.pairs,
                          sorted(run.costs), inputs.images or None, run.hor_size,
                          not opts.no_labels)
    if opts.costs is not None:
        _write_costs(opts.costs, top, hor, run.costs, run.gamma, run.checked,
                     run.camera_checked, inputs.refinement)
    write_cameras(opts, inputs.refined_cameras, inputs.refinement)
    return run.pairs


def _write_costs(path: str, top: Mapping, hor: Mapping, costs: dict, gamma: float,
                 checked=None, camera_checked=None, refinement=None) -> None:
    """``--costs``' JSON (docs/formats.md); ``checked``, ``camera_checked``, ``refinement``:
    the run's appearance and camera checks and its top camera refinement, if any."""
    import json

    from xvmatch.core.atomic_files import atomic_write_text

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
    from xvmatch.inference.matching.site_bundle import json_figure

    if refinement is not None:
        fit = refinement.fit
        record["top_camera_refinement"] = {
            "turned": refinement.turned, "moving": refinement.moving,
            "message": refinement.message, "fit": None if fit is None else {
                "frame": fit.frame, "rotation_deg": list(fit.rotation_deg),
                "angle_deg": fit.angle_deg, "frames": fit.frames,
                "loss_before": json_figure(fit.loss_before),
                "loss_after": json_figure(fit.loss_after)}}
    if camera_checked is not None:
        record["camera_check"] = {
            "judged": camera_checked.judged, "cameras_used": camera_checked.trusted,
            "kept": camera_checked.kept, "positives": camera_checked.positives,
            "share": json_figure(camera_checked.share),
            "standard_error": json_figure(camera_checked.error),
            "consistency": json_figure(camera_checked.consistency),
            "fit_loss": json_figure(camera_checked.fit_loss),
            "top_camera_moving": camera_checked.moving,
            "min_keep": camera_checked.min_keep, "min_pairs": camera_checked.min_pairs}
    if checked is not None:
        record["appearance_check"] = {
            "judged": checked.judged, "images_used": checked.trusted,
            "auc": json_figure(checked.auc), "standard_error": json_figure(checked.error),
            "positives": checked.positives, "negatives": checked.negatives,
            "min_auc": checked.min_auc, "min_pairs": checked.min_pairs}
        if checked.frames:
            record["appearance_check"]["frame_check"] = {
                "frames": checked.frames, "from_boxes": checked.frames_dropped}
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
            (:mod:`xvmatch.viz.box_canvas`).
        hor_size: the horizontal image size.
        labels: print each box's id (``--no-labels``: none).
    """
    import shutil
    import tempfile
    from pathlib import Path

    import numpy as np

    from xvmatch.core.output_paths import claim_folder
    from xvmatch.viz.box_canvas import blank_view, top_plan
    from xvmatch.viz.match_drawing import (
        draw_matches,
        frames_to_draw,
        picture_path,
        write_match_picture,
    )

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
