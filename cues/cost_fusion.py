"""Normalising association costs to [0, 1] and fusing them, Section III-C of the paper.

Costs from different cues have different ranges (Fig. 2 of the geometric-priors paper), so each
is first mapped to [0, 1]:

* a distance in [0, inf) (colour histogram Eq. 3, ray distance Eq. 6) by ``tanh(d)``;
* a cosine similarity ``s`` in [-1, 1] (learned re-id features) by ``1/2 (1 - s)``.

Normalised costs are then fused by one rule behind the :class:`CostFusion` interface: a
weighted sum (``w_geo d'_geo + w_app d'_app``) or the product of Eq. 8 (``d'_geo d'_app``).
A learned fusion head implements the same interface: named (M, N) costs in [0, 1] in, one
(M, N) cost in [0, 1] out.

Cheirality (Eq. 7) is not a cost to fuse but a crisp veto. It is added, after any rule, by
:func:`add_cheirality`: ``A = fused + C`` with ``C`` in {0, beta}. For the sum rule this equals
adding a beta term to the sum; for the product rule it is deliberately *not* a factor, since a
product with ``d'_geo = 0`` would cancel it. Either way a violating pair costs at least
``beta > 1 >= fused``, above any sensible non-association cost ``gamma`` (Eq. 2), so it is
never matched.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = [
    "CostFusion",
    "ProductFusion",
    "SumFusion",
    "add_cheirality",
    "normalise_cosine_similarity",
    "normalise_distance",
]

_COSINE_TOL = 1e-6  # round-off allowed outside [-1, 1] for a cosine similarity


def _as_array(values: np.ndarray, name: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if np.isnan(arr).any():
        raise ValueError(f"{name} contains NaN; fix the cue that produced it before fusing")
    return arr


def normalise_distance(distance: np.ndarray) -> np.ndarray:
    """Map a distance in [0, inf) to [0, 1) with ``tanh`` (Section III-C, ``d' = tanh(d)``).

    tanh keeps small distances nearly unchanged and squashes large ones; ``inf`` maps to 1.

    Args:
        distance: array of any shape, values >= 0 (``inf`` allowed).

    Returns:
        ``tanh(distance)``, same shape, in [0, 1].

    Raises:
        ValueError: NaN or negative values.
    """
    d = _as_array(distance, "distance")
    if (d < 0).any():
        raise ValueError(f"distance must be >= 0, got a minimum of {d.min():.6g}")
    return np.tanh(d)


def normalise_cosine_similarity(similarity: np.ndarray) -> np.ndarray:
    """Map a cosine similarity in [-1, 1] to a distance in [0, 1]: ``d'_nn = 1/2 (1 - s_nn)``.

    Min-max normalisation of Section III-C; round-off up to 1e-6 outside [-1, 1] is clipped.

    Args:
        similarity: array of any shape, values in [-1, 1].

    Returns:
        Distances of the same shape in [0, 1]; 0 for identical directions.

    Raises:
        ValueError: NaN, inf or values outside [-1, 1].
    """
    s = _as_array(similarity, "similarity")
    if s.size and (s.min() < -1 - _COSINE_TOL or s.max() > 1 + _COSINE_TOL):
        raise ValueError(
            f"similarity must be a cosine in [-1, 1], got range [{s.min():.6g}, {s.max():.6g}]; "
            "are the features L2-normalised?"
        )
    return 0.5 * (1.0 - np.clip(s, -1.0, 1.0))


def _check_costs(costs: Mapping[str, np.ndarray], names: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Validate the normalised costs a rule needs; extra names are ignored."""
    if not isinstance(costs, Mapping):
        raise TypeError(f"costs must be a mapping {{name: (M, N) array}}, got {type(costs)}")
    missing = [n for n in names if n not in costs]
    if missing:
        raise ValueError(
            f"costs lack {', '.join(missing)}; got {', '.join(map(str, costs)) or 'none'}"
        )
    checked: dict[str, np.ndarray] = {}
    shape = None
    for n in names:
        arr = _as_array(costs[n], f"costs[{n!r}]")
        if arr.ndim != 2:
            raise ValueError(f"costs[{n!r}] must be an (M, N) matrix, got shape {arr.shape}")
        if shape is not None and arr.shape != shape:
            raise ValueError(
                f"costs[{n!r}] has shape {arr.shape} but costs[{names[0]!r}] has {shape}"
            )
        shape = arr.shape
        if arr.size and (arr.min() < 0 or arr.max() > 1):
            raise ValueError(
                f"costs[{n!r}] must be normalised to [0, 1], got range "
                f"[{arr.min():.6g}, {arr.max():.6g}]; apply normalise_distance or "
                "normalise_cosine_similarity first"
            )
        checked[n] = arr
    return checked


def _check_names(names: tuple[str, ...], rule: str) -> None:
    if not names:
        raise ValueError(f"{rule} needs at least one cost name")
    if len(set(names)) != len(names):
        raise ValueError(f"{rule} names must be distinct, got {names}")


@runtime_checkable
class CostFusion(Protocol):
    """Fuses named, normalised association costs into one cost matrix.

    Implementations take ``{name: (M, N) array in [0, 1]}`` (extra names are ignored, so one
    dictionary of every computed cue can feed any rule) and return an (M, N) array in [0, 1].
    """

    def __call__(self, costs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Fuse ``{name: (M, N) cost in [0, 1]}`` into one (M, N) cost in [0, 1]."""
        ...


@dataclass(frozen=True)
class SumFusion:
    """Weighted sum of normalised costs (Section III-C, ``w_geo d'_geo + w_app d'_app``).

    The weights are divided by their sum so the fused cost stays in [0, 1]; with the paper's
    ``w_i = 0.5`` (Section IV-B) this changes nothing. The non-association cost ``gamma``
    must be tuned with the weights (the paper uses 0.25).

    Attributes:
        weights: ``{name: weight}``, weights finite and >= 0 with a positive sum.
    """

    weights: Mapping[str, float]

    def __post_init__(self) -> None:
        if not isinstance(self.weights, Mapping):
            raise TypeError(
                f"SumFusion weights must be a mapping {{name: weight}}, got {self.weights!r}"
            )
        object.__setattr__(self, "weights", dict(self.weights))  # private copy, not aliased
        names = tuple(self.weights)
        _check_names(names, "SumFusion")
        w = np.array([self.weights[n] for n in names], dtype=float)
        if not np.isfinite(w).all() or (w < 0).any() or w.sum() <= 0:
            raise ValueError(f"SumFusion weights must be finite, >= 0, sum > 0; got {self.weights}")

    def __call__(self, costs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Fuse ``{name: (M, N) cost in [0, 1]}`` into ``sum_k w_k c_k / sum_k w_k``."""
        names = tuple(self.weights)
        checked = _check_costs(costs, names)
        total = float(sum(self.weights[n] for n in names))
        fused = sum(float(self.weights[n]) / total * checked[n] for n in names)
        return np.clip(np.asarray(fused, dtype=float), 0.0, 1.0)


@dataclass(frozen=True)
class ProductFusion:
    """Product of normalised costs, Eq. 8 (``d_geo,app* = d'_geo d'_app``).

    Parameter-free apart from the non-association cost ``gamma`` (the paper uses 0.1). A pair
    is cheap when any cue is confident, which suits the sharply peaked geometric cost.

    Attributes:
        names: the costs to multiply, e.g. ``("geo", "nn")``.
    """

    names: tuple[str, ...]

    def __post_init__(self) -> None:
        if isinstance(self.names, str):
            raise TypeError(f"ProductFusion names must be a tuple of names, got {self.names!r}")
        object.__setattr__(self, "names", tuple(self.names))
        _check_names(self.names, "ProductFusion")

    def __call__(self, costs: Mapping[str, np.ndarray]) -> np.ndarray:
        """Fuse ``{name: (M, N) cost in [0, 1]}`` into ``prod_k c_k``."""
        checked = _check_costs(costs, self.names)
        fused = np.ones_like(checked[self.names[0]])
        for n in self.names:
            fused = fused * checked[n]
        return fused


def add_cheirality(fused: np.ndarray, cheirality: np.ndarray) -> np.ndarray:
    """Add the cheirality term (0 or beta, Eq. 7) to a fused cost, for any fusion rule.

    Args:
        fused: (M, N) fused cost in [0, 1].
        cheirality: (M, N) cost from ``ray_priors.cheirality_cost``: 0 where the
            constraint holds, ``beta`` (finite, >> 1) where it is violated.

    Returns:
        (M, N) cost ``fused + cheirality``: unchanged for valid pairs, >= beta for the others.
    """
    f = _as_array(fused, "fused")
    c = _as_array(cheirality, "cheirality")
    if f.ndim != 2 or f.shape != c.shape:
        raise ValueError(
            f"fused and cheirality must be (M, N) matrices of one shape, got {f.shape} and "
            f"{c.shape}"
        )
    if not np.isfinite(c).all() or (c < 0).any():
        raise ValueError("cheirality must be finite and >= 0 (0 or beta)")
    return f + c
