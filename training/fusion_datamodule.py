"""Cue matrices of synthetic image pairs, for learning a fusion head.

Each item is one image pair in one setting (ground-truth boxes, or detector-noise boxes matched
to the ground truth at IoU 0.3), its boxes shuffled per view, built exactly as the evaluation
builds its trials (:func:`xvmatch.datasets.pair_trials.scene_trials`): the
normalised cues ``{"app", "geo", "cheir", "hist"}`` as ``(M, N)`` matrices, the ground-truth
match matrix, and what the Eq. 9 accuracy needs (which boxes stand for a person seen in one
view only, the number of unique persons). The appearance cue comes from a trained appearance
weights file (frozen); ids only build the labels.

Training pairs use detector-noise seeds (``noise_seeds``) and a scrambling seed different from
the evaluation's (0), so the head never sees the evaluation's detections; validation pairs are
built with the evaluation's own settings, on a validation folder.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import NamedTuple

import lightning as L
import numpy as np
import torch
from torch import Tensor
from torch.utils.data import DataLoader, Dataset

from xvmatch.datasets.pair_trials import CUES, SETTINGS, PairTrial, TrialConfig, dataset_trials
from xvmatch.models.appearance_net import appearance_from_weights
from xvmatch.training.appearance_costs import AppearanceCoster

__all__ = ["CueBatch", "CuePairDataModule", "TrialDataset", "collate_trials"]


class CueBatch(NamedTuple):
    """A padded batch of trials.

    Attributes:
        costs: ``{cue: (B, M, N)}`` normalised cues (padding 1).
        top_mask: ``(B, M)`` bool, real top boxes.
        ego_mask: ``(B, N)`` bool, real egocentric boxes.
        match: ``(B, M, N)`` bool ground truth.
        top_solo: ``(B, M)`` bool, the box stands for a person seen in the top view only.
        ego_solo: ``(B, N)`` bool, likewise for the egocentric view.
        n_union: ``(B,)`` unique persons of Eq. 9.
    """

    costs: dict[str, Tensor]
    top_mask: Tensor
    ego_mask: Tensor
    match: Tensor
    top_solo: Tensor
    ego_solo: Tensor
    n_union: Tensor


class TrialDataset(Dataset):
    """A list of :class:`PairTrial` as a map-style dataset."""

    def __init__(self, trials: Sequence[PairTrial]) -> None:
        self.trials = list(trials)

    def __len__(self) -> int:
        return len(self.trials)

    def __getitem__(self, k: int) -> PairTrial:
        return self.trials[k]


def collate_trials(trials: Sequence[PairTrial], names: Sequence[str] = CUES) -> CueBatch:
    """Pad trials to the batch's largest M and N (at least 1 each; empty sides allowed).

    Args:
        trials: the trials (with ``app`` costs when ``"app"`` is among ``names``).
        names: the cues to stack.
    """
    if not trials:
        raise ValueError("cannot collate an empty list of trials")
    b = len(trials)
    m = max(1, max(t.top_boxes.shape[0] for t in trials))
    n = max(1, max(t.ego_boxes.shape[0] for t in trials))
    costs = {k: torch.ones(b, m, n) for k in names}
    top_mask = torch.zeros(b, m, dtype=torch.bool)
    ego_mask = torch.zeros(b, n, dtype=torch.bool)
    match = torch.zeros(b, m, n, dtype=torch.bool)
    top_solo = torch.zeros(b, m, dtype=torch.bool)
    ego_solo = torch.zeros(b, n, dtype=torch.bool)
    n_union = torch.zeros(b, dtype=torch.long)
    for i, t in enumerate(trials):
        mi, ni = t.top_boxes.shape[0], t.ego_boxes.shape[0]
        cues = t.cues()
        for k in names:
            if k not in cues:
                raise ValueError(f"trial {t.scene}/{t.frame} has no {k!r} cue; build the trials "
                                 "with an appearance coster")
            costs[k][i, :mi, :ni] = torch.from_numpy(np.asarray(cues[k], np.float32))
        top_mask[i, :mi] = True
        ego_mask[i, :ni] = True
        match[i, :mi, :ni] = torch.from_numpy(t.match())
        ts, es = t.solo()
        top_solo[i, :mi] = torch.from_numpy(ts)
        ego_solo[i, :ni] = torch.from_numpy(es)
        n_union[i] = t.n_union
    return CueBatch(costs, top_mask, ego_mask, match, top_solo, ego_solo, n_union)


class _Collate:
    def __init__(self, names: Sequence[str]) -> None:
        self.names = tuple(names)

    def __call__(self, trials: Sequence[PairTrial]) -> CueBatch:
        return collate_trials(trials, self.names)


def _folders(value: str | Sequence[str] | None) -> list[str]:
    if value is None:
        return []
    return [value] if isinstance(value, str | os.PathLike) else [os.fspath(v) for v in value]


class CuePairDataModule(L.LightningDataModule):
    """Trials of synthetic image pairs with their cue matrices: train and validation folders.

    Args:
        train_data: dataset folder(s) for the head; use scenes the appearance network was not
            trained on, so its costs are as on unseen data.
        val_data: dataset folder(s) for validation (the evaluation's settings and seeds).
        appearance_weights: appearance weights file giving the ``"app"`` cue; None: no
            ``"app"`` cue (a head on ``geo``/``cheir``/``hist`` only).
        names: the cues the head takes (the batch carries only these).
        settings: ``"gt"`` and/or ``"det"`` trials for training.
        noise_seeds: detector-noise seeds of the training ``"det"`` trials (one copy each);
            keep them different from the evaluation's seed 0.
        scramble_seed: shuffling seed of the training trials.
        batch_size: trials per batch.
        seed: seed of the batch order.
        device: where the appearance network runs while the cues are computed.
    """

    def __init__(
        self,
        train_data: str | list[str],
        val_data: str | list[str],
        appearance_weights: str | None = None,
        names: list[str] | None = None,
        settings: list[str] | None = None,
        noise_seeds: list[int] | None = None,
        scramble_seed: int = 5,
        batch_size: int = 16,
        seed: int = 0,
        device: str = "cpu",
    ) -> None:
        super().__init__()
        self.save_hyperparameters()
        self.train_folders = _folders(train_data)
        self.val_folders = _folders(val_data)
        if not self.train_folders or not self.val_folders:
            raise ValueError("train_data and val_data must each name at least one folder")
        self.names = tuple(names or ("app", "geo", "cheir"))
        unknown = [k for k in self.names if k not in CUES]
        if unknown:
            raise ValueError(f"names must be among {', '.join(CUES)}, got {unknown}")
        if "app" in self.names and appearance_weights is None:
            raise ValueError("the 'app' cue needs appearance_weights (a file written by "
                             "training the appearance network)")
        self.settings = tuple(settings or SETTINGS)
        bad = [s for s in self.settings if s not in SETTINGS]
        if bad:
            raise ValueError(f"settings must be among {', '.join(SETTINGS)}, got {bad}")
        self.noise_seeds = tuple(int(s) for s in (noise_seeds if noise_seeds is not None
                                                  else (11, 12)))
        if int(batch_size) < 1:
            raise ValueError(f"batch_size must be >= 1, got {batch_size}")
        self.batch_size = int(batch_size)
        self.splits: dict[str, list[PairTrial]] = {}

    def _coster(self) -> AppearanceCoster | None:
        weights = self.hparams.appearance_weights
        if weights is None or "app" not in self.names:
            return None
        return AppearanceCoster(appearance_from_weights(weights), device=self.hparams.device)

    def setup(self, stage: str | None = None) -> None:
        """Build the trials (once): the training settings and noise seeds, and validation."""
        if "train" in self.splits:
            return
        coster = self._coster()
        train: list[PairTrial] = []
        for folder in self.train_folders:
            if "gt" in self.settings:
                config = TrialConfig(scramble_seed=self.hparams.scramble_seed)
                train += dataset_trials(folder, config, ("gt",), coster)
            if "det" in self.settings:
                for s in self.noise_seeds:
                    config = TrialConfig(noise_seed=s, scramble_seed=self.hparams.scramble_seed)
                    train += dataset_trials(folder, config, ("det",), coster)
        val: list[PairTrial] = []
        for folder in self.val_folders:
            val += dataset_trials(folder, TrialConfig(), SETTINGS, coster)
        self.splits = {"train": train, "val": val}

    def _loader(self, split: str, shuffle: bool) -> DataLoader:
        if split not in self.splits:
            raise RuntimeError(f"no {split} split: call setup() first")
        generator = torch.Generator().manual_seed(int(self.hparams.seed)) if shuffle else None
        return DataLoader(TrialDataset(self.splits[split]), batch_size=self.batch_size,
                          shuffle=shuffle, generator=generator, collate_fn=_Collate(self.names))

    def train_dataloader(self) -> DataLoader:
        """Shuffled training trials (seeded)."""
        return self._loader("train", True)

    def val_dataloader(self) -> DataLoader:
        """Validation trials in order."""
        return self._loader("val", False)

    def describe(self) -> str:
        """One line: trials per split."""
        return "; ".join(f"{k}: {len(v)} trials" for k, v in self.splits.items()) or "not set up"
