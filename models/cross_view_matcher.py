"""The one cross-view matcher: box geometry, optional appearance and camera cues, one dustbin.

``CrossViewMatcher`` wraps the box-only :class:`~xvmatch.models.geometry_encoder.
GeometryEncoder` (the spatial-distribution features of the CVMHAT search, attention across the
two sets) and fuses into it the pair cues that a frame may or may not have, each a normalised
``(M, N)`` cost in [0, 1]:

* ``"app"``: the Siamese appearance cost ``|a - b| / 2`` of the two crops' descriptors
  (Sec. 3.3.2 of the CVMHAT paper; :mod:`xvmatch.models.appearance_net`), with images;
* ``"ray"``: ``tanh`` of the distance between the two boxes' projection rays (Eqs. 4-6 of the
  geometric-priors paper), with calibrated cameras;
* ``"cheir"``: 1 where the cheirality test fails (Eq. 7), with calibrated cameras.

A cue enters twice, both times as ``(logit(c) * available, available)`` so that a missing cue is
an input of its own rather than a fake value: early, embedded and added to every pair's
embedding before the attention rounds (so attention reasons over appearance and rays too), and
late, in the fusion head that adds a learned per-pair term to the geometry score. The fused
scores, a learnable dustbin score (the non-association cost) and log-space Sinkhorn give matching
probabilities P and the cost ``1 - P``; Hungarian assignment with gamma runs outside the graph.

One trained model covers the three input settings of the deployed matcher: boxes only (every cue
unavailable), images without cameras (``app``), images with cameras (``app``, ``ray``,
``cheir``). Availability is a ``(B, K)`` mask, never a Python branch, so the module exports to
ONNX with dynamic numbers of frames, people and hypotheses.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from xvmatch.models.geometry_encoder import GeometryEncoder, GeometryOutput

__all__ = ["CUES", "CrossViewMatcher"]

CUES: tuple[str, ...] = ("app", "ray", "cheir")
"""The pair cues a matcher can take besides the box geometry, in input order."""

_EPS = 1e-4


class CrossViewMatcher(nn.Module):
    """Geometry encoder plus optional pair cues, fused early and late, with one dustbin.

    Args:
        geometry: the box-only geometry encoder (its dustbin and Sinkhorn are the matcher's).
        cues: names of the pair cues this matcher takes, a subset of :data:`CUES` in that
            order; empty for a box-only matcher.
        hidden: hidden units of the late fusion head.
    """

    def __init__(
        self, geometry: GeometryEncoder, cues: Sequence[str] = CUES, hidden: int = 32
    ) -> None:
        super().__init__()
        cues = tuple(cues)
        if isinstance(cues, str) or any(c not in CUES for c in cues) or list(cues) != [
            c for c in CUES if c in cues
        ]:
            raise ValueError(f"cues must be a subset of {CUES} in that order, got {cues}")
        if int(hidden) < 1:
            raise ValueError(f"hidden must be >= 1, got {hidden}")
        self.geometry = geometry
        self.cues = cues
        self.config = {"cues": list(cues), "hidden": int(hidden)}
        k = len(cues)
        if k:
            width = int(geometry.config["width"])
            self.cue_embed = nn.Sequential(
                nn.Linear(2 * k, width), nn.ReLU(), nn.Linear(width, width)
            )
            self.fusion = nn.Sequential(
                nn.Linear(2 * k + 1, int(hidden)), nn.ReLU(), nn.Linear(int(hidden), 1)
            )
            self.fusion_linear = nn.Linear(2 * k, 1)
            # Start as the geometry model alone: cues add nothing until trained.
            for layer in (self.cue_embed[2], self.fusion[2], self.fusion_linear):
                nn.init.zeros_(layer.weight)
                nn.init.zeros_(layer.bias)

    @property
    def n_cues(self) -> int:
        """K, the number of pair cues."""
        return len(self.cues)

    def forward(
        self,
        top: Tensor,
        hor: Tensor,
        hyp: Tensor,
        pair: Tensor,
        top_mask: Tensor,
        hor_mask: Tensor,
        hyp_mask: Tensor,
        cues: Tensor | None = None,
        cue_mask: Tensor | None = None,
    ) -> GeometryOutput:
        """Match a batch of frames.

        Args:
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask: the geometry features, as in
                :meth:`GeometryEncoder.forward`.
            cues: ``(B, M, N, K)`` pair cues in [0, 1], in the order of :attr:`cues` (ignored
                where unavailable); None for a box-only call.
            cue_mask: ``(B, K)`` bool, which cues each frame has; None: none.

        Returns:
            :class:`~xvmatch.models.geometry_encoder.GeometryOutput` of the fused matcher.
        """
        enc = self.geometry
        extra = None
        x = None
        if self.n_cues and cues is not None and cue_mask is not None:
            avail = cue_mask.to(top.dtype)[:, None, None, :].expand_as(cues)
            logit = torch.logit(cues.clamp(_EPS, 1.0 - _EPS)) * avail
            x = torch.cat([logit, avail], dim=-1)  # (B, M, N, 2K)
            extra = self.cue_embed(x)
        a, b, pair_emb, frame_logits = enc.encode(
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, pair_extra=extra
        )
        scores, pa, pb = enc.pair_scores(a, b, pair_emb)
        if x is not None:
            late = self.fusion(torch.cat([x, scores[..., None]], dim=-1)).squeeze(-1)
            scores = scores + late + self.fusion_linear(x).squeeze(-1)
        cost, log_assignment = enc.match(scores, top_mask, hor_mask)
        return GeometryOutput(
            cost=cost,
            log_assignment=log_assignment,
            hypothesis_logits=frame_logits,
            top_descriptors=nn.functional.normalize(pa, dim=-1),
            hor_descriptors=nn.functional.normalize(pb, dim=-1),
        )
