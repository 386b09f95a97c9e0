"""Does the INT8 appearance network give the FP32 network's matches? (issue 34, item 4)

On the deployed benchmark's test scenes (``benchmarks/deployed_matcher_eval.py``: seed 1000,
20 scenes x 5 frames per scenario, rendered into ``--work`` if missing; ground-truth and
detector-noise boxes, ids scrambled), runs a bundle's matcher with its FP32 and its INT8
appearance network in the settings with images, and prints the share of the FP32 matched pairs
that INT8 keeps, and of frames whose assignment is identical: INT8 alone, and as ``associate``
runs it, its near-tie frames scored again with FP32 (the manifest's re-check tolerance), with the
share of frames re-checked. The issue's bar: 99% of the pairs.

Usage:
    python benchmarks/int8_agreement.py [--model default] [--work runs/deployed_eval]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from deployed_matcher_eval import render

from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.evaluation.deployed_matcher_eval import (
    OnnxAppearanceCoster,
    matcher_costs,
)
from xvmatch.inference.assignment import assign
from xvmatch.inference.bundle import int8_recheck_tolerance
from xvmatch.inference.learned_association import load_matcher_bundle, rechecked_costs

IMAGE_SETTINGS = ("images", "images+cameras")


def setting_costs(model: str, path: Path, precision: str) -> dict[str, list[np.ndarray]]:
    """Per image setting, each trial's matcher costs with one appearance precision."""
    matcher = load_matcher_bundle(model, precision=precision)
    trials = dataset_trials(path, TrialConfig(), SETTINGS, OnnxAppearanceCoster(matcher))
    return {s: matcher_costs(matcher, trials, s) for s in IMAGE_SETTINGS}


def matched(costs: list[np.ndarray], gamma: float) -> list[set]:
    """Each trial's matched pairs."""
    return [set(map(tuple, np.asarray(assign(c, gamma)).tolist())) for c in costs]


def main() -> int:
    """Print the agreement table; 0 on success."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="default", help="bundle with an INT8 network")
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    args = parser.parse_args()
    start = time.perf_counter()
    matcher = load_matcher_bundle(args.model, precision="fp32")
    gamma = matcher.gamma
    tolerance = int8_recheck_tolerance(matcher.bundle.manifest.appearance.int8)
    print(f"{args.model}: FP32 matched pairs that INT8 keeps (identical frames); re-checked: "
          + ("no tolerance recorded" if tolerance is None else
             f"near ties scored again with FP32, cost tolerance {tolerance:.4f}"))
    for scenario in ("overview", "drone"):
        path = render(args.work, scenario, "test", args.workers)
        fp32, int8 = (setting_costs(args.model, path, p) for p in ("fp32", "int8"))
        for s in IMAGE_SETTINGS:
            runs = {"INT8": (int8[s], None)}
            if tolerance is not None:
                runs["re-checked"] = rechecked_costs(fp32[s], int8[s], gamma, tolerance)
            reference = matched(fp32[s], gamma)
            pairs = sum(len(a) for a in reference)
            for label, (costs, again) in runs.items():
                other = matched(costs, gamma)
                kept = sum(len(a & b) for a, b in zip(reference, other, strict=True))
                same = sum(a == b for a, b in zip(reference, other, strict=True))
                extra = "" if again is None else f", {again} re-checked"
                print(f"{scenario:<9} {s:<15} {label:<10} {kept}/{pairs} pairs "
                      f"({100 * kept / max(pairs, 1):.1f}%), {same}/{len(reference)} frames "
                      f"identical{extra}")
    print(f"{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
