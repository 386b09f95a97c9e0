"""Fusion heads on torch tensors: learned, sum, product (Section III-C of the geometric-priors
paper).

The same call convention as :class:`xvmatch.cues.cost_fusion.CostFusion`, on batched torch
tensors: ``head({name: (..., M, N) cost in [0, 1]})`` returns one ``(..., M, N)`` cost in
[0, 1]; names the head does not use are ignored, a missing one is an error. The rules match the
numpy ones (:class:`~xvmatch.cues.cost_fusion.SumFusion`,
:class:`~xvmatch.cues.cost_fusion.ProductFusion`); :class:`LearnedFusionHead` is a small
per-pair MLP over the costs' logits, trained end to end. Value ranges are not checked at run time
(that would be a data-dependent branch, which ONNX export forbids): inputs are clamped to [0, 1].
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import Tensor, nn

__all__ = ["LearnedFusionHead", "ProductFusionHead", "SumFusionHead"]

_EPS = 1e-4


def _check_names(names: Sequence[str], rule: str) -> tuple[str, ...]:
    if isinstance(names, str):
        raise TypeError(f"{rule} names must be a sequence of names, got the string {names!r}")
    names = tuple(names)
    if not names:
        raise ValueError(f"{rule} needs at least one cost name")
    if len(set(names)) != len(names):
        raise ValueError(f"{rule} names must be distinct, got {names}")
    return names


def _gather(costs: Mapping[str, Tensor], names: tuple[str, ...]) -> list[Tensor]:
    if not isinstance(costs, Mapping):
        raise TypeError(f"costs must be a mapping {{name: tensor}}, got {type(costs)}")
    missing = [n for n in names if n not in costs]
    if missing:
        raise ValueError(
            f"costs lack {', '.join(missing)}; got {', '.join(map(str, costs)) or 'none'}"
        )
    shape = costs[names[0]].shape
    for n in names:
        if costs[n].shape != shape:
            raise ValueError(
                f"costs[{n!r}] has shape {tuple(costs[n].shape)} but costs[{names[0]!r}] "
                f"has {tuple(shape)}"
            )
    return [costs[n].clamp(0.0, 1.0) for n in names]


class SumFusionHead(nn.Module):
    """Weighted sum ``sum_k w_k c_k / sum_k w_k`` (weights fixed, kept as a buffer).

    Args:
        weights: ``{name: weight}``, finite, >= 0, positive sum.
    """

    def __init__(self, weights: Mapping[str, float]) -> None:
        super().__init__()
        self.names = _check_names(list(weights), "SumFusionHead")
        w = torch.tensor([float(weights[n]) for n in self.names])
        if not torch.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ValueError(f"SumFusionHead weights must be finite, >= 0, sum > 0; got {weights}")
        self.register_buffer("weights", w / w.sum())

    def forward(self, costs: Mapping[str, Tensor]) -> Tensor:
        """Fuse ``{name: cost}`` into one cost in [0, 1]."""
        parts = _gather(costs, self.names)
        fused = sum(self.weights[k] * c for k, c in enumerate(parts))
        return fused.clamp(0.0, 1.0)


class ProductFusionHead(nn.Module):
    """Product of the costs (Eq. 8 of the geometric-priors paper).

    Args:
        names: the costs to multiply, e.g. ``("geo", "app")``.
    """

    def __init__(self, names: Sequence[str]) -> None:
        super().__init__()
        self.names = _check_names(names, "ProductFusionHead")

    def forward(self, costs: Mapping[str, Tensor]) -> Tensor:
        """Fuse ``{name: cost}`` into ``prod_k c_k``."""
        parts = _gather(costs, self.names)
        fused = parts[0]
        for c in parts[1:]:
            fused = fused * c
        return fused


class LearnedFusionHead(nn.Module):
    """Per-pair MLP over the logits of the named costs, squashed back to [0, 1].

    Initialised close to the mean of the costs' logits, i.e. a geometric-mean-like rule, so an
    untrained head is already a sensible fusion.

    Args:
        names: the costs to fuse, in a fixed order.
        hidden: hidden units of the MLP.
    """

    def __init__(self, names: Sequence[str], hidden: int = 16) -> None:
        super().__init__()
        self.names = _check_names(names, "LearnedFusionHead")
        k = len(self.names)
        self.linear = nn.Linear(k, 1)
        self.mlp = nn.Sequential(nn.Linear(k, hidden), nn.ReLU(), nn.Linear(hidden, 1))
        with torch.no_grad():
            self.linear.weight.fill_(1.0 / k)
            self.linear.bias.zero_()
            self.mlp[2].weight.zero_()
            self.mlp[2].bias.zero_()

    def forward(self, costs: Mapping[str, Tensor]) -> Tensor:
        """Fuse ``{name: cost}`` into one learned cost in [0, 1]."""
        parts = _gather(costs, self.names)
        x = torch.logit(torch.stack(parts, dim=-1).clamp(_EPS, 1.0 - _EPS))
        return torch.sigmoid(self.linear(x) + self.mlp(x)).squeeze(-1)
