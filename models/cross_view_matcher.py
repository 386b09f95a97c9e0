"""The cross-view matcher: geometry model, optional other cues, one fusion head.

``CrossViewMatcher`` composes the box-only :class:`~xvmatch.models.geometry_encoder.
GeometryEncoder` with any other normalised costs (e.g. an appearance cost from a Siamese
branch), fused by a head of :mod:`xvmatch.models.fusion_heads` under the name ``"geo"`` for the
geometry cost. With boxes only (no other cost) the fused cost is the geometry cost itself.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

from torch import Tensor, nn

from xvmatch.models.geometry_encoder import GeometryEncoder, GeometryOutput

__all__ = ["CrossViewMatcher", "MatcherOutput"]


class MatcherOutput(NamedTuple):
    """Output of :class:`CrossViewMatcher`.

    Attributes:
        cost: ``(B, M, N)`` fused cost in [0, 1] (the geometry cost when box-only).
        geometry: the :class:`GeometryOutput` of the geometry model.
    """

    cost: Tensor
    geometry: GeometryOutput


class CrossViewMatcher(nn.Module):
    """Geometry model plus optional extra cues, fused into one normalised cost matrix.

    Args:
        geometry: the box-only geometry model.
        fusion: fusion head over ``{"geo": ..., **other costs}``; needed only when other costs
            are passed to :meth:`forward`.
    """

    def __init__(self, geometry: GeometryEncoder, fusion: nn.Module | None = None) -> None:
        super().__init__()
        self.geometry = geometry
        self.fusion = fusion

    def forward(
        self,
        top: Tensor,
        hor: Tensor,
        hyp: Tensor,
        pair: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        hyp_mask: Tensor,
        other_costs: Mapping[str, Tensor] | None = None,
    ) -> MatcherOutput:
        """Cost matrix of a padded batch (inputs as :meth:`GeometryEncoder.forward`).

        Args:
            other_costs: optional ``{name: (B, M, N) cost in [0, 1]}`` of other cues (e.g.
                ``"app"``), fused with the geometry cost ``"geo"``; None or empty: box-only.
        """
        geo = self.geometry(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask)
        if not other_costs:
            return MatcherOutput(cost=geo.cost, geometry=geo)
        if self.fusion is None:
            raise ValueError(
                f"other costs ({', '.join(other_costs)}) were given but the matcher has no "
                "fusion head; build it with fusion=SumFusionHead(...) or another head"
            )
        if "geo" in other_costs:
            raise ValueError("'geo' is the geometry model's own cost; rename the other cost")
        fused = self.fusion({"geo": geo.cost, **other_costs})
        pair_mask = (top_mask[:, :, None] & hor_mask[:, None, :]).to(fused.dtype)
        return MatcherOutput(cost=fused * pair_mask + (1.0 - pair_mask), geometry=geo)
