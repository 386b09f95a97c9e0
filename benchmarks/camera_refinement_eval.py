"""The learned matcher with a top camera calibrated with an error: as given, refined, and none.

For each scenario and seed, renders a video (:func:`xvmatch.datasets.tracking_video.
render_tracking_video`, 25 fps, ``--people`` 12 to 20), scrambles the ids per view, and for each
calibration error D of ``--errors`` gives the learned matcher (``--model``, boxes only, frame by
frame: what ``associate --model M --cameras`` does) the cameras turned D degrees about a random
axis and moved D / 10 m (:func:`tracking_eval.with_camera_error`: the top camera once for the
video, the egocentric one anew every frame), then the same cameras with the top one refined on
the video's boxes (:func:`xvmatch.inference.matching.camera_refinement.refine_run_cameras`, what
``--refine-top-camera auto`` does), and scores both against no cameras at all; "checked" is
what ``--camera-check on`` (the default) then does: the refined cameras, or none when the camera
check (:func:`xvmatch.inference.matching.camera_check.check_run_cameras`) leaves them out (it judges
only videos of 150 frames or more: ``--frames 160``). Prints each video's line (the turn found,
how far the refined top camera still is from the true one, the check's share of pseudo-matches
kept, the Eq. 9 accuracy of each) and the means per scenario and error: Eq. 9 accuracy and
CVIDF1 of every frame, and the refinement's time against the association's in the same run.

With ``--moved``, the errors are metres instead: the top camera's centre moved that far in a
random direction (the same for every error of a seed), its orientation and the egocentric
cameras exact (what a drone's satellite positioning gets wrong).

With ``--multi-ego N`` (2 or 3), ``xvmatch associate-multi`` instead: rendered drone videos of
N egocentric views (:func:`xvmatch.datasets.multi_ego_scenes.render_multi_ego`, written as the
command's input files), every view's camera folder holding the top camera turned D degrees
(the egocentric cameras exact), run with no cameras, the cameras as given
(``--refine-top-camera off``) and refined (the default; the camera check does not judge videos
this short); prints each video's line and the mean F1 of the top-egocentric pairs.

Usage:
    python benchmarks/camera_refinement_eval.py [--scenario overview drone] [--frames 60]
        [--seeds 1 2 5 6 11 12 13 16] [--errors 0 0.5 1 2 3] [--people 12 20] [--model default]
    python benchmarks/camera_refinement_eval.py --moved --errors 0.5 1 2 4 8
    python benchmarks/camera_refinement_eval.py --multi-ego 2 --frames 40 --seeds 1 2 3
        --errors 2 3
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

sys.path.insert(0, str(Path(__file__).resolve().parent))

from tracking_eval import ERROR_VIEWS, as_detections, with_camera_error

from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.inference.matching.camera_check import DOUBT_LOSS, check_run_cameras
from xvmatch.inference.matching.camera_refinement import refine_run_cameras
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.inference.tracks.tracking import learned_frame_evidence
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize

ARMS = ("none", "given", "refined")
CHECKED_ARMS = (*ARMS, "checked")


def scored(pairs, truth_top, truth_hor, top, hor):
    """Per-frame counts of row pairs mapped back to the true ids."""
    pred = {f: [(truth_top[a], truth_hor[b]) for a, b in p] for f, p in pairs.items()}
    return count_sequence(pred, top, hor)


def _rows(path: Path) -> list[tuple[int, int]]:
    """(frame, id) of each row of a MOT file, in order."""
    return [(int(r[0]), int(float(r[1]))) for r in
            (line.split(",") for line in path.read_text().splitlines())]


def with_moved_top(cameras: dict, metres: float, seed: int) -> dict:
    """``{frame: FrameCameras}`` with the top camera's centre moved ``metres`` in a random
    direction drawn from ``seed`` (``--moved``)."""
    from xvmatch.geometry.camera import FrameCameras

    step = np.random.default_rng([seed, 7]).normal(size=3)
    top = cameras[min(cameras)].top
    moved = replace(top, c=top.c + metres * step / np.linalg.norm(step))
    return {f: FrameCameras(moved, c.hor) for f, c in cameras.items()}


def multi_pair_counts(inputs, out: Path) -> tuple[int, int, int]:
    """(right, wrong, missed) top-egocentric pairs of ``associate-multi``'s output folder
    ``out`` (its rows are the input rows in order; the input ids, the renders' people, score
    only)."""
    def by_frame(view: str, given: Path) -> dict[int, list[tuple[int, int]]]:
        """``{frame: [(input id, output id)]}`` of one view, the rows in order."""
        rows: dict[int, list[tuple[int, int]]] = {}
        for (f, t), (_, p) in zip(_rows(given), _rows(out / view), strict=True):
            rows.setdefault(f, []).append((t, p))
        return rows

    top = by_frame("top.txt", inputs.boxes[0])
    right = wrong = true = 0
    for k in range(1, len(inputs.boxes)):
        for f, hor in sorted(by_frame(f"hor{k}.txt", inputs.boxes[k]).items()):
            person = {p: t for t, p in top.get(f, [])}
            true += len(set(person.values()) & {t for t, _ in hor})
            found = [person[p] == t for t, p in hor if p in person]
            right, wrong = right + sum(found), wrong + len(found) - sum(found)
    return right, wrong, true - right


def multi_ego_main(args: argparse.Namespace) -> int:
    """The ``--multi-ego N`` mode (module docstring)."""
    import tempfile

    from xvmatch.cli import main as cli
    from xvmatch.datasets.multi_ego_scenes import (
        multi_ego_config,
        render_multi_ego,
        write_multi_ego_inputs,
    )
    from xvmatch.formats.camera_io import save_cameras
    from xvmatch.geometry.top_camera_refinement import turned_camera

    print(f"associate-multi --model {args.model}, {args.multi_ego} egocentric views, drone "
          f"videos of {args.frames} frames, the top camera turned; F1 of the top-egocentric "
          "pairs, %")
    f1 = {(d, arm): [] for d in args.errors for arm in ARMS}
    for seed in args.seeds:
        frames = render_multi_ego([seed, 0], n_ego=args.multi_ego, n_frames=args.frames,
                                  config=multi_ego_config(args.multi_ego, fps=25.0))
        axis = np.random.default_rng(seed).normal(size=3)
        with tempfile.TemporaryDirectory() as tmp:
            folder = Path(tmp)
            inputs = write_multi_ego_inputs(frames, folder / "in", seed)
            size = "x".join(map(str, frames[0].views[1].camera.image_size))
            base = ["associate-multi", "--top", str(inputs.boxes[0]), "--hor",
                    *map(str, inputs.boxes[1:]), "--model", args.model, "--image-size", size,
                    "--quiet"]

            def score(name: str, *extra: str, base=base, folder=folder, inputs=inputs,
                      seed=seed) -> float:
                if cli([*base, "--out", str(folder / name), *extra]) != 0:
                    raise SystemExit(f"associate-multi failed on seed {seed}")
                right, wrong, missed = multi_pair_counts(inputs, folder / name)
                return 100.0 * 2 * right / max(2 * right + wrong + missed, 1)

            none = score("none")
            for d in args.errors:
                turned = turned_camera(frames[0].views[0].camera,
                                       d * axis / np.linalg.norm(axis))
                cams = []
                for v in range(1, args.multi_ego + 1):
                    cam_folder = folder / f"cams_{d:g}_{v}"
                    cam_folder.mkdir()
                    for f in frames:
                        save_cameras(cam_folder / f"{f.frame:06d}.json",
                                     {"top": turned, "ego": f.views[v].camera})
                    cams.append(str(cam_folder))
                row = {"none": none,
                       "given": score(f"given_{d:g}", "--cameras", *cams,
                                      "--refine-top-camera", "off"),
                       "refined": score(f"refined_{d:g}", "--cameras", *cams)}
                for arm in ARMS:
                    f1[(d, arm)].append(row[arm])
                print(f"seed {seed:3d} error {d:g}: " + " ".join(
                    f"{arm} {row[arm]:.1f}" for arm in ARMS), flush=True)
    print(f"\nmean over {len(args.seeds)} videos, F1 of the top-egocentric pairs")
    print(f"{'error (deg)':>11} " + " ".join(f"{arm:>8}" for arm in ARMS))
    for d in args.errors:
        print(f"{d:>11g} " + " ".join(f"{np.mean(f1[(d, arm)]):8.1f}" for arm in ARMS))
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", nargs="+", default=["overview", "drone"],
                        choices=("overview", "drone"))
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 5, 6, 11, 12, 13, 16])
    parser.add_argument("--frames", type=int, default=60, help="frames per video")
    parser.add_argument("--errors", type=float, nargs="+", default=[0, 0.5, 1, 2, 3],
                        metavar="DEG", help="calibration errors, degrees")
    parser.add_argument("--error-on", choices=tuple(ERROR_VIEWS), default="both",
                        help="the cameras given with the error (default both)")
    parser.add_argument("--moved", action="store_true",
                        help="--errors are metres the top camera's centre is moved (module "
                        "docstring)")
    parser.add_argument("--people", type=int, nargs=2, default=[12, 20])
    parser.add_argument("--model", default="default")
    parser.add_argument("--multi-ego", type=int, choices=(2, 3), default=None, metavar="N",
                        help="associate-multi with N egocentric views instead (module docstring)")
    args = parser.parse_args()
    if args.multi_ego:
        return multi_ego_main(args)
    model = load_matcher_bundle(args.model)
    print(f"learned matcher {args.model}, boxes only, frame by frame; {len(args.seeds)} videos "
          f"of {args.frames} frames per scenario, {args.people[0]}-{args.people[1]} people, ids "
          "scrambled per view")
    for scenario in args.scenario:
        counts = {(d, arm): [] for d in args.errors for arm in CHECKED_ARMS}
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
                given = CameraFrames("rendered", per_frame=(
                    video.cameras if not d else with_moved_top(video.cameras, d, seed)
                    if args.moved else with_camera_error(video.cameras, d, seed,
                                                         ERROR_VIEWS[args.error_on])))
                start = time.perf_counter()
                refined, what = refine_run_cameras(given, det_top, det_hor, frames)
                timing["refine"] += time.perf_counter() - start
                start = time.perf_counter()
                rows = {"none": none,
                        "given": scored(run(given), truth_top, truth_hor, video.top, video.hor)}
                timing["associate"] += time.perf_counter() - start
                rows["refined"] = (rows["given"] if refined is given else scored(
                    run(refined), truth_top, truth_hor, video.top, video.hor))
                check = check_run_cameras(det_top, det_hor, frames, model, video.hor_size,
                                          refined, float(model.gamma), what.fit_loss)
                rows["checked"] = rows["refined"] if check.trusted else none
                for arm in CHECKED_ARMS:
                    counts[(d, arm)] += rows[arm]
                true_top = video.cameras[frames[0]].top
                left = np.degrees(Rotation.from_matrix(
                    refined.get(frames[0]).top.R @ true_top.R.T).magnitude())
                turn = what.fit.angle_deg if what.turned else 0.0
                loss = ("" if what.fit is None else
                        f" (loss {what.fit.loss_before:.3f} -> {what.fit.loss_after:.3f})")
                verdict = ("not doubted" if not (what.fit_loss or 0.0) > DOUBT_LOSS else
                           "not judged" if not check.judged else
                           "kept" if check.trusted else "left out")
                print(f"{scenario} seed {seed:3d} error {d:g}: turned {turn:.2f} deg{loss}, "
                      f"{left:.2f} from the true camera; check {check.kept}/{check.positives} "
                      f"{verdict}; Eq. 9 "
                      + " ".join(f"{arm} {summarize(rows[arm]).acc9:.1f}"
                                 for arm in CHECKED_ARMS), flush=True)
        print(f"\n{scenario}: mean over {len(args.seeds)} videos, Eq. 9 accuracy / CVIDF1")
        unit = "m" if args.moved else "deg"
        print(f"{f'error ({unit})':>11} " + " ".join(f"{arm:>13}" for arm in CHECKED_ARMS))
        for d in args.errors:
            cells = [summarize(counts[(d, arm)]) for arm in CHECKED_ARMS]
            print(f"{d:>11g} " + " ".join(f"{c.acc9:6.1f} /{c.cvidf1:5.1f}" for c in cells))
        print(f"refinement {timing['refine']:.1f} s in all, "
              f"{timing['refine'] / max(timing['associate'], 1e-9):.2f}x the time of the "
              "association with the given cameras\n", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
