"""Fit a bundle's frame check (issue 31) on the deployed benchmark's validation renders.

For single image pairs and short clips, ``associate`` cannot judge the appearance cue over time;
the frame check (:mod:`xvmatch.inference.matching.frame_check`) judges each frame from the
statistics of its appearance costs against the box-only matcher's, and matches the frames whose
images look more likely to hurt than to help from the boxes alone. This fits it for one bundle: the
validation renders of ``benchmarks/deployed_matcher_eval.py`` (seed 2000, ``--scenes`` per
scenario, both scenarios), each image through its own simulated camera at every strength of
``--shifts`` (0: none), ground-truth and detector-noise boxes; each frame is weighted by what the
images gained or lost there (Eq. 9 accuracy with images minus boxes only). The threshold is
chosen by two-fold cross-validation over scenes (:mod:`xvmatch.evaluation.frame_check_threshold`:
the lowest whose worst held-out cell is not below boxes only; ``--threshold`` a number to set
it). It prints, per scenario and strength, images minus boxes before and after the check on
those (fitting) frames;
judge it on the test split with ``benchmarks/matcher_comparison.py``, whose ``checked`` column
applies the bundle's frame check. ``--out`` writes the manifest record (JSON); ``--install``
writes it into the bundle's ``manifest.json`` (the only file changed; the bundle's files and
their sha256 stay as they are).

Usage:
    python benchmarks/fit_frame_check.py [--bundle default] [--scenes 150] [--shifts 0 1 2 3]
        [--threshold auto] [--work runs/deployed_eval] [--out record.json] [--install]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import numpy as np
from deployed_matcher_eval import SIZES, ShiftedCoster, check_scenes_and_shifts, render

from xvmatch.commands._types import float_in
from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Input, Output, check_script_outputs
from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.evaluation.deployed_matcher_eval import (
    OnnxAppearanceCoster,
    frame_check_samples,
)
from xvmatch.evaluation.frame_check_threshold import (
    THRESHOLDS,
    choose_threshold,
    cross_validate_thresholds,
)
from xvmatch.inference.matching.bundle import MANIFEST, read_manifest
from xvmatch.inference.matching.frame_check import fit_frame_check
from xvmatch.inference.matching.learned_association import load_matcher_bundle


def _threshold(text: str) -> str | float:
    """``--threshold``: ``auto`` or a probability in (0, 1)."""
    return "auto" if text == "auto" else float_in(0, 1, "or auto", low_open=True,
                                                   high_open=True)(text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bundle", default="default", help="a bundle with an appearance "
                        "network (default: the shipped one)")
    parser.add_argument("--scenes", type=int, default=150, help="validation scenes per "
                        "scenario, 5 frames each (default 150)")
    parser.add_argument("--shifts", nargs="+", type=float, default=[0.0, 1.0, 2.0, 3.0],
                        help="camera-shift strengths, each in [0, 3] (0: none)")
    parser.add_argument("--threshold", default="auto", type=_threshold,
                        help="probability that images help above which they are used, in "
                        "(0, 1), or auto (default): the lowest of "
                        f"{' '.join(map(str, THRESHOLDS))} whose worst cell, cross-validated "
                        "over scenes, is not below boxes only")
    parser.add_argument("--ridge", type=float, default=1.0, help="L2 penalty, >= 0")
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--out", type=Path, default=None, help="write the record here (JSON)")
    parser.add_argument("--install", action="store_true",
                        help="write the record into the bundle's manifest.json")
    args = parser.parse_args()
    check_scenes_and_shifts(parser, args.scenes, args.shifts)
    threshold = None if args.threshold == "auto" else args.threshold  # auto: cross-validated
    if not args.ridge >= 0:
        parser.error(f"--ridge: expected a number >= 0, got {args.ridge:g}")
    check_script_outputs(parser, [Output("--out", args.out)], [Input("--bundle", args.bundle)])
    try:
        matcher = load_matcher_bundle(args.bundle)
    except (OSError, ValueError) as exc:
        parser.error(f"--bundle: {exc}")
    if matcher.bundle.manifest.appearance is None:
        parser.error(f"--bundle: {args.bundle}: this bundle has no appearance network")
    if matcher.bundle.manifest.adaptation is not None:
        parser.error(f"--bundle: {args.bundle}: a site bundle; the frame check is not used "
                     "with an adapted cue")
    start = time.perf_counter()
    parts = []
    for scenario in sorted(SIZES):
        path = render(args.work, scenario, "val", args.workers, args.scenes)
        for strength in args.shifts:
            coster = OnnxAppearanceCoster(matcher)
            if strength:
                coster = ShiftedCoster(coster, strength)
            trials = dataset_trials(path, TrialConfig(), SETTINGS, coster)
            samples = frame_check_samples(matcher, trials)
            parts.append((scenario, strength, samples))
            print(f"{scenario}, strength {strength:g}: {len(samples.gains)} frames, images - "
                  f"boxes {100 * samples.gains.mean():+.2f} points "
                  f"({time.perf_counter() - start:.0f} s)", flush=True)
    feats = np.concatenate([p[2].features for p in parts])
    gains = np.concatenate([p[2].gains for p in parts])
    choice = None
    if threshold is None:
        try:
            scores = cross_validate_thresholds([p[2] for p in parts], THRESHOLDS, args.ridge)
        except ValueError as exc:
            parser.error(f"--threshold auto: {exc} (give more --scenes, or a number)")
        print("\nThresholds, cross-validated over scenes (2 folds), images - boxes on the held-out"
              " scenes (points): worst cell, all cells summed")
        for s in scores:
            print(f"  {s.threshold:.2f}: worst {s.worst:+.2f}  summed {s.total:+.2f}")
        threshold = choose_threshold(scores).threshold
        print(f"  chosen: {threshold:.2f}")
        choice = {"rule": "lowest threshold whose worst held-out cell is >= 0 points "
                          "(2 folds of scenes)",
                  "scores": [[s.threshold, round(s.worst, 3), round(s.total, 3)]
                             for s in scores]}
    fitted = {"data": "deployed benchmark validation renders (seed 2000), "
                      f"{args.scenes} scenes x 5 frames per scenario, both scenarios",
              "shifts": [float(s) for s in args.shifts], "box_settings": list(SETTINGS),
              "frames": len(gains), "ridge": float(args.ridge),
              "command": "python benchmarks/fit_frame_check.py " + " ".join(sys.argv[1:])}
    if choice is not None:
        fitted["threshold_choice"] = choice
    check = fit_frame_check(feats, gains, threshold, args.ridge, fitted)
    print("\nOn the fitting frames, images - boxes (points), without and with the check; "
          "share of frames with images:")
    for scenario, strength, samples in parts:
        use, g = check.trusted(samples.features), samples.gains
        print(f"  {scenario:<8} strength {strength:g}: {100 * g.mean():+.2f} -> "
              f"{100 * np.where(use, g, 0.0).mean():+.2f}  ({use.mean():.2f})")
    record = check.to_record()
    if args.out:
        atomic_write_text(args.out, json.dumps(record, indent=2) + "\n")
    if args.install:
        folder = matcher.bundle.manifest.folder
        doc = json.loads((folder / MANIFEST).read_text(encoding="utf-8"))
        doc["frame_check"] = record
        atomic_write_text(folder / MANIFEST, json.dumps(doc, indent=2) + "\n")
        read_manifest(folder)  # the written manifest reads back
        print(f"installed in {folder / MANIFEST}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
