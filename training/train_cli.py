"""The LightningCLI behind ``xvmatch train --config FILE``.

Model and data are chosen in the YAML file by ``class_path`` (any LightningModule and
LightningDataModule of the package, e.g. :class:`~xvmatch.training.appearance_module.
AppearanceModule` with :class:`~xvmatch.training.image_datamodule.ImagePairDataModule`, or
:class:`~xvmatch.training.fusion_module.FusionModule` with
:class:`~xvmatch.training.fusion_datamodule.CuePairDataModule`); their typed ``__init__``
arguments are the configuration. Everything else is Lightning's own: the ``trainer`` section
(loggers, checkpoints, early stopping, progress bar, ``strategy``/``devices``/``num_nodes`` for
several GPUs or machines), ``seed_everything`` and ``ckpt_path`` (resume). The resolved
configuration is written as ``config.yaml`` into each run's log directory.

Examples::

    xvmatch train --config configs/appearance_cpu.yaml
    xvmatch train --config configs/appearance_cpu.yaml --trainer.max_epochs 2
    xvmatch train --config configs/appearance_cpu.yaml --ckpt_path runs/.../last.ckpt
    python -m xvmatch.training.train_cli fit --config configs/appearance_cpu.yaml
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Mapping, Sequence

__all__ = ["CHECKPOINT_NAMES", "STAGES", "check_checkpoint_options", "check_ckpt_file",
           "check_ckpt_path", "cli_args", "cli_main"]

STAGES: tuple[str, ...] = ("fit", "validate", "test")
"""LightningCLI subcommands ``xvmatch train`` can run (``fit`` by default)."""
CHECKPOINT_NAMES: tuple[str, ...] = ("best", "last", "hpc", "registry")
"""``--ckpt_path`` values Lightning resolves itself to a checkpoint of the run's own callback
(``registry`` also as ``registry:NAME``), when no file of that name exists."""


def check_ckpt_file(path: str, what: str = "--ckpt_path") -> bool:
    """The checks of :func:`check_ckpt_path` that read nothing (no torch, no Lightning): a
    regular local file, not a FIFO, a device, a folder, missing or a URL. False for one of
    Lightning's own names (:data:`CHECKPOINT_NAMES`), which it resolves itself.

    Raises:
        ValueError: one line naming ``what`` and the path.
    """
    from xvmatch.core.input_files import check_input_file

    name = os.fspath(path)
    if name.split(":")[0] in CHECKPOINT_NAMES and not os.path.lexists(name):
        return False
    if "://" in name:
        raise ValueError(f"{what} {name}: only a local checkpoint file is read (weights only); "
                         "download it first")
    check_input_file(name, what)
    return True


def check_ckpt_path(path: str, what: str = "--ckpt_path") -> None:
    """Refuse, in one line and without blocking, a checkpoint Lightning could not read as
    weights only: not a regular local file (a FIFO, a device, a folder, missing, a URL), or
    one that ``torch.load(weights_only=True)`` refuses (truncated, not a zip, pickled code),
    or without a ``state_dict``. Lightning's own names (:data:`CHECKPOINT_NAMES`) pass.

    Raises:
        ValueError: one line naming ``what`` and the path.
    """
    name = os.fspath(path)
    if not check_ckpt_file(name, what):
        return
    import torch

    try:
        with warnings.catch_warnings():  # e.g. a pickle protocol note: the refusal says it all
            warnings.simplefilter("ignore")
            blob = torch.load(name, map_location="cpu", weights_only=True)
    except Exception as exc:  # zip, pickle and weights-only errors of an untrusted file
        raise ValueError(f"{what} {name}: not a checkpoint read as weights only "
                         f"({_load_error(exc)})") from None
    if not isinstance(blob, dict) or not isinstance(blob.get("state_dict"), dict):
        raise ValueError(f"{what} {name}: not a Lightning checkpoint (no state_dict)")


_TORCH_BOILERPLATE = ("Weights only load failed", "In PyTorch", "Please file an issue",
                      "Check the documentation", "WeightsUnpickler error:")
"""Lines of torch's weights-only refusal that say nothing about the file."""


def _load_error(exc: BaseException) -> str:
    """Why ``torch.load`` refused a file, in at most 160 characters: the line of torch's
    message naming the cause (e.g. the blocked global), else its first sentence; never its
    advice to load without ``weights_only``."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    causes = [ln for ln in lines if not ln.startswith(_TORCH_BOILERPLATE)]
    if lines and lines[0].startswith("Weights only load failed"):
        text = "pickled objects other than tensors: " + (causes[0] if causes else "refused")
    else:
        text = (causes[0] if causes else "").split(". ")[0]
    return f"{type(exc).__name__}: {text}"[:160] if text else type(exc).__name__


def check_checkpoint_options(config: Mapping) -> None:
    """Check a parsed LightningCLI configuration's checkpoint options before anything runs:
    ``ckpt_path`` with :func:`check_ckpt_path`, and ``weights_only``, which may only be left
    out or true (a checkpoint read otherwise can run code; Lightning is then told true)."""
    stage = config.get("subcommand")
    section = config.get(stage) if stage else None
    if section is None:
        return
    if section.get("weights_only") is False:
        raise ValueError("--weights_only false: checkpoints are read with weights only (an "
                         "unpickled checkpoint can run code); leave --weights_only out")
    if "weights_only" in section:
        section["weights_only"] = True
    if section.get("ckpt_path"):
        check_ckpt_path(str(section["ckpt_path"]))


def cli_args(config: str, extra: Sequence[str] = (), stage: str = "fit") -> list[str]:
    """The LightningCLI argument list of ``xvmatch train --config FILE [EXTRA...]``.

    Args:
        config: the YAML file.
        extra: further LightningCLI arguments (e.g. ``--trainer.max_epochs 2``); an explicit
            subcommand may not be among them (use ``stage``).
        stage: one of :data:`STAGES`.
    """
    if stage not in STAGES:
        raise ValueError(f"stage must be one of {', '.join(STAGES)}, got {stage!r}")
    return [stage, "--config", str(config), *extra]


def cli_main(args: Sequence[str] | None = None, *, run: bool = True):
    """Build (and by default run) the LightningCLI.

    Args:
        args: command-line arguments, subcommand first when ``run`` (e.g. ``["fit",
            "--config", "configs/appearance_cpu.yaml"]``); None: ``sys.argv``.
        run: run the subcommand; False only parses and instantiates (no subcommand then).

    Returns:
        The ``LightningCLI`` (its ``model``, ``datamodule``, ``trainer`` and ``config``).

    Raises:
        ImportError: jsonargparse is missing (``pip install 'jsonargparse[signatures]'``,
            part of the ``learn`` extra).
        ValueError: a ``ckpt_path`` that is not a checkpoint read as weights only, or
            ``weights_only`` false (:func:`check_checkpoint_options`; one line).
    """
    from lightning.pytorch.cli import _JSONARGPARSE_SIGNATURES_AVAILABLE, LightningCLI

    if not _JSONARGPARSE_SIGNATURES_AVAILABLE:
        raise ImportError("xvmatch train needs jsonargparse: pip install "
                          "'jsonargparse[signatures]>=4.27.7'")
    import lightning as L

    class CheckedCLI(LightningCLI):
        """LightningCLI that checks the checkpoint options (:func:`check_checkpoint_options`)
        once parsed, before its own first read of ``ckpt_path``."""

        def parse_arguments(self, parser, args) -> None:
            with warnings.catch_warnings():
                # xvmatch train hands its own arguments over on purpose: not a mistake
                warnings.filterwarnings("ignore", message="LightningCLI's args parameter")
                super().parse_arguments(parser, args)
            check_checkpoint_options(self.config)

    return CheckedCLI(
        L.LightningModule,
        L.LightningDataModule,
        subclass_mode_model=True,
        subclass_mode_data=True,
        seed_everything_default=0,
        save_config_kwargs={"overwrite": True},
        args=None if args is None else list(args),
        run=run,
        parser_kwargs={"default_env": False},
    )


if __name__ == "__main__":
    cli_main()
