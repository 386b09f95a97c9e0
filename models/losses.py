"""Training losses of the learned matcher, as ``nn.Module``s (like ``torch.nn`` losses).

* :class:`ContrastiveLoss`: the contrastive loss of Hadsell, Chopra and LeCun ("Dimensionality
  Reduction by Learning an Invariant Mapping", CVPR 2006, Eq. 4 with ``1/2`` dropped):
  ``L = y d^2 + (1 - y) max(0, m - d)^2`` on distances ``d`` in [0, 1], here both on the
  fused costs and on the distances between the two views' person descriptors. Negatives are the
  hardest ones of each row and column (online hard-negative mining within the frame).
* :class:`AssignmentNLLLoss`: the negative log-likelihood of the ground-truth partial assignment
  under the Sinkhorn matrix, dustbins included (SuperGlue, Sarlin et al., CVPR 2020, Eq. 10).
* :class:`HypothesisLoss`: cross-entropy of the frame-level hypothesis scores against the
  hypotheses whose camera location O is the true camera wearer.
* :class:`GeometryMatchingLoss`: their weighted sum, with each term reported.

All take padded batches with masks and never divide by zero: a batch with no positive (or no
negative, or no labelled frame) contributes 0 for that part.
"""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = [
    "AssignmentNLLLoss", "ContrastiveLoss", "GeometryMatchingLoss", "HypothesisLoss",
    "frame_nll",
]


def _mean(values: Tensor, mask: Tensor) -> Tensor:
    m = mask.to(values.dtype)
    return (values * m).sum() / m.sum().clamp(min=1.0)


def hard_negative_mask(distance: Tensor, negatives: Tensor, k: int) -> Tensor:
    """Negatives among the ``k`` smallest distances of their row or of their column.

    Args:
        distance: ``(B, M, N)``.
        negatives: ``(B, M, N)`` bool, candidate negatives.
        k: negatives kept per row and per column; ``k <= 0`` keeps them all.

    Returns:
        ``(B, M, N)`` bool (ties at the k-th distance are all kept).
    """
    if k <= 0:
        return negatives
    big = torch.finfo(distance.dtype).max
    d = distance.detach().masked_fill(~negatives, big)
    out = torch.zeros_like(negatives)
    for dim in (2, 1):
        size = d.shape[dim]
        if size == 0:
            continue
        kth = d.topk(min(k, size), dim=dim, largest=False).values.amax(dim=dim, keepdim=True)
        out = out | (negatives & (d <= kth))
    return out


class ContrastiveLoss(nn.Module):
    """Contrastive loss of Hadsell et al. (2006) on pair distances in [0, 1].

    ``mean over positives of d^2 + mean over (hard) negatives of max(0, margin - d)^2``; the two
    means are taken separately so the many negatives do not drown the few positives.

    Args:
        margin: m, the distance beyond which a negative costs nothing.
        hard_negatives: negatives kept per row and column (the smallest distances); 0 keeps all.
    """

    def __init__(self, margin: float = 0.5, hard_negatives: int = 2) -> None:
        super().__init__()
        if not margin > 0:
            raise ValueError(f"margin must be > 0, got {margin}")
        self.margin = float(margin)
        self.hard_negatives = int(hard_negatives)

    def forward(self, distance: Tensor, match: Tensor, pair_mask: Tensor) -> Tensor:
        """Loss of ``distance (B, M, N)`` given the ground truth ``match (B, M, N)`` bool, over
        the valid pairs ``pair_mask (B, M, N)``."""
        positives = match & pair_mask
        negatives = hard_negative_mask(distance, ~match & pair_mask, self.hard_negatives)
        pos = _mean(distance.pow(2), positives)
        neg = _mean((self.margin - distance).clamp(min=0.0).pow(2), negatives)
        return pos + neg


def assignment_targets(match: Tensor, top_mask: Tensor, hor_mask: Tensor) -> Tensor:
    """``(B, M + 1, N + 1)`` bool targets: matched pairs, unmatched rows in the dustbin column,
    unmatched columns in the dustbin row."""
    pair_mask = top_mask[:, :, None] & hor_mask[:, None, :]
    match = match & pair_mask
    row_free = top_mask & ~match.any(dim=2)
    col_free = hor_mask & ~match.any(dim=1)
    b = match.shape[0]
    corner = torch.zeros(b, 1, 1, dtype=torch.bool, device=match.device)
    return torch.cat(
        [
            torch.cat([match, row_free[:, :, None]], dim=2),
            torch.cat([col_free[:, None, :], corner], dim=2),
        ],
        dim=1,
    )


def frame_nll(log_assignment: Tensor, match: Tensor, top_mask: Tensor,
              hor_mask: Tensor) -> Tensor:
    """``(B,)`` per-frame mean negative log-likelihood of the true assignment, dustbins
    included (0 for a frame without people)."""
    targets = assignment_targets(match, top_mask, hor_mask).to(log_assignment.dtype)
    return (-log_assignment * targets).sum((1, 2)) / targets.sum((1, 2)).clamp(min=1.0)


class AssignmentNLLLoss(nn.Module):
    """Mean negative log-likelihood of the true assignment, dustbins included (SuperGlue)."""

    def forward(
        self, log_assignment: Tensor, match: Tensor, top_mask: Tensor, hor_mask: Tensor
    ) -> Tensor:
        """Loss of ``log_assignment (B, M + 1, N + 1)`` for ``match (B, M, N)`` bool."""
        targets = assignment_targets(match, top_mask, hor_mask)
        return _mean(-log_assignment, targets)


class HypothesisLoss(nn.Module):
    """Cross-entropy of ``(B, H)`` hypothesis logits against a set of correct hypotheses.

    ``-log sum_{h correct} softmax(logits)_h`` over the valid hypotheses, averaged over the
    frames that have at least one correct hypothesis (others are unlabelled: the wearer's box
    may be missing).
    """

    def forward(self, logits: Tensor, correct: Tensor, hyp_mask: Tensor) -> Tensor:
        """Loss of ``logits (B, H)`` given ``correct (B, H)`` bool and ``hyp_mask (B, H)``."""
        neg = torch.finfo(logits.dtype).min / 4
        correct = correct & hyp_mask
        labelled = correct.any(dim=1)
        all_valid = torch.logsumexp(logits.masked_fill(~hyp_mask, neg), dim=1)
        good = torch.logsumexp(logits.masked_fill(~correct, neg), dim=1)
        per_frame = torch.where(labelled, all_valid - good, torch.zeros_like(good))
        return _mean(per_frame, labelled)


class GeometryMatchingLoss(nn.Module):
    """Weighted sum of the assignment NLL, the contrastive losses and the hypothesis loss.

    Args:
        nll_weight: weight of :class:`AssignmentNLLLoss`.
        cost_weight: weight of the contrastive loss on the costs ``1 - P``.
        embedding_weight: weight of the contrastive loss on descriptor distances
            ``|a - b| / 2`` (unit descriptors, so in [0, 1]).
        hypothesis_weight: weight of :class:`HypothesisLoss`.
        cost_margin: contrastive margin on costs.
        embedding_margin: contrastive margin on descriptor distances.
        hard_negatives: hardest negatives kept per row and column.
        gate_weight: weight of the clean-frame term of an appearance-confidence fine-tune
            (:meth:`gate_term`, added by the training module where the batch marks the frames
            with corrupted appearance); 0 (default): none.
        gate_target_weight: weight of the per-frame gate target of an appearance-confidence
            fine-tune (:meth:`gate_target_term`, added by the training module, which runs
            each frame with the gates open and closed); 0 (default): none.
    """

    def __init__(
        self,
        nll_weight: float = 1.0,
        cost_weight: float = 1.0,
        embedding_weight: float = 0.5,
        hypothesis_weight: float = 0.5,
        cost_margin: float = 0.9,
        embedding_margin: float = 0.5,
        hard_negatives: int = 2,
        gate_weight: float = 0.0,
        gate_target_weight: float = 0.0,
    ) -> None:
        super().__init__()
        if not float(gate_weight) >= 0:
            raise ValueError(f"gate_weight must be >= 0, got {gate_weight}")
        if not float(gate_target_weight) >= 0:
            raise ValueError(f"gate_target_weight must be >= 0, got {gate_target_weight}")
        self.gate_weight = float(gate_weight)
        self.gate_target_weight = float(gate_target_weight)
        self.weights = {
            "nll": float(nll_weight),
            "cost": float(cost_weight),
            "embedding": float(embedding_weight),
            "hypothesis": float(hypothesis_weight),
        }
        if any(w < 0 for w in self.weights.values()):
            raise ValueError(f"loss weights must be >= 0, got {self.weights}")
        self.nll = AssignmentNLLLoss()
        self.cost = ContrastiveLoss(cost_margin, hard_negatives)
        self.embedding = ContrastiveLoss(embedding_margin, hard_negatives)
        self.hypothesis = HypothesisLoss()

    def forward(
        self,
        output,
        match: Tensor,
        camera_correct: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        hyp_mask: Tensor,
    ) -> dict[str, Tensor]:
        """Loss terms and their weighted ``total``.

        Args:
            output: a :class:`~xvmatch.models.geometry_encoder.GeometryOutput`.
            match: ``(B, M, N)`` bool ground-truth pairs.
            camera_correct: ``(B, H)`` bool, hypotheses whose O is the camera wearer.
            top_mask, hor_mask, hyp_mask: the batch masks.
        """
        pair_mask = top_mask[:, :, None] & hor_mask[:, None, :]
        cosine = output.top_descriptors @ output.hor_descriptors.transpose(1, 2)
        emb_dist = 0.5 * (2.0 - 2.0 * cosine).clamp(min=1e-12).sqrt()
        terms = {
            "nll": self.nll(output.log_assignment, match, top_mask, hor_mask),
            "cost": self.cost(output.cost, match, pair_mask),
            "embedding": self.embedding(emb_dist.clamp(0.0, 1.0), match, pair_mask),
            "hypothesis": self.hypothesis(output.hypothesis_logits, camera_correct, hyp_mask),
        }
        terms["total"] = sum(self.weights[k] * v for k, v in terms.items())
        return terms

    def gate_term(self, gates: Tensor, clean: Tensor) -> Tensor:
        """Clean-frame term of the appearance confidence: the mean over the ``clean`` frames of
        the squared distances of both gates from 1 (0 when no frame is clean).

        Args:
            gates: ``(B, 2)`` gates of the ``app`` cue (early, late).
            clean: ``(B,)`` bool, frames whose appearance costs are not corrupted (and present).
        """
        per_frame = ((gates - 1.0) ** 2).sum(dim=-1)
        return _mean(per_frame, clean)

    def gate_target_term(self, gates: Tensor, nll_open: Tensor, nll_closed: Tensor,
                         has_app: Tensor) -> Tensor:
        """Per-frame gate target of the appearance confidence: a cost-sensitive choice
        between the frame's two ends. The target is 1 (images as without the confidence)
        where the gates-open pass explains the true assignment better than the gates-closed
        (boxes-only) pass, else 0; each frame weighs by how much the choice matters, the gap
        between the two passes' NLLs: the mean over the frames with images of that gap times
        the squared distances of both gates from the target (0 when no frame has images).

        Args:
            gates: ``(B, 2)`` gates of the ``app`` cue (early, late).
            nll_open, nll_closed: ``(B,)`` per-frame NLLs (:func:`frame_nll`) with both gates
                1 and both 0; treated as constants.
            has_app: ``(B,)`` bool, frames with the appearance cue.
        """
        gap = (nll_closed - nll_open).detach()
        target = (gap > 0).to(gates.dtype)
        per_frame = gap.abs() * ((gates - target[:, None]) ** 2).sum(dim=-1)
        return _mean(per_frame, has_app)
