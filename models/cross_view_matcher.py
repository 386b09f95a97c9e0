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

**Appearance confidence** (``app_confidence=True``, issue 31): an appearance network trained on
renders can make real matching worse, so the matcher can learn when to trust it. A first pass
runs the matcher box-only (the deployed boxes-only setting); :func:`app_confidence_features`
summarises each frame's appearance cost matrix on its own (mean, spread, best-to-second margins)
and against that box-only pass's scores (how often the appearance's best partner is the
geometry's, the appearance cost at the geometry's best pairs, their correlation); a small head
turns them into two gates in [0, 2], one for the early and one for the late fusion, which scale
the ``app`` cue's ``(logit, available)`` inputs: 0 is the boxes-only input, 1 the cue as before.
The head's last layer starts at zero (gates exactly 1), so a fine-tune starts as the matcher it
was loaded from. The second pass costs a second run of the encoder.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import Tensor, nn

from xvmatch.models.geometry_encoder import GeometryEncoder, GeometryOutput

__all__ = ["CONFIDENCE_FEATURES", "CUES", "CrossViewMatcher", "app_confidence_features"]

CUES: tuple[str, ...] = ("app", "ray", "cheir")
"""The pair cues a matcher can take besides the box geometry, in input order."""

_EPS = 1e-4

CONFIDENCE_FEATURES: tuple[str, ...] = (
    "mean", "spread", "row_margin", "col_margin", "row_agree", "col_agree", "geo_best_gap",
    "geo_corr",
)
"""The per-frame appearance statistics of :func:`app_confidence_features`, in order."""

_FAR = 4.0  # above every cost in [0, 1]: padding never wins a minimum
_LOW = -1.0e4  # below every geometry score: padding never wins a maximum


def _masked_mean(x: Tensor, weight: Tensor, dims: tuple[int, ...]) -> Tensor:
    return (x * weight).sum(dims) / weight.sum(dims).clamp(min=1.0)


def app_confidence_features(app: Tensor, available: Tensor, geometry_scores: Tensor,
                            top_mask: Tensor, hor_mask: Tensor) -> Tensor:
    """Per-frame statistics of the appearance cost matrix, alone and against box geometry.

    All are masked to the valid pairs (padding never counts) and are 0 for a frame without the
    appearance cue or without pairs; no data-dependent branch (ONNX-exportable).

    Args:
        app: ``(B, M, N)`` appearance costs in [0, 1] (``|a - b| / 2``).
        available: ``(B,)`` bool, the frame has the cue.
        geometry_scores: ``(B, M, N)`` pair scores of the box-only matcher (higher: more
            likely the same person).
        top_mask, hor_mask: ``(B, M)``, ``(B, N)`` bool, valid people.

    Returns:
        ``(B, 8)``, in the order of :data:`CONFIDENCE_FEATURES`: mean cost; its standard
        deviation; mean gap between each row's best and second-best cost (rows with two valid
        columns or more), and the same per column; fraction of rows (columns) whose cheapest
        appearance partner is the geometry's highest-scoring one; mean cost minus the mean cost
        at the geometry's best partner of each row and column; Pearson correlation of the
        negated cost with the geometry scores over the valid pairs.
    """
    dtype = app.dtype
    valid = top_mask[:, :, None] & hor_mask[:, None, :]
    vf = valid.to(dtype)
    mean = _masked_mean(app, vf, (1, 2))
    centred = (app - mean[:, None, None]) * vf
    spread = ((centred * centred).sum((1, 2)) / vf.sum((1, 2)).clamp(min=1.0)).clamp(
        min=1e-12).sqrt()
    cost = torch.where(valid, app, torch.full_like(app, _FAR))
    geo = torch.where(valid, geometry_scores, torch.full_like(geometry_scores, _LOW))
    feats = [mean, spread]
    firsts, agrees, gaps = [], [], []
    for dim in (2, 1):  # rows (best column), then columns (best row)
        index = torch.cumsum(torch.ones_like(cost), dim=dim) - 1.0
        best_cost, app_arg = cost.min(dim=dim, keepdim=True)
        first = index == app_arg.to(dtype)
        second = torch.where(first, torch.full_like(cost, _FAR), cost).min(dim=dim).values
        count = vf.sum(dim)
        line = (count > 0.5).to(dtype)
        two = (count > 1.5).to(dtype)
        margin = (second - best_cost.squeeze(dim)).clamp(0.0, 1.0)
        firsts.append(_masked_mean(margin, two, (1,)))
        geo_arg = geo.argmax(dim=dim, keepdim=True)
        agrees.append(_masked_mean((app_arg == geo_arg).squeeze(dim).to(dtype), line, (1,)))
        at_geo = (app * (index == geo_arg.to(dtype)).to(dtype)).sum(dim)
        gaps.append(mean - _masked_mean(at_geo, line, (1,)))
    s_mean = _masked_mean(geometry_scores, vf, (1, 2))
    s_centred = (geometry_scores - s_mean[:, None, None]) * vf
    cov = -(centred * s_centred).sum((1, 2))
    norm = ((centred * centred).sum((1, 2)) * (s_centred * s_centred).sum((1, 2))).clamp(
        min=1e-12).sqrt()
    corr = cov / norm
    feats += firsts + agrees + [0.5 * (gaps[0] + gaps[1]), corr]
    has = available.to(dtype) * (vf.sum((1, 2)) > 0.5).to(dtype)
    return torch.stack(feats, dim=-1) * has[:, None]


def _cap(gates: Tensor) -> Tensor:
    """``min(1, gates)``; at exactly 1 (a fresh head) half the gradient still passes
    (``torch.minimum``; ``clamp`` passes none there, and the head would never move)."""
    return torch.minimum(gates, torch.ones_like(gates))


class CrossViewMatcher(nn.Module):
    """Geometry encoder plus optional pair cues, fused early and late, with one dustbin.

    Args:
        geometry: the box-only geometry encoder (its dustbin and Sinkhorn are the matcher's).
        cues: names of the pair cues this matcher takes, a subset of :data:`CUES` in that
            order; empty for a box-only matcher.
        hidden: hidden units of the late fusion head.
        app_confidence: gate the ``app`` cue by its per-frame confidence (module docstring);
            needs the ``app`` cue. False: the matcher as before (the stored config then has no
            such key, so older files load unchanged).
        app_gate_cap: cap both gates at 1 (``min(1, gate)``: the confidence can only
            down-weight the ``app`` cue); needs ``app_confidence``. Stored in the config only
            when on, so older files load unchanged.
    """

    def __init__(
        self, geometry: GeometryEncoder, cues: Sequence[str] = CUES, hidden: int = 32,
        app_confidence: bool = False,
        app_gate_cap: bool = False,
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
        if not isinstance(app_confidence, bool):
            raise ValueError(f"app_confidence must be a bool, got {app_confidence!r}")
        if app_confidence and "app" not in cues:
            raise ValueError("app_confidence needs the 'app' cue")
        self.app_confidence = app_confidence
        if app_confidence:
            self.config["app_confidence"] = True
        if not isinstance(app_gate_cap, bool):
            raise ValueError(f"app_gate_cap must be a bool, got {app_gate_cap!r}")
        if app_gate_cap and not app_confidence:
            raise ValueError("app_gate_cap needs app_confidence")
        self.app_gate_cap = app_gate_cap
        if app_gate_cap:
            self.config["app_gate_cap"] = True
        self.last_gates: Tensor | None = None
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
        if app_confidence:
            # Gates of the app cue, early and late, from its statistics and the cue mask.
            self.confidence = nn.Sequential(
                nn.Linear(len(CONFIDENCE_FEATURES) + k, 16), nn.ReLU(), nn.Linear(16, 2)
            )
            nn.init.zeros_(self.confidence[2].weight)  # gates exactly 1: the loaded matcher
            nn.init.zeros_(self.confidence[2].bias)
            app_columns = torch.zeros(2 * k)
            app_columns[cues.index("app")] = 1.0
            app_columns[k + cues.index("app")] = 1.0
            self.register_buffer("app_columns", app_columns, persistent=False)

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
        gates: Tensor | None = None,
    ) -> GeometryOutput:
        """Match a batch of frames.

        Args:
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask: the geometry features, as in
                :meth:`GeometryEncoder.forward`.
            cues: ``(B, M, N, K)`` pair cues in [0, 1], in the order of :attr:`cues` (ignored
                where unavailable); None for a box-only call.
            cue_mask: ``(B, K)`` bool, which cues each frame has; None: none.
            gates: ``(B, 2)`` gates of the ``app`` cue to use instead of the confidence
                head's (a matcher built with ``app_confidence``; not capped; :attr:`last_gates`
                keeps the head's last ones): 0 gives the boxes-only input, 1 the cue as without the
                confidence. Training only (the per-frame gate target); None: the head's.

        Returns:
            :class:`~xvmatch.models.geometry_encoder.GeometryOutput` of the fused matcher.
        """
        if gates is not None and not self.app_confidence:
            raise ValueError("gates need a matcher built with app_confidence")
        enc = self.geometry
        if self.app_confidence and gates is None:
            self.last_gates = None
        extra = None
        x = None
        x_late = None
        if self.n_cues and cues is not None and cue_mask is not None:
            avail = cue_mask.to(top.dtype)[:, None, None, :].expand_as(cues)
            logit = torch.logit(cues.clamp(_EPS, 1.0 - _EPS)) * avail
            x = torch.cat([logit, avail], dim=-1)  # (B, M, N, 2K)
            x_late = x
            if self.app_confidence and gates is None:
                gates = self._gates(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues,
                                    cue_mask, x)
                # Read by a training loss's gate terms; before the cap, so that a term can
                # pull a gate out of the cap's flat region (where the cost has no gradient).
                self.last_gates = gates
                if self.app_gate_cap:
                    gates = _cap(gates)
            if self.app_confidence:
                x, x_late = (x * (1.0 + self.app_columns * (gates[:, i, None] - 1.0))[
                    :, None, None, :] for i in (0, 1))
            extra = self.cue_embed(x)
        a, b, pair_emb, frame_logits = enc.encode(
            top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, pair_extra=extra
        )
        scores, pa, pb = enc.pair_scores(a, b, pair_emb)
        if x_late is not None:
            scores = self._late(x_late, scores)
        cost, log_assignment = enc.match(scores, top_mask, hor_mask)
        return GeometryOutput(
            cost=cost,
            log_assignment=log_assignment,
            hypothesis_logits=frame_logits,
            top_descriptors=nn.functional.normalize(pa, dim=-1),
            hor_descriptors=nn.functional.normalize(pb, dim=-1),
        )

    def _late(self, x: Tensor, scores: Tensor) -> Tensor:
        """Geometry scores plus the late fusion of the cue inputs ``x``."""
        late = self.fusion(torch.cat([x, scores[..., None]], dim=-1)).squeeze(-1)
        return scores + late + self.fusion_linear(x).squeeze(-1)

    def app_gates(self, top: Tensor, hor: Tensor, hyp: Tensor, pair: Tensor, top_mask: Tensor,
                  hor_mask: Tensor, hyp_mask: Tensor, cues: Tensor, cue_mask: Tensor,
                  x: Tensor) -> Tensor:
        """``(B, 2)`` gates in [0, 2] of the ``app`` cue (early, late) of a matcher built with
        ``app_confidence``: its statistics (:func:`app_confidence_features`) against a
        box-only pass of this matcher (no gradient), and the cue mask, through
        :attr:`confidence` (capped at 1 with ``app_gate_cap``)."""
        gates = self._gates(top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, cues, cue_mask, x)
        return _cap(gates) if self.app_gate_cap else gates

    def _gates(self, top: Tensor, hor: Tensor, hyp: Tensor, pair: Tensor, top_mask: Tensor,
               hor_mask: Tensor, hyp_mask: Tensor, cues: Tensor, cue_mask: Tensor,
               x: Tensor) -> Tensor:
        """The gates of :meth:`app_gates` before the cap."""
        with torch.no_grad():
            x0 = torch.zeros_like(x)
            a, b, pair_emb, _ = self.geometry.encode(
                top, hor, hyp, pair, top_mask, hor_mask, hyp_mask, pair_extra=self.cue_embed(x0)
            )
            scores, _, _ = self.geometry.pair_scores(a, b, pair_emb)
            scores = self._late(x0, scores)
            i = self.cues.index("app")
            feats = app_confidence_features(cues[..., i], cue_mask[:, i], scores, top_mask,
                                            hor_mask)
        mask = cue_mask.to(feats.dtype)
        return 1.0 + torch.tanh(self.confidence(torch.cat([feats, mask], dim=-1)))
