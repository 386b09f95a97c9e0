"""The learned matcher with a top camera calibrated with an error: as given, refined, and none.

For each scenario and seed, renders a video (:func:`xvmatch.datasets.tracking_video.
render_tracking_video`, 25 fps, ``--people`` 12 to 20), scrambles the ids per view, and for each
calibration error D of ``--errors`` gives the learned matcher (``--model``, boxes only, frame by
frame: what ``associate --model M --cameras`` does) the cameras turned D degrees about a random
axis and moved D / 10 m (:func:`tracking_eval.with_camera_error`: the top camera once for the
video, the egocentric one anew every frame), then the same cameras with the top one refined on
the video's boxes (:func:`xvmatch.inference.camera_refinement.refine_run_cameras`, what
``--refine-top-camera auto`` does), and scores both against no cameras at all. Prints each
video's line (the turn found, how far the refined top camera still is from the true one, the
Eq. 9 accuracy of each) and the means per scenario and error: Eq. 9 accuracy and CVIDF1 of every
frame, and the refinement's time against the association's in the same run.

Usage:
    python benchmarks/camera_refinement_eval.py [--scenario overview drone] [--frames 60]
        [--seeds 1 2 5 6 11 12 13 16] [--errors 0 0.5 1 2 3] [--people 12 20] [--model default]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tracking_eval import as_detections, with_camera_error

from xvmatch.datasets.camera_frames import CameraFrames
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.inference.camera_refinement import refine_run_cameras
from xvmatch.inference.cross_view_metrics import count_sequence, summarize
from xvmatch.inference.learned_association import load_matcher_bundle
from xvmatch.inference.tracking import learned_frame_evidence

ARMS = ("none", "given", "refined")


def scored(pairs, truth_top, truth_hor, top, hor):
    """Per-frame counts of row pairs mapped back to the true ids."""
    pred = {f: [(truth_top[a], truth_hor[b]) for a, b in p] for f, p in pairs.items()}
    return count_sequence(pred, top, hor)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", nargs="+", default=["overview", "drone"],
                        choices=("overview", "drone"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 5, 6, 11, 12, 13, 16])
    parser.add_argument("--frames", type=int, default=60, help="frames per video")
    parser.add_argument("--errors", type=float, nargs="+", default=[0, 0.5, 1, 2, 3],
                        metavar="DEG", help="calibration errors, degrees")
    parser.add_argument("--people", type=int, nargs=2, default=[12, 20])
    parser.add_argument("--model", default="default")
    args = parser.parse_args()
    model = load_matcher_bundle(args.model)
    print(f"learned matcher {args.model}, boxes only, frame by frame; {len(args.seeds)} videos "
          f"of {args.frames} frames per scenario, {args.people[0]}-{args.people[1]} people, ids "
          "scrambled per view")
    for scenario in args.scenario:
        counts = {(d, arm): [] for d in args.errors for arm in ARMS}
        timing = {"refine": 0.0, "associate": 0.0}
        for seed in args.seeds:
            video = render_tracking_video(seed, args.frames, SynthConfig(
                scenario=scenario, n_people=tuple(args.people), fps=25.0))
            det_top, truth_top = as_detections(video.top, seed * 2 + 1)
            det_hor, truth_hor = as_detections(video.hor, seed * 2 + 2)
            frames = sorted(video.hor)

            def run(cameras, det_top=det_top, det_hor=det_hor, video=video):
                ev = learned_frame_evidence(det_top, det_hor, video.hor_size, model,
                                            cameras=cameras)
                return ev.frame_pairs

            none = scored(run(None), truth_top, truth_hor, video.top, video.hor)
            for d in args.errors:
                given = CameraFrames("rendered", per_frame=with_camera_error(
                    video.cameras, d, seed) if d else video.cameras)
                start = time.perf_counter()
                refined, what = refine_run_cameras(given, det_top, det_hor, frames)
                timing["refine"] += time.perf_counter() - start
                start = time.perf_counter()
                rows = {"none": none,
                        "given": scored(run(given), truth_top, truth_hor, video.top, video.hor)}
                timing["associate"] += time.perf_counter() - start
                rows["refined"] = (rows["given"] if refined is given else scored(
                    run(refined), truth_top, truth_hor, video.top, video.hor))
                for arm in ARMS:
                    counts[(d, arm)] += rows[arm]
                true_top = video.cameras[frames[0]].top
                left = np.degrees(Rotation.from_matrix(
                    refined.get(frames[0]).top.R @ true_top.R.T).magnitude())
                turn = what.fit.angle_deg if what.turned else 0.0
                print(f"{scenario} seed {seed:3d} error {d:g}: turned {turn:.2f} deg, "
                      f"{left:.2f} from the true camera; Eq. 9 "
                      + " ".join(f"{arm} {summarize(rows[arm]).acc9:.1f}" for arm in ARMS),
                      flush=True)
        print(f"\n{scenario}: mean over {len(args.seeds)} videos, Eq. 9 accuracy / CVIDF1")
        print(f"{'error (deg)':>11} " + " ".join(f"{arm:>13}" for arm in ARMS))
        for d in args.errors:
            cells = [summarize(counts[(d, arm)]) for arm in ARMS]
            print(f"{d:>11g} " + " ".join(f"{c.acc9:6.1f} /{c.cvidf1:5.1f}" for c in cells))
        print(f"refinement {timing['refine']:.1f} s in all, "
              f"{timing['refine'] / max(timing['associate'], 1e-9):.2f}x the time of the "
              "association with the given cameras\n", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
