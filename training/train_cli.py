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

from collections.abc import Sequence

__all__ = ["STAGES", "cli_args", "cli_main"]

STAGES: tuple[str, ...] = ("fit", "validate", "test")
"""LightningCLI subcommands ``xvmatch train`` can run (``fit`` by default)."""


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
    """
    from lightning.pytorch.cli import _JSONARGPARSE_SIGNATURES_AVAILABLE, LightningCLI

    if not _JSONARGPARSE_SIGNATURES_AVAILABLE:
        raise ImportError("xvmatch train needs jsonargparse: pip install "
                          "'jsonargparse[signatures]>=4.27.7'")
    import lightning as L

    return LightningCLI(
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
