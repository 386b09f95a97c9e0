"""Fine-tune a matcher file's appearance branch, optionally through simulated other cameras
(issue 31, item 3).

Starts from the appearance network inside ``--base`` (default: the shipped
``models/default_matcher.pt``) and trains it further on the default recipe's appearance renders
(``training/make_default_bundle.py``'s ``app_*`` sets, validation on ``val_*``, rendered into
``--work`` when missing), with the hyperparameters of the network's own config in ``configs/``
(``appearance_mobilenetv2.yaml`` or ``appearance_cpu.yaml``) but ``--learning-rate``. With
``--shift-probability P`` that share of each view's crops of a pair first go through one
simulated other camera (:func:`xvmatch.datasets.camera_shift.camera_shift`, strength uniform up
to ``--shift-max``; ``ImagePairDataModule(camera_shift_probability=...)``) before the usual
augmentation. The best epoch by validation rank-1 (clean crops) is kept.

Writes ``--out``: the base matcher file with the fine-tuned network (geometry and cue layers
unchanged; the input of ``make_robust_matcher.py --base``), its appearance weights beside it
(``OUT_appearance.pt``) and the run's logs and checkpoints in ``OUT.run/``.

Usage:
    OMP_NUM_THREADS=1 python training/finetune_appearance.py --out runs/app_shift/shift.pt \\
        [--base models/default_matcher.pt] [--shift-probability 0.5] [--shift-max 2] \\
        [--epochs 2] [--learning-rate 5e-4] [--work runs/default_bundle]
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, os.fspath(Path(__file__).resolve().parent))

import make_default_bundle as recipe  # noqa: E402  (the recipe's renders, configs and log)

from xvmatch.core.output_paths import Input, Output, check_script_outputs  # noqa: E402
from xvmatch.datasets.camera_shift import MAX_STRENGTH  # noqa: E402

CONFIG_OF_ARCH = {"mobilenetv2": "mobilenetv2", "small": "compact"}
"""A network's ``arch`` -> its key in ``recipe.APPEARANCE_CONFIGS``."""


def module_from_config(net, arch: str, learning_rate: float):
    """The config's training module (class and arguments) around ``net``, at
    ``learning_rate``."""
    import yaml

    config = ROOT / "configs" / recipe.APPEARANCE_CONFIGS[CONFIG_OF_ARCH[arch]]
    model = yaml.safe_load(config.read_text())["model"]
    module_name, _, class_name = model["class_path"].rpartition(".")
    cls = getattr(importlib.import_module(module_name), class_name)
    kwargs = {k: v for k, v in model["init_args"].items() if k != "net"}
    return cls(net, **{**kwargs, "lr": float(learning_rate)}), config


def files_beside(out: Path) -> tuple[Path, Path]:
    """What a run writes beside a matcher file ``out`` (this script and
    ``make_robust_matcher.py``): its run folder and the appearance weights file."""
    return out.with_name(out.name + ".run"), out.with_name(out.stem + "_appearance.pt")


def _parser() -> argparse.ArgumentParser:
    """The command line of :func:`main`."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--base", default="default", help="matcher file whose appearance "
                        "network to fine-tune (default: the shipped one)")
    parser.add_argument("--out", type=Path, required=True, help="matcher file to write")
    parser.add_argument("--work", type=Path, default=Path("runs/default_bundle"),
                        help="the recipe's working folder (its renders are reused)")
    parser.add_argument("--train-data", nargs="+", default=None,
                        help="dataset folders to train on (default: the recipe's app_* sets)")
    parser.add_argument("--val-data", nargs="+", default=None,
                        help="dataset folders to validate on (default: the recipe's val_* sets)")
    parser.add_argument("--epochs", type=int, default=2, help="epochs (default 2)")
    parser.add_argument("--learning-rate", type=float, default=5e-4,
                        help="peak learning rate of the head (default 5e-4)")
    parser.add_argument("--shift-probability", type=float, default=0.0,
                        help="share of each view's crops of a pair through another simulated "
                        "camera (default 0: none)")
    parser.add_argument("--shift-max", type=float, default=2.0,
                        help=f"the strongest such camera, in (0, {MAX_STRENGTH:g}] (default 2)")
    parser.add_argument("--seed", type=int, default=0, help="seed of everything (default 0)")
    parser.add_argument("--workers", type=int, default=1, help="render and crop threads")
    return parser


def _check_args(parser: argparse.ArgumentParser, args: argparse.Namespace) -> tuple[Path, Path]:
    """Refuse bad options and outputs that exist or are unsafe, before any work
    (``parser.error``); the run folder and appearance weights file written beside ``--out``."""
    if args.epochs < 1:
        parser.error(f"--epochs: expected at least 1, got {args.epochs}")
    if not args.learning_rate > 0:
        parser.error(f"--learning-rate: expected a positive number, got {args.learning_rate}")
    recipe.check_camera_shift(parser, args.shift_probability, "--shift-probability",
                              args.shift_max, "--shift-max")
    run, weights = files_beside(args.out)
    for path, what in ((args.out, "exists"), (weights, f"{weights}, written beside it, exists"),
                       (run, f"{run}, written beside it, exists")):
        if os.path.lexists(path):
            parser.error(f"--out {args.out}: {what}; choose a new file (nothing is written "
                         "over)")
    check_script_outputs(parser, [Output("--out", args.out, parents=True),
                                  Output("--out", weights, parents=True),
                                  Output("--out", run, folder=True)],
                         [Input("--base", None if args.base == "default" else args.base),
                          *(Input("--train-data", d) for d in args.train_data or ()),
                          *(Input("--val-data", d) for d in args.val_data or ())])
    return run, weights


def _check_base(parser: argparse.ArgumentParser, args: argparse.Namespace, base) -> str:
    """The base matcher's appearance ``arch``, refused (``parser.error``) without an
    appearance network or a training config for it."""
    if base.appearance is None:
        parser.error(f"--base {args.base}: a matcher with an appearance network is needed")
    arch = base.appearance.arch
    if arch not in CONFIG_OF_ARCH:
        parser.error(f"--base {args.base}: no training config for an appearance_{arch} "
                     f"network (known: {', '.join(CONFIG_OF_ARCH)})")
    return arch


def _data_folders(args: argparse.Namespace) -> tuple[list[str], list[str]]:
    """The training and validation dataset folders: those given, else the recipe's
    ``app_*`` and ``val_*`` renders (rendered into ``--work`` when missing)."""
    if args.train_data is None or args.val_data is None:
        data = recipe.render(args.work, args.workers)
    train = args.train_data or [os.fspath(data["app_drone"]), os.fspath(data["app_overview"])]
    val = args.val_data or [os.fspath(data["val_drone"]), os.fspath(data["val_overview"])]
    return train, val


def _trainer(run: Path, weights: Path, epochs: int):
    """A CPU trainer logging to ``run``, keeping the best epoch by validation rank-1, and
    writing the appearance weights to ``weights``; and its checkpoint callback."""
    import lightning as L
    from lightning.pytorch.callbacks import ModelCheckpoint
    from lightning.pytorch.loggers import CSVLogger

    from xvmatch.training.appearance_module import SaveAppearanceWeights

    checkpoint = ModelCheckpoint(dirpath=run / "checkpoints", monitor="val/rank1", mode="max",
                                 save_last=True)
    trainer = L.Trainer(accelerator="cpu", devices=1, max_epochs=epochs,
                        default_root_dir=run, enable_progress_bar=False,
                        logger=CSVLogger(run, name=""), log_every_n_steps=50,
                        callbacks=[checkpoint, SaveAppearanceWeights(path=os.fspath(weights))])
    return trainer, checkpoint


def main(argv: list[str] | None = None) -> int:
    """Fine-tune and write the matcher file; 0 on success."""
    parser = _parser()
    args = parser.parse_args(argv)
    run, weights = _check_args(parser, args)
    start = time.perf_counter()
    import lightning as L
    import torch

    from xvmatch.models.appearance_net import appearance_from_weights
    from xvmatch.models.matcher_file import load_matcher, save_matcher
    from xvmatch.training.image_datamodule import ImagePairDataModule

    torch.set_num_threads(1)
    L.seed_everything(args.seed, workers=True, verbose=False)
    base = load_matcher(args.base)
    arch = _check_base(parser, args, base)
    train, val = _data_folders(args)
    height, width = base.appearance.preprocessing.input_size
    dm = ImagePairDataModule(train_data=train, val_data=val, input_height=height,
                             input_width=width, batch_size=8, hard_radius=1.0, augment=True,
                             seed=args.seed, workers=args.workers,
                             camera_shift_probability=args.shift_probability,
                             camera_shift_max=args.shift_max)
    model, config = module_from_config(base.appearance.train(), arch, args.learning_rate)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    trainer, checkpoint = _trainer(run, weights, args.epochs)
    before = float(trainer.validate(model, datamodule=dm, verbose=False)[0]["val/rank1"])
    trainer.fit(model, datamodule=dm)
    best = float(checkpoint.best_model_score)
    net = appearance_from_weights(weights)
    record = {"base": os.fspath(args.base), "config": config.name, "epochs": args.epochs,
              "learning_rate": args.learning_rate, "seed": args.seed,
              "camera_shift": {"probability": args.shift_probability, "max": args.shift_max},
              "train_data": train, "val_data": val,
              "val_rank1": {"before": round(before, 4), "after": round(best, 4)}}
    save_matcher(args.out, base.matcher, base.feature_config, base.gamma,
                 {**base.meta, "appearance_finetune": record}, appearance=net,
                 crop_context=base.crop_context)
    recipe.log(f"wrote {args.out}: validation rank-1 {before:.3f} -> {best:.3f} "
               f"({time.perf_counter() - start:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
