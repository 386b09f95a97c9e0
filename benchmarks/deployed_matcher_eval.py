"""The deployed ONNX matcher against the handcrafted baseline on synthetic test scenes.

For each scenario (``overview``: 640x360, the geometric-priors paper's setting; ``drone``:
1280x720, the CVMHAT setting), renders (once, then reused) a test set (seed 1000, 20 scenes x 5
frames, the baseline's) and a validation set (seed 2000), builds the trials every synthetic
evaluation uses (ground-truth boxes and detector noise, boxes shuffled per frame and view: ids
scrambled), and scores on exactly the same boxes:

* the eight handcrafted rows of ``xvmatch baseline`` (paper gammas), and the same rows with
  gammas tuned on the validation set (the grid of ``GAMMA_GRID``, best mean Eq. 9 accuracy over
  both settings, middle of ties);
* the learned matcher through the ONNX runtime (no torch) in each input setting: boxes only,
  images, cameras, images + cameras; with the bundle's gamma and with gamma tuned the same way.

Prints one table per scenario (Eq. 9 accuracy, ground-truth boxes / detector noise), what images
add to the learned matcher (images minus boxes, images+cameras minus cameras, in points, with a
95% interval from resampling the 20 test scenes: 100 frames of 20 scenes move a cell by about
+-2 points; ``--scenes N`` renders N test and N validation scenes instead, seeds unchanged, so
the first 20 are the baseline's), and the milliseconds per image pair of each learned setting,
and writes everything to ``--json``.

``--shift S`` (S in (0, 3]) is a stress test for the real-photo gap: before the appearance
network sees an image, each view's image gets its own camera change
(:func:`xvmatch.datasets.camera_shift.camera_shift`: white balance, exposure, tone curve, hue and
saturation, blur, sensor noise, JPEG; strength 1 is stronger than the training augmentation),
drawn from the image's own bytes so both box settings see the same picture. Box costs are
unchanged, so it asks whether images still beat boxes alone when appearance is less reliable.
``--texture D`` (D in (0, 1]) renders the same scenes with photographic textures laid over the
people (:mod:`xvmatch.datasets.render.person_textures`): clothing the network never saw.

Usage:
    python benchmarks/deployed_matcher_eval.py [--model default] [--work runs/deployed_eval]
        [--scenarios overview drone] [--workers 2] [--shift 0.5] [--texture 1] [--scenes 20]
        [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Input, Output, check_script_outputs
from xvmatch.cues.matcher_inputs import INPUT_SETTINGS
from xvmatch.datasets.camera_shift import MAX_STRENGTH, camera_shift
from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.datasets.render.image_render import Difficulty
from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.evaluation.deployed_matcher_eval import (
    OnnxAppearanceCoster,
    frame_accuracy,
    frame_count,
    matcher_costs,
)
from xvmatch.evaluation.handcrafted_baseline import BaselineConfig, Method, fused_cost
from xvmatch.inference.linking.assignment import GAMMA_GRID
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.metrics.confidence import grouped_difference_interval
from xvmatch.metrics.cross_view_metrics import summarize

ROLES = {"test": (1000, 20, 5), "val": (2000, 20, 5)}
"""role: (seed, scenes, frames per scene), as benchmarks/learned_matcher_eval.py."""
SIZES = {"overview": (640, 360), "drone": (1280, 720)}


def check_scenes_and_shifts(parser: argparse.ArgumentParser, scenes: int,
                            shifts: list[float]) -> None:
    """Refuse (the parser's usage error) fewer than 2 scenes or a shift strength out of
    [0, 3], as every script on these renders does."""
    if scenes < 2:
        parser.error(f"--scenes: expected at least 2, got {scenes}")
    for s in shifts:
        if not 0.0 <= s <= MAX_STRENGTH:
            parser.error(f"--shifts: expected numbers in [0, {MAX_STRENGTH:g}], got {s:g}")


def render(work: Path, scenario: str, role: str, workers: int, scenes: int | None = None,
           texture: float = 0.0) -> Path:
    """The dataset of a role (``scenes``: instead of the role's 20; ``texture``: the people
    wear photographic textures of that depth, :mod:`xvmatch.datasets.render.person_textures`, on
    otherwise the same scenes), rendered if not there yet."""
    seed, default_scenes, frames = ROLES[role]
    scenes = default_scenes if scenes is None else int(scenes)
    size = SIZES[scenario]
    path = work / "data" / (f"{scenario}_{role}_s{seed}_{scenes}x{frames}_{size[0]}x{size[1]}"
                            + (f"_tex{texture:g}" if texture else ""))
    if (path / MANIFEST).is_file() and len(SyntheticDataset(path)) == scenes * frames:
        return path
    generate_dataset(path, SynthConfig(scenario=scenario, top_size=size, ego_size=size),
                     n_scenes=scenes, n_frames=frames, seed=seed, workers=workers,
                     difficulty=Difficulty(texture=texture) if texture else None)
    return path


class ShiftedCoster:
    """An appearance coster that sees each image through :func:`camera_shift`."""

    def __init__(self, coster: OnnxAppearanceCoster, strength: float) -> None:
        self.coster, self.strength = coster, strength

    def __call__(self, top_image, top_boxes, ego_image, ego_boxes) -> np.ndarray:
        return self.coster(camera_shift(top_image, self.strength), top_boxes,
                           camera_shift(ego_image, self.strength, seed=1), ego_boxes)


def frame_counts(trials, costs, gamma: float, setting: str) -> tuple[list, list]:
    """Eq. 9 counts of each frame of one box setting under one gamma, and its scene."""
    pairs = [(frame_count(t, c, gamma), t.scene)
             for t, c in zip(trials, costs, strict=True) if t.setting == setting]
    return [c for c, _ in pairs], [s for _, s in pairs]


def frame_accuracies(trials, costs, gamma: float, setting: str) -> tuple[np.ndarray, list]:
    """Eq. 9 accuracy (fraction) of each frame of one box setting that has an id, and its
    scene (the frames :func:`summarize` averages)."""
    pairs = [(frame_accuracy(t, c, gamma), t.scene)
             for t, c in zip(trials, costs, strict=True) if t.setting == setting]
    kept = [(a, s) for a, s in pairs if a is not None]
    return np.asarray([a for a, _ in kept], dtype=float), [s for _, s in kept]


def interval(a: np.ndarray, b: np.ndarray, scenes: list) -> dict:
    """Mean of ``a - b`` in points (``a``, ``b``: per-frame fractions) and its 95% interval
    from resampling whole scenes (``grouped_difference_interval``)."""
    r = grouped_difference_interval(100.0 * a, 100.0 * b, scenes)
    return {"points": r.difference, "low": r.low, "high": r.high, "scenes": r.n_groups}


def shown(d: dict) -> str:
    """``+1.2 [-0.3, +2.6]`` (no interval with fewer than two scenes)."""
    if d["low"] is None:
        return f"{d['points']:+.1f}"
    return f"{d['points']:+.1f} [{d['low']:+.1f}, {d['high']:+.1f}]"


def image_gains(trials, costs: dict, gamma: float) -> dict:
    """What images add on these frames: for images against boxes and images+cameras against
    cameras, per box setting, the Eq. 9 difference in points with its 95% interval from
    resampling whole scenes (``grouped_difference_interval``)."""
    out = {}
    for opened, closed in (("images", "boxes"), ("images+cameras", "cameras")):
        out[f"{opened} - {closed}"] = row = {}
        for setting in SETTINGS:
            a, scenes = frame_accuracies(trials, costs[opened], gamma, setting)
            b, _ = frame_accuracies(trials, costs[closed], gamma, setting)
            row[setting] = interval(a, b, scenes)
    return out


def scores(trials, costs, gamma: float) -> dict[str, float]:
    """Eq. 9 accuracy (fraction) per setting of the trials under one gamma."""
    return {setting: summarize(frame_counts(trials, costs, gamma, setting)[0]).acc9 / 100.0
            for setting in SETTINGS}


def tuned(trials, costs) -> float:
    """Gamma of the grid with the best mean Eq. 9 accuracy (middle of ties)."""
    curve = {g: float(np.mean(list(scores(trials, costs, g).values()))) for g in GAMMA_GRID}
    best = max(curve.values())
    tied = [g for g, a in curve.items() if a == best]
    return tied[(len(tied) - 1) // 2]


def scenario_run(args: argparse.Namespace, scenario: str) -> dict:
    """Every row on one scenario's test set; the JSON-ready record."""
    matcher = load_matcher_bundle(args.model)
    coster = OnnxAppearanceCoster(matcher)
    if args.shift:
        coster = ShiftedCoster(coster, args.shift)
    paths = {role: render(args.work, scenario, role, args.workers, args.scenes, args.texture)
             for role in ROLES}
    trials = {role: dataset_trials(paths[role], TrialConfig(), SETTINGS, coster)
              for role in ROLES}
    rows = []
    config = BaselineConfig()
    for m in config.methods():
        name = m.name + (" + cheirality" if m.cheirality else "")
        costs = {r: [fused_cost(t.costs, m) for t in trials[r]] for r in ROLES}
        rows.append({"method": f"handcrafted: {name}", "gamma": m.gamma,
                     **scores(trials["test"], costs["test"], m.gamma)})
        g = tuned(trials["val"], costs["val"])
        tuned_method = Method(m.rule, m.cheirality, g)
        test_costs = [fused_cost(t.costs, tuned_method) for t in trials["test"]]
        rows.append({"method": f"handcrafted, tuned: {name}", "gamma": g,
                     **scores(trials["test"], test_costs, g)})
    timing, learned_costs = {}, {}
    for setting in INPUT_SETTINGS:
        start = time.perf_counter()
        test_costs = learned_costs[setting] = matcher_costs(matcher, trials["test"], setting)
        timing[setting] = 1000 * (time.perf_counter() - start) / len(trials["test"])
        val_costs = matcher_costs(matcher, trials["val"], setting)
        rows.append({"method": f"learned (ONNX): {setting}", "gamma": matcher.gamma,
                     **scores(trials["test"], test_costs, matcher.gamma)})
        g = tuned(trials["val"], val_costs)
        rows.append({"method": f"learned (ONNX), tuned: {setting}", "gamma": g,
                     **scores(trials["test"], test_costs, g)})
    n = sum(1 for t in trials["test"] if t.setting == "gt")
    width = max(len(r["method"]) for r in rows)
    print(f"\n{scenario}: Eq. 9 accuracy on {n} test pairs ({paths['test'].name}), ids "
          f"scrambled; GT / det" + (f"; images camera-shifted, strength {args.shift}"
                                    if args.shift else "")
          + (f"; people textured, depth {args.texture:g}" if args.texture else ""))
    best = {s: max(r[s] for r in rows if not r["method"].startswith("learned")) for s in SETTINGS}
    for r in rows:
        mark = " ".join("+" if r["method"].startswith("learned") and r[s] > best[s] else " "
                        for s in SETTINGS)
        print(f"{r['method']:<{width}}  gamma {r['gamma']:<5g}  {r['gt']:.3f} / {r['det']:.3f}  "
              f"{mark}")
    print("(+: above every handcrafted row in that setting)")
    gains = image_gains(trials["test"], learned_costs, matcher.gamma)
    for name, row in gains.items():
        print(f"learned, {name} (bundle's gamma), points, 95% scene-bootstrap interval: " +
              " / ".join(shown(r) for r in row.values()))
    print("ms per image pair (features, cues, ONNX; both box settings): " +
          ", ".join(f"{k} {v:.1f}" for k, v in timing.items()))
    return {"scenario": scenario, "shift": args.shift, "texture": args.texture,
            "data": {k: str(v) for k, v in paths.items()},
            "pairs": n, "rows": rows, "image_gains": gains, "ms_per_pair": timing}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="default", help="matcher bundle (default: shipped)")
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--scenarios", nargs="+", default=["overview", "drone"],
                        choices=sorted(SIZES))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--shift", type=float, default=0.0,
                        help="camera change of each view's images, strength in [0, 3] (0: none)")
    parser.add_argument("--texture", type=float, default=0.0,
                        help="people wear photographic textures of this depth in [0, 1] (0: "
                        "none; needs pip install --no-deps scikit-image)")
    parser.add_argument("--scenes", type=int, default=20,
                        help="test and validation scenes per scenario, 5 frames each (default "
                        "20, the baseline's; more narrows the intervals of what images add)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()
    if args.scenes < 2:
        parser.error(f"--scenes: expected at least 2, got {args.scenes}")
    if not 0.0 <= args.shift <= MAX_STRENGTH:
        parser.error(f"--shift: expected a number in [0, {MAX_STRENGTH:g}], got {args.shift}")
    if not 0.0 <= args.texture <= 1.0:
        parser.error(f"--texture: expected a number in [0, 1], got {args.texture}")
    check_script_outputs(parser, [Output("--json", args.json)], [Input("--model", args.model)])
    start = time.perf_counter()
    results = [scenario_run(args, s) for s in args.scenarios]
    print(f"\n{time.perf_counter() - start:.0f} s in all")
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
