"""Fit a bundle's frame check (issue 31) on the deployed benchmark's validation renders.

For single image pairs and short clips, ``associate`` cannot judge the appearance cue over time;
the frame check (:mod:`xvmatch.inference.frame_check`) judges each frame from the statistics of
its appearance costs against the box-only matcher's, and matches the frames whose images look
more likely to hurt than to help from the boxes alone. This fits it for one bundle: the
validation renders of ``benchmarks/deployed_matcher_eval.py`` (seed 2000, ``--scenes`` per
scenario, both scenarios), each image through its own simulated camera at every strength of
``--shifts`` (0: none), ground-truth and detector-noise boxes; each frame is weighted by what the
images gained or lost there (Eq. 9 accuracy with images minus boxes only). It prints, per
scenario and strength, images minus boxes before and after the check on those (fitting) frames;
judge it on the test split with ``benchmarks/matcher_comparison.py``, whose ``checked`` column
applies the bundle's frame check. ``--out`` writes the manifest record (JSON); ``--install``
writes it into the bundle's ``manifest.json`` (the only file changed; the bundle's files and
their sha256 stay as they are).

Usage:
    python benchmarks/fit_frame_check.py [--bundle default] [--scenes 60] [--shifts 0 1 2 3]
        [--work runs/deployed_eval] [--out record.json] [--install]
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

from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.evaluation.deployed_matcher_eval import (
    OnnxAppearanceCoster,
    frame_check_samples,
)
from xvmatch.geometry.atomic_files import atomic_write_text
from xvmatch.geometry.output_paths import Input, Output, check_script_outputs
from xvmatch.inference.bundle import MANIFEST, read_manifest
from xvmatch.inference.frame_check import fit_frame_check
from xvmatch.inference.learned_association import load_matcher_bundle


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bundle", default="default", help="a bundle with an appearance "
                        "network (default: the shipped one)")
    parser.add_argument("--scenes", type=int, default=60, help="validation scenes per "
                        "scenario, 5 frames each (default 60)")
    parser.add_argument("--shifts", nargs="+", type=float, default=[0.0, 1.0, 2.0, 3.0],
                        help="camera-shift strengths, each in [0, 3] (0: none)")
    parser.add_argument("--threshold", type=float, default=0.5,
                        help="probability that images help above which they are used, in "
                        "(0, 1) (default 0.5)")
    parser.add_argument("--ridge", type=float, default=1.0, help="L2 penalty, >= 0")
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--out", type=Path, default=None, help="write the record here (JSON)")
    parser.add_argument("--install", action="store_true",
                        help="write the record into the bundle's manifest.json")
    args = parser.parse_args()
    check_scenes_and_shifts(parser, args.scenes, args.shifts)
    if not 0.0 < args.threshold < 1.0:
        parser.error(f"--threshold: expected a number in (0, 1), got {args.threshold:g}")
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
            feats, gains = frame_check_samples(matcher, trials)
            parts.append((scenario, strength, feats, gains))
            print(f"{scenario}, strength {strength:g}: {len(gains)} frames, images - boxes "
                  f"{100 * gains.mean():+.2f} points ({time.perf_counter() - start:.0f} s)",
                  flush=True)
    feats = np.concatenate([p[2] for p in parts])
    gains = np.concatenate([p[3] for p in parts])
    fitted = {"data": "deployed benchmark validation renders (seed 2000), "
                      f"{args.scenes} scenes x 5 frames per scenario, both scenarios",
              "shifts": [float(s) for s in args.shifts], "box_settings": list(SETTINGS),
              "frames": len(gains), "ridge": float(args.ridge),
              "command": "python benchmarks/fit_frame_check.py " + " ".join(sys.argv[1:])}
    check = fit_frame_check(feats, gains, args.threshold, args.ridge, fitted)
    print("\nOn the fitting frames, images - boxes (points), without and with the check; "
          "share of frames with images:")
    for scenario, strength, f, g in parts:
        use = check.trusted(f)
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
