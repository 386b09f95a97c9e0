"""Appearance alone on synthetic held-out frames: the shipped bundle's appearance network against
other trained appearance networks (compact trunk, ImageNet-initialised MobileNetV2 or
EfficientNet-Lite0), on the same frames.

The frames and trials are those of ``benchmarks/deployed_matcher_eval.py`` (test: seed 1000,
20 scenes x 5 frames; validation: seed 2000; ``overview`` 640x360 and ``drone`` 1280x720;
ground-truth boxes and detector noise, shuffled per view, ids scrambled): its renders under
``--work`` are reused. Each network gives the appearance cost ``|a - b| / 2`` of every box pair;
the rows associate by that cost alone (and with the cheirality veto of Eq. 7), with the
non-association cost gamma tuned on the validation frames (best mean Eq. 9 accuracy over
``GAMMA_GRID``, middle of ties), and report Eq. 9 accuracy and CVIDF1 on the test frames.

Bundles (the shipped one, ``inference/default_bundle``, unless ``--no-default``; others with
``--bundles NAME=FOLDER``) run their ONNX FP32 network; other networks are appearance weights
files (``xvmatch train`` writes ``appearance_weights.pt``), run in torch on one thread.
``--raw-imagenet ARCH`` adds the untrained ImageNet trunk itself (its pooled 1,280-d features,
unit length, no head): what the initialisation knows before training.

Usage:
    python benchmarks/pretrained_backbones_eval.py --weights mobilenetv2=runs/.../w.pt
        [--bundles compact=runs/bundle_compact] [--no-default] [--raw-imagenet mobilenetv2]
        [--work runs/deployed_eval] [--scenarios overview drone] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from torch import nn

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Input, Output, check_script_outputs
from xvmatch.datasets.pair_trials import SETTINGS, TrialConfig, dataset_trials
from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
from xvmatch.datasets.synthetic_scenes import SynthConfig
from xvmatch.evaluation.deployed_matcher_eval import OnnxAppearanceCoster
from xvmatch.evaluation.learned_matcher_eval import CueRule, score_rule, tune_gamma
from xvmatch.inference.matching.learned_association import load_matcher_bundle
from xvmatch.metrics.cross_view_metrics import summarize
from xvmatch.models.appearance_net import (
    AppearanceNet,
    appearance_efficientnet_lite0,
    appearance_from_weights,
    appearance_mobilenetv2,
)
from xvmatch.training.appearance_costs import AppearanceCoster

ROLES = {"test": (1000, 20, 5), "val": (2000, 20, 5)}
"""role: (seed, scenes, frames per scene), as benchmarks/deployed_matcher_eval.py."""
SIZES = {"overview": (640, 360), "drone": (1280, 720)}
RULES = (CueRule("app", "appearance only", cue="app"),
         CueRule("app+cheirality", "appearance only + cheirality veto", cue="app",
                 cheirality=True))


def render(work: Path, scenario: str, role: str, workers: int) -> Path:
    """The dataset of a role (the deployed benchmark's path), rendered if not there yet."""
    seed, scenes, frames = ROLES[role]
    size = SIZES[scenario]
    path = work / "data" / f"{scenario}_{role}_s{seed}_{scenes}x{frames}_{size[0]}x{size[1]}"
    if (path / MANIFEST).is_file() and len(SyntheticDataset(path)) == scenes * frames:
        return path
    generate_dataset(path, SynthConfig(scenario=scenario, top_size=size, ego_size=size),
                     n_scenes=scenes, n_frames=frames, seed=seed, workers=workers)
    return path


def raw_imagenet(arch: str) -> AppearanceNet:
    """The ImageNet trunk of ``arch`` with no head: unit-length pooled features of 128x64
    crops."""
    builder = {"mobilenetv2": appearance_mobilenetv2,
               "efficientnet_lite0": appearance_efficientnet_lite0}[arch]
    net = builder(init="imagenet")
    net.head = nn.Identity()
    net.embedding_dim = net.trunk.out_channels
    return net.eval()


def network_rows(name: str, coster, paths: dict[str, Path]) -> list[dict]:
    """Both rules of one network: tuned gamma, Eq. 9 accuracy and CVIDF1 per setting (%)."""
    start = time.perf_counter()
    trials = {role: dataset_trials(paths[role], TrialConfig(), SETTINGS, coster)
              for role in ROLES}
    build_s = time.perf_counter() - start
    rows = []
    for rule in RULES:
        gamma, _ = tune_gamma(trials["val"], rule)
        row = {"network": name, "rule": rule.key, "gamma": gamma,
               "trials_s": round(build_s, 1)}
        for setting in SETTINGS:
            s = summarize([score_rule(t, rule, gamma) for t in trials["test"]
                           if t.setting == setting])
            row[f"acc9_{setting}"] = s.acc9
            row[f"cvidf1_{setting}"] = s.cvidf1
        rows.append(row)
    return rows


def main() -> int:
    """Score every network on every scenario; print a table, write ``--json``."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--weights", nargs="*", default=[], metavar="NAME=FILE",
                        help="appearance weights files to compare with the shipped bundle's")
    parser.add_argument("--bundles", nargs="*", default=[], metavar="NAME=FOLDER",
                        help="bundles whose ONNX appearance networks to compare too")
    parser.add_argument("--raw-imagenet", nargs="*", default=[],
                        choices=["mobilenetv2", "efficientnet_lite0"],
                        help="also score these untrained ImageNet trunks (pooled features)")
    parser.add_argument("--no-default", action="store_true",
                        help="leave out the shipped bundle's network")
    parser.add_argument("--work", type=Path, default=Path("runs/deployed_eval"))
    parser.add_argument("--scenarios", nargs="+", default=["overview", "drone"],
                        choices=sorted(SIZES))
    parser.add_argument("--workers", type=int, default=2, help="render processes")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()
    check_script_outputs(parser, [Output("--json", args.json)],
                         [Input(option, item.partition("=")[2] or None)
                          for option, items in (("--bundles", args.bundles),
                                                ("--weights", args.weights)) for item in items])
    torch.set_num_threads(1)
    costers = {}
    bundles = [] if args.no_default else [("shipped bundle", "default")]
    for item in args.bundles:
        name, _, path = item.partition("=")
        if not path:
            parser.error(f"--bundles takes NAME=FOLDER, got {item!r}")
        bundles.append((name, path))
    for name, path in bundles:
        matcher = load_matcher_bundle(path, precision="fp32")
        arch = matcher.bundle.manifest.appearance.arch if matcher.bundle.manifest.appearance \
            else "none"
        costers[f"{name} ({arch}, ONNX FP32)"] = OnnxAppearanceCoster(matcher)
    for arch in args.raw_imagenet:
        costers[f"{arch} ImageNet features, untrained"] = AppearanceCoster(raw_imagenet(arch))
    for item in args.weights:
        name, _, path = item.partition("=")
        if not path:
            parser.error(f"--weights takes NAME=FILE, got {item!r}")
        costers[name] = AppearanceCoster(appearance_from_weights(path))
    results = []
    for scenario in args.scenarios:
        paths = {role: render(args.work, scenario, role, args.workers) for role in ROLES}
        rows = []
        for name, coster in costers.items():
            rows += network_rows(name, coster, paths)
        width = max(len(r["network"]) for r in rows)
        n = len(SyntheticDataset(paths["test"]))
        print(f"\n{scenario}: {n} test pairs ({paths['test'].name}), gamma tuned on "
              f"{paths['val'].name}; Eq. 9 accuracy / CVIDF1 (%), GT boxes | detector noise")
        for r in rows:
            print(f"{r['network']:<{width}}  {r['rule']:<15s} gamma {r['gamma']:<5g} "
                  f"{r['acc9_gt']:5.1f} / {r['cvidf1_gt']:5.1f} | "
                  f"{r['acc9_det']:5.1f} / {r['cvidf1_det']:5.1f}   ({r['trials_s']:.0f} s)")
        results.append({"scenario": scenario, "data": {k: str(v) for k, v in paths.items()},
                        "rows": rows})
    if args.json:
        atomic_write_text(args.json, json.dumps(results, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
