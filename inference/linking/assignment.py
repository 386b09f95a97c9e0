"""One-to-at-most-one association of two detection sets, Eqs. 1-2 of the geometric-priors paper.

Eq. 1 asks for binary ``x_ij`` minimising ``sum_ij c_ij x_ij`` with at most one 1 per row and per
column. Eq. 2 makes "not associated" explicit: the (M, N) cost matrix is embedded in an
(M + N) x (M + N) matrix whose other entries all equal the non-association cost ``gamma``, and
the Hungarian algorithm (``scipy.optimize.linear_sum_assignment``) solves it exactly.

Every feasible full assignment of the augmented matrix with K real pairs costs
``sum c_ij + gamma (M + N - K)``, so a pair is worth matching only when ``c_ij < gamma``:
``gamma`` is the largest cost still accepted. Ties at ``c_ij == gamma`` are resolved as "not
associated", which keeps the result deterministic and does not change the optimal objective.
:class:`FrameCosts` holds a frame's costs and its assignment, as the learned matcher gives them
to the appearance check and the tracker.

This module uses numpy and scipy only (no torch, no OpenCV).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import linear_sum_assignment

__all__ = [
    "GAMMA_GRID",
    "FrameCosts",
    "assign",
    "assignment_is_stable",
    "assignment_matrix",
    "augmented_cost_matrix",
]

GAMMA_GRID: tuple[float, ...] = tuple(round(0.05 * k, 2) for k in range(1, 21))
"""Candidate non-association costs for choosing gamma on validation data: 0.05, 0.10, ..., 1.0
(normalised costs are < 1, so gamma = 1 accepts every pair the Hungarian solution wants)."""


def _check_cost(cost: np.ndarray) -> np.ndarray:
    arr = np.asarray(cost, dtype=float)
    if arr.ndim != 2:
        raise ValueError(f"cost must be an (M, N) matrix, got shape {arr.shape}")
    if np.isnan(arr).any():
        rows, cols = np.nonzero(np.isnan(arr))
        raise ValueError(
            f"cost contains NaN at {len(rows)} entries (first at row {rows[0]}, col {cols[0]}); "
            "use inf to forbid a pair"
        )
    if np.isneginf(arr).any():
        raise ValueError("cost contains -inf; costs must be finite or +inf (forbidden pair)")
    return arr


def _check_gamma(gamma: float) -> float:
    g = float(gamma)
    if not np.isfinite(g):
        raise ValueError(f"gamma (non-association cost) must be finite, got {gamma}")
    return g


def augmented_cost_matrix(cost: np.ndarray, gamma: float) -> np.ndarray:
    """The (M + N) x (M + N) matrix ``A`` of Eq. 2.

    ``A_ij = c_ij`` for ``i < M, j < N`` and ``gamma`` elsewhere: column ``N + i`` leaves row
    ``i`` unassociated, row ``M + j`` leaves column ``j`` unassociated.

    Args:
        cost: (M, N) association costs; ``+inf`` forbids a pair, NaN is rejected.
        gamma: finite non-association cost.

    Returns:
        (M + N, M + N) float matrix.
    """
    c = _check_cost(cost)
    g = _check_gamma(gamma)
    m, n = c.shape
    augmented = np.full((m + n, m + n), g)
    augmented[:m, :n] = c
    return augmented


def assign(cost: np.ndarray, gamma: float) -> np.ndarray:
    """Optimal one-to-at-most-one association (Eq. 1) with non-association cost gamma (Eq. 2).

    Args:
        cost: (M, N) association costs (dissimilarities). ``+inf`` marks a forbidden pair;
            NaN and ``-inf`` are rejected. M or N may be 0.
        gamma: finite non-association cost; only pairs with ``cost < gamma`` can be matched.

    Returns:
        (K, 2) int64 array of matched ``(row, col)`` pairs, sorted by row, ``K <= min(M, N)``.
        Empty ``(0, 2)`` when either side is empty or every pair costs ``>= gamma``.

    Raises:
        ValueError: cost not 2-D, NaN or -inf in cost, or non-finite gamma.

    Example:
        >>> assign(np.array([[0.1, 0.9], [0.8, 0.7]]), gamma=0.5).tolist()
        [[0, 0]]
    """
    augmented = augmented_cost_matrix(cost, gamma)
    c = np.asarray(cost, dtype=float)
    m, n = c.shape
    if m == 0 or n == 0:
        return np.zeros((0, 2), dtype=np.int64)
    rows, cols = linear_sum_assignment(augmented)
    real = (rows < m) & (cols < n)
    rows, cols = rows[real], cols[real]
    keep = c[rows, cols] < float(gamma)  # drop ties (c == gamma): same objective, deterministic
    pairs = np.stack([rows[keep], cols[keep]], axis=1).astype(np.int64)
    return pairs[np.argsort(pairs[:, 0], kind="stable")].reshape(-1, 2)


def assignment_is_stable(cost: np.ndarray, gamma: float, tolerance: float) -> bool:
    """Whether :func:`assign`'s solution stays optimal however each finite cost moves by up to
    ``tolerance`` (``gamma`` fixed): a cost matrix known only that closely gives these pairs.

    The worst case for the solution ``A`` raises its own pairs' costs and lowers every other:
    for any ``C'`` within the tolerance and any other assignment ``B``,
    ``C'(A) - C'(B) <= W(A) - W(B)`` with ``W`` that worst case, since the pairs both share
    cancel. So ``A`` stays optimal for all of them exactly when it is optimal for ``W``: one more
    Hungarian solve (ties count as stable).

    Raises:
        ValueError: as :func:`assign`, or a negative or non-finite ``tolerance``.
    """
    t = float(tolerance)
    if not (np.isfinite(t) and t >= 0):
        raise ValueError(f"tolerance must be finite and >= 0, got {tolerance}")
    augmented = augmented_cost_matrix(cost, gamma)
    m, n = np.asarray(cost).shape
    if m == 0 or n == 0:
        return True
    rows, cols = linear_sum_assignment(augmented)
    worst = augmented.copy()
    worst[:m, :n] -= t  # inf stays inf: a forbidden pair stays forbidden
    real = (rows < m) & (cols < n)
    worst[rows[real], cols[real]] += 2.0 * t
    chosen = worst[rows, cols].sum()
    r, c = linear_sum_assignment(worst)
    best = worst[r, c].sum()
    return bool(chosen <= best + 1e-9 * max(1.0, abs(best)))


def assignment_matrix(pairs: np.ndarray, m: int, n: int) -> np.ndarray:
    """Binary association matrix ``x`` of Eq. 1 from matched pairs.

    Args:
        pairs: (K, 2) ``(row, col)`` pairs, as returned by :func:`assign`.
        m, n: number of rows and columns.

    Returns:
        (m, n) bool matrix, True at the matched pairs.

    Raises:
        ValueError: pairs out of range or not one-to-at-most-one.
    """
    if m < 0 or n < 0:
        raise ValueError(f"m and n must be >= 0, got {m}, {n}")
    p = np.asarray(pairs)
    if p.size == 0:
        return np.zeros((m, n), dtype=bool)
    if p.ndim != 2 or p.shape[1] != 2 or not np.issubdtype(p.dtype, np.integer):
        raise ValueError(f"pairs must be a (K, 2) integer array, got {p.shape} {p.dtype}")
    if (p < 0).any() or (p[:, 0] >= m).any() or (p[:, 1] >= n).any():
        raise ValueError(f"pairs out of range for a {m} x {n} matrix")
    if len(np.unique(p[:, 0])) != len(p) or len(np.unique(p[:, 1])) != len(p):
        raise ValueError("pairs repeat a row or a column; Eq. 1 allows at most one per row/col")
    x = np.zeros((m, n), dtype=bool)
    x[p[:, 0], p[:, 1]] = True
    return x


@dataclass(frozen=True, eq=False)
class FrameCosts:
    """The learned matcher's verdict on one frame, in the rows of the detections.

    Attributes:
        top_rows: (M,) the top-view detection rows, in the order of the cost rows.
        hor_rows: (N,) the horizontal detection rows, in the order of the cost columns.
        cost: (M, N) the matcher's costs in [0, 1].
        paired: (M, N) bool, the frame's assignment with the non-association cost gamma
            (geometric-priors Eqs. 1-2): the pairs the matcher makes on this frame alone.
    """

    top_rows: np.ndarray
    hor_rows: np.ndarray
    cost: np.ndarray
    paired: np.ndarray
