"""The learned matcher under a top camera in flight, its per-frame cameras exact or biased.

A drone's telemetry gives its camera per frame; a constant attitude error (the camera's mount,
or the heading) is refined away as for a fixed camera, in the camera's own frame or in the
world (:mod:`xvmatch.inference.matching.camera_refinement`), and the camera check then judges the
result (:mod:`xvmatch.inference.matching.camera_check`, ``moving``). For each seed this renders a
drone video whose top camera flies (:func:`xvmatch.datasets.tracking_video.render_tracking_video`,
``flight``), scrambles the ids per view, and associates the frames with the shipped matcher
(boxes only) given no cameras, the exact ones, the top camera turned by ``--bias`` (a rotation
vector, degrees) in its own frame on every frame ("mount"), or in the world ("heading"); each
camera arm as given, refined, and refined then checked ("checked": the run without cameras
where the check left them out). Prints per video each arm's Eq. 9 accuracy, the refinement's
turn and the check's verdict, then the frames of all videos pooled: Eq. 9 accuracy / CVIDF1
(renders only; ids score only).

Usage:
    python benchmarks/flying_camera_eval.py [--seeds 1 2 3 4] [--frames 100] [--speed 2]
        [--yaw-rate 5] [--bias 2 -1.5 1] [--jitter 0] [--drift 0] [--model default]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

from camera_refinement_eval import scored
from tracking_eval import as_detections

from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.geometry.camera import Camera, FrameCameras
from xvmatch.geometry.top_camera_refinement import turned_camera
from xvmatch.inference.matching.camera_check import check_run_cameras
from xvmatch.inference.matching.camera_refinement import refine_run_cameras
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.tracks.tracking import learned_frame_evidence
from xvmatch.metrics.cross_view_metrics import summarize

CAMERAS = ("exact", "mount", "heading")


def biased(cameras: dict, kind: str, bias_deg: np.ndarray, jitter_deg: float = 0.0,
           seed: int = 0, drift_deg: float = 0.0) -> dict:
    """``{frame: FrameCameras}`` with every frame's top camera turned by ``bias_deg`` in its
    own frame (``mount``: ``R' = B R``) or in the world (``heading``), or as they are
    (``exact``); then, with ``drift_deg``, turned about the vertical by an angle growing
    evenly from 0 on the first frame to ``drift_deg`` on the last (a heading that drifts);
    then, with ``jitter_deg``, each frame's turned anew in the world by a rotation vector of
    ``jitter_deg`` degrees per axis (normal; the same draws in every arm of a seed)."""
    if kind == "exact" and not jitter_deg and not drift_deg:
        return cameras
    frames = sorted(cameras)
    b = Rotation.from_rotvec(np.radians(bias_deg)).as_matrix()
    rng = np.random.default_rng([seed, 31])
    out = {}
    for f, c in sorted(cameras.items()):
        top = (c.top if kind == "exact" else
               Camera(K=c.top.K, R=b @ c.top.R, c=c.top.c, width=c.top.width,
                      height=c.top.height) if kind == "mount" else
               turned_camera(c.top, bias_deg))
        if drift_deg:
            share = (f - frames[0]) / max(frames[-1] - frames[0], 1)
            top = turned_camera(top, [0.0, 0.0, drift_deg * share])
        if jitter_deg:
            top = turned_camera(top, rng.normal(0.0, jitter_deg, 3))
        out[f] = FrameCameras(top, c.hor)
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4])
    parser.add_argument("--frames", type=int, default=100)
    parser.add_argument("--speed", type=float, default=2.0, help="m/s")
    parser.add_argument("--yaw-rate", type=float, default=5.0, help="degrees/s")
    parser.add_argument("--bias", type=float, nargs=3, default=[2.0, -1.5, 1.0],
                        help="rotation vector of the attitude error, degrees")
    parser.add_argument("--jitter", type=float, default=0.0,
                        help="telemetry noise: each frame's top camera also turned by a rotation "
                        "vector of this many degrees per axis, drawn anew (default 0)")
    parser.add_argument("--drift", type=float, default=0.0,
                        help="a heading that drifts: each frame's top camera also turned about "
                        "the vertical, from 0 degrees on the first frame to this on the last "
                        "(default 0)")
    parser.add_argument("--people", type=int, nargs=2, default=[8, 12])
    parser.add_argument("--model", default="default")
    args = parser.parse_args(argv)
    if args.frames < 10 or args.people[0] < 1 or args.people[1] < args.people[0]:
        parser.error("--frames 10 or more, --people LOW HIGH with 1 <= LOW <= HIGH")
    if not args.jitter >= 0.0:
        parser.error(f"--jitter: expected degrees, 0 or more, got {args.jitter}")
    model = load_matcher_bundle(args.model)
    bias = np.asarray(args.bias, dtype=float)
    print(f"drone videos of {args.frames} frames, the top camera flying {args.speed:g} m/s and "
          f"turning {args.yaw_rate:g} deg/s; attitude error {np.linalg.norm(bias):.2f} deg, "
          f"jitter {args.jitter:g} deg per axis, drift {args.drift:g} deg; "
          f"{args.people[0]}-{args.people[1]} people, ids scrambled per view, boxes only")
    arms = ["none", *CAMERAS, *(f"{c} {stage}" for stage in ("refined", "checked")
                                for c in CAMERAS)]
    counts = {arm: [] for arm in arms}
    for seed in args.seeds:
        start = time.perf_counter()
        video = render_tracking_video(seed, args.frames, SynthConfig(
            scenario="drone", n_people=tuple(args.people), fps=25.0),
            flight=(args.speed, args.yaw_rate))
        det_top, truth_top = as_detections(video.top, seed * 2 + 1)
        det_hor, truth_hor = as_detections(video.hor, seed * 2 + 2)
        frames = sorted(video.hor)

        def run(cameras, det_top=det_top, det_hor=det_hor, video=video,
                truth_top=truth_top, truth_hor=truth_hor):
            ev = learned_frame_evidence(det_top, det_hor, video.hor_size, model,
                                        cameras=cameras)
            return scored(ev.frame_pairs, truth_top, truth_hor, video.top, video.hor)

        rows = {"none": run(None)}
        verdicts = []
        for kind in CAMERAS:
            given = CameraFrames("rendered", per_frame=biased(video.cameras, kind, bias,
                                                              args.jitter, seed, args.drift))
            rows[kind] = run(given)
            used, what = refine_run_cameras(given, det_top, det_hor, frames)
            rows[f"{kind} refined"] = run(used) if what.turned else rows[kind]
            check = check_run_cameras(det_top, det_hor, frames, model, video.hor_size, used,
                                      float(model.gamma), what.fit_loss, moving=what.moving)
            rows[f"{kind} checked"] = rows[f"{kind} refined"] if check.trusted else rows["none"]
            turn = (f"turned {what.fit.angle_deg:.2f} deg ({what.fit.frame})" if what.turned
                    else "kept")
            verdicts.append(f"{kind} {turn}, " + (
                "not judged" if not check.judged else f"kept {check.share:.2f}"
                if check.trusted else f"left out {check.share:.2f}"))
        for arm in arms:
            counts[arm] += rows[arm]
        print(f"seed {seed}: " + " ".join(f"{arm} {summarize(rows[arm]).acc9:.1f}"
                                          for arm in arms)
              + f"; {'; '.join(verdicts)} ({time.perf_counter() - start:.0f} s)",
              flush=True)
    print(f"\nall {len(args.seeds)} videos, frames pooled: Eq. 9 accuracy / CVIDF1")
    for arm in arms:
        cell = summarize(counts[arm])
        print(f"{arm:>16} {cell.acc9:6.1f} / {cell.cvidf1:5.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
