"""The ``xvmatch train`` command: Lightning training from a YAML configuration.

``add_train_parser`` registers the sub-command on the ``subparsers`` of the main parser; its
``func`` takes the parsed arguments and returns an exit code. Everything after ``--config FILE``
is handed to LightningCLI (:mod:`xvmatch.training.train_cli`), e.g. ``--trainer.max_epochs 2``
or ``--ckpt_path last.ckpt`` to resume. Imports are lazy: other commands never load torch or
Lightning through it.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

__all__ = ["EXAMPLE", "add_train_parser"]

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
    "--trainer.strategy ddp"
)


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
    p = subparsers.add_parser(
        "train",
        help=help_text,
        description=help_text + " Any further LightningCLI argument may follow, e.g. "
        "--trainer.max_epochs 2 or --ckpt_path last.ckpt (resume); see `python -m "
        "xvmatch.training.train_cli fit --help` for all of them.",
        epilog=f"example:\n  {EXAMPLE}",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--config", required=True, metavar="FILE",
                   help="YAML configuration, e.g. configs/appearance_cpu.yaml")
    p.add_argument("--stage", choices=("fit", "validate", "test"), default="fit",
                   help="what to run (default fit); validate/test take --ckpt_path")
    p.__class__ = _TrainParser  # add_parser builds the main parser's class; extend this one
    p.set_defaults(func=_cmd_train, lightning_args=[])
    return p


def _cmd_train(args: argparse.Namespace) -> int:
    config = Path(args.config)
    if not config.is_file():
        raise ValueError(f"{args.config}: no such configuration file; see configs/ for examples")
    from xvmatch.training.train_cli import cli_args, cli_main

    extra = [a for a in args.lightning_args if a != "--"]
    try:
        cli_main(cli_args(str(config), extra, args.stage))
    except SystemExit as exc:  # jsonargparse reports bad configurations by exiting
        code = exc.code if isinstance(exc.code, int) else 2
        if code:
            print(f"xvmatch: error: training configuration {args.config} rejected (see above)",
                  file=sys.stderr)
        return code
    return 0
