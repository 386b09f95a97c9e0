"""Several static cameras (issue 32): association, linkage and localisation on simulated scenes.

Scenes of ``datasets/multicam_scenes.py`` (20 people on a 24 m floor, 400 frames at 10 frames/s,
2, 4 and 7 static cameras around it; each camera's track ids scrambled on their own, so ids are
never equal across cameras), three seeds each, in three conditions:

* ``gt``: ground-truth boxes and per-camera track ids (a new id whenever a person comes back
  into a camera's view);
* ``noise``: what ``xvmatch noise`` does on every camera (5% box jitter, 10% misses, 0.3 false
  boxes per frame);
* ``tracker``: that and a tracker's id switches (0.02 per frame and camera) and fragments (0.2
  per track);
* ``switches`` (issue 68): ground-truth boxes with 10% of them missed and id switches (0.02 per
  frame and camera: one switch about every 300 frames of a track, measured and reported as
  ``frames per switch``), nothing else.

For each: ``--method ours`` (the default: tracks split on evidence, ``--split-frames auto``),
ours with fixed pieces of 20 frames (``--split-frames 20``), ours with the tracks cut on
evidence however many are cut (no fixed pieces where many are: the evidence split's groups on
their own), ours with whole tracks
(``--split-frames 0``, as the paper) and ``--method dtw`` (paper 004's M1) scored with
``metrics/multicam_metrics.py`` (Eqs. 13-14 P and R averaged over overlapping camera pairs,
box-pair F1, global IDF1, ground error of the fused foot points); ``ours, no calibration``: the
default run without the cameras (issue 68, item 2: each calibrated from its people, registered
to the others; a refused estimate scores 0); and the localisation of paper
003 (two most visible views against all views, principal axes along the vertical against image
columns), with our association's ids and with the true ids (to separate localisation from
association errors). Then the speed case, 7 cameras x 400 frames x 20 people, timed as the
whole ``xvmatch multicam`` command (a fresh process of the base install when ``--xvmatch`` is
given, else this interpreter), both methods and ours without the calibration file in the same
run.

Usage:
    python benchmarks/multicam_eval.py [--seeds 1 2 3] [--cameras 2 4 7] [--out DIR]
        [--xvmatch .venv-base/bin/xvmatch] [--write DIR --write-cameras 4 [--write-noise]]

``--write DIR`` only writes one simulated scene as files (cameras.json, boxes/, gt/,
ground_gt.csv) for trying the command, and exits (``--write-rendered``: rendered, with
images/NAME/ folders).

``--rendered`` (issue 32, item 5): rendered scenes instead (:mod:`xvmatch.datasets.
multicam_render`: the same people and cameras, 640x360 images, each camera its own photometry,
boxes from the rendered pixels, track ids scrambled per camera), 2 and 4 cameras, 200 frames,
``gt``, ``noise`` and ``tracker`` boxes; ``ours`` without and with the images (the deployed
bundle's appearance network, ``--model``, on each camera's JPEG frames read back as ``xvmatch
multicam --images`` reads them). The appearance weight is chosen on ``--tune-seeds`` (mean
global IDF1 over the grid ``--weights``) and reported on ``--seeds``:

    python benchmarks/multicam_eval.py --rendered --seeds 1 2 3 --tune-seeds 101 102
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Output, check_script_outputs
from xvmatch.datasets.detector_noise import DetectorNoise
from xvmatch.datasets.multicam_scenes import (
    MulticamConfig,
    TrackerNoise,
    add_tracker_noise,
    simulate_multicam_scene,
    write_multicam_scene,
)
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.geometry.ground_plane import GroundCamera
from xvmatch.inference.views.multicam import MulticamOptions, associate_cameras, relabel
from xvmatch.inference.views.multicam_localisation import LocalisationOptions, localise
from xvmatch.inference.views.multicam_run import MulticamRunOptions, run_multicam
from xvmatch.metrics.multicam_metrics import match_to_truth, multicam_scores

CONDITIONS = {
    "gt": None,
    "noise": TrackerNoise(DetectorNoise(0.05, 0.10, 0.3), 0.0, 0.0),
    "tracker": TrackerNoise(DetectorNoise(0.05, 0.10, 0.3), 0.02, 0.2),
    "switches": TrackerNoise(DetectorNoise(0.0, 0.10, 0.0), 0.02, 0.0),
}
RENDERED_CONDITIONS = ("gt", "noise", "tracker")
METHODS = {
    "ours": MulticamOptions(),
    "ours, fixed pieces": MulticamOptions(split="fixed"),
    "ours, evidence cuts always": MulticamOptions(evidence_max_cut_share=1.0),
    "ours, whole tracks": MulticamOptions(split_frames=0),
    "dtw": MulticamOptions(method="dtw", split_frames=0),
}
NO_CALIBRATION = "ours, no calibration"
"""The default run without the cameras: each calibrated from its people and registered to the
others (``xvmatch multicam`` without ``--cameras``); its ground is in the estimate's own frame,
so no ground error is given, and a refused estimate scores 0."""
LOCALISERS = {
    "two best views, vertical axes": LocalisationOptions("two_best", "vertical"),
    "all views, vertical axes": LocalisationOptions("all", "vertical"),
    "two best views, image columns": LocalisationOptions("two_best", "column"),
    "all views, image columns": LocalisationOptions("all", "column"),
}


def _scene(n_cameras: int, seed: int, frames: int, people: int, condition: str):
    scene = simulate_multicam_scene(
        MulticamConfig(n_cameras=n_cameras, n_people=(people, people)), frames, seed)
    noise = CONDITIONS[condition]
    return scene if noise is None else add_tracker_noise(scene, noise, seed)


def _truth_ground(scene) -> dict:
    return {k + 1: (np.arange(1, scene.n_frames + 1), scene.positions[:, k])
            for k in range(scene.positions.shape[1])}


def _true_ids(scene) -> dict:
    """Each camera's input boxes with their true global ids (false boxes dropped)."""
    out = {}
    for name, frames in scene.boxes.items():
        truth = match_to_truth(frames, scene.gt[name])
        out[name] = {f: FrameBoxes(f, truth[f][truth[f] >= 0], rec.boxes[truth[f] >= 0])
                     for f, rec in frames.items()}
    return out


def _foot_fusion(cameras, boxes) -> dict:
    """Per true id and frame, the mean of its foot points on the ground over the cameras."""
    from xvmatch.geometry.ground_plane import foot_points

    acc: dict[int, dict[int, list]] = {}
    for name, frames in boxes.items():
        for f, rec in frames.items():
            if not len(rec):
                continue
            xy, ok = cameras[name].to_ground(foot_points(rec.boxes))
            for g, p, good in zip(rec.ids.tolist(), xy, ok, strict=True):
                if good:
                    acc.setdefault(g, {}).setdefault(f, []).append(p)
    out = {}
    for g, per in acc.items():
        fr = np.array(sorted(per))
        out[g] = (fr, np.array([np.mean(per[f], axis=0) for f in fr]))
    return out


def frames_per_switch(scene) -> float:
    """Boxes of the input tracks per change of the true person along one (a tracker's id
    switch or a fragment's new id does not count, only a track that goes on with someone
    else): how often a track switches, in frames; inf without any."""
    boxes = switches = 0
    for name, frames in scene.boxes.items():
        truth = match_to_truth(frames, scene.gt[name])
        last: dict[int, int] = {}
        for f in sorted(frames):
            for t, g in zip(frames[f].ids.tolist(), truth[f].tolist(), strict=True):
                if g < 0:
                    continue
                boxes += 1
                switches += int(t in last and last[t] != g)
                last[t] = g
    return boxes / switches if switches else float("inf")


def evaluate(n_cameras: int, seed: int, frames: int, people: int, condition: str,
             localisation: bool = True) -> dict:
    """Every score of one scene and condition (the localisers' only with ``localisation``)."""
    scene = _scene(n_cameras, seed, frames, people, condition)
    cams = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
    truth = _truth_ground(scene)
    row = {"cameras": n_cameras, "seed": seed, "condition": condition,
           "frames_per_switch": frames_per_switch(scene)}
    for method, options in METHODS.items():
        start = time.perf_counter()
        res = associate_cameras(cams, scene.boxes, options)
        seconds = time.perf_counter() - start
        rl = relabel(scene.boxes, res)
        s = multicam_scores(rl, scene.gt, res.ground, truth)
        row[method] = _row(s, seconds, s["ground"]["median"])
        if method == "ours":
            ours_rl, ours_res = rl, res
    row[NO_CALIBRATION] = _without_cameras(scene)
    if not localisation:
        return row
    loc = {"foot points, fused (association)": row["ours"]["ground_median"]}
    true_rl = _true_ids(scene)
    foot = _foot_fusion(cams, true_rl)
    oracle = {"foot points, fused": _median_error(foot, truth)}
    for label, opts in LOCALISERS.items():
        est = localise(cams, ours_rl, ours_res.ground, opts)
        loc[label] = multicam_scores(ours_rl, scene.gt, est, truth)["ground"]["median"]
        oracle[label] = _median_error(localise(cams, true_rl, foot, opts), truth)
    row["localisation"] = loc
    row["localisation_true_ids"] = oracle
    return row


def _without_cameras(scene) -> dict:
    """The scores of ``xvmatch multicam``'s run without a calibration file on ``scene``."""
    sizes = {n: (c.width, c.height) for n, c in scene.cameras.items()}
    start = time.perf_counter()
    try:
        run = run_multicam(None, scene.boxes, MulticamRunOptions(
            image_sizes=sizes, above_horizon="drop"), warn=lambda _line: None)
    except ValueError:
        return {"P": 0.0, "R": 0.0, "box_F1": 0.0, "IDF1": 0.0, "ground_median": float("nan"),
                "seconds": time.perf_counter() - start, "pairs": 0, "refused": 1}
    seconds = time.perf_counter() - start
    return {**_row(multicam_scores(run.relabelled, scene.gt), seconds, float("nan")),
            "refused": 0}


def _row(s: dict, seconds: float, ground_median: float) -> dict:
    """One method's cells of a scene's row from its :func:`multicam_scores`."""
    return {"P": s["P"], "R": s["R"], "box_F1": s["box_pairs"]["F1"], "IDF1": s["idf1"]["IDF1"],
            "ground_median": ground_median, "seconds": seconds, "pairs": s["overlapping_pairs"]}


def _median_error(est: dict, truth: dict) -> float:
    errors = []
    for g, (fr, xy) in est.items():
        tf, txy = truth[g]
        _, ia, ib = np.intersect1d(fr, tf, return_indices=True)
        errors.append(np.linalg.norm(xy[ia] - txy[ib], axis=1))
    return float(np.median(np.concatenate(errors)))


def speed_case(xvmatch: str | None, seed: int = 1) -> dict:
    """Wall time of the whole ``xvmatch multicam`` command, 7 cameras x 400 frames x 20
    people, both methods and ours without the calibration file (``--image-size NAME=WxH``
    instead), on files written here."""
    scene = _scene(7, seed, 400, 20, "gt")
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        paths = write_multicam_scene(Path(tmp) / "scene", scene)
        boxes = [f"{n}={paths['boxes'] / (n + '.txt')}" for n in scene.cameras]
        sizes = [f"{n}={c.width}x{c.height}" for n, c in scene.cameras.items()]
        for method in ("ours", "dtw", NO_CALIBRATION):
            given = (["--image-size", *sizes] if method == NO_CALIBRATION else
                     ["--cameras", str(paths["cameras"]), "--method", method])
            args = ["multicam", "--boxes", *boxes, *given,
                    "--out", str(Path(tmp) / f"out_{len(out)}"), "--quiet"]
            before = resource.getrusage(resource.RUSAGE_CHILDREN)
            start = time.perf_counter()
            subprocess.run([xvmatch or sys.executable, *([] if xvmatch else
                                                         ["-m", "xvmatch"]), *args], check=True)
            wall = time.perf_counter() - start
            after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
            out[method] = {"wall": wall, "cpu": cpu}
    return out


def _mean(rows, *keys):
    vals = []
    for r in rows:
        v = r
        for k in keys:
            v = v[k]
        vals.append(v)
    return float(np.mean(vals))


def report(rows: list[dict], speed: dict) -> str:
    """Markdown tables of the means over seeds."""
    lines = ["| cameras | boxes | method | P | R | box-pair F1 | global IDF1 | ground median (m) "
             "| seconds |", "|---|---|---|---|---|---|---|---|---|"]
    switching = [r["frames_per_switch"] for r in rows if np.isfinite(r["frames_per_switch"])]
    keys = sorted({(r["cameras"], r["condition"]) for r in rows},
                  key=lambda k: (k[0], list(CONDITIONS).index(k[1])))
    for cams, cond in keys:
        sel = [r for r in rows if r["cameras"] == cams and r["condition"] == cond]
        for method in (*METHODS, NO_CALIBRATION):
            lines.append(
                f"| {cams} | {cond} | {method} | {_mean(sel, method, 'P'):.3f} | "
                f"{_mean(sel, method, 'R'):.3f} | {_mean(sel, method, 'box_F1'):.3f} | "
                f"{_mean(sel, method, 'IDF1'):.3f} | {_mean(sel, method, 'ground_median'):.3f} "
                f"| {_mean(sel, method, 'seconds'):.2f} |")
    if switching:
        lines += ["", "Frames of a track per id switch (the mean over the scenes that have "
                  f"any): {np.mean(switching):.0f}"]
    if not all("localisation" in r for r in rows):
        return "\n".join(lines + _speed_lines(speed))
    lines += ["", "Localisation, median ground error (m); our association's ids / true ids:",
              "", "| cameras | boxes | " + " | ".join(["foot points, fused", *LOCALISERS])
              + " |", "|---|---|" + "---|" * (1 + len(LOCALISERS))]
    for cams, cond in keys:
        sel = [r for r in rows if r["cameras"] == cams and r["condition"] == cond]
        cells = [f"{_mean(sel, 'localisation', 'foot points, fused (association)'):.3f} / "
                 f"{_mean(sel, 'localisation_true_ids', 'foot points, fused'):.3f}"]
        for label in LOCALISERS:
            cells.append(f"{_mean(sel, 'localisation', label):.3f} / "
                         f"{_mean(sel, 'localisation_true_ids', label):.3f}")
        lines.append(f"| {cams} | {cond} | " + " | ".join(cells) + " |")
    return "\n".join(lines + _speed_lines(speed))


def _speed_lines(speed: dict) -> list[str]:
    if not speed:
        return []
    return ["", "Whole command, 7 cameras x 400 frames x 20 people (fresh process): "
            + ", ".join(f"{m} {t['wall']:.2f} s wall, {t['cpu']:.2f} s CPU"
                        for m, t in speed.items())]


def _embedder(model, path: str, memo: dict):
    """``embed(frame, boxes)`` of one camera's image folder with ``model``'s network, memoised
    on (frame, boxes) so that a sweep embeds each crop once."""
    from xvmatch.formats.frame_sources import open_frames

    source = open_frames(path)
    last: dict = {}

    def embed(frame: int, boxes: np.ndarray) -> np.ndarray:
        key = (path, frame, np.asarray(boxes, dtype=float).tobytes())
        if key not in memo:
            if last.get("frame") != frame:
                last["frame"], last["image"] = frame, source.get(frame)
            memo[key] = model.descriptors(last["image"], boxes)
        return memo[key]

    return embed


def rendered_rows(n_cameras: int, seed: int, frames: int, people: int, model, weights,
                  work: Path) -> list[dict]:
    """Scores of one rendered scene, ``gt`` and ``noise`` boxes, ours without images (weight
    ``None``) and with images at each appearance weight."""
    from dataclasses import replace as dc_replace

    from xvmatch.datasets.render.multicam_render import write_rendered_multicam_scene

    config = MulticamConfig(n_cameras=n_cameras, n_people=(people, people))
    start = time.perf_counter()
    scene, paths = write_rendered_multicam_scene(work / f"r{n_cameras}_{seed}", config,
                                                 frames, seed)
    render_s = time.perf_counter() - start
    cams = {n: GroundCamera.from_camera(c) for n, c in scene.cameras.items()}
    truth = _truth_ground(scene)
    memo: dict = {}
    embed = {n: _embedder(model, str(paths["images"] / n), memo) for n in scene.cameras}
    rows = []
    for condition in RENDERED_CONDITIONS:
        noise = CONDITIONS[condition]
        sc = scene if noise is None else add_tracker_noise(scene, noise, seed)
        for w in [None, *weights]:
            opts = MulticamOptions() if w is None else dc_replace(MulticamOptions(),
                                                                   appearance_weight=w)
            start = time.perf_counter()
            res = associate_cameras(cams, sc.boxes, opts, appearance=None if w is None
                                    else embed)
            seconds = time.perf_counter() - start
            s = multicam_scores(relabel(sc.boxes, res), sc.gt, res.ground, truth)
            rows.append({"cameras": n_cameras, "seed": seed, "condition": condition,
                         "weight": w, "P": s["P"], "R": s["R"],
                         "box_F1": s["box_pairs"]["F1"], "IDF1": s["idf1"]["IDF1"],
                         "seconds": seconds, "render_seconds": render_s})
    return rows


def rendered_main(args) -> int:
    """``--rendered``: tune the appearance weight on the tuning seeds, report on the others."""
    from xvmatch.inference.matching.learned_association import load_matcher_bundle

    start = time.perf_counter()
    model = load_matcher_bundle(args.model)
    if model.bundle.adaptation is not None:
        print(f"{args.model}: a site adaptation is for top/horizontal pairs; multicam uses the "
              "raw descriptors", file=sys.stderr)
    weights = list(args.weights)
    with tempfile.TemporaryDirectory() as tmp:
        tune = [r for cams in args.cameras for seed in args.tune_seeds
                for r in rendered_rows(cams, seed, args.frames, args.people, model, weights,
                                       Path(tmp))]
        score = {w: float(np.mean([r["IDF1"] for r in tune if r["weight"] == w]))
                 for w in weights}
        best = max(weights, key=lambda w: (score[w], -w))
        print("tuning seeds, mean global IDF1 by weight: " + ", ".join(
            f"{w:g}: {score[w]:.4f}" for w in weights) + f"; none: "
            f"{np.mean([r['IDF1'] for r in tune if r['weight'] is None]):.4f}; chosen {best:g}",
            file=sys.stderr)
        test = [r for cams in args.cameras for seed in args.seeds
                for r in rendered_rows(cams, seed, args.frames, args.people, model, [best],
                                       Path(tmp))]
    lines = [f"Rendered scenes, seeds {' '.join(map(str, args.seeds))} (appearance weight "
             f"{best:g}, chosen on seeds {' '.join(map(str, args.tune_seeds))}):", "",
             "| cameras | boxes | images | P | R | box-pair F1 | global IDF1 | seconds |",
             "|---|---|---|---|---|---|---|---|"]
    for cams in args.cameras:
        for cond in RENDERED_CONDITIONS:
            for w, label in ((None, "no"), (best, "yes")):
                sel = [r for r in test if r["cameras"] == cams and r["condition"] == cond
                       and r["weight"] == w]
                lines.append(f"| {cams} | {cond} | {label} | {_mean(sel, 'P'):.3f} | "
                             f"{_mean(sel, 'R'):.3f} | {_mean(sel, 'box_F1'):.3f} | "
                             f"{_mean(sel, 'IDF1'):.3f} | {_mean(sel, 'seconds'):.2f} |")
    renders = {(r["cameras"], r["seed"]): r["render_seconds"] for r in test}
    lines += ["", "Render and write (s), per scene: " + ", ".join(
        f"{c} cameras seed {s}: {t:.1f}" for (c, s), t in sorted(renders.items()))]
    text = "\n".join(lines)
    print(text)
    print(f"\nbenchmark wall time {time.perf_counter() - start:.0f} s")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.out) / "rendered_results.json", json.dumps(
            {"tuning": tune, "test": test, "weights": weights, "chosen": best}, indent=1))
    return 0


def main() -> int:
    """Run the benchmark (or write one scene with ``--write``)."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3])
    p.add_argument("--cameras", type=int, nargs="+", default=[2, 4, 7])
    p.add_argument("--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS))
    p.add_argument("--no-localisation", action="store_true",
                   help="association scores only (skips paper 003's localisers)")
    p.add_argument("--frames", type=int, default=400)
    p.add_argument("--people", type=int, default=20)
    p.add_argument("--out", default=None, help="folder for results.json")
    p.add_argument("--xvmatch", default=None, help="xvmatch executable for the speed case")
    p.add_argument("--no-speed", action="store_true")
    p.add_argument("--write", default=None, metavar="DIR", help="write one scene and exit")
    p.add_argument("--write-cameras", type=int, default=4)
    p.add_argument("--write-noise", action="store_true")
    p.add_argument("--write-rendered", action="store_true")
    p.add_argument("--rendered", action="store_true",
                   help="rendered scenes, ours without and with images (see the docstring)")
    p.add_argument("--tune-seeds", type=int, nargs="+", default=[101, 102])
    p.add_argument("--weights", type=float, nargs="+", default=[0.5, 1.0, 2.0, 4.0, 8.0, 16.0])
    p.add_argument("--model", default="default", help="bundle of the appearance network")
    args = p.parse_args()
    check_script_outputs(p, [Output("--out", args.out, folder=True, files=(
        "rendered_results.json" if args.rendered else "results.json",))])
    if args.rendered:
        if args.cameras == [2, 4, 7]:
            args.cameras = [2, 4]
        if args.frames == 400:
            args.frames = 200
        return rendered_main(args)
    if args.write and args.write_rendered:
        from xvmatch.datasets.render.multicam_render import write_rendered_multicam_scene

        _, paths = write_rendered_multicam_scene(
            args.write, MulticamConfig(n_cameras=args.write_cameras,
                                       n_people=(args.people, args.people)),
            args.frames, args.seeds[0])
        print(json.dumps({k: os.fspath(v) for k, v in paths.items()}, indent=2))
        return 0
    if args.write:
        scene = _scene(args.write_cameras, args.seeds[0], args.frames, args.people,
                       "noise" if args.write_noise else "gt")
        paths = write_multicam_scene(args.write, scene)
        print(json.dumps({k: os.fspath(v) for k, v in paths.items()}, indent=2))
        return 0
    start = time.perf_counter()
    rows = []
    for cams in args.cameras:
        for cond in args.conditions:
            for seed in args.seeds:
                rows.append(evaluate(cams, seed, args.frames, args.people, cond,
                                     not args.no_localisation))
                print(f"{cams} cameras, {cond}, seed {seed}: ours IDF1 "
                      f"{rows[-1]['ours']['IDF1']:.3f}", file=sys.stderr)
    speed = {} if args.no_speed else speed_case(args.xvmatch)
    text = report(rows, speed)
    print(text)
    print(f"\nbenchmark wall time {time.perf_counter() - start:.0f} s")
    if args.out:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        atomic_write_text(Path(args.out) / "results.json",
                          json.dumps({"rows": rows, "speed": speed}, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
