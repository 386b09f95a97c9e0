"""Site adaptation (``xvmatch adapt``) on rendered videos under a strong simulated camera change.

For each seed, one rendered video (:func:`xvmatch.datasets.tracking_video.
render_tracking_video`; ``--scenario`` drone, the default, or overview: a camera on a building;
``--people`` people, ``--frames`` frames at 25 fps, 400 by default);
ids scrambled per view at once (the box files' ids only name boxes; cross-view id equality is
never an input). Each view's images go through ONE fixed simulated camera
(:func:`xvmatch.datasets.camera_shift.camera_shift` with ``per_image=False``, strength
``--strengths``; the top and the horizontal view get different cameras). The adaptation is
fitted on the first ``--adapt-fraction`` of the frames (pairs mined as ``xvmatch adapt`` mines
them: no labels) and every setting is scored on the rest (geometric-priors Eq. 9 accuracy and
CVIDF1, %):

* boxes only; images (unshifted: the renders the network was trained on); images shifted;
  images shifted with the appearance check (``associate``'s default,
  :mod:`xvmatch.inference.matching.appearance_check`: the boxes alone when the cue fails on the test
  part's own box-only pseudo-matches); images shifted + the adaptation (one row per
  ``--calibrations``; ``odds`` is what ``adapt`` writes), and with the check; and the fraction
  of the shift's CVIDF1 loss the adaptation recovers ``(adapted - shifted) / (unshifted -
  shifted)``.

With ``--ceiling`` one more row: the same fit with the ground-truth cross-view pairs of the
embedded frames instead of the pseudo-matches (every person seen in both views; the ids of the
render, for this upper bound only): how much better pseudo-labels could give.

With ``--cameras`` the box-only matcher (the mining, every row's matching and the check) also
gets each frame's calibrated cameras as rendered, as ``adapt --cameras`` and ``associate
--cameras`` would (the camera wearer found from them, not from ids).

With ``--cli`` the first seed's shifted video is also written as box files and image folders,
and the command line is timed: ``xvmatch adapt`` on the adaptation part, then ``associate
--model SITE/`` against ``--model default`` on the test part (the same run, the ratio printed).

Usage:
    python benchmarks/site_adaptation_eval.py [--seeds 1 2 5 6] [--strengths 0 2 3] [--frames 400]
        [--scenario drone|overview] [--people 12 20] [--vector descriptors|features|stages]
        [--ceiling] [--cameras] [--cli] [--work runs/site_adaptation]
"""

from __future__ import annotations

import argparse
import os
import shlex
import subprocess
import sys
import time
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from xvmatch.datasets.camera_shift import camera_shift
from xvmatch.datasets.synthetic_scenes import SCENARIOS, SynthConfig
from xvmatch.datasets.tracking_video import render_tracking_video
from xvmatch.formats.camera_frames import CameraFrames
from xvmatch.formats.mot_boxes import FrameBoxes
from xvmatch.inference.adaptation.adaptation_pairs import (
    MinedPairs,
    MiningConfig,
    embed_frames,
    mine_pairs,
    plan_bursts,
    reference_costs,
)
from xvmatch.inference.adaptation.site_adaptation import (
    CALIBRATIONS,
    VECTORS,
    choose_fit,
    fit_site_adaptation,
)
from xvmatch.inference.matching.learned_association import (
    LearnedMatcher,
    associate_sequence_learned,
    box_only_costs,
    load_matcher_bundle,
)
from xvmatch.inference.matching.site_bundle import (
    adapted_vectors,
    vector_pair_sets,
    vectors_embedder,
)
from xvmatch.metrics.cross_view_metrics import count_sequence, summarize


class _Images:
    """An in-memory image source (``get(frame)``)."""

    def __init__(self, images: dict[int, np.ndarray]) -> None:
        self.images = images

    def get(self, frame: int) -> np.ndarray:
        """The image of ``frame``."""
        return self.images[frame]


def _scrambled(frames: dict[int, FrameBoxes], rng: np.random.Generator):
    """The records with ids relabelled by a random permutation, and the map back."""
    ids = sorted({int(i) for r in frames.values() for i in r.ids})
    new = (rng.permutation(len(ids)) + 1000).tolist()
    forward = dict(zip(ids, new, strict=True))
    back = {v: k for k, v in forward.items()}
    return {f: FrameBoxes(f, np.array([forward[int(i)] for i in r.ids], dtype=np.int64), r.boxes)
            for f, r in frames.items()}, back


def true_pairs(mined: MinedPairs, bursts: Sequence[np.ndarray], truth_top: dict,
               truth_hor: dict) -> MinedPairs:
    """``mined`` with its cross-view pairs replaced by the ground truth's: every top/horizontal
    box pair of an embedded frame, positive when the true ids agree (``truth_top``,
    ``truth_hor``: ``{frame: FrameBoxes}`` with the render's ids, in the mined records' order),
    each in its burst's group."""
    burst_of = {int(f): k for k, b in enumerate(bursts) for f in np.asarray(b).tolist()}
    pos, neg = [], []
    start = {"top": 0, "hor": 0}
    for f in mined.embed_frames.tolist():
        t, h = truth_top[f].ids, truth_hor[f].ids
        a, b = np.repeat(np.arange(len(t)), len(h)), np.tile(np.arange(len(h)), len(t))
        rows = np.stack([start["top"] + a, start["hor"] + b, np.full(a.size, burst_of[f])], 1)
        same = t[a] == h[b]
        pos.append(rows[same])
        neg.append(rows[~same])
        start["top"] += len(t)
        start["hor"] += len(h)
    p, n = (np.concatenate(x).astype(np.int64).reshape(-1, 3) for x in (pos, neg))
    return replace(mined, cross_pos=p[:, :2], cross_pos_group=p[:, 2], cross_neg=n[:, :2],
                   cross_neg_group=n[:, 2])


def _score(pred, top, hor, back_top, back_hor, gt_top, gt_hor, frames) -> tuple[float, float]:
    """Eq. 9 accuracy and CVIDF1 (%) of predictions in scrambled ids against the ground truth."""
    real = {f: [(back_top[a], back_hor[b]) for a, b in p] for f, p in pred.items()}
    s = summarize(count_sequence(real, gt_top, gt_hor, frames))
    return s.acc9, s.cvidf1


def _shifted(images: dict[int, np.ndarray], strength: float, seed: int) -> dict[int, np.ndarray]:
    return {f: camera_shift(im, strength, seed=seed, per_image=False) for f, im in images.items()}


def _video(seed: int, args):
    """The rendered video of ``seed``, its records with ids scrambled per view (and the maps
    back), and the first test frame."""
    video = render_tracking_video(seed, args.frames, SynthConfig(
        scenario=args.scenario, n_people=tuple(args.people), fps=25.0))
    rng = np.random.default_rng([seed, 31])
    top, back_top = _scrambled(video.top, rng)
    hor, back_hor = _scrambled(video.hor, rng)
    frames = sorted(top)
    return video, top, hor, back_top, back_hor, frames[int(args.adapt_fraction * len(frames))]


def run_seed(seed: int, args, matcher: LearnedMatcher, reference) -> list[dict]:
    """Every row of one seed (one per strength)."""
    t0 = time.perf_counter()
    video, top, hor, back_top, back_hor, cut = _video(seed, args)
    frames = sorted(top)
    adapt_frames = [f for f in frames if f < cut and len(top[f].ids) and len(hor[f].ids)]
    test = [f for f in frames if f >= cut]
    config = MiningConfig(shots=args.shots)
    bursts = plan_bursts(adapt_frames, config.burst, config.max_frames)
    cameras = (CameraFrames("the rendered cameras", per_frame=video.cameras) if args.cameras
               else None)
    costs = box_only_costs(top, hor, [int(f) for b in bursts for f in b], matcher,
                           video.hor_size, cameras=cameras)
    mined = mine_pairs(top, hor, bursts, costs, matcher.gamma, config)
    cp = mined.cross_pos
    ids = {v: np.concatenate([r[f].ids for f in mined.embed_frames]) for v, r in
           (("top", video.top), ("hor", video.hor))}
    precision = float((ids["top"][cp[:, 0]] == ids["hor"][cp[:, 1]]).mean()) if len(cp) else 0.0

    truth = true_pairs(mined, bursts, video.top, video.hor) if args.ceiling else None
    embed = vectors_embedder(matcher, args.vectors)

    def run(model, images, check: bool = False):
        checked: list = []
        pred = associate_sequence_learned(
            top, hor, video.hor_size[0], model, hor_height=video.hor_size[1], frames=test,
            top_images=images[0] if images else None, hor_images=images[1] if images else None,
            cameras=cameras, appearance_check=check, checked=checked)
        score = _score(pred, top, hor, back_top, back_hor, video.top, video.hor, test)
        return (*score, checked[0]) if check else score

    base = {"boxes": run(matcher, None),
            "images": run(matcher, (_Images(video.top_images), _Images(video.hor_images)))}
    rows = []
    def fitted(pairs, vectors, cal: str):
        """The fit ``adapt`` keeps on these mined pairs and vectors, and its site matcher."""
        sets = vector_pair_sets(pairs, *vectors, matcher.bundle.manifest.appearance,
                                args.vectors)
        fit = choose_fit({v: fit_site_adaptation(p, calibration=cal, reference=reference)
                          for v, p in sets.items()})
        return fit, LearnedMatcher(replace(matcher.bundle, adaptation=fit.adaptation))

    for strength in args.strengths:
        shifted = (_Images(_shifted(video.top_images, strength, 100 + seed)),
                   _Images(_shifted(video.hor_images, strength, 200 + seed)))
        vectors = (embed_frames(mined.embed_frames, top, shifted[0], embed),
                   embed_frames(mined.embed_frames, hor, shifted[1], embed))
        *checked, check = run(matcher, shifted, check=True)
        row = {"seed": seed, "strength": strength, **base, "shifted": run(matcher, shifted),
               "checked": tuple(checked), "check": check,
               "pseudo": (len(cp), precision)}
        for cal in args.calibrations:
            fit, site = fitted(mined, vectors, cal)
            row["fit"] = fit
            if fit.accepted:
                row[f"adapted {cal}"] = run(site, shifted)
                *adapted_checked, row["adapted check"] = run(site, shifted, check=True)
                row[f"adapted {cal}, checked"] = tuple(adapted_checked)
            else:  # refused: the user keeps the default bundle, with its check
                row[f"adapted {cal}"] = row["shifted"]
                row[f"adapted {cal}, checked"] = row["checked"]
                row["adapted check"] = check
        if truth is not None:  # the upper bound: the same fit on the true pairs
            fit, site = fitted(truth, vectors, args.calibrations[0])
            row["true pairs"] = run(site, shifted) if fit.accepted else row["shifted"]
        row["seconds"] = time.perf_counter() - t0
        rows.append(row)
    return rows


def _print_rows(rows: list[dict], calibrations: list[str]) -> None:
    settings = ["boxes", "images", "shifted", "checked",
                *(f"adapted {c}" for c in calibrations), f"adapted {calibrations[0]}, checked",
                *(["true pairs"] if "true pairs" in rows[0] else [])]
    print("\nEq. 9 accuracy / CVIDF1 (%) on the test part; checked: with the appearance check "
          "(associate's default), which falls back to the boxes when the cue fails on the test "
          "part's own pseudo-matches; recovered = (adapted - shifted) / (images - shifted), "
          "CVIDF1")
    print("seed strength | " + " | ".join(settings) + " | recovered | pseudo pairs (precision) "
          "| held-out AUC before -> after (rank) | check AUC, default / adapted")
    for r in rows:
        cells = " | ".join(f"{r[s][0]:.1f} / {r[s][1]:.1f}" for s in settings)
        lost = r["images"][1] - r["shifted"][1]
        rec = ((r[f"adapted {calibrations[0]}"][1] - r["shifted"][1]) / lost
               if abs(lost) > 1e-9 else float("nan"))
        fit = r["fit"]
        print(f"{r['seed']} {r['strength']:g} | {cells} | {rec:.2f} | {r['pseudo'][0]} "
              f"({100 * r['pseudo'][1]:.1f}%) | {fit.auc_before:.3f} -> {fit.auc_after:.3f} "
              f"({fit.adaptation.rank if fit.accepted else 'refused'}"
              f"{', ' + fit.adaptation.vector if fit.accepted else ''}) | "
              f"{_check(r['check'])} / {_check(r['adapted check'])}")
    for strength in sorted({r["strength"] for r in rows}):
        sub = [r for r in rows if r["strength"] == strength]
        means = {s: np.mean([r[s] for r in sub], axis=0) for s in settings}
        lost = means["images"][1] - means["shifted"][1]
        named = {c: f"adapted {c}" for c in calibrations}
        if "true pairs" in means:
            named["true pairs"] = "true pairs"
        rec = ", ".join(f"{name} {(means[k][1] - means['shifted'][1]) / lost:.2f}"
                        for name, k in named.items()) if abs(lost) > 1e-9 else "n/a"
        print(f"mean, strength {strength:g} ({len(sub)} seeds) | " + " | ".join(
            f"{s} {means[s][0]:.1f} / {means[s][1]:.1f}" for s in settings)
              + f" | recovered: {rec}")


def _check(check) -> str:
    """An appearance check in a few characters: its AUC, and boxes when it failed (not judged:
    too few pairs, or the box-only matcher's consistency when below the bar)."""
    if not check.judged:
        return f"not judged{f' (consistency {check.consistency:.2f})' if check.unsteady else ''}"
    return f"{check.auc:.3f}{'' if check.trusted else ' (boxes)'}"


def _timed(cmd: list[str]) -> float:
    print("$ " + shlex.join(cmd))
    t = time.perf_counter()
    done = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t
    if done.returncode != 0:
        raise SystemExit(f"command failed ({done.returncode}): {done.stderr.strip()[-400:]}")
    return seconds


def cli_timing(args) -> None:
    """Write the first seed's shifted video and time ``adapt`` and ``associate``."""
    import cv2

    from xvmatch.formats.mot_boxes import write_mot_boxes

    seed, strength = args.seeds[0], args.strengths[-1]
    video, top, hor, _, _, cut = _video(seed, args)
    frames = sorted(top)
    work = Path(args.work) / f"cli_{args.scenario}_seed{seed}_s{strength:g}"
    work.mkdir(parents=True, exist_ok=True)
    paths = {}
    for part, keep in (("adapt", lambda f: f < cut), ("test", lambda f: f >= cut)):
        for view, recs, images, vseed in (("top", top, video.top_images, 100 + seed),
                                          ("hor", hor, video.hor_images, 200 + seed)):
            folder = work / f"{part}_{view}"
            folder.mkdir(exist_ok=True)
            for f in frames:
                if keep(f):
                    image = camera_shift(images[f], strength, seed=vseed, per_image=False)
                    cv2.imwrite(str(folder / f"{f:06d}.png"), image)
            paths[(part, view)] = work / f"{part}_{view}.txt"
            write_mot_boxes(paths[(part, view)], {f: r for f, r in recs.items() if keep(f)})
    exe = str(Path(sys.executable).parent / "xvmatch")
    site = work / "site"
    adapt = [exe, "adapt", "--top", str(paths[("adapt", "top")]),
             "--hor", str(paths[("adapt", "hor")]), "--top-images", str(work / "adapt_top"),
             "--hor-images", str(work / "adapt_hor"), "--out", str(site), "--quiet"]
    t_adapt = _timed(adapt)
    print(f"adapt: {t_adapt:.1f} s for {sum(1 for f in frames if f < cut)} frames")
    times = {}
    for name in ("default", str(site), "default", str(site)):
        cmd = [exe, "associate", "--model", name, "--top", str(paths[("test", "top")]),
               "--hor", str(paths[("test", "hor")]), "--top-images", str(work / "test_top"),
               "--hor-images", str(work / "test_hor"), "--out", str(work / "pred.csv"),
               "--quiet"]
        times.setdefault(name, []).append(_timed(cmd))
    d, s = min(times["default"]), min(times[str(site)])
    print(f"associate --model default {d:.2f} s, --model SITE/ {s:.2f} s (best of 2): "
          f"ratio SITE/default {s / d:.3f}")


def main() -> int:
    """Run the benchmark (see the module docstring)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 5, 6])
    parser.add_argument("--strengths", type=float, nargs="+", default=[0.0, 2.0, 3.0])
    parser.add_argument("--frames", type=int, default=400)
    parser.add_argument("--scenario", choices=SCENARIOS, default="drone",
                        help="the rendered scene: a drone above or a camera on a building")
    parser.add_argument("--people", type=int, nargs=2, default=[12, 20])
    parser.add_argument("--adapt-fraction", type=float, default=0.6)
    parser.add_argument("--calibrations", nargs="+", default=["odds"], choices=CALIBRATIONS)
    parser.add_argument("--model", default="default")
    parser.add_argument("--shots", type=int, default=MiningConfig().shots,
                        help="frames embedded per burst")
    parser.add_argument("--vector", choices=VECTORS, default=None,
                        help="what the adaptation maps (default: as xvmatch adapt, both the "
                             "network's stages (else features) and its descriptors when it gives "
                             "them, the better on the held-out pairs kept)")
    parser.add_argument("--ceiling", action="store_true",
                        help="also fit on the true cross-view pairs of the embedded frames (the "
                        "render's ids): the upper bound of better pseudo-labels")
    parser.add_argument("--cameras", action="store_true",
                        help="give the box-only matcher each frame's rendered cameras")
    parser.add_argument("--cli", action="store_true", help="also time the command line")
    parser.add_argument("--work", default="runs/site_adaptation")
    args = parser.parse_args()
    if args.cli and args.cameras:
        parser.error("--cli times the commands without cameras: leave out --cameras")
    print("$ python " + shlex.join(sys.argv))
    t0 = time.perf_counter()
    matcher = load_matcher_bundle(args.model)
    args.vectors = ((args.vector,) if args.vector else
                    adapted_vectors(matcher.bundle.manifest.appearance))
    print(f"adapting the network's {' or '.join(args.vectors)}")
    reference = reference_costs(matcher.descriptors)
    rows = []
    for seed in args.seeds:
        rows += run_seed(seed, args, matcher, reference)
        print(f"seed {seed}: {rows[-1]['seconds']:.0f} s", file=sys.stderr)
    _print_rows(rows, args.calibrations)
    if args.cli:
        cli_timing(args)
    print(f"wall time {time.perf_counter() - t0:.0f} s ({os.cpu_count()} CPUs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
