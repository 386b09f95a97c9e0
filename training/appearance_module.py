"""Lightning training of the Siamese appearance branch (Section 3.3.2 of the CVMHAT paper).

:class:`AppearanceModule` wraps a plain :class:`~xvmatch.models.appearance_net.AppearanceNet`
(one set of weights for both views) and holds only the steps, the metrics and the optimiser.
Each batch holds whole image pairs (:class:`~xvmatch.training.image_datamodule.CropBatch`); the
descriptors of every real crop of both views go through the network in one pass, and the
contrastive loss of Hadsell et al. (:class:`~xvmatch.models.losses.ContrastiveLoss`) is taken
on the ``(M, N)`` descriptor distances ``|a - b| / 2`` of each pair, keeping the hardest
negatives of each row and column; a second contrastive term, weighted by ``geo_hard_weight``,
is taken over the true pairs and the geometrically hard negatives only (false pairs whose rays
nearly meet: where the fused matcher needs appearance most).

Metrics (validation and test, over whole epochs): ``loss``; ``rank1``, the fraction of
egocentric crops with a partner whose nearest top-view crop is that partner; ``pos_dist`` and
``neg_dist``, the mean distance of true and false pairs.

:class:`SaveAppearanceWeights` writes the best checkpoint's network as an appearance weights
file (:func:`~xvmatch.models.appearance_net.save_appearance_weights`), which carries its
preprocessing, at the end of ``fit``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_info
from torch import Tensor, nn

from xvmatch.models.appearance_net import appearance_distance, save_appearance_weights
from xvmatch.models.losses import ContrastiveLoss
from xvmatch.training.checkpoint_files import best_checkpoint_path, load_checkpoint_state
from xvmatch.training.image_datamodule import CropBatch

__all__ = [
    "AppearanceModule",
    "SaveAppearanceWeights",
    "embed_batch",
    "hparams_ignore",
    "pair_metrics",
]


def hparams_ignore(*names: str) -> list[str]:
    """Module arguments to leave out of ``save_hyperparameters``.

    When LightningCLI instantiates the module, the hyperparameters it saves are the parsed
    configuration, where a sub-module argument is its ``class_path``/``init_args``: keeping it
    lets ``load_from_checkpoint(path)`` rebuild the module alone. Built in Python, the argument
    is the module object itself, already in the state dict: it is left out, and
    ``load_from_checkpoint(path, net=...)`` takes it again.
    """
    try:
        from lightning.pytorch.core.mixins.hparams_mixin import _given_hyperparameters
    except ImportError:  # a Lightning without the CLI hook: always leave them out
        return list(names)
    return [] if _given_hyperparameters.get() is not None else list(names)


def embed_batch(net: nn.Module, batch: CropBatch) -> tuple[Tensor, Tensor]:
    """Descriptors of the real crops of a batch, in one pass, scattered back to the padding.

    Args:
        net: a network with ``embed_crops((K, H, W, 3)) -> (K, D)``.
        batch: the padded batch.

    Returns:
        ``(B, M, D)`` top and ``(B, N, D)`` egocentric descriptors; zeros on padding.
    """
    top = batch.top[batch.top_mask]
    ego = batch.ego[batch.ego_mask]
    crops = torch.cat([top, ego.to(top.dtype)], dim=0)
    emb = net.embed_crops(crops)
    d = emb.shape[1]
    out_top = emb.new_zeros(*batch.top_mask.shape, d)
    out_ego = emb.new_zeros(*batch.ego_mask.shape, d)
    out_top[batch.top_mask] = emb[: top.shape[0]]
    out_ego[batch.ego_mask] = emb[top.shape[0]:]
    return out_top, out_ego


def pair_metrics(distance: Tensor, match: Tensor, pair_mask: Tensor) -> dict[str, Tensor]:
    """Sums behind the epoch metrics of a batch (divide once per epoch).

    Returns:
        ``{"rank1_hits", "rank1_total", "pos_sum", "pos_count", "neg_sum", "neg_count"}``
        as 0-d tensors: an egocentric crop counts in ``rank1_total`` when it has a partner,
        and a hit when its nearest valid top crop is that partner.
    """
    match = match & pair_mask
    big = torch.finfo(distance.dtype).max
    d = distance.detach().masked_fill(~pair_mask, big)
    has_partner = match.any(dim=1)
    if d.shape[1] > 0:
        nearest = d.argmin(dim=1, keepdim=True)
        hit = match.gather(1, nearest).squeeze(1) & has_partner
    else:
        hit = has_partner
    neg = ~match & pair_mask
    dist = distance.detach()
    return {
        "rank1_hits": hit.sum(), "rank1_total": has_partner.sum(),
        "pos_sum": dist[match].sum(), "pos_count": match.sum(),
        "neg_sum": dist[neg].sum(), "neg_count": neg.sum(),
    }


class AppearanceModule(L.LightningModule):
    """Contrastive training of a Siamese appearance network on image pairs.

    Args:
        net: the network shared by both views (e.g. ``appearance_small()``); its input size
            must equal the DataModule's crops.
        margin: contrastive margin on descriptor distances in [0, 1].
        hard_negatives: hardest negatives kept per row and column of a pair (0: all).
        lr: peak learning rate of AdamW.
        weight_decay: AdamW weight decay.
        warmup_steps: linear warm-up steps, then cosine decay to ``lr * final_lr_ratio`` at the
            last step.
        final_lr_ratio: final learning rate over the peak.
        geo_hard_weight: weight of the contrastive term over true pairs and geometrically hard
            negatives (0: off).
    """

    def __init__(
        self,
        net: nn.Module,
        margin: float = 0.5,
        hard_negatives: int = 2,
        lr: float = 1e-3,
        weight_decay: float = 1e-4,
        warmup_steps: int = 50,
        final_lr_ratio: float = 0.05,
        geo_hard_weight: float = 0.0,
    ) -> None:
        super().__init__()
        if not hasattr(net, "embed_crops"):
            raise TypeError(f"net must have embed_crops (an AppearanceNet), got {type(net)}")
        self.save_hyperparameters(ignore=hparams_ignore("net"))
        self.net = net
        self.loss = ContrastiveLoss(margin, hard_negatives)
        self.geo_hard_loss = ContrastiveLoss(margin, hard_negatives=0)
        self._sums: dict[str, dict[str, Tensor]] = {}

    def forward(self, batch: CropBatch) -> Tensor:
        """``(B, M, N)`` appearance costs of a batch of pairs (padding included)."""
        top, ego = embed_batch(self.net, batch)
        return appearance_distance(top, ego)

    def setup(self, stage: str) -> None:
        """Check that the DataModule crops at the network's input size."""
        dm = getattr(self.trainer, "datamodule", None) if self._trainer is not None else None
        size = getattr(dm, "input_size", None)
        want = getattr(getattr(self.net, "preprocessing", None), "input_size", None)
        if size is not None and want is not None and tuple(size) != tuple(want):
            raise ValueError(
                f"the data crops {size[0]}x{size[1]} but the network expects "
                f"{want[0]}x{want[1]} (height x width); set data.input_height/input_width"
            )

    def _step(self, batch: CropBatch) -> tuple[Tensor, Tensor, Tensor]:
        distance = self(batch)
        pair_mask = batch.top_mask[:, :, None] & batch.ego_mask[:, None, :]
        loss = self.loss(distance, batch.match, pair_mask)
        if self.hparams.geo_hard_weight > 0:
            hard = pair_mask & (batch.match | batch.near)
            loss = loss + self.hparams.geo_hard_weight * self.geo_hard_loss(
                distance, batch.match, hard)
        return loss, distance, pair_mask

    def training_step(self, batch: CropBatch, batch_idx: int) -> Tensor | None:
        """Contrastive loss of a training batch (None, a skipped step, when it has fewer
        than two crops: batch normalisation needs two)."""
        if int(batch.top_mask.sum() + batch.ego_mask.sum()) < 2:
            return None
        loss, _, _ = self._step(batch)
        self.log("train/loss", loss, prog_bar=True, batch_size=batch.top.shape[0])
        return loss

    def _eval_step(self, batch: CropBatch, split: str) -> None:
        loss, distance, pair_mask = self._step(batch)
        sums = pair_metrics(distance, batch.match, pair_mask)
        sums["loss_sum"] = loss.detach() * batch.top.shape[0]
        sums["loss_count"] = torch.tensor(batch.top.shape[0])
        acc = self._sums.setdefault(split, {})
        for k, v in sums.items():
            acc[k] = acc.get(k, 0) + v.detach().double().cpu()

    def _eval_end(self, split: str) -> None:
        acc = self._sums.pop(split, None)
        if not acc:
            return

        def ratio(num: str, den: str) -> float:
            d = float(acc[den])
            return float(acc[num]) / d if d > 0 else math.nan

        self.log_dict({
            f"{split}/loss": ratio("loss_sum", "loss_count"),
            f"{split}/rank1": ratio("rank1_hits", "rank1_total"),
            f"{split}/pos_dist": ratio("pos_sum", "pos_count"),
            f"{split}/neg_dist": ratio("neg_sum", "neg_count"),
        }, prog_bar=split == "val", sync_dist=True)

    def validation_step(self, batch: CropBatch, batch_idx: int) -> None:
        """Accumulate the validation metrics."""
        self._eval_step(batch, "val")

    def on_validation_epoch_end(self) -> None:
        """Log ``val/loss``, ``val/rank1``, ``val/pos_dist``, ``val/neg_dist``."""
        self._eval_end("val")

    def test_step(self, batch: CropBatch, batch_idx: int) -> None:
        """Accumulate the test metrics."""
        self._eval_step(batch, "test")

    def on_test_epoch_end(self) -> None:
        """Log the ``test/`` metrics."""
        self._eval_end("test")

    def configure_optimizers(self):
        """AdamW with linear warm-up and cosine decay, stepped every batch."""
        hp = self.hparams
        optimizer = torch.optim.AdamW(self.parameters(), lr=hp.lr, weight_decay=hp.weight_decay)
        total = max(1, int(self.trainer.estimated_stepping_batches))
        warm = max(0, min(int(hp.warmup_steps), total - 1))

        def factor(step: int) -> float:
            if step < warm:
                return (step + 1) / (warm + 1)
            t = min(1.0, (step - warm) / max(1, total - warm))
            return hp.final_lr_ratio + (1 - hp.final_lr_ratio) * 0.5 * (1 + math.cos(math.pi * t))

        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, factor)
        return {"optimizer": optimizer,
                "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}


class SaveAppearanceWeights(L.Callback):
    """At the end of ``fit``, write the best checkpoint's network as an appearance weights file.

    The best checkpoint is the one of the first ``ModelCheckpoint`` callback with a monitored
    metric; without one, the final network is written.

    Args:
        filename: file name, written in the run's log directory (``trainer.log_dir``).
        path: an explicit output path instead (overrides ``filename``).
    """

    def __init__(self, filename: str = "appearance_weights.pt", path: str | None = None) -> None:
        super().__init__()
        self.filename = filename
        self.path = path
        self.written: Path | None = None

    def on_fit_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        """Load the best checkpoint (if any) into the module and write its network.

        The best checkpoint is read with ``weights_only=True`` and only from the checkpoint
        callback's own folder: a resumed checkpoint could store any path there.
        """
        best, score = "", None
        ckpt = trainer.checkpoint_callback
        best_path = best_checkpoint_path(ckpt)  # refuses a path outside the run's own folder
        if best_path is not None:
            best = os.fspath(best_path)
            score = ckpt.best_model_score
            pl_module.load_state_dict(load_checkpoint_state(best_path))
        if not trainer.is_global_zero:
            return
        out = Path(self.path) if self.path else Path(trainer.log_dir or ".") / self.filename
        dm = trainer.datamodule
        meta = {
            "checkpoint": os.fspath(best),
            "monitor": getattr(ckpt, "monitor", None),
            "best_score": None if score is None else float(score),
            "epochs": int(trainer.current_epoch),
            "global_step": int(trainer.global_step),
            "train_data": list(getattr(dm, "train_folders", [])),
            # the crops' margin, so that a bundle made of these weights crops as in training
            "context": float(getattr(getattr(dm, "hparams", None), "context", 0.1)),
            "val_data": list(getattr(dm, "val_folders", [])),
            "module": {k: v for k, v in pl_module.hparams.items()
                       if isinstance(v, int | float | str | bool)},
        }
        self.written = save_appearance_weights(pl_module.net, out, meta).path
        rank_zero_info(f"wrote appearance weights {out}")
