"""Learned matcher vs the handcrafted baseline on synthetic overview and drone scenes (issue 5).

For each scenario, renders (once, then reused) four datasets with different seeds:

=======  =====  ===========  ========================================================
role     seed   scenes x f   use
=======  =====  ===========  ========================================================
train    1      400 x 3      appearance network (configs/appearance_cpu.yaml)
fuse     3      100 x 3      fusion heads (configs/fusion_overview.yaml), unseen by the network
val      2000   20 x 5       early stopping, checkpoint choice, every row's gamma
test     1000   20 x 5       the table (the baseline's overview test set)
=======  =====  ===========  ========================================================

``overview`` images are 640x360 (the baseline's setting), ``drone`` images 1280x720 (nadir
top-view people are about 30 px across there). Then trains, each in its own process with
``python -m xvmatch.training.train_cli fit --config ...`` (the command behind ``xvmatch train``)
and measured for wall time and peak resident memory: the appearance network, a geometry-only
head on ``{geo, cheir}`` and the fused head on ``{app, geo, cheir}``; and evaluates every row on
the test set, boxes shuffled per frame and view (ids scrambled), Eq. 9 accuracy on ground-truth
boxes and with detector noise (:mod:`xvmatch.evaluation.learned_matcher_eval`).

``--resnet50-steps K`` also times K CPU training steps of the full ResNet-50 recipe
(configs/appearance_resnet50.yaml, 256x128 crops) in a separate process and extrapolates the
recipe's wall time from them (clearly an extrapolation: no GPU here).

Usage:
    python benchmarks/learned_matcher_eval.py [--work DIR] [--scenarios overview drone]
        [--appearance-epochs 6] [--reuse] [--resnet50-steps 3] [--json FILE]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.core.output_paths import Output, check_script_outputs

REPO = Path(__file__).resolve().parents[1]
CONFIGS = REPO / "configs"
ROLES: dict[str, tuple[int, int, int]] = {
    "train": (1, 400, 3),
    "fuse": (3, 100, 3),
    "val": (2000, 20, 5),
    "test": (1000, 20, 5),
}
"""role: (seed, scenes, frames per scene)."""
SIZES: dict[str, tuple[int, int]] = {"overview": (640, 360), "drone": (1280, 720)}


def render(work: Path, scenario: str, role: str, workers: int) -> Path:
    """The dataset of a role, rendered if not there yet."""
    from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    seed, scenes, frames = ROLES[role]
    size = SIZES[scenario]
    path = work / "data" / f"{scenario}_{role}_s{seed}_{scenes}x{frames}_{size[0]}x{size[1]}"
    if (path / MANIFEST).is_file():
        data = SyntheticDataset(path)
        if (data.seed, len(data.scene_names), len(data)) == (seed, scenes, scenes * frames):
            return path
    start = time.perf_counter()
    generate_dataset(path, SynthConfig(scenario=scenario, top_size=size, ego_size=size),
                     n_scenes=scenes, n_frames=frames, seed=seed, workers=workers)
    print(f"rendered {scenes * frames} {scenario} pairs (seed {seed}) into {path} in "
          f"{time.perf_counter() - start:.1f} s", flush=True)
    return path


def run_measured(cmd: list[str], cwd: Path, log: Path, threads: int) -> dict:
    """Run a command with ``threads`` OpenMP threads, output to ``log``; its wall time and
    peak resident memory (its own)."""
    env = {**os.environ, "OMP_NUM_THREADS": str(threads)}
    start = time.perf_counter()
    with open(log, "w") as out:
        proc = subprocess.Popen(cmd, cwd=cwd, stdout=out, stderr=subprocess.STDOUT, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    code = os.waitstatus_to_exitcode(status)
    proc.returncode = code
    if code != 0:
        tail = log.read_text(errors="replace").splitlines()[-15:]
        raise RuntimeError(f"{' '.join(cmd)} failed with {code}:\n" + "\n".join(tail))
    return {"wall_s": round(wall, 1), "peak_rss_mib": round(usage.ru_maxrss / 1024, 1),
            "log": os.fspath(log)}


def _versions(root: Path) -> set[Path]:
    return set(root.glob("version_*")) if root.is_dir() else set()


def train(config: str, overrides: list[str], run_dir: Path, name: str,
          threads: int) -> tuple[Path, dict]:
    """Train one configuration in a process of its own; (its version folder, its cost)."""
    root = run_dir / "runs" / Path(config).stem
    before = _versions(root)
    cmd = [sys.executable, "-m", "xvmatch.training.train_cli", "fit",
           "--config", os.fspath(CONFIGS / config), "--trainer.enable_progress_bar", "false",
           *overrides]
    run_dir.mkdir(parents=True, exist_ok=True)
    cost = run_measured(cmd, run_dir, run_dir / f"{name}.log", threads)
    new = sorted(_versions(root) - before, key=lambda p: int(p.name.split("_")[1]))
    if not new:
        raise RuntimeError(f"{name}: no new run folder under {root}")
    print(f"trained {name}: {cost['wall_s']} s, peak {cost['peak_rss_mib']} MiB -> {new[-1]}",
          flush=True)
    return new[-1], cost


def best_checkpoint(version: Path) -> Path:
    """The monitored-best checkpoint of a run (not ``last.ckpt``)."""
    ckpts = [p for p in (version / "checkpoints").glob("*.ckpt") if p.name != "last.ckpt"]
    if not ckpts:
        raise RuntimeError(f"{version}: no best checkpoint")
    return max(ckpts, key=lambda p: p.stat().st_mtime)


def scenario_run(args: argparse.Namespace, scenario: str) -> dict:
    """Render, train, evaluate one scenario; returns the JSON-ready record."""
    from xvmatch.datasets.pair_trials import dataset_trials
    from xvmatch.evaluation.learned_matcher_eval import (
        default_rules,
        evaluate_learned_matcher,
        format_learned_table,
    )
    from xvmatch.models.appearance_net import appearance_from_weights
    from xvmatch.training.appearance_costs import AppearanceCoster
    from xvmatch.training.fusion_module import FusionModule

    paths = {role: render(args.work, scenario, role, args.workers) for role in ROLES}
    run_dir = args.work / f"runs_{scenario}"
    costs = {}
    weights = run_dir / "appearance_weights.pt"
    if not (args.reuse and weights.is_file()):
        version, costs["appearance"] = train(
            "appearance_cpu.yaml",
            ["--data.train_data", f"[{paths['train']}]", "--data.val_data", str(paths["val"]),
             "--trainer.max_epochs", str(args.appearance_epochs),
             "--model.net.init_args.input_size", f"[{args.crop[0]}, {args.crop[1]}]",
             "--data.input_height", str(args.crop[0]), "--data.input_width", str(args.crop[1])],
            run_dir, "appearance", args.threads)
        (version / "appearance_weights.pt").replace(weights)
    heads = {}
    for label, names in (("geometry only", ["geo", "cheir"]), ("fused", ["app", "geo", "cheir"])):
        key = "fusion_" + "_".join(names)
        ckpt = run_dir / f"{key}.ckpt"
        if not (args.reuse and ckpt.is_file()):
            listed = "[" + ", ".join(names) + "]"
            version, costs[key] = train(
                "fusion_overview.yaml",
                ["--data.train_data", str(paths["fuse"]), "--data.val_data", str(paths["val"]),
                 "--data.appearance_weights", str(weights), "--data.names", listed,
                 "--model.head.init_args.names", listed],
                run_dir, key, args.threads)
            best_checkpoint(version).replace(ckpt)
        heads[label] = FusionModule.load_from_checkpoint(ckpt, map_location="cpu").head.eval()

    coster = AppearanceCoster(appearance_from_weights(weights))
    start = time.perf_counter()
    val = dataset_trials(paths["val"], coster=coster)
    test = dataset_trials(paths["test"], coster=coster)
    result = evaluate_learned_matcher(test, val, default_rules(heads),
                                      test_data=str(paths["test"]), val_data=str(paths["val"]),
                                      scenario=scenario)
    for name, c in costs.items():
        result.info[f"training {name}"] = f"{c['wall_s']} s wall, peak {c['peak_rss_mib']} MiB"
    result.info["evaluation"] = f"{time.perf_counter() - start:.1f} s (costs, gammas, tables)"
    print(format_learned_table(result), flush=True)
    hand = max(r.accuracy("gt") for r in result.rows if r.family.startswith("handcrafted"))
    hand_det = max(r.accuracy("det") for r in result.rows if r.family.startswith("handcrafted"))
    fused = result.row("learned(app,geo,cheir)")
    print(f"{scenario}: learned fusion {fused.accuracy('gt'):.3f} / {fused.accuracy('det'):.3f}"
          f" vs best handcrafted row {hand:.3f} / {hand_det:.3f} (GT / det)\n", flush=True)
    return {
        "scenario": scenario,
        "data": {k: os.fspath(v) for k, v in paths.items()},
        "training": costs,
        "rows": [{"key": r.key, "name": r.name, "family": r.family, "gamma": r.gamma,
                  "acc_gt": r.accuracy("gt"), "acc_det": r.accuracy("det")}
                 for r in result.rows],
    }


def resnet50_probe(data: str, steps: int, batch_size: int) -> dict:
    """Time ``steps`` CPU training steps of the full recipe (runs in its own process)."""
    import torch

    from xvmatch.datasets.synthetic_io import SyntheticDataset
    from xvmatch.models.appearance_net import appearance_resnet50
    from xvmatch.training.appearance_module import AppearanceModule
    from xvmatch.training.image_datamodule import (
        augment_crops,
        collate_crop_pairs,
        load_crop_pairs,
    )

    torch.manual_seed(0)
    dataset = SyntheticDataset(data)
    need = (steps + 1) * batch_size
    scenes, n = [], 0
    for name in dataset.scene_names:  # only the scenes the steps use: crops of 256x128 are big
        if n >= need:
            break
        scenes.append(name)
        n += len(dataset.scene(name).pairs)
    pairs = load_crop_pairs(data, scenes, (256, 128), workers=2)[:need]
    module = AppearanceModule(appearance_resnet50())
    optimizer = torch.optim.AdamW(module.parameters(), lr=3e-4)
    g = torch.Generator().manual_seed(0)
    times, crops = [], []
    for k in range(steps + 1):
        batch = augment_crops(collate_crop_pairs(pairs[k * batch_size:(k + 1) * batch_size]), g)
        start = time.perf_counter()
        loss, _, _ = module._step(batch)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if k:  # the first step warms up allocators and kernels
            times.append(time.perf_counter() - start)
            crops.append(int(batch.top_mask.sum() + batch.ego_mask.sum()))
    return {"seconds_per_step": float(np.mean(times)), "crops_per_step": float(np.mean(crops)),
            "steps": steps, "threads": torch.get_num_threads()}


def resnet50_cost(args: argparse.Namespace, scenario: str) -> dict:
    """Measured CPU steps of the ResNet-50 recipe and the extrapolated full-recipe time."""
    import yaml

    paths = {role: render(args.work, scenario, role, args.workers) for role in ("train",)}
    log = args.work / "resnet50_probe.log"
    out = args.work / "resnet50_probe.json"
    cmd = [sys.executable, os.fspath(Path(__file__).resolve()), "--probe-resnet50",
           str(paths["train"]), "--resnet50-steps", str(args.resnet50_steps),
           "--json", os.fspath(out)]
    cost = run_measured(cmd, REPO, log, args.threads)
    probe = json.loads(out.read_text())
    recipe = yaml.safe_load((CONFIGS / "appearance_resnet50.yaml").read_text())
    epochs = int(recipe["trainer"]["max_epochs"])
    batch = int(recipe["data"]["init_args"]["batch_size"])
    from xvmatch.datasets.synthetic_io import SyntheticDataset

    n_pairs = len(SyntheticDataset(paths["train"]))
    steps = epochs * math.ceil(n_pairs / batch)
    hours = steps * probe["seconds_per_step"] / 3600
    record = {**probe, "probe_wall_s": cost["wall_s"], "probe_peak_rss_mib": cost["peak_rss_mib"],
              "recipe_epochs": epochs, "recipe_steps": steps,
              "extrapolated_cpu_hours": round(hours, 1)}
    print(f"ResNet-50 recipe, MEASURED on this CPU: {probe['seconds_per_step']:.2f} s per step "
          f"of {batch} pairs ({probe['crops_per_step']:.0f} crops, 256x128, "
          f"{probe['threads']} threads), peak {cost['peak_rss_mib']} MiB; EXTRAPOLATED: "
          f"{steps} steps ({epochs} epochs x {math.ceil(n_pairs / batch)}) = about {hours:.1f} "
          "CPU hours (validation excluded; no GPU in this task)", flush=True)
    return record


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path,
                        default=Path(tempfile.gettempdir()) / "xvmatch_learned",
                        help="folder for datasets, runs and logs")
    parser.add_argument("--scenarios", nargs="+", default=["overview", "drone"],
                        choices=sorted(SIZES))
    parser.add_argument("--appearance-epochs", type=int, default=6)
    parser.add_argument("--crop", type=int, nargs=2, default=(128, 64), metavar=("H", "W"),
                        help="crop size of the CPU recipe (default 128 64)")
    parser.add_argument("--workers", type=int, default=2, help="rendering processes")
    parser.add_argument("--threads", type=int, default=1,
                        help="torch/OpenMP threads of every training and evaluation process "
                        "(default 1: on a busy 2-core machine two threads were up to 30x "
                        "slower from oversubscription)")
    parser.add_argument("--reuse", action="store_true",
                        help="reuse trained weights and heads found in --work")
    parser.add_argument("--resnet50-steps", type=int, default=0,
                        help="also time this many CPU steps of the ResNet-50 recipe")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    parser.add_argument("--probe-resnet50", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.probe_resnet50:  # this script's own child, writing into --work
        record = resnet50_probe(args.probe_resnet50, max(1, args.resnet50_steps), 8)
        atomic_write_text(args.json, json.dumps(record))
        return 0
    check_script_outputs(parser, [Output("--json", args.json)])
    import torch

    torch.set_num_threads(args.threads)
    args.work.mkdir(parents=True, exist_ok=True)
    records = [scenario_run(args, s) for s in args.scenarios]
    report = {"scenarios": records}
    if args.resnet50_steps:
        report["resnet50"] = resnet50_cost(args, args.scenarios[0])
    if args.json:
        atomic_write_text(args.json, json.dumps(report, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
