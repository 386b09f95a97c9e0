"""Train the learned matcher end to end and write its matcher file (``xvmatch fit-geometry`` for
the box-only matcher on box files; the default bundle's recipe for the matcher with cues).

:func:`fit_matcher` runs Lightning with everything a reproducible run needs: a global seed
(``lightning.seed_everything``, deterministic algorithms), checkpoints of the best validation
CVIDF1 and of the last epoch (``ModelCheckpoint``), resuming from the last checkpoint, early
stopping on the validation CVIDF1, CSV and TensorBoard logs, a progress bar, and the resolved
configuration saved as ``config.json`` in the run folder. It reports the wall time and the peak
memory (``resource.getrusage``) of the run. :func:`fit_geometry` trains a box-only matcher;
:func:`fit_geometry_cvmhat` builds the CVMHAT DataModule for the command line.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import lightning as L
import torch
from lightning.pytorch.callbacks import EarlyStopping, ModelCheckpoint, TQDMProgressBar
from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger

from xvmatch.core.atomic_files import atomic_write_text
from xvmatch.cues.spatial_features import FeatureConfig
from xvmatch.models.appearance_net import AppearanceNet
from xvmatch.models.cross_view_matcher import CrossViewMatcher
from xvmatch.models.geometry_encoder import GeometryEncoder
from xvmatch.models.losses import GeometryMatchingLoss
from xvmatch.models.matcher_file import save_matcher
from xvmatch.training.box_datamodule import (
    CvmhatBoxDataModule,
    MixedBoxDataModule,
    SimBoxDataModule,
)
from xvmatch.training.checkpoint_files import (
    best_checkpoint_path,
    check_checkpoint_file,
    load_checkpoint_state,
)
from xvmatch.training.geometry_module import GeometryMatchingModule

__all__ = ["FitResult", "fit_geometry", "fit_geometry_cvmhat", "fit_matcher", "peak_memory_mb"]


def peak_memory_mb() -> float:
    """Peak resident memory of this process so far, in MiB (``ru_maxrss``)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


@dataclass(frozen=True)
class FitResult:
    """What a training run produced.

    Attributes:
        model_path: the model file written.
        best_score: best validation CVIDF1 (percent), None without validation data.
        epochs: epochs run (early stopping may end before the maximum).
        wall_time_s: wall time of the whole call, feature extraction included.
        peak_memory_mb: peak resident memory of the process at the end (MiB).
        run_dir: folder of the checkpoints, logs and ``config.json``.
    """

    model_path: Path
    best_score: float | None
    epochs: int
    wall_time_s: float
    peak_memory_mb: float
    run_dir: Path


def fit_geometry(
    datamodule: L.LightningDataModule,
    out: str | os.PathLike,
    *,
    feature_config: FeatureConfig,
    model_config: Mapping[str, Any] | None = None,
    **kwargs: Any,
) -> FitResult:
    """Train a box-only matcher (a :class:`GeometryEncoder` of ``model_config``, no cues) on
    ``datamodule`` and write its matcher file ``out``; other arguments as :func:`fit_matcher`."""
    L.seed_everything(int(kwargs.get("seed", 0)), workers=True, verbose=False)  # the weights
    matcher = CrossViewMatcher(GeometryEncoder(**dict(model_config or {})), cues=())
    return fit_matcher(datamodule, out, matcher=matcher, feature_config=feature_config,
                       **kwargs)


def _prepare_run(
    out: Path, run_dir: str | os.PathLike | None, resume: bool, epochs: int,
    threads: int | None,
) -> tuple[Path, Path | None]:
    """Check the fit's arguments and create its run folder, before any work.

    Args:
        out: matcher file to write.
        run_dir: checkpoints and logs (default ``<out>.run`` beside ``out``).
        resume: continue from ``run_dir/checkpoints/last.ckpt`` when it exists.
        epochs: most epochs (>= 1).
        threads: torch intra-op threads (>= 1), or None for torch's default.

    Returns:
        The run folder and the checkpoint to resume from (None: a fresh start).
    """
    if epochs < 1:
        raise ValueError(f"epochs must be >= 1, got {epochs}")
    if not out.parent.is_dir():
        raise ValueError(f"cannot write {os.fspath(out)!r}: folder {os.fspath(out.parent)!r} "
                         "does not exist")
    run = Path(run_dir) if run_dir is not None else out.with_name(out.name + ".run")
    last = run / "checkpoints" / "last.ckpt"
    resume_from = last if resume and last.exists() else None
    if resume_from is not None:  # before any work: a corrupt file is one line naming it
        check_checkpoint_file(resume_from)
    run.mkdir(parents=True, exist_ok=True)
    if threads is not None:
        if threads < 1:
            raise ValueError(f"threads must be >= 1, got {threads}")
        torch.set_num_threads(threads)
    return run, resume_from


def _write_run_config(
    run: Path, settings: Mapping[str, Any], matcher: CrossViewMatcher,
    loss_config: Mapping[str, Any] | None, feature_config: FeatureConfig,
    datamodule: L.LightningDataModule,
) -> None:
    """Write ``run/config.json``: the fit's settings, the model's and the data's configuration.

    Args:
        run: the run folder.
        settings: out, seed, epochs, learning rate, weight decay, gamma and patience, in order.
        matcher: the matcher being trained.
        loss_config: keyword arguments of the loss.
        feature_config: the feature configuration.
        datamodule: the DataModule (its public settings are recorded).
    """
    config = {
        **settings,
        "model_config": matcher.geometry.config,
        "matcher_config": matcher.config,
        "loss_config": dict(loss_config or {}),
        "feature_config": feature_config.to_dict(),
        "datamodule": {
            k: (v if isinstance(v, int | float | str | bool | type(None) | list) else str(v))
            for k, v in vars(datamodule).items()
            if not k.startswith("_") and not k.endswith("_parts") and k not in ("trainer",)
        },
    }
    atomic_write_text(run / "config.json", json.dumps(config, indent=2, default=str) + "\n")


def _keep_best(module: GeometryMatchingModule, checkpoint: ModelCheckpoint,
               has_val: bool) -> float | None:
    """Load the best validation checkpoint into ``module``; returns its score (None: no val)."""
    best_path = best_checkpoint_path(checkpoint)  # only from the run's own checkpoint folder
    if has_val and best_path is not None:
        module.load_state_dict(load_checkpoint_state(best_path))
        return float(checkpoint.best_model_score)
    return None


def _matcher_trainer(
    run: Path, epochs: int, has_val: bool, patience: int, progress: bool
) -> tuple[L.Trainer, ModelCheckpoint]:
    """The deterministic CPU trainer of a matcher fit, and its checkpoint callback.

    Keeps the best validation CVIDF1 and the last epoch, stops after ``patience`` epochs
    without a better one (when there is validation), and logs to CSV and TensorBoard in ``run``.
    """
    checkpoint = ModelCheckpoint(
        dirpath=run / "checkpoints",
        filename="best-{epoch:02d}",
        monitor="val_f1" if has_val else None,
        mode="max",
        save_last=True,
        save_top_k=1,
    )
    callbacks: list = [checkpoint]
    if has_val:
        callbacks.append(EarlyStopping(monitor="val_f1", mode="max", patience=patience))
    if progress:
        callbacks.append(TQDMProgressBar(refresh_rate=20))
    trainer = L.Trainer(
        max_epochs=epochs,
        accelerator="cpu",
        devices=1,
        deterministic=True,
        gradient_clip_val=1.0,
        callbacks=callbacks,
        logger=[CSVLogger(run, name="csv"), TensorBoardLogger(run, name="tensorboard")],
        enable_progress_bar=progress,
        enable_model_summary=False,
        log_every_n_steps=20,
        num_sanity_val_steps=0,
        limit_val_batches=1.0 if has_val else 0,
    )
    return trainer, checkpoint


def fit_matcher(
    datamodule: L.LightningDataModule,
    out: str | os.PathLike,
    *,
    matcher: CrossViewMatcher,
    feature_config: FeatureConfig,
    appearance: AppearanceNet | None = None,
    loss_config: Mapping[str, Any] | None = None,
    epochs: int = 8,
    seed: int = 0,
    learning_rate: float = 2e-3,
    weight_decay: float = 1e-4,
    gamma: float = 0.5,
    run_dir: str | os.PathLike | None = None,
    resume: bool = False,
    patience: int = 3,
    progress: bool = True,
    meta: Mapping[str, Any] | None = None,
    threads: int | None = None,
) -> FitResult:
    """Train a :class:`CrossViewMatcher` on ``datamodule`` and write the matcher file ``out``.

    Args:
        datamodule: a DataModule yielding ``collate_labelled`` batches (its ``val_parts`` may
            be empty: then the last epoch is kept and nothing stops early).
        out: matcher file to write (atomically).
        matcher: the matcher to train (e.g. initialised from a box-only one).
        feature_config: the feature configuration the DataModule uses (stored in the file).
        appearance: the frozen appearance network behind the ``app`` cue (stored in the file).
        loss_config: keyword arguments of :class:`GeometryMatchingLoss`.
        epochs: most epochs.
        seed: global seed (weights, shuffling).
        learning_rate: peak learning rate (AdamW, warm-up then cosine decay).
        weight_decay: AdamW weight decay.
        gamma: non-association cost stored with the model and used for the validation CVIDF1.
        run_dir: checkpoints and logs (default ``<out>.run`` beside ``out``).
        resume: continue from ``run_dir/checkpoints/last.ckpt`` when it exists.
        patience: epochs without a better validation CVIDF1 before stopping.
        progress: show a progress bar.
        meta: JSON-able notes stored in the model file (the run adds its own).
        threads: torch intra-op threads for the run (None: torch's default). On a shared or
            small machine 1 is often fastest for these small tensors.

    Returns:
        :class:`FitResult`.
    """
    start = time.perf_counter()
    out = Path(out)
    run, resume_from = _prepare_run(out, run_dir, resume, epochs, threads)
    L.seed_everything(seed, workers=True, verbose=False)
    datamodule.setup("fit")
    has_val = bool(getattr(datamodule, "val_parts", [True]))

    matcher.train()  # a matcher loaded from a file comes in eval mode; Lightning keeps modes
    module = GeometryMatchingModule(matcher, GeometryMatchingLoss(**dict(loss_config or {})),
                                    learning_rate=learning_rate, weight_decay=weight_decay,
                                    gamma=gamma)
    settings = {"out": os.fspath(out), "seed": seed, "epochs": epochs,
                "learning_rate": learning_rate, "weight_decay": weight_decay, "gamma": gamma,
                "patience": patience}
    _write_run_config(run, settings, matcher, loss_config, feature_config, datamodule)
    trainer, checkpoint = _matcher_trainer(run, epochs, has_val, patience, progress)
    trainer.fit(module, datamodule=datamodule, ckpt_path=resume_from)

    best_score = _keep_best(module, checkpoint, has_val)
    notes = {**dict(meta or {}), "seed": seed, "epochs_run": int(trainer.current_epoch),
             "best_val_f1": best_score, "model_config": matcher.geometry.config,
             "matcher_config": matcher.config}
    save_matcher(out, module.model, feature_config, gamma, notes, appearance=appearance)
    return FitResult(
        model_path=out,
        best_score=best_score,
        epochs=int(trainer.current_epoch),
        wall_time_s=time.perf_counter() - start,
        peak_memory_mb=peak_memory_mb(),
        run_dir=run,
    )


def _print_offsets(real: CvmhatBoxDataModule) -> None:
    """Say on stderr, one line per pair, each offset that is not in sync or was applied."""
    for name, o in real.offsets.items():
        if o.status != "within_tolerance" or o.applied:
            kept = "re-timed" if o.applied else "the files' timing kept"
            print(f"{name}: offset {o.offset:+d} frames ({o.status}; {kept})", file=sys.stderr)


def fit_geometry_cvmhat(
    cvmhat_dir: str | os.PathLike,
    out: str | os.PathLike,
    *,
    sites: Sequence[str] | None = None,
    epochs: int = 12,
    seed: int = 0,
    noise_copies: int = 2,
    sim_scenes: int = 300,
    cache_dir: str | os.PathLike | None = None,
    workers: int = 1,
    run_dir: str | os.PathLike | None = None,
    resume: bool = False,
    progress: bool = True,
    model_config: Mapping[str, Any] | None = None,
    feature_config: FeatureConfig | None = None,
    threads: int | None = None,
    synchronise: bool = True,
) -> FitResult:
    """Train on CVMHAT-format box pairs (``NAME_top.txt`` / ``NAME_hor.txt``) of ``sites``.

    With ``synchronise`` each pair's top view is first re-timed by the offset
    ``associate --offset auto`` applies (estimated from the boxes, cached; 0 for pairs in sync),
    so that the labels hold for the frame pairs the model sees; the model file's meta records
    the re-timed pairs.

    The last 15% of every sequence validates (early stopping, best checkpoint);
    ``noise_copies`` detector-noise copies (seeds 1000, 1001, ...) of the training frames and one
    of the validation frames (seed 999) teach robustness to detections; ``sim_scenes`` scenes of
    the box simulator (randomised configurations, 30 frames each, seeded by ``seed``) join the
    training set as a regulariser: trained on a few real sites alone, the model learns
    site-specific shortcuts and transfers worse to a new site.
    """
    feature_config = feature_config or FeatureConfig()
    real = CvmhatBoxDataModule(
        data_dir=os.fspath(cvmhat_dir),
        train_sites=list(sites) if sites else None,
        noise_seeds=[1000 + k for k in range(noise_copies)],
        val_noise_seed=999 if noise_copies else None,
        feature_config=feature_config,
        cache_dir=os.fspath(cache_dir) if cache_dir is not None else None,
        workers=workers,
        seed=seed,
        synchronise=synchronise,
    )
    retimed = {name: o.applied for name, o in real.training_offsets().items() if o.applied}
    if progress:
        _print_offsets(real)
    dm = real
    if sim_scenes > 0:
        sim = SimBoxDataModule(
            n_scenes=sim_scenes,
            val_scenes=0,
            feature_config=feature_config,
            cache_dir=os.fspath(cache_dir) if cache_dir is not None else None,
            workers=workers,
            seed=seed,
        )
        dm = MixedBoxDataModule(real, sim, seed=seed)
    return fit_geometry(
        dm,
        out,
        feature_config=feature_config,
        model_config=model_config,
        epochs=epochs,
        seed=seed,
        run_dir=run_dir,
        resume=resume,
        progress=progress,
        threads=threads,
        meta={
            "trained_on": "CVMHAT-format boxes",
            "sites": sorted(real._sites()[0]),
            "noise_copies": noise_copies,
            "sim_scenes": sim_scenes,
            "synchronised": synchronise,
            "retimed": retimed,
        },
    )
