"""The box-only learned geometry model: attention across the two sets, dustbin, log-Sinkhorn.

Input: the features of :mod:`xvmatch.cues.spatial_features` for a batch of frames, padded
with masks (:func:`~xvmatch.cues.spatial_features.collate_frames`): per hypothesis h of the
CVMHAT search (Section 3.2 of the CVMHAT paper) and pair (i, j) a feature vector, per hypothesis
a few scalars, per person its box geometry.

1. Every (h, i, j) becomes an embedding (MLP of its pair features plus its hypothesis' features).
2. Hypothesis pooling: a frame-level score per hypothesis (from the masked mean and max of its
   pair embeddings and its own features) plus a pair-level score give, per pair, softmax weights
   over the hypotheses; the pair embedding is the weighted mean plus the max over hypotheses. The
   frame-level scores are trained to find the hypothesis whose O is the camera wearer.
3. People embeddings (box geometry plus pooled pair embeddings) go through ``layers`` rounds of
   self-attention within each set and cross-attention between the sets, SuperGlue-style, the
   cross-attention logits biased by the pair embeddings; after each round the pair embeddings
   are updated from their two ends.
4. Pair scores (MLP of the pair embedding plus a dot product of the two people's descriptors), a
   learnable dustbin score for "no match", and log-space Sinkhorn (SuperGlue, Sarlin et al.,
   CVPR 2020, Sec. 3.3) give matching probabilities P; the cost is ``1 - P`` in [0, 1].

Everything is masked, with no data-dependent Python branch, so the module traces to ONNX; padded
or empty sets (M = 0, N = 0 or no hypothesis) give costs of 1 and no NaN.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import torch
from torch import Tensor, nn

from xvmatch.cues.spatial_features import (
    HOR_FEATURES,
    HYP_FEATURES,
    PAIR_FEATURES,
    TOP_FEATURES,
)

__all__ = ["CrossSetLayer", "GeometryEncoder", "GeometryOutput", "LogSinkhorn", "MaskedAttention"]

_NEG = -1e4  # finite "minus infinity": keeps masked softmax / logsumexp free of NaN


def _mlp(dims: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for k in range(len(dims) - 1):
        layers.append(nn.Linear(dims[k], dims[k + 1]))
        if k < len(dims) - 2:
            layers.append(nn.LayerNorm(dims[k + 1]))
            layers.append(nn.ReLU())
    return nn.Sequential(*layers)


def _masked_max(x: Tensor, mask: Tensor, dim: int) -> Tensor:
    """Max of ``x (..., D)`` over ``dim`` where ``mask`` (``x`` without its last axis); 0 if
    none. A sentinel entry keeps the reduction defined when ``dim`` has size 0."""
    m = mask.unsqueeze(-1)
    filled = x.masked_fill(~m, _NEG)
    sentinel = torch.full_like(filled.narrow(dim, 0, 0).sum(dim=dim, keepdim=True), _NEG)
    big = torch.cat([filled, sentinel], dim=dim).amax(dim=dim)
    anyv = (m.to(x.dtype).sum(dim=dim) > 0).to(x.dtype)
    return big * anyv


def _masked_mean(x: Tensor, mask: Tensor, dim: int) -> Tensor:
    """Mean of ``x`` over ``dim`` where ``mask``; 0 if none."""
    m = mask.unsqueeze(-1).to(x.dtype)
    return (x * m).sum(dim=dim) / m.sum(dim=dim).clamp(min=1.0)


class MaskedAttention(nn.Module):
    """Multi-head attention with a key mask and an optional additive logit bias.

    Args:
        width: embedding size (divisible by ``heads``).
        heads: attention heads.
    """

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        if width % heads:
            raise ValueError(f"width ({width}) must be divisible by heads ({heads})")
        self.heads = heads
        self.head_dim = width // heads
        self.q = nn.Linear(width, width)
        self.k = nn.Linear(width, width)
        self.v = nn.Linear(width, width)
        self.out = nn.Linear(width, width)

    def forward(
        self, x: Tensor, source: Tensor, key_mask: Tensor, bias: Tensor | None = None
    ) -> Tensor:
        """Messages ``(B, L, D)`` to ``x (B, L, D)`` from ``source (B, S, D)``.

        Args:
            key_mask: ``(B, S)`` valid source entries; queries with none get a zero message.
            bias: optional ``(B, heads, L, S)`` added to the attention logits.
        """
        b, n_q, _ = x.shape
        n_k = source.shape[1]
        q = self.q(x).view(b, n_q, self.heads, self.head_dim).transpose(1, 2)
        k = self.k(source).view(b, n_k, self.heads, self.head_dim).transpose(1, 2)
        v = self.v(source).view(b, n_k, self.heads, self.head_dim).transpose(1, 2)
        logits = q @ k.transpose(-1, -2) / math.sqrt(self.head_dim)
        if bias is not None:
            logits = logits + bias
        logits = logits.masked_fill(~key_mask[:, None, None, :], _NEG)
        attn = torch.softmax(logits, dim=-1)
        msg = (attn @ v).transpose(1, 2).reshape(b, n_q, self.heads * self.head_dim)
        has_keys = key_mask.any(dim=1).to(x.dtype)[:, None, None]
        return self.out(msg) * has_keys


class CrossSetLayer(nn.Module):
    """One round: self-attention in each set, pair-biased cross-attention, pair update.

    Args:
        width: embedding size.
        heads: attention heads.
    """

    def __init__(self, width: int, heads: int) -> None:
        super().__init__()
        self.self_top = MaskedAttention(width, heads)
        self.self_hor = MaskedAttention(width, heads)
        self.cross_top = MaskedAttention(width, heads)
        self.cross_hor = MaskedAttention(width, heads)
        self.bias = nn.Linear(width, heads)
        self.update_top = _mlp([3 * width, 2 * width, width])
        self.update_hor = _mlp([3 * width, 2 * width, width])
        self.pair_from_top = nn.Linear(width, width)
        self.pair_from_hor = nn.Linear(width, width)
        self.pair_self = nn.Linear(width, width)
        self.pair_out = nn.Sequential(nn.LayerNorm(width), nn.ReLU(), nn.Linear(width, width))

    def forward(
        self,
        top: Tensor,
        hor: Tensor,
        pair: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        pair_mask: Tensor,
    ) -> tuple[Tensor, Tensor, Tensor]:
        """Update ``top (B, M, D)``, ``hor (B, N, D)`` and ``pair (B, M, N, D)``."""
        bias = self.bias(pair).permute(0, 3, 1, 2)  # (B, heads, M, N)
        m_top = torch.cat(
            [
                top,
                self.self_top(top, top, top_mask),
                self.cross_top(top, hor, hor_mask, bias),
            ],
            dim=-1,
        )
        m_hor = torch.cat(
            [
                hor,
                self.self_hor(hor, hor, hor_mask),
                self.cross_hor(hor, top, top_mask, bias.transpose(-1, -2)),
            ],
            dim=-1,
        )
        top = (top + self.update_top(m_top)) * top_mask[..., None].to(top.dtype)
        hor = (hor + self.update_hor(m_hor)) * hor_mask[..., None].to(hor.dtype)
        delta = (
            self.pair_self(pair)
            + self.pair_from_top(top)[:, :, None, :]
            + self.pair_from_hor(hor)[:, None, :, :]
        )
        pair = (pair + self.pair_out(delta)) * pair_mask[..., None].to(pair.dtype)
        return top, hor, pair


class LogSinkhorn(nn.Module):
    """Masked log-space Sinkhorn with a dustbin row and column (SuperGlue, Sec. 3.3).

    Each valid top row has mass 1, each valid horizontal column mass 1, the dustbin row mass N
    and the dustbin column mass M (per frame), all divided by M + N; padded rows and columns
    have no mass.

    Args:
        iterations: fixed number of iterations (no early stop: ONNX-friendly).
    """

    def __init__(self, iterations: int = 20) -> None:
        super().__init__()
        if iterations < 1:
            raise ValueError(f"sinkhorn iterations must be >= 1, got {iterations}")
        self.iterations = iterations

    def forward(
        self, scores: Tensor, dustbin: Tensor, row_mask: Tensor, col_mask: Tensor
    ) -> Tensor:
        """Log assignment ``(B, M + 1, N + 1)`` from ``scores (B, M, N)``; a valid row of the
        result sums to 1 in probability (the dustbin column included)."""
        b, m, n = scores.shape
        one = scores.new_ones(b, 1, dtype=torch.bool).bool()
        rows = torch.cat([row_mask, one], dim=1)
        cols = torch.cat([col_mask, one], dim=1)
        bins_col = dustbin.expand(b, m, 1)
        bins_row = dustbin.expand(b, 1, n)
        corner = dustbin.expand(b, 1, 1)
        couplings = torch.cat(
            [torch.cat([scores, bins_col], dim=2), torch.cat([bins_row, corner], dim=2)], dim=1
        )
        couplings = couplings.masked_fill(~(rows[:, :, None] & cols[:, None, :]), _NEG)
        n_rows = row_mask.sum(dim=1).to(scores.dtype)
        n_cols = col_mask.sum(dim=1).to(scores.dtype)
        norm = -torch.log((n_rows + n_cols).clamp(min=1.0))
        log_mu = torch.cat(
            [
                torch.where(row_mask, norm[:, None], scores.new_full((b, m), _NEG)),
                torch.where(n_cols > 0, torch.log(n_cols.clamp(min=1.0)) + norm,
                            torch.full_like(norm, _NEG))[:, None],
            ],
            dim=1,
        )
        log_nu = torch.cat(
            [
                torch.where(col_mask, norm[:, None], scores.new_full((b, n), _NEG)),
                torch.where(n_rows > 0, torch.log(n_rows.clamp(min=1.0)) + norm,
                            torch.full_like(norm, _NEG))[:, None],
            ],
            dim=1,
        )
        u = torch.zeros_like(log_mu)
        v = torch.zeros_like(log_nu)
        for _ in range(self.iterations):
            u = log_mu - torch.logsumexp(couplings + v[:, None, :], dim=2)
            v = log_nu - torch.logsumexp(couplings + u[:, :, None], dim=1)
        return couplings + u[:, :, None] + v[:, None, :] - norm[:, None, None]


class GeometryOutput(NamedTuple):
    """What :class:`GeometryEncoder` returns (a tuple, so it exports to ONNX).

    Attributes:
        cost: ``(B, M, N)`` matching cost ``1 - P`` in [0, 1]; 1 on padding.
        log_assignment: ``(B, M + 1, N + 1)`` log matching probabilities with dustbins.
        hypothesis_logits: ``(B, H)`` frame-level hypothesis scores (masked: -1e4).
        top_descriptors: ``(B, M, D)`` L2-normalised top-view person descriptors.
        hor_descriptors: ``(B, N, D)`` L2-normalised horizontal-view person descriptors.
    """

    cost: Tensor
    log_assignment: Tensor
    hypothesis_logits: Tensor
    top_descriptors: Tensor
    hor_descriptors: Tensor


class GeometryEncoder(nn.Module):
    """Box-only cross-view matcher over the CVMHAT search hypotheses (see the module docstring).

    Args:
        width: embedding size D.
        layers: rounds of self/cross attention.
        heads: attention heads (divides ``width``).
        sinkhorn_iterations: log-Sinkhorn iterations.
        initial_dustbin: initial value of the learnable dustbin score.
    """

    def __init__(
        self,
        width: int = 64,
        layers: int = 2,
        heads: int = 4,
        sinkhorn_iterations: int = 20,
        initial_dustbin: float = 1.0,
    ) -> None:
        super().__init__()
        if width < 1 or layers < 0:
            raise ValueError(f"need width >= 1 and layers >= 0, got {width} and {layers}")
        self.config = {
            "width": width,
            "layers": layers,
            "heads": heads,
            "sinkhorn_iterations": sinkhorn_iterations,
            "initial_dustbin": initial_dustbin,
        }
        d = width
        self.pair_in = _mlp([len(PAIR_FEATURES), d, d])
        self.hyp_in = nn.Linear(len(HYP_FEATURES), d)
        self.hyp_score = _mlp([3 * d, d, 1])
        self.pair_hyp_score = nn.Linear(d, 1)
        self.pair_mix = _mlp([2 * d, d, d])
        self.top_in = _mlp([len(TOP_FEATURES) + 2 * d, d, d])
        self.hor_in = _mlp([len(HOR_FEATURES) + 2 * d, d, d])
        self.layers = nn.ModuleList([CrossSetLayer(d, heads) for _ in range(layers)])
        self.score = _mlp([d, d, 1])
        self.top_desc = nn.Linear(d, d)
        self.hor_desc = nn.Linear(d, d)
        self.dot_scale = 1.0 / math.sqrt(d)
        self.dustbin = nn.Parameter(torch.tensor(float(initial_dustbin)))
        self.sinkhorn = LogSinkhorn(sinkhorn_iterations)

    def encode(
        self,
        top: Tensor,
        hor: Tensor,
        hyp: Tensor,
        pair: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        hyp_mask: Tensor,
        pair_extra: Tensor | None = None,
    ) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """Steps 1-3: people and pair embeddings after the attention rounds.

        Args:
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask: as in :meth:`forward`.
            pair_extra: optional ``(B, M, N, D)`` added to every pair's embedding before the
                people embeddings and the attention rounds (other cues of the pair, e.g. the
                appearance cost, embedded by :class:`~xvmatch.models.cross_view_matcher.
                CrossViewMatcher`).

        Returns:
            ``(top (B, M, D), hor (B, N, D), pair (B, M, N, D), hypothesis logits (B, H))``.
        """
        pair_mask = top_mask[:, :, None] & hor_mask[:, None, :]  # (B, M, N)
        hyp_pair_mask = hyp_mask[:, :, None, None] & pair_mask[:, None]  # (B, H, M, N)
        b, h, m, n, _ = pair.shape

        # 1. Per-hypothesis pair embeddings.
        e = self.pair_in(pair) + self.hyp_in(hyp)[:, :, None, None, :]
        e = e * hyp_pair_mask[..., None].to(e.dtype)

        # 2. Hypothesis weights: frame-level + pair-level scores, softmax over H. Explicit sizes
        #    (not flatten / -1) keep the exported graph valid when a dimension is 0.
        flat = e.reshape(b, h, m * n, e.shape[-1])
        flat_mask = hyp_pair_mask.reshape(b, h, m * n)
        pooled = torch.cat(
            [
                _masked_mean(flat, flat_mask, dim=2),
                _masked_max(flat, flat_mask, dim=2),
                self.hyp_in(hyp),
            ],
            dim=-1,
        )
        frame_logits = self.hyp_score(pooled).squeeze(-1).masked_fill(~hyp_mask, _NEG)
        local = self.pair_hyp_score(e).squeeze(-1)  # (B, H, M, N)
        logits = (frame_logits[:, :, None, None] + local).masked_fill(~hyp_pair_mask, _NEG)
        weights = torch.softmax(logits, dim=1) * hyp_pair_mask.to(e.dtype)
        mixed = (weights.unsqueeze(-1) * e).sum(dim=1)
        pair_emb = self.pair_mix(
            torch.cat([mixed, _masked_max(e, hyp_pair_mask, dim=1)], dim=-1)
        )
        if pair_extra is not None:
            pair_emb = pair_emb + pair_extra
        pair_emb = pair_emb * pair_mask[..., None].to(e.dtype)

        # 3. People embeddings and attention across the two sets.
        a = self.top_in(
            torch.cat(
                [
                    top,
                    _masked_mean(pair_emb, pair_mask, dim=2),
                    _masked_max(pair_emb, pair_mask, dim=2),
                ],
                dim=-1,
            )
        ) * top_mask[..., None].to(e.dtype)
        t_mask = pair_mask.transpose(1, 2)
        b_emb = self.hor_in(
            torch.cat(
                [
                    hor,
                    _masked_mean(pair_emb.transpose(1, 2), t_mask, dim=2),
                    _masked_max(pair_emb.transpose(1, 2), t_mask, dim=2),
                ],
                dim=-1,
            )
        ) * hor_mask[..., None].to(e.dtype)
        for layer in self.layers:
            a, b_emb, pair_emb = layer(a, b_emb, pair_emb, top_mask, hor_mask, pair_mask)
        return a, b_emb, pair_emb, frame_logits

    def pair_scores(self, top: Tensor, hor: Tensor, pair: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """Step 4a: ``(scores (B, M, N), top descriptors, hor descriptors)`` from the encoded
        people and pairs (an MLP of the pair embedding plus a scaled dot product)."""
        pa, pb = self.top_desc(top), self.hor_desc(hor)
        scores = self.score(pair).squeeze(-1) + (pa @ pb.transpose(1, 2)) * self.dot_scale
        return scores, pa, pb

    def match(self, scores: Tensor, top_mask: Tensor, hor_mask: Tensor) -> tuple[Tensor, Tensor]:
        """Step 4b: the dustbin and log-Sinkhorn; ``(cost 1 - P (B, M, N), log assignment
        (B, M + 1, N + 1))``, cost 1 on padding."""
        pair_mask = top_mask[:, :, None] & hor_mask[:, None, :]
        log_assignment = self.sinkhorn(scores, self.dustbin, top_mask, hor_mask)
        prob = log_assignment[:, :-1, :-1].exp() * pair_mask.to(scores.dtype)
        return (1.0 - prob).clamp(0.0, 1.0), log_assignment

    def forward(
        self,
        top: Tensor,
        hor: Tensor,
        hyp: Tensor,
        pair: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        hyp_mask: Tensor,
    ) -> GeometryOutput:
        """Match a batch of frames.

        Args:
            top: ``(B, M, len(TOP_FEATURES))``.
            hor: ``(B, N, len(HOR_FEATURES))``.
            hyp: ``(B, H, len(HYP_FEATURES))``.
            pair: ``(B, H, M, N, len(PAIR_FEATURES))``.
            top_mask, hor_mask, hyp_mask: ``(B, M)``, ``(B, N)``, ``(B, H)`` bool, valid entries.

        Returns:
            :class:`GeometryOutput`.
        """
        a, b, pair_emb, frame_logits = self.encode(
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask
        )
        scores, pa, pb = self.pair_scores(a, b, pair_emb)
        cost, log_assignment = self.match(scores, top_mask, hor_mask)
        return GeometryOutput(
            cost=cost,
            log_assignment=log_assignment,
            hypothesis_logits=frame_logits,
            top_descriptors=nn.functional.normalize(pa, dim=-1),
            hor_descriptors=nn.functional.normalize(pb, dim=-1),
        )
