"""LightningModule of the learned matcher: steps, logging and the optimiser, nothing else.

It wraps a plain :class:`~xvmatch.models.cross_view_matcher.CrossViewMatcher` (or a bare
:class:`~xvmatch.models.geometry_encoder.GeometryEncoder`) and a
:class:`~xvmatch.models.losses.GeometryMatchingLoss`, both passed in. Validation also measures
the association itself: each frame's cost matrix goes through the Hungarian assignment with the
non-association cost ``gamma`` (Eq. 2 of the geometric-priors paper) and the cross-view ID F1
(CVIDF1, in percent) is logged as ``val_f1``, the quantity checkpointing and early stopping
watch.

A loss with a ``gate_weight`` above 0 (appearance-confidence fine-tunes, issue 31) adds its
clean-frame term on batches that mark the frames with corrupted appearance (``app_corrupted``);
one with a ``gate_target_weight`` above 0 adds its per-frame gate target, for which each batch
runs twice more without gradient (gates open, gates closed).
"""

from __future__ import annotations

import math

import lightning as L
import numpy as np
import torch
from torch import Tensor, nn

from xvmatch.inference.linking.assignment import assign
from xvmatch.metrics.cross_view_metrics import count_frame, summarize
from xvmatch.models.losses import GeometryMatchingLoss, frame_nll

__all__ = ["GeometryMatchingModule", "frame_counts"]

_INPUTS = ("top", "hor", "hyp", "pair", "top_mask", "hor_mask", "hyp_mask")


def frame_counts(cost: np.ndarray, match: np.ndarray, gamma: float):
    """Association counts of one frame from its cost matrix and ground-truth pairs.

    Rows and columns stand for people; a matched column takes its row's label, an unmatched one
    a label of its own, so :func:`~xvmatch.metrics.cross_view_metrics.count_frame` scores it
    like the real ids would.
    """
    m, n = cost.shape
    top_ids = np.arange(m)
    hor_ids = -1 - np.arange(n)
    rows, cols = np.nonzero(match)
    hor_ids[cols] = rows
    pairs = assign(cost, gamma)
    return count_frame(top_ids, hor_ids, [(int(a), int(hor_ids[b])) for a, b in pairs])


class GeometryMatchingModule(L.LightningModule):
    """Trains a matcher on padded frame batches with labels (``collate_labelled``); batches
    with ``cues`` and ``cue_mask`` pass them on.

    Args:
        model: the matcher (or bare geometry encoder) to train.
        loss: the training loss (default :class:`GeometryMatchingLoss` with its defaults).
        learning_rate: peak learning rate (AdamW; warm-up then cosine decay).
        weight_decay: AdamW weight decay.
        gamma: non-association cost used to measure the validation CVIDF1.
    """

    def __init__(
        self,
        model: nn.Module,
        loss: GeometryMatchingLoss | None = None,
        learning_rate: float = 2e-3,
        weight_decay: float = 1e-4,
        gamma: float = 0.5,
    ) -> None:
        super().__init__()
        if not learning_rate > 0:
            raise ValueError(f"learning_rate must be > 0, got {learning_rate}")
        self.model = model
        self.loss = loss or GeometryMatchingLoss()
        self.learning_rate = learning_rate
        self.weight_decay = weight_decay
        self.gamma = gamma
        self.save_hyperparameters(ignore=["model", "loss"])
        self._val_counts: list = []

    def forward(self, batch: dict[str, Tensor], gates: Tensor | None = None):
        """The model's :class:`GeometryOutput` for a batch from ``collate_labelled``
        (``gates``: the ``app`` cue's gates instead of the confidence head's)."""
        inputs = [batch[k] for k in _INPUTS]
        if "cues" in batch:
            return self.model(*inputs, batch["cues"], batch["cue_mask"], gates=gates)
        return self.model(*inputs)

    def _gate_target(self, batch: dict[str, Tensor], gates: Tensor) -> Tensor:
        """The loss's per-frame gate target term: each frame run again with the ``app``
        gates open (1) and closed (0), no gradient."""
        with torch.no_grad():
            nll = [frame_nll(self(batch, torch.full_like(gates, value)).log_assignment,
                             batch["match"], batch["top_mask"], batch["hor_mask"])
                   for value in (1.0, 0.0)]
        has_app = batch["cue_mask"][:, self.model.cues.index("app")]
        return self.loss.gate_target_term(gates, nll[0], nll[1], has_app)

    def _step(self, batch: dict[str, Tensor], stage: str) -> tuple[Tensor, object]:
        output = self(batch)
        terms = self.loss(
            output,
            batch["match"],
            batch["camera_correct"],
            batch["top_mask"],
            batch["hor_mask"],
            batch["hyp_mask"],
        )
        gate_weight = getattr(self.loss, "gate_weight", 0.0)
        gates = getattr(self.model, "last_gates", None)
        if gate_weight > 0 and gates is not None and "app_corrupted" in batch:
            # Clean-frame term: gates of frames with uncorrupted appearance pulled to 1.
            i = self.model.cues.index("app")
            clean = batch["cue_mask"][:, i] & ~batch["app_corrupted"]
            terms = dict(terms)
            terms["gate"] = self.loss.gate_term(gates, clean)
            terms["total"] = terms["total"] + gate_weight * terms["gate"]
        target_weight = getattr(self.loss, "gate_target_weight", 0.0)
        if target_weight > 0 and gates is not None:
            terms = dict(terms)
            terms["gate_target"] = self._gate_target(batch, gates)
            terms["total"] = terms["total"] + target_weight * terms["gate_target"]
        size = int(batch["top"].shape[0])
        for name, value in terms.items():
            self.log(
                f"{stage}/{name}", value, batch_size=size, prog_bar=(name == "total"),
                on_step=(stage == "train"), on_epoch=True,
            )
        return terms["total"], output

    def training_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        loss, _ = self._step(batch, "train")
        return loss

    def validation_step(self, batch: dict[str, Tensor], batch_idx: int) -> Tensor:
        loss, output = self._step(batch, "val")
        cost = output.cost.detach().cpu().numpy()
        match = batch["match"].cpu().numpy()
        m = batch["top_mask"].sum(dim=1).cpu().numpy()
        n = batch["hor_mask"].sum(dim=1).cpu().numpy()
        for k in range(cost.shape[0]):
            self._val_counts.append(
                frame_counts(cost[k, : m[k], : n[k]], match[k, : m[k], : n[k]], self.gamma)
            )
        return loss

    def on_validation_epoch_end(self) -> None:
        if self._val_counts:
            scores = summarize(self._val_counts)
            self.log("val_f1", scores.cvidf1, prog_bar=True)
            self.log("val_cvma", scores.cvma)
        self._val_counts = []

    def configure_optimizers(self):
        optimiser = torch.optim.AdamW(
            self.model.parameters(), lr=self.learning_rate, weight_decay=self.weight_decay
        )
        # Linear warm-up over the first 10% of the steps, then cosine decay to 1% of the peak.
        # The total is read when the optimiser is built, so resuming with a larger epoch budget
        # stretches the schedule instead of failing (the lambda itself is not checkpointed).
        total = max(int(self.trainer.estimated_stepping_batches), 1)
        warmup = max(1, total // 10)

        def factor(step: int) -> float:
            if step < warmup:
                return (step + 1) / warmup
            progress = min(1.0, (step - warmup) / max(1, total - warmup))
            return 0.01 + 0.99 * 0.5 * (1.0 + math.cos(math.pi * progress))

        schedule = torch.optim.lr_scheduler.LambdaLR(optimiser, factor)
        return {
            "optimizer": optimiser,
            "lr_scheduler": {"scheduler": schedule, "interval": "step"},
        }
