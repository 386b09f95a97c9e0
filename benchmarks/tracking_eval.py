"""Complementary-view tracking on the CVMHAT dev split: MIP and spectral against frame mode.

For each sequence pair, the ground-truth boxes are turned into detections: ids replaced by row
numbers and the boxes of each frame shuffled, per view (cross-view id equality is never an
input). The frame-level association (the exhaustive search of ``xvmatch associate``, O searched
unless ``--camera-given``) runs once and feeds both solvers, so the three rows score the same
frames from the same evidence:

- frame: the frame association's pairs, scored by the frame metrics (CVIDF1, CVMA);
- mip / spectral: ``track_pair`` with that solver; tracks scored by
  :func:`xvmatch.metrics.track_metrics.evaluate_tracks` (pairs = same track id in a frame;
  per view IDF1, MOTA, HOTA from TrackEval).

With ``--weights learned`` (the default runs both), the learned matcher of ``--model``
(default: the shipped bundle) also associates every frame from the boxes alone, once, and
feeds two more rows:

- frame-learned: its pairs, scored as the frame row;
- mip-learned / spectral-learned: ``track_pair`` with the cross-view weights from its costs
  (``--learned-rule``, :func:`xvmatch.inference.tracks.track_costs.frame_evidence`).

With ``--offset auto`` each pair (and noise seed) is first re-timed as ``xvmatch track --offset
auto`` does: the offset estimated from the detections, applied when the clips back it
(:func:`xvmatch.formats.mot_boxes.align_views`), the ground truth re-timed the same way.

OVERALL pools every frame of every sequence (cross-view counts summed, TrackEval's
``combine_sequences`` per view); ``--noise 1 2 3`` pools the three noise seeds the same way.
Last, the whole ``xvmatch track`` command is timed on one 1,200-frame pair, pinned to one core
(``taskset -c 0`` where it exists), with each weighting in the same run (``--model`` for the
learned one), in seconds and seconds per frame; with its defaults, so since 2026-11-27 with the
offset estimate of its default ``--offset auto`` (10-25 s per pair).

With ``--synthetic N``, rendered videos instead (:func:`xvmatch.datasets.tracking_video.
render_tracking_video`, 25 fps, ``--people`` 6 to 12; ``--scenario`` drone, the default, or
overview: a camera on a building), ids scrambled per view the same way,
tracked with the MIP from boxes only and with the images: colour terms alone (no network), and
with the appearance network of ``--model`` (default: the shipped bundle), the learned weights'
row with the command's appearance check and without it. ``--shift S`` puts each view's images
through one fixed simulated camera of strength S first (the adaptation benchmark's stress test).
``--cameras`` gives the learned matcher each frame's rendered cameras, as ``xvmatch track
--cameras`` does: the learned rows' cross-view weights (and their appearance check) then rest
on the camera cues too; the handcrafted rows do not change. ``--camera-error DEG`` gives them
calibrated with an error (:func:`with_camera_error`); the fixed top camera is then refined on
each video's boxes as the command does (:mod:`xvmatch.inference.matching.camera_refinement`; its
line is printed), unless ``--refine-top-camera off``. ``--w1`` sets Eq. 17's share. ``--flight SPEED
YAW_RATE`` flies the drone's top camera (its cameras per frame, a telemetry error a mount
offset shared by every frame).

Usage:
    python benchmarks/tracking_eval.py [--data ../shared/data/cvmhat] [--cache DIR]
        [--camera-given] [--time-sequence V1-S_55-G_1] [--no-timing] [--half even|odd]
        [--solvers mip spectral] [--c0 C] [--sigma S] [--noise SEED [SEED ...]]
        [--weights handcrafted learned] [--model default] [--learned-rule margin] [--mirror]
        [--offset auto]
    python benchmarks/tracking_eval.py --synthetic 8 [--synthetic-frames 100] [--model default]
        [--people 6 12] [--shift 3] [--scenario drone|overview] [--flight 2 5]
        [--cameras [--camera-error 2] [--refine-top-camera off]]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.datasets.detector_noise import FALSE_ID_BASE, DetectorNoise, apply_detector_noise
from xvmatch.datasets.synthetic_scenes import SCENARIOS
from xvmatch.formats.cvmhat import IMAGE_SIZE, default_cvmhat_dir, read_sequence, sequence_names
from xvmatch.formats.mot_boxes import FrameBoxes, align_views
from xvmatch.inference.linking.assignment import FrameCosts
from xvmatch.inference.linking.tracklets import Tracklet, split_clips, view_tracklets
from xvmatch.inference.tracks.track_costs import (
    FITTED_CAMERAS_W1,
    LEARNED_DUMMY_WEIGHT,
    LEARNED_RULES,
    TrackWeights,
)
from xvmatch.inference.tracks.track_mip import MIP_MAX_LOOPS
from xvmatch.inference.tracks.tracking import (
    LearnedEvidence,
    TrackConfig,
    associate_frames,
    learned_frame_evidence,
    track_pair,
)
from xvmatch.metrics.cross_view_metrics import summarize
from xvmatch.metrics.track_metrics import (
    pool_view_scores,
    track_pair_counts,
    tracklet_scores,
    view_track_results,
)

SOLVERS = ("mip", "spectral")


def as_detections(frames: dict[int, FrameBoxes], seed: int):
    """Ids -> row numbers, boxes shuffled per frame; returns records and ``{row: true id}``."""
    rng = np.random.default_rng(seed)
    out, truth, row = {}, {}, 0
    for f in sorted(frames):
        rec = frames[f]
        order = rng.permutation(len(rec))
        rows = np.arange(row, row + len(rec))
        truth.update(zip(rows.tolist(), rec.ids[order].tolist(), strict=True))
        out[f] = FrameBoxes(f, rows, rec.boxes[order])
        row += len(rec)
    return out, truth


def as_tracks(det: dict[int, FrameBoxes], track_of_row: dict[int, int]) -> dict[int, FrameBoxes]:
    out = {}
    for f, rec in det.items():
        keep = [k for k, r in enumerate(rec.ids.tolist()) if r in track_of_row]
        if keep:
            ids = np.array([track_of_row[int(rec.ids[k])] for k in keep])
            out[f] = FrameBoxes(f, ids, rec.boxes[keep])
    return out


def frame_tracks(det_top, det_hor, pairs):
    """The frame association as per-frame pseudo-tracks (a pair shares an id), so that it is
    scored by the same box matching as the tracks (needed with detector noise)."""
    out_top, out_hor = {}, {}
    for det, out, side in ((det_top, out_top, 0), (det_hor, out_hor, 1)):
        for f, rec in det.items():
            paired = {p[side]: k + 1 for k, p in enumerate(pairs.get(f, ()))}
            ids = [paired.get(int(r), 1_000_000 + int(r)) for r in rec.ids]
            out[f] = FrameBoxes(f, np.array(ids, dtype=np.int64), rec.boxes)
    return out_top, out_hor


def frame_pairs_cached(name, top, hor, camera_rows, cache: Path | None, tag: str):
    path = cache / f"{name}.{tag}.json" if cache else None
    if path and path.exists():
        return {int(f): [tuple(p) for p in v] for f, v in json.loads(path.read_text()).items()}
    pairs = associate_frames(top, hor, float(IMAGE_SIZE[0]), camera_rows=camera_rows)
    if path:
        atomic_write_text(path, json.dumps({str(f): v for f, v in pairs.items()}))
    return pairs


def offset_cached(name, top, hor, cache: Path | None, tag: str) -> int:
    """The offset ``xvmatch track --offset auto`` applies to a pair of detection files (0 when
    the clips do not back the estimate), kept in ``cache``."""
    from xvmatch.cues.offset_estimation import AUTO_MAX_OFFSET, OFFSET_STEP, estimate_offset
    from xvmatch.cues.spatial_matching import SpatialParams

    # The search's step in the name: a cache of another search is not reused.
    path = cache / f"{name}.{tag}.offset-step{OFFSET_STEP}.json" if cache else None
    if path and path.exists():
        return int(json.loads(path.read_text())["applied"])
    est = estimate_offset(top, hor, hor_width=float(IMAGE_SIZE[0]), params=SpatialParams(),
                          max_offset=AUTO_MAX_OFFSET)
    if path:
        atomic_write_text(path, json.dumps({"offset": est.offset, "applied": est.applied}))
    return int(est.applied)


def learned_evidence_cached(name, top, hor, camera_rows, cache: Path | None, tag: str, model,
                            mirror: bool) -> LearnedEvidence:
    """The learned matcher's box-only evidence of one pair, kept in ``cache`` (JSON: float64
    costs written in full) under the bundle's matcher digest."""
    digest = model.bundle.manifest.matcher_sha256[:12]
    path = (cache / f"{name}.{tag}.learned-{digest}{'-mirror' if mirror else ''}.json"
            if cache else None)
    if path and path.exists():
        raw = json.loads(path.read_text())
        costs = {int(f): FrameCosts(np.array(t, dtype=np.int64), np.array(h, dtype=np.int64),
                                    np.array(c, dtype=float).reshape(len(t), len(h)),
                                    np.array(p, dtype=bool).reshape(len(t), len(h)))
                 for f, (t, h, c, p) in raw["costs"].items()}
        return LearnedEvidence(costs, float(raw["gamma"]))
    ev = learned_frame_evidence(top, hor, IMAGE_SIZE, model, camera_rows=camera_rows,
                                mirror=mirror)
    if path:
        atomic_write_text(path, json.dumps({"gamma": ev.gamma, "costs": {
            str(f): [c.top_rows.tolist(), c.hor_rows.tolist(), c.cost.ravel().tolist(),
                     c.paired.ravel().tolist()] for f, c in ev.costs.items()}}))
    return ev


def fmt_row(name, frames, cv, top=None, hor=None, extra=""):
    views = ""
    if top is not None:
        views = (f" | {top.idf1:5.1f} {top.mota:5.1f} {top.hota:5.1f} {top.idsw:4d}"
                 f" | {hor.idf1:5.1f} {hor.mota:5.1f} {hor.hota:5.1f} {hor.idsw:4d}")
    return f"{name:<20} {frames:5d} {cv.cvidf1:6.1f} {cv.cvma:6.1f}{views} {extra}"


def score_tracks(label: str, res, det, truth, frames, pooled: list, views: dict,
                 extra: str) -> None:
    """Score one tracking result (``det``, ``truth``: the (top, hor) detections and ground
    truth), add its counts and per-view results to the pools and print its row."""
    (det_top, det_hor), (top, hor) = det, truth
    tr_top, tr_hor = as_tracks(det_top, res.top_rows), as_tracks(det_hor, res.hor_rows)
    counts = track_pair_counts(tr_top, tr_hor, top, hor, frames)
    pooled.extend(counts)
    r_top, r_hor = view_track_results(top, tr_top), view_track_results(hor, tr_hor)
    views["top"].append(r_top)
    views["hor"].append(r_hor)
    print(fmt_row(label, len(frames), summarize(counts), pool_view_scores([r_top]),
                  pool_view_scores([r_hor]), extra))


def time_command(folder: Path, name: str, top, hor, solver: str,
                 extra: tuple[str, ...] = ()) -> tuple[float, float]:
    """Wall and CPU seconds of ``xvmatch track`` on detection files (ids -1), one core;
    ``extra``: more options (``--model default`` for the learned weights)."""
    tmp = Path(tempfile.mkdtemp(prefix="track_time_"))
    try:
        for view, frames in (("top", top), ("hor", hor)):
            lines = [f"{f},-1,{b[0]:g},{b[1]:g},{b[2]:g},{b[3]:g},-1,-1,-1,-1"
                     for f in sorted(frames) for b in frames[f].boxes.tolist()]
            (tmp / f"{view}.txt").write_text("\n".join(lines) + "\n")
        exe = str(Path(sys.executable).with_name("xvmatch"))
        cmd = [exe, "track", "--top", str(tmp / "top.txt"), "--hor", str(tmp / "hor.txt"),
               "--out", str(tmp / "out"), "--quiet", "--solver", solver, *extra]
        if shutil.which("taskset"):
            cmd = ["taskset", "-c", "0", *cmd]
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        start = time.perf_counter()
        subprocess.run(cmd, check=True)
        wall = time.perf_counter() - start
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
        return wall, cpu
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


SYNTHETIC_ARMS = ("boxes", "colour", "network-cv", "network", "boxes-learned",
                  "network-learned", "unchecked-learned")
"""The --synthetic rows: boxes only; images, colour terms only (no network); images and the
appearance network across views (Eq. 17) with colour over time (Eq. 14, the paper's); the
network across views and over time (with ``--weights handcrafted``); the learned weights from
boxes only (``--model`` without images) and with the network (``--model`` with images, with
the command's default appearance check, :func:`~xvmatch.inference.matching.appearance_check.
check_tracklet_appearance`); the same without the check (``--appearance-check off``)."""


ERROR_VIEWS = {"both": ("top", "hor"), "top": ("top",), "ego": ("hor",)}
"""``--error-on``: the views :func:`with_camera_error` puts the error on."""


def with_camera_error(cameras: dict, degrees: float, seed: int,
                      views: tuple[str, ...] = ("top", "hor")) -> dict:
    """``{frame: FrameCameras}`` as a calibration would give them with an error: each camera of
    ``views`` turned by ``degrees`` about a random axis and moved ``degrees / 10`` metres in a
    random direction; the top camera once for the whole video (a fixed camera's calibration;
    a top camera in flight: every frame's by the same turn in its own frame, a mount offset,
    and the same step), the egocentric one anew every frame (its pose tracked frame by
    frame)."""
    from scipy.spatial.transform import Rotation

    from xvmatch.geometry.camera import Camera, FrameCameras

    rng = np.random.default_rng(seed)

    def off(cam: Camera) -> Camera:
        axis, step = rng.normal(size=3), rng.normal(size=3)
        turn = Rotation.from_rotvec(np.radians(degrees) * axis / np.linalg.norm(axis))
        return Camera(K=cam.K, R=cam.R @ turn.as_matrix().T,
                      c=cam.c + degrees / 10 * step / np.linalg.norm(step),
                      width=cam.width, height=cam.height)

    frames = sorted(cameras)
    top = cameras[frames[0]].top if frames else None
    tops = dict.fromkeys(frames, top)
    if top is not None and "top" in views:
        moved = off(top)
        if all(cameras[f].top is top for f in frames):
            tops = dict.fromkeys(frames, moved)
        else:  # in flight: the same mount offset (R' = B R) and step on every frame
            mount, step = moved.R @ top.R.T, moved.c - top.c
            tops = {f: Camera(K=cameras[f].top.K, R=mount @ cameras[f].top.R,
                              c=cameras[f].top.c + step, width=cameras[f].top.width,
                              height=cameras[f].top.height) for f in frames}
    elif top is not None:
        tops = {f: cameras[f].top for f in frames}
    return {f: FrameCameras(tops[f], off(cameras[f].hor) if "hor" in views else cameras[f].hor)
            for f in frames}


def synthetic_main(args: argparse.Namespace) -> int:
    """The --synthetic mode: rendered videos, boxes only against boxes and images."""
    from dataclasses import replace

    from xvmatch.datasets.camera_shift import camera_shift
    from xvmatch.datasets.synthetic_scenes import SynthConfig
    from xvmatch.datasets.tracking_video import render_tracking_video
    from xvmatch.formats.camera_frames import CameraFrames
    from xvmatch.inference.matching.camera_refinement import refine_run_cameras
    from xvmatch.inference.matching.learned_association import load_matcher_bundle
    from xvmatch.inference.tracks.tracking import TrackImages

    model = load_matcher_bundle(args.model)
    w1 = TrackWeights().w1 if args.w1 is None else args.w1
    auto_w1 = args.cameras and args.w1 is None and args.refine_top_camera == "auto"
    hand = TrackWeights(c0=TrackWeights().c0 if args.c0 is None else args.c0, sigma=args.sigma,
                        w1=w1)
    learned = TrackWeights(c0=LEARNED_DUMMY_WEIGHT if args.c0 is None else args.c0,
                           sigma=args.sigma, w1=w1)
    print(f"{args.synthetic} rendered {args.scenario} videos of {args.synthetic_frames} frames "
          f"(25 fps, {args.people[0]}-{args.people[1]} people, images camera-shifted "
          f"{args.shift:g}, "
          f"{'the learned weights with the rendered cameras' if args.cameras else ''}"
          f"{f' (calibrated {args.camera_error:g} deg off)' if args.camera_error else ''}"
          f"{', ' if args.cameras else ''}"
          f"seeds {args.seed}..{args.seed + args.synthetic - 1}), ground-truth boxes, ids "
          f"replaced by shuffled row numbers per view; MIP, c0 {hand.c0:g} (learned weights: "
          f"{learned.c0:g}), clips of {args.clip_length}, sigma {args.sigma:g}, w1 "
          f"{hand.w1:g}{' (learned: 1 where the cameras fit)' if auto_w1 else ''}, w2 "
          f"{hand.w2:g}; network: {args.model}")
    head = (f"{'scene':<20} {'frames':>5} {'CVIDF1':>6} {'CVMA':>6} | top IDF1 MOTA HOTA IDSW"
            f" | hor IDF1 MOTA HOTA IDSW")
    print(head)
    arms = [a for a in SYNTHETIC_ARMS if a in args.arms]
    pooled = {k: [] for k in ("frame", "frame-learned", *arms)}
    views = {k: {"top": [], "hor": []} for k in arms}
    loops = dict.fromkeys(arms, 0)
    for k in range(args.synthetic):
        seed = args.seed + k
        start = time.perf_counter()
        video = render_tracking_video(seed, args.synthetic_frames, SynthConfig(
            scenario=args.scenario, n_people=tuple(args.people), fps=25.0),
            flight=None if args.flight is None else tuple(args.flight))
        if args.shift:  # each view through one fixed simulated camera of its own
            video = replace(video, top_images={
                f: camera_shift(im, args.shift, seed=100 + seed, per_image=False)
                for f, im in video.top_images.items()}, hor_images={
                f: camera_shift(im, args.shift, seed=200 + seed, per_image=False)
                for f, im in video.hor_images.items()})
        t_render = time.perf_counter() - start
        top, hor = video.top, video.hor
        det_top, _ = as_detections(top, seed * 2 + 1)
        det_hor, _ = as_detections(hor, seed * 2 + 2)
        width = float(video.hor_size[0])
        fp = associate_frames(det_top, det_hor, width)
        cameras, fitted = None, learned
        if args.cameras:
            cameras = CameraFrames("the rendered cameras", per_frame=video.cameras
                                   if not args.camera_error else
                                   with_camera_error(video.cameras, args.camera_error, seed,
                                                     ERROR_VIEWS[args.error_on]))
            if args.refine_top_camera == "auto":
                cameras, refinement = refine_run_cameras(cameras, det_top, det_hor, sorted(hor))
                print(f"seed {seed} {refinement.message}")
                if args.w1 is None and refinement.fits:  # as track does
                    fitted = replace(learned, w1=FITTED_CAMERAS_W1)
                    print(f"seed {seed} the top camera fits: w1 {FITTED_CAMERAS_W1:g}")
        ev = learned_frame_evidence(det_top, det_hor, video.hor_size, model, cameras=cameras)
        frames = sorted(set(top) | set(hor))
        name = f"seed {seed}"
        counts = track_pair_counts(*frame_tracks(det_top, det_hor, fp), top, hor, frames)
        pooled["frame"] += counts
        print(fmt_row(f"{name} frame", len(frames), summarize(counts),
                      extra=f"render {t_render:.0f}s"))
        counts = track_pair_counts(*frame_tracks(det_top, det_hor, ev.frame_pairs), top, hor,
                                   frames)
        pooled["frame-learned"] += counts
        print(fmt_row(f"{name} frame-learned", len(frames), summarize(counts)))
        for arm in arms:
            images = None
            if not arm.startswith("boxes"):
                images = TrackImages(video.top_images, video.hor_images,
                                     None if arm == "colour" else model.descriptors)
            config = TrackConfig(clip_length=args.clip_length, min_iou=args.min_iou,
                                 max_gap=args.max_gap,
                                 weights=fitted if arm.endswith("-learned") else hand,
                                 time_appearance="colour" if arm == "network-cv"
                                 else "network")
            start = time.perf_counter()
            checked = []
            res = track_pair(det_top, det_hor, width, config=config, frame_pairs=fp,
                             images=images, learned=ev if arm.endswith("-learned") else None,
                             appearance_check=arm == "network-learned", checked=checked)
            verdict = ""
            if checked and checked[0].judged:
                verdict = (f" check AUC {checked[0].auc:.3f}+-{checked[0].error:.3f} "
                           f"{'kept' if checked[0].trusted else 'FELL BACK'}")
            elif checked:
                verdict = f" check: {checked[0].positives} pairs, not judged"
            loops[arm] = max(loops[arm], res.max_loops)
            score_tracks(f"{name} {arm}", res, (det_top, det_hor), (top, hor), frames,
                         pooled[arm], views[arm], f"track {time.perf_counter() - start:.1f}s "
                         f"fallback {res.n_fallback}/{res.n_windows} loops "
                         f"{res.max_loops}{verdict}")
        sys.stdout.flush()
    print("-" * len(head))
    total = len(pooled["frame"])
    print(fmt_row("OVERALL frame", total, summarize(pooled["frame"])))
    print(fmt_row("OVERALL frame-learned", total, summarize(pooled["frame-learned"])))
    for arm in arms:
        print(fmt_row(f"OVERALL {arm}", total, summarize(pooled[arm]),
                      pool_view_scores(views[arm]["top"]), pool_view_scores(views[arm]["hor"])))
    print_loops(loops)
    return 0


def print_loops(loops: dict[str, int]) -> None:
    """The most loop constraints one window's MIP added, per row, against the budget."""
    print("most loops one window added (MIP_MAX_LOOPS " + str(MIP_MAX_LOOPS) + "): "
          + ", ".join(f"{arm} {n}" for arm, n in loops.items()))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default=None, help="CVMHAT folder (default: shared data)")
    parser.add_argument("--cache", default=None,
                        help="folder for the frame associations (reused when present)")
    parser.add_argument("--camera-given", action="store_true",
                        help="O given: the wearer's rows (ground-truth id 0) are known")
    parser.add_argument("--seed", type=int, default=0, help="seed of the row shuffling")
    parser.add_argument("--frames", type=int, default=None, help="first N frames only")
    parser.add_argument("--sequences", nargs="*", default=None, help="subset of names")
    parser.add_argument("--noise", type=int, nargs="+", default=None, metavar="SEED",
                        help="apply the default detector noise (5%% jitter, 10%% misses, 0.3 "
                        "false boxes per frame and view) with each seed; OVERALL pools them")
    parser.add_argument("--half", choices=("even", "odd"), default=None,
                        help="every other sequence (sorted names; even = 1st, 3rd, ...): "
                        "choose settings on one half, report them on the other")
    parser.add_argument("--solvers", nargs="+", choices=SOLVERS, default=list(SOLVERS))
    parser.add_argument("--c0", type=float, default=None,
                        help="dummy weight of Eq. 1 (default: the command's, 0.1 with the "
                        "handcrafted weights, 0.02 with the learned ones)")
    parser.add_argument("--sigma", type=float, default=TrackWeights().sigma,
                        help="Eq. 15 scale per box height")
    parser.add_argument("--camera-error", type=float, default=0.0, metavar="DEG",
                        help="--cameras: calibrate them with an error, each camera turned by "
                        "DEG degrees and moved DEG / 10 m (the top camera once, the egocentric "
                        "one every frame)")
    parser.add_argument("--error-on", choices=tuple(ERROR_VIEWS), default="both",
                        help="with --camera-error: the cameras given with the error")
    parser.add_argument("--refine-top-camera", choices=("auto", "off"), default="auto",
                        help="--cameras: refine the fixed top camera on each video's boxes, as "
                        "the command does (default auto)")
    parser.add_argument("--w1", type=float, default=None,
                        help="--synthetic: share of the spatial term in a cross-view weight "
                        "(Eq. 17; 1: the images only over time; default the command's: 0.3, "
                        "or 1 for the learned weights when the refined cameras fit)")
    parser.add_argument("--max-gap", type=int, default=3, help="frames a tracklet may miss")
    parser.add_argument("--clip-length", type=int, default=TrackConfig().clip_length,
                        help="frames per clip (tracking; the tracklet table keeps 10)")
    parser.add_argument("--min-iou", type=float, default=0.5, help="tracklet IoU link")
    parser.add_argument("--time-sequence", default="V1-S_55-G_1")
    parser.add_argument("--no-timing", action="store_true")
    parser.add_argument("--synthetic", type=int, default=None, metavar="N",
                        help="instead of CVMHAT: N rendered videos (seeds --seed ...), "
                        "tracked from boxes only and with images (colour, the network)")
    parser.add_argument("--scenario", choices=SCENARIOS, default="drone",
                        help="--synthetic: the rendered scene, a drone above or a camera on a "
                        "building")
    parser.add_argument("--synthetic-frames", type=int, default=100,
                        help="frames per rendered video (25 fps)")
    parser.add_argument("--flight", type=float, nargs=2, default=None,
                        metavar=("SPEED", "YAW_RATE"),
                        help="--synthetic drone: the top camera flies (m/s, degrees/s; "
                        "render_tracking_video's flight), its cameras per frame")
    parser.add_argument("--people", type=int, nargs=2, default=[6, 12], metavar=("MIN", "MAX"),
                        help="people per rendered video (--synthetic)")
    parser.add_argument("--shift", type=float, default=0.0, metavar="S",
                        help="--synthetic: each view's images through one fixed simulated "
                        "camera of strength S (camera_shift, per_image=False), the adaptation "
                        "benchmark's stress test")
    parser.add_argument("--arms", nargs="+", choices=SYNTHETIC_ARMS, default=SYNTHETIC_ARMS,
                        help="with --synthetic: the rows to track (default all)")
    parser.add_argument("--cameras", action="store_true",
                        help="--synthetic: the learned weights' matcher also gets each frame's "
                        "rendered cameras, as 'xvmatch track --cameras' would (the wearer "
                        "found from them, not from ids)")
    parser.add_argument("--model", default="default",
                        help="matcher bundle: the learned weights' matcher (boxes only), and "
                        "the appearance network for --synthetic")
    parser.add_argument("--weights", nargs="+", choices=("handcrafted", "learned"),
                        default=["handcrafted", "learned"],
                        help="cross-view weights to run: Eq. 13 on the handcrafted frame "
                        "association, and/or the learned matcher's costs")
    parser.add_argument("--learned-rule", choices=LEARNED_RULES, default=LEARNED_RULES[0],
                        help="how the learned costs become evidence (frame_evidence)")
    parser.add_argument("--learned-share", type=float, default=1.0,
                        help="share of the learned evidence in the cross-view spatial term "
                        "(the rest: Eq. 13 on the handcrafted frame association)")
    parser.add_argument("--offset", choices=("0", "auto"), default="0",
                        help="auto: re-time each pair as 'track --offset auto' does")
    parser.add_argument("--mirror", action="store_true",
                        help="the learned matcher also scores the mirrored scene")
    args = parser.parse_args()
    if args.cameras and not args.synthetic:
        parser.error("--cameras gives the rendered cameras: it needs --synthetic N")
    if args.camera_error and not args.cameras:
        parser.error("--camera-error is an error of the --cameras: add --cameras")
    if args.flight is not None and (not args.synthetic or args.scenario != "drone"):
        parser.error("--flight flies the drone's top camera: it needs --synthetic N and the "
                     "drone scenario")
    if args.synthetic:
        return synthetic_main(args)
    folder = Path(args.data) if args.data else default_cvmhat_dir()
    if not folder.is_dir():
        print(f"no CVMHAT data in {folder}", file=sys.stderr)
        return 1
    cache = Path(args.cache) if args.cache else None
    if cache:
        cache.mkdir(parents=True, exist_ok=True)
    names = args.sequences or sequence_names(folder)
    if args.half:
        names = sorted(names)[0 if args.half == "even" else 1::2]
    solvers = tuple(args.solvers)
    learned = "learned" in args.weights
    model = None
    if learned:
        from xvmatch.inference.matching.learned_association import load_matcher_bundle

        model = load_matcher_bundle(args.model)
    arms = [s for s in solvers if "handcrafted" in args.weights]
    arms += [f"{s}-learned" for s in solvers if learned]
    frame_rows = ["frame", *(["frame-learned"] if learned else [])]

    def c0(arm: str) -> float:
        if args.c0 is not None:
            return args.c0
        return LEARNED_DUMMY_WEIGHT if arm.endswith("-learned") else TrackWeights().c0

    def config(arm: str) -> TrackConfig:
        return TrackConfig(clip_length=args.clip_length, min_iou=args.min_iou,
                           max_gap=args.max_gap,
                           weights=TrackWeights(c0=c0(arm), sigma=args.sigma),
                           solver=arm.split("-")[0], learned_rule=args.learned_rule,
                           learned_share=args.learned_share)

    head = (f"{'sequence':<20} {'frames':>5} {'CVIDF1':>6} {'CVMA':>6} | top IDF1 MOTA HOTA IDSW"
            f" | hor IDF1 MOTA HOTA IDSW")
    noise_seeds = args.noise if args.noise is not None else [None]
    boxes = ("ground-truth" if args.noise is None else
             f"noisy (seeds {' '.join(map(str, args.noise))}, pooled)")
    print(f"O {'given' if args.camera_given else 'searched'}; {boxes} boxes, ids replaced "
          f"by shuffled row numbers per view; c0 {' / '.join(f'{c0(a):g}' for a in arms)} "
          f"({' / '.join(arms)}), clip length {args.clip_length}, sigma {args.sigma:g}, min IoU "
          f"{args.min_iou:g}" + (f"; learned: {args.model}, rule {args.learned_rule}"
                                 f"{', mirror' if args.mirror else ''}" if learned else ""))
    print(head)
    pooled = {k: [] for k in (*frame_rows, *arms)}
    views = {s: {"top": [], "hor": []} for s in arms}
    loops = dict.fromkeys(arms, 0)
    made = {"top": [], "hor": []}
    people: dict[str, dict] = {"top": {}, "hor": {}}
    for noise_seed in noise_seeds:
        for name in names:
            top, hor = read_sequence(folder, name)
            if args.frames:
                top = {f: r for f, r in top.items() if f <= args.frames}
                hor = {f: r for f, r in hor.items() if f <= args.frames}
            in_top, in_hor = top, hor
            label = name if noise_seed is None or len(noise_seeds) == 1 else (
                f"{name}#{noise_seed}")
            if noise_seed is not None:
                noise = DetectorNoise()
                in_top = apply_detector_noise(top, IMAGE_SIZE, noise, noise_seed, "top",
                                              keep_ids=(0,) if args.camera_given else ())
                in_hor = apply_detector_noise(hor, IMAGE_SIZE, noise, noise_seed, "hor")
            det_top, truth_top = as_detections(in_top, args.seed * 2 + 1)
            det_hor, truth_hor = as_detections(in_hor, args.seed * 2 + 2)
            offset = 0
            if args.offset == "auto":
                offset = offset_cached(name, det_top, det_hor, cache, f"s{args.seed}" + (
                    f"n{noise_seed}" if noise_seed is not None else ""))
                if offset:
                    det_top, det_hor = align_views(det_top, det_hor, offset)
                    top, hor = align_views(top, hor, offset)
                    print(f"{label}: re-timed by {offset:+d} frames")
            clips = split_clips(sorted(set(det_top) | set(det_hor)), 10)
            for view, det, truth in (("top", det_top, truth_top), ("hor", det_hor, truth_hor)):
                base = len(people[view])  # rows of every sequence kept apart
                for clip in view_tracklets(det, clips, args.min_iou, args.max_gap):
                    made[view].append([Tracklet(t.clip, t.frames, t.rows + base, t.boxes)
                                       for t in clip])
                people[view].update({r + base: (f"{label}:{i}" if i < FALSE_ID_BASE["top"]
                                                else None) for r, i in truth.items()})
            camera_rows = ([r for r, i in truth_top.items() if i == 0] if args.camera_given
                           else None)
            tag = ("B" if args.camera_given else "A") + f"s{args.seed}" + (
                f"f{args.frames}" if args.frames else "") + (
                f"n{noise_seed}" if noise_seed is not None else "") + (
                f"o{offset}" if offset else "")
            frames = sorted(set(top) | set(hor))
            start = time.perf_counter()
            evidence = {"frame": frame_pairs_cached(name, det_top, det_hor, camera_rows, cache,
                                                    tag)}
            t_assoc = {"frame": time.perf_counter() - start}
            ev = None
            if learned:
                start = time.perf_counter()
                ev = learned_evidence_cached(name, det_top, det_hor, camera_rows, cache, tag,
                                             model, args.mirror)
                t_assoc["frame-learned"] = time.perf_counter() - start
                evidence["frame-learned"] = ev.frame_pairs
            for row in frame_rows:
                counts = track_pair_counts(*frame_tracks(det_top, det_hor, evidence[row]), top,
                                           hor, frames)
                pooled[row] += counts
                print(fmt_row(f"{label} {row}", len(frames), summarize(counts),
                              extra=f"assoc {t_assoc[row]:.0f}s"))
            for arm in arms:
                start = time.perf_counter()
                res = track_pair(det_top, det_hor, float(IMAGE_SIZE[0]),
                                 config=config(arm), camera_rows=camera_rows,
                                 frame_pairs=evidence["frame"],
                                 learned=ev if arm.endswith("-learned") else None)
                t_track = time.perf_counter() - start
                loops[arm] = max(loops[arm], res.max_loops)
                score_tracks(f"{label} {arm}", res, (det_top, det_hor), (top, hor), frames,
                             pooled[arm], views[arm],
                             f"track {t_track:.1f}s fallback {res.n_fallback}/{res.n_windows} "
                             f"loops {res.max_loops}")
            sys.stdout.flush()
    print("-" * len(head))
    total = len(pooled["frame"])
    frame_cv = {}
    for row in frame_rows:
        frame_cv[row] = summarize(pooled[row])
        print(fmt_row(f"OVERALL {row}", total, frame_cv[row]))
    overall = {}
    for arm in arms:
        cv = summarize(pooled[arm])
        top_s = pool_view_scores(views[arm]["top"])
        hor_s = pool_view_scores(views[arm]["hor"])
        overall[arm] = (cv, top_s, hor_s)
        print(fmt_row(f"OVERALL {arm}", total, cv, top_s, hor_s))
    print_loops({arm: n for arm, n in loops.items() if arm.startswith("mip")})
    for view in ("top", "hor"):
        ts = tracklet_scores(made[view], people[view])
        print(f"tracklets ({view}, Table 10): P {ts.precision:.2f} R {ts.recall:.2f} "
              f"F1 {ts.f1:.2f} ({ts.n_right} right of {ts.n_tracklets} made, "
              f"{ts.n_person_clips} person-clips)")
    for suffix, frame_row in (("", "frame"), ("-learned", "frame-learned")):
        if f"mip{suffix}" not in overall:
            continue
        mip_cv, mip_top, _ = overall[f"mip{suffix}"]
        spec = overall.get(f"spectral{suffix}")
        vs = (f"; MIP - spectral CVIDF1 = {mip_cv.cvidf1 - spec[0].cvidf1:+.1f} (> 0)"
              if spec else "")
        gain = mip_cv.cvidf1 - frame_cv[frame_row].cvidf1
        goals = ((f"CVIDF1 {mip_cv.cvidf1:.1f} (>= 96), top IDF1 {mip_top.idf1:.1f} (>= 97; "
                  f"issue 33), over {frame_row} {gain:+.1f}") if suffix else
                 (f"tracking CVIDF1 - {frame_row} = {gain:+.1f} (>= +5); top IDF1 "
                  f"{mip_top.idf1:.1f} (>= 90)"))
        print(f"targets (mip{suffix}): {goals}{vs}")
    if not args.no_timing and args.time_sequence in names:
        top, hor = read_sequence(folder, args.time_sequence)
        n = len(set(top) | set(hor))
        for weights in args.weights:
            extra = ("--model", args.model) if weights == "learned" else ()
            for solver in solvers:
                wall, cpu = time_command(folder, args.time_sequence, top, hor, solver, extra)
                print(f"xvmatch track {' '.join(('--solver', solver, *extra))} on "
                      f"{args.time_sequence} ({n} frames), one core: {wall:.1f} s wall "
                      f"({wall / n:.4f} s per frame), {cpu:.1f} s CPU ({cpu / n:.4f} s per "
                      "frame; target <= 0.05)")
    return 0


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    raise SystemExit(main())
