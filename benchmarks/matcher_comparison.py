"""Matcher bundles side by side on the same camera-shifted scenes, with paired intervals.

The question of issue 31 is whether images ever make a matcher worse than boxes only, and
whether a candidate matcher is better than the shipped one; on 100 frames of 20 scenes a cell
moves by about +-2 points, so a point value alone cannot answer either. For each scenario, shift
strength and box setting (ground truth, detector noise), this prints each bundle's Eq. 9
accuracy with images and with boxes only, images - boxes, and each bundle minus the first (with
images and with boxes only), all in points with a 95% interval from resampling whole scenes
(:func:`xvmatch.metrics.confidence.grouped_difference_interval`; the differences are paired:
the same frames, the same boxes, the same shifted images). ``cue AUC`` is how well each
network's appearance cost alone tells a true pair from the other people of its frame
(:func:`xvmatch.evaluation.deployed_matcher_eval.cue_auc`; 0.5: not at all), whatever the matcher
makes of it. ``checked`` (bundles with a frame check,
:mod:`xvmatch.inference.matching.frame_check`): the images where the check trusts a frame's cue and
the boxes alone elsewhere, as ``associate`` matches single image pairs, with its differences from
boxes only and from the images.

Scenes: the deployed benchmark's renders (``benchmarks/deployed_matcher_eval.py``; test seed
1000 or validation seed 2000 with ``--split val``; ``--scenes N`` per scenario, the first 20
being the usual ones), rendered into ``--work`` if missing. Choose between candidates on the
validation split and report on the test split. Appearance costs are computed once per distinct
appearance network (the manifests' sha256), through that bundle's FP32 ONNX file; every bundle
runs with its own gamma.

Usage:
    python benchmarks/matcher_comparison.py --models default CANDIDATE [--split val]
        [--shifts 0 3] [--scenes 60] [--scenarios overview drone] [--work runs/deployed_eval]
        [--workers 2] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from deployed_matcher_eval import (
    ROLES,
    SIZES,
    ShiftedCoster,
    check_scenes_and_shifts,
    frame_accuracies,
    interval,
    render,
    shown,
)

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Input, Output, check_script_outputs
from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.evaluation.deployed_matcher_eval import (
    OnnxAppearanceCoster,
    cue_auc,
    frame_checked_costs,
    matcher_costs,
)
from xvmatch.inference.matching.learned_association import LearnedMatcher, load_matcher_bundle

SETTING_NAMES = {"gt": "ground-truth boxes", "det": "detector noise"}


def compare(models: dict[str, LearnedMatcher], trials: dict[str, list]) -> list[dict]:
    """Per box setting and bundle: accuracies and paired differences on the given trials
    (``trials``: per appearance sha256, built with that network's costs)."""
    acc = {}
    for name, m in models.items():
        own = trials[m.bundle.manifest.appearance.sha256]
        costs = {cue: matcher_costs(m, own, cue) for cue in ("images", "boxes")}
        check = m.bundle.manifest.frame_check if m.bundle.manifest.adaptation is None else None
        if check is not None:
            costs["checked"] = frame_checked_costs(check, own, costs["images"], costs["boxes"])
        for cue, cue_costs in costs.items():
            for setting in SETTINGS:
                acc[name, cue, setting] = frame_accuracies(own, cue_costs, m.gamma, setting)
    first = next(iter(models))
    rows = []
    for setting in SETTINGS:
        for name in models:
            (img, scenes), (box, _) = acc[name, "images", setting], acc[name, "boxes", setting]
            row = {"setting": setting, "model": name, "frames": len(img),
                   "images": 100.0 * float(img.mean()), "boxes": 100.0 * float(box.mean()),
                   "images - boxes": interval(img, box, scenes),
                   "cue AUC": cue_auc(trials[models[name].bundle.manifest.appearance.sha256],
                                      setting)}
            if (name, "checked", setting) in acc:
                checked = acc[name, "checked", setting][0]
                row["checked"] = 100.0 * float(checked.mean())
                row["checked - boxes"] = interval(checked, box, scenes)
                row["checked - images"] = interval(checked, img, scenes)
            if name != first:
                for cue in ("images", "boxes"):
                    ref, ref_scenes = acc[first, cue, setting]
                    if ref_scenes != scenes:  # same trials, same frames: a bug if not
                        raise RuntimeError(f"{name} and {first} were scored on different frames")
                    row[f"{cue} vs {first}"] = interval(acc[name, cue, setting][0], ref, scenes)
            rows.append(row)
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["default"],
                        help="bundles with an appearance network; the first is the reference")
    parser.add_argument("--split", choices=sorted(ROLES), default="test",
                        help="test scenes (seed 1000) or validation scenes (seed 2000)")
    parser.add_argument("--shifts", nargs="+", type=float, default=[0.0, 3.0],
                        help="camera-shift strengths of the images, each in [0, 3] (0: none)")
    parser.add_argument("--scenes", type=int, default=20, help="scenes per scenario, 5 frames "
                        "each (default 20, the deployed benchmark's)")
    parser.add_argument("--scenarios", nargs="+", default=["overview", "drone"],
                        choices=sorted(SIZES))
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()
    check_scenes_and_shifts(parser, args.scenes, args.shifts)
    if len(set(args.models)) != len(args.models):
        parser.error(f"--models: a bundle is named twice: {' '.join(args.models)}")
    check_script_outputs(parser, [Output("--json", args.json)],
                         [Input("--models", name) for name in args.models])
    models = {}
    for name in args.models:
        try:
            models[name] = load_matcher_bundle(name)
        except (OSError, ValueError) as exc:
            parser.error(f"--models: {exc}")
        if models[name].bundle.manifest.appearance is None:
            parser.error(f"--models: {name}: this bundle has no appearance network")
    networks = {m.bundle.manifest.appearance.sha256: m for m in models.values()}
    start = time.perf_counter()
    results = []
    for scenario in args.scenarios:
        path = render(args.work, scenario, args.split, args.workers, args.scenes)
        for strength in args.shifts:
            trials = {}
            for sha, m in networks.items():
                coster = OnnxAppearanceCoster(m)
                if strength:
                    coster = ShiftedCoster(coster, strength)
                trials[sha] = dataset_trials(path, TrialConfig(), SETTINGS, coster)
            rows = compare(models, trials)
            print(f"\n{scenario}, {args.split} scenes ({path.name}), shift strength {strength:g}:"
                  f" Eq. 9 accuracy (%), differences in points with 95% scene-bootstrap "
                  f"intervals")
            width = max(len(n) for n in models)
            for row in rows:
                checked = (f"  checked {row['checked']:.1f}  checked - boxes "
                           f"{shown(row['checked - boxes'])}  checked - images "
                           f"{shown(row['checked - images'])}" if "checked" in row else "")
                vs = "".join(f"  {cue} vs first {shown(row[f'{cue} vs {args.models[0]}'])}"
                             for cue in ("images", "boxes") if row["model"] != args.models[0])
                print(f"{SETTING_NAMES[row['setting']]:<18} {row['model']:<{width}}  "
                      f"images {row['images']:.1f}  boxes {row['boxes']:.1f}  "
                      f"images - boxes {shown(row['images - boxes'])}{checked}{vs}  "
                      f"cue AUC {row['cue AUC']:.3f}")
                results.append({"scenario": scenario, "split": args.split, "shift": strength,
                                "data": str(path), **row})
            print(f"({time.perf_counter() - start:.0f} s so far)", flush=True)
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
