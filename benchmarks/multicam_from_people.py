"""``xvmatch multicam`` without a calibration file (issue 68, item 2): the cameras calibrated and
registered from their people (:mod:`xvmatch.inference.views.multicam_from_people`) against the
true cameras, on rendered multi-camera box scenes, per-camera ids as a tracker gives them.

Per scene and condition (``gt``: the true boxes; ``tracker``: box jitter, misses, false boxes,
id switches and fragments, as ``benchmarks/multicam_eval.py``), the association's trajectory
precision and recall and its box-pair F1 with the true cameras and with the estimated ones
(whole tracks and the default), whether the estimate refused, and its time.

    .venv/bin/python benchmarks/multicam_from_people.py --seeds 4
"""

from __future__ import annotations

import argparse
import sys
import time

from multicam_eval import CONDITIONS  # the same tracker noise

from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    add_tracker_noise,
    simulate_multicam_scene,
)
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views import multicam_from_people
from xvmatch.inference.views.multicam import MulticamOptions
from xvmatch.inference.views.multicam_from_people import RegistrationError, estimate_cameras
from xvmatch.inference.views.multicam_run import MulticamRunOptions, run_multicam
from xvmatch.metrics.multicam_metrics import multicam_scores


def _scores(cameras, scene, options: MulticamOptions) -> tuple[float, float, float]:
    run = run_multicam(cameras, scene.boxes,
                       MulticamRunOptions(association=options, above_horizon="drop"),
                       warn=lambda _line: None)
    s = multicam_scores(run.relabelled, scene.gt)
    return s["P"], s["R"], s["box_pairs"]["F1"]


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--cameras", type=int, default=4)
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--people", type=int, default=12)
    p.add_argument("--conditions", nargs="+", default=["gt", "tracker"],
                   choices=sorted(CONDITIONS))
    p.add_argument("--keep-short-tracks", action="store_true",
                   help="let every track take part in the estimate (before short tracks were "
                   "left out)")
    args = p.parse_args(argv)
    if args.keep_short_tracks:
        multicam_from_people._MIN_TRACK_BOXES = 0
    methods = {"default": MulticamOptions(), "whole tracks": MulticamOptions(split_frames=0)}
    print("| condition | seed | cameras | estimate (s) | " + " | ".join(
        f"{m} P/R/F1" for m in methods) + " |")
    print("|---|---|---|---|" + "---|" * len(methods))
    for condition in args.conditions:
        for seed in range(args.seeds):
            scene = simulate_multicam_scene(
                MulticamConfig(n_cameras=args.cameras, n_people=(args.people, args.people)),
                args.frames, seed)
            if CONDITIONS[condition] is not None:
                scene = add_tracker_noise(scene, CONDITIONS[condition], seed)
            true = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
            sizes = {n: (c.width, c.height) for n, c in scene.cameras.items()}
            start = time.perf_counter()
            try:
                estimated = estimate_cameras(scene.boxes, sizes).cameras
            except RegistrationError as exc:
                estimated, refused = None, str(exc)
            seconds = time.perf_counter() - start
            for label, cams in (("true", true), ("from people", estimated)):
                if cams is None:
                    print(f"| {condition} | {seed} | {label} | {seconds:.0f} | refused: "
                          f"{refused[:90]} |", flush=True)
                    continue
                cells = [_scores(cams, scene, m) for m in methods.values()]
                print(f"| {condition} | {seed} | {label} | "
                      f"{seconds if label != 'true' else 0:.0f} | "
                      + " | ".join(f"{a:.3f}/{b:.3f}/{c:.3f}" for a, b, c in cells) + " |",
                      flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
