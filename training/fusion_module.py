"""Lightning training of a fusion head on cue matrices (learned fusion of Section III-C).

:class:`FusionModule` wraps a fusion head of :mod:`xvmatch.models.fusion_heads` (typically a
:class:`~xvmatch.models.fusion_heads.LearnedFusionHead` over ``{"app", "geo", "cheir"}``) and
trains it on :class:`~xvmatch.training.fusion_datamodule.CueBatch` batches with

* the contrastive loss of Hadsell et al. on the fused costs
  (:class:`~xvmatch.models.losses.ContrastiveLoss`, hardest negatives per row and column), and
* optionally an assignment-level loss: the negative log-likelihood of the true partial
  assignment under a log-space Sinkhorn of ``-cost / temperature`` with one learnable
  non-association score ``-gamma / temperature`` (the dustbin of SuperGlue; Eq. 2's gamma made
  differentiable), :class:`~xvmatch.models.losses.AssignmentNLLLoss`.

Validation also reports ``val/acc9``: the Eq. 9 accuracy of the Hungarian association (Eqs.
1-2, :func:`xvmatch.inference.linking.assignment.assign`) at the best gamma of a grid, and that
gamma (``val/gamma``), computed exactly as
:func:`xvmatch.evaluation.handcrafted_baseline.count_pair` does from the batch's labels.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import lightning as L
import numpy as np
import torch
from torch import Tensor, nn

from xvmatch.inference.linking.assignment import GAMMA_GRID, assign
from xvmatch.models.geometry_encoder import LogSinkhorn
from xvmatch.models.losses import AssignmentNLLLoss, ContrastiveLoss
from xvmatch.training.appearance_module import hparams_ignore
from xvmatch.training.fusion_datamodule import CueBatch

__all__ = ["FusionModule", "batch_acc9"]


def batch_acc9(cost: np.ndarray, batch: CueBatch, gammas: Sequence[float]) -> np.ndarray:
    """Per-pair Eq. 9 accuracy of the Hungarian association at each gamma.

    ``(TP + TN) / U`` with TP the predicted pairs that are true, TN the boxes of persons seen
    in one view only that are left unmatched, U the unique persons (as
    :func:`~xvmatch.metrics.cross_view_metrics.count_pair`).

    Args:
        cost: ``(B, M, N)`` fused costs.
        batch: the batch's masks and labels.
        gammas: non-association costs.

    Returns:
        ``(B, len(gammas))`` accuracies; NaN for pairs without persons.
    """
    out = np.full((cost.shape[0], len(gammas)), np.nan)
    top_mask = batch.top_mask.cpu().numpy()
    ego_mask = batch.ego_mask.cpu().numpy()
    match = batch.match.cpu().numpy()
    top_solo = batch.top_solo.cpu().numpy()
    ego_solo = batch.ego_solo.cpu().numpy()
    n_union = batch.n_union.cpu().numpy()
    for b in range(cost.shape[0]):
        if n_union[b] == 0:
            continue
        m, n = int(top_mask[b].sum()), int(ego_mask[b].sum())
        c = cost[b, :m, :n]
        for k, g in enumerate(gammas):
            pairs = assign(c, g)
            tp = int(match[b, pairs[:, 0], pairs[:, 1]].sum())
            free_top = np.ones(m, bool)
            free_top[pairs[:, 0]] = False
            free_ego = np.ones(n, bool)
            free_ego[pairs[:, 1]] = False
            tn = int((top_solo[b, :m] & free_top).sum() + (ego_solo[b, :n] & free_ego).sum())
            out[b, k] = (tp + tn) / n_union[b]
    return out


class FusionModule(L.LightningModule):
    """Learns a fusion head from cue matrices.

    Args:
        head: the fusion head (``head({cue: (B, M, N)}) -> (B, M, N)`` in [0, 1]).
        margin: contrastive margin on fused costs.
        hard_negatives: hardest negatives kept per row and column (0: all).
        nll_weight: weight of the assignment NLL (0: contrastive loss only).
        temperature: Sinkhorn temperature on costs.
        gamma_init: initial non-association cost of the Sinkhorn dustbin.
        lr: Adam learning rate.
        weight_decay: Adam weight decay.
        gamma_grid: gammas tried for ``val/acc9`` (default: the baseline's grid).
        sinkhorn_iterations: Sinkhorn iterations.
    """

    def __init__(
        self,
        head: nn.Module,
        margin: float = 0.9,
        hard_negatives: int = 2,
        nll_weight: float = 0.5,
        temperature: float = 0.1,
        gamma_init: float = 0.3,
        lr: float = 1e-2,
        weight_decay: float = 0.0,
        gamma_grid: list[float] | None = None,
        sinkhorn_iterations: int = 20,
    ) -> None:
        super().__init__()
        if not temperature > 0:
            raise ValueError(f"temperature must be > 0, got {temperature}")
        if not 0 < gamma_init < 1:
            raise ValueError(f"gamma_init must be in (0, 1), got {gamma_init}")
        self.save_hyperparameters(ignore=hparams_ignore("head"))
        self.head = head
        self.contrastive = ContrastiveLoss(margin, hard_negatives)
        self.nll = AssignmentNLLLoss()
        self.sinkhorn = LogSinkhorn(sinkhorn_iterations)
        self.gamma_logit = nn.Parameter(torch.logit(torch.tensor(float(gamma_init))))
        self.gamma_grid = tuple(float(g) for g in (gamma_grid or GAMMA_GRID))
        self._val: list[np.ndarray] = []
        self._val_loss: list[tuple[float, int]] = []

    def forward(self, batch: CueBatch) -> Tensor:
        """``(B, M, N)`` fused costs; 1 on padding."""
        fused = self.head(batch.costs)
        pair_mask = (batch.top_mask[:, :, None] & batch.ego_mask[:, None, :]).to(fused.dtype)
        return fused * pair_mask + (1.0 - pair_mask)

    def losses(self, batch: CueBatch) -> tuple[dict[str, Tensor], Tensor]:
        """``({"contrastive", "nll", "total"}, fused costs)`` of a batch."""
        fused = self(batch)
        pair_mask = batch.top_mask[:, :, None] & batch.ego_mask[:, None, :]
        terms = {"contrastive": self.contrastive(fused, batch.match, pair_mask)}
        total = terms["contrastive"]
        if self.hparams.nll_weight > 0:
            t = self.hparams.temperature
            dustbin = -torch.sigmoid(self.gamma_logit) / t
            log_p = self.sinkhorn(-fused / t, dustbin, batch.top_mask, batch.ego_mask)
            terms["nll"] = self.nll(log_p, batch.match, batch.top_mask, batch.ego_mask)
            total = total + self.hparams.nll_weight * terms["nll"]
        terms["total"] = total
        return terms, fused

    def training_step(self, batch: CueBatch, batch_idx: int) -> Tensor:
        """Weighted loss of a training batch."""
        terms, _ = self.losses(batch)
        b = batch.top_mask.shape[0]
        self.log("train/loss", terms["total"], prog_bar=True, batch_size=b)
        for k in ("contrastive", "nll"):
            if k in terms:
                self.log(f"train/{k}", terms[k], batch_size=b)
        self.log("train/gamma", torch.sigmoid(self.gamma_logit), batch_size=b)
        return terms["total"]

    def validation_step(self, batch: CueBatch, batch_idx: int) -> None:
        """Accumulate the loss and the per-pair accuracies over the gamma grid."""
        terms, fused = self.losses(batch)
        b = batch.top_mask.shape[0]
        self._val_loss.append((float(terms["total"]) * b, b))
        self._val.append(batch_acc9(fused.detach().double().cpu().numpy(), batch,
                                    self.gamma_grid))

    def on_validation_epoch_end(self) -> None:
        """Log ``val/loss``, ``val/acc9`` (best gamma of the grid) and ``val/gamma``."""
        if not self._val:
            return
        acc = np.concatenate(self._val)
        acc = acc[~np.isnan(acc[:, 0])]
        mean = acc.mean(axis=0) if len(acc) else np.zeros(len(self.gamma_grid))
        best = float(mean.max())
        tied = [g for g, a in zip(self.gamma_grid, mean, strict=True) if a == best]
        loss = sum(v for v, _ in self._val_loss) / max(1, sum(n for _, n in self._val_loss))
        self.log_dict({"val/loss": loss, "val/acc9": best,
                       "val/gamma": tied[(len(tied) - 1) // 2]}, prog_bar=True)
        self._val, self._val_loss = [], []

    def configure_optimizers(self):
        """Adam on the head and the dustbin score, cosine-decayed per epoch."""
        optimizer = torch.optim.Adam(self.parameters(), lr=self.hparams.lr,
                                     weight_decay=self.hparams.weight_decay)
        epochs = self.trainer.max_epochs if self.trainer.max_epochs and \
            self.trainer.max_epochs > 0 else 1
        scheduler = torch.optim.lr_scheduler.LambdaLR(
            optimizer, lambda e: 0.1 + 0.9 * 0.5 * (1 + math.cos(math.pi * min(1.0, e / epochs)))
        )
        return {"optimizer": optimizer, "lr_scheduler": scheduler}
