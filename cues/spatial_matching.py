"""Matching of two spatial-distribution vector sets (CVMHAT paper, Section 3.2.3, Eqs. 11-12).

Everything is batched over hypotheses: one call matches the horizontal-view set against the
top-view sets of every (O, theta) hypothesis at once, with no Python loop per hypothesis.

What the paper leaves open is settled as the authors' public code does it: the scale mu comes
from a first monotonic (DTW) matching on x alone followed by the one-to-one clean-up, as the mean
ratio of the matched y values; both matchings are DTW paths from the first to the last element of
each sorted set (steps right, down, diagonal), cleaned up to one-to-one as the paper describes.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np

from xvmatch.core import kernel_choice

__all__ = [
    "MatchResult",
    "SpatialParams",
    "cached_penalty_table",
    "cost_lower_bound",
    "match_vector_sets",
    "monotonic_path",
    "one_to_one",
    "penalty_table",
]


@dataclass(frozen=True)
class SpatialParams:
    """Parameters of the spatial-distribution association (defaults of the authors' code).

    Attributes:
        rho: penalty base of Eq. 12 (rho > 1): fewer matched pairs cost rho^(L / kappa).
        lam: balance factor lambda of Eq. 11 between the x and y dissimilarities; y_hor is in
            units of a 2688-pixel-wide image whatever the resolution
            (:func:`~xvmatch.cues.spatial_vectors.horizontal_vectors`), so the paper's 0.003
            holds for any image size.
        tau_deg: occlusion tolerance tau (degrees), Sec. 3.2.2.
        dtheta_deg: orientation step of the search (degrees), Sec. 3.2.4.
        fov_deg: field-of-view angle alpha of the horizontal camera (degrees), Eq. 6.
        scale_threshold: only pairs with |x_top - x_hor| below this enter the scale estimate
            (the "very small threshold" of Sec. 3.2.3; the authors' code effectively uses none).
        damping_r, damping_u: damping of the reduced search window
            S_t = 2 pi (r^(t-1) + u) / (1 + u), Sec. 3.2.4.
    """

    rho: float = 15.0
    lam: float = 0.003
    tau_deg: float = 2.0
    dtheta_deg: float = 1.0
    fov_deg: float = 90.0
    scale_threshold: float = np.inf
    damping_r: float = 0.95
    damping_u: float = 0.1

    def __post_init__(self) -> None:
        checks = {
            "rho": self.rho > 1.0,
            "lam": self.lam > 0.0,
            "tau_deg": self.tau_deg >= 0.0,
            "dtheta_deg": 0.0 < self.dtheta_deg <= 360.0,
            "fov_deg": 0.0 < self.fov_deg < 180.0,
            "scale_threshold": self.scale_threshold > 0.0,
            "damping_r": 0.0 < self.damping_r <= 1.0,
            "damping_u": self.damping_u > 0.0,
        }
        bad = [name for name, ok in checks.items() if not ok]
        if bad:
            values = ", ".join(f"{n}={getattr(self, n)!r}" for n in bad)
            raise ValueError(
                f"invalid spatial parameter(s): {values} (need rho > 1, lam > 0, tau >= 0, "
                "0 < dtheta <= 360, 0 < fov < 180, scale_threshold > 0, 0 < r <= 1, u > 0)"
            )


def monotonic_path(cost: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """Minimum-cost monotonic (DTW) path through each cost matrix of a batch.

    The path of batch element b runs from (0, 0) to (rows[b] - 1, Q - 1) with steps down, right
    or diagonal; on ties the diagonal step is preferred, then down. Rows at or past ``rows[b]``
    are padding and never visited.

    Args:
        cost: ``(B, K, Q)`` non-negative finite dissimilarities (padding rows may hold anything
            finite).
        rows: ``(B,)`` number of valid rows per batch element (0 gives an empty path).

    Returns:
        ``(B, K, Q)`` boolean mask of the path cells.
    """
    n_batch, n_rows, n_cols = cost.shape
    if n_batch == 0 or n_rows == 0 or n_cols == 0:
        return np.zeros(cost.shape, dtype=bool)
    # The batch is the last (contiguous) axis, so each step below is one vector operation over
    # all hypotheses. acc[i + 1, j + 1] = cost[i, j] + min(acc[i, j], acc[i, j + 1],
    # acc[i + 1, j]), the DTW recurrence, on a grid padded with a row and a column of +inf
    # (acc[0, 0] = 0 starts the path at (0, 0)).
    width = n_cols + 1
    costs = np.ascontiguousarray(cost.transpose(1, 2, 0))  # (K, Q, B)
    acc = np.full((n_rows + 1, width, n_batch), np.inf)
    acc[0, 0] = 0.0
    for i in range(n_rows):
        reach = np.minimum(acc[i, :-1], acc[i, 1:])  # diagonal and vertical predecessors
        row, out = costs[i], acc[i + 1]
        for j in range(n_cols):
            out[j + 1] = row[j] + np.minimum(reach[j], out[j])
    # Backtracking step of every cell (in flat indices of the padded grid): diagonal on ties,
    # then vertical, then horizontal; none at the start cell (1, 1).
    stride = n_batch
    up_step, diag_step = width * stride, (width + 1) * stride
    diag, up, left = acc[:-1, :-1], acc[:-1, 1:], acc[1:, :-1]
    steps = np.zeros((n_rows + 1, width, n_batch), dtype=np.intp)
    steps[1:, 1:] = np.where((diag <= up) & (diag <= left), diag_step,
                             np.where(up <= left, up_step, stride))
    steps[1, 1] = 0
    steps = steps.reshape(-1)
    # Walk back from (rows[b], Q) to (1, 1) (at most K + Q - 2 steps).
    alive = np.asarray(rows) > 0
    start = (width + 1) * stride
    pos = np.where(alive, (np.asarray(rows, dtype=np.intp) * width + n_cols) * stride, start)
    pos = pos + np.arange(n_batch)
    visited = [pos]
    for _ in range(n_rows + n_cols - 2):
        pos = pos - steps[pos]
        visited.append(pos)
    padded = np.zeros((n_rows + 1) * width * n_batch, dtype=bool)
    padded[np.concatenate(visited)] = True
    path = padded.reshape(n_rows + 1, width, n_batch)[1:, 1:].transpose(2, 0, 1)
    path = np.ascontiguousarray(path)
    path[~alive] = False
    return path


def one_to_one(path: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """One-to-one clean-up of a monotonic path (Sec. 3.2.3).

    A top vector (row) matched to several horizontal vectors keeps only the least dissimilar;
    then a horizontal vector (column) still matched to several top vectors keeps only the least
    dissimilar.

    Args:
        path: ``(B, K, Q)`` boolean path masks.
        cost: ``(B, K, Q)`` dissimilarities.

    Returns:
        ``(B, K, Q)`` boolean mask of the kept pairs (at most one per row and per column).
    """
    if path.size == 0:
        return path.copy()
    n_rows, n_cols = path.shape[1:]
    masked = np.where(path, cost, np.inf)
    best_col = np.argmin(masked, axis=2)
    keep = path & (np.arange(n_cols)[None, None, :] == best_col[:, :, None])
    masked = np.where(keep, cost, np.inf)
    best_row = np.argmin(masked, axis=1)
    keep &= np.arange(n_rows)[None, :, None] == best_row[:, None, :]
    return keep


def penalty_table(rho: float, size: int) -> np.ndarray:
    """``(size + 1, size + 1)`` table of rho^(L / kappa), Eq. 12's penalty, at [L, kappa] for
    L, kappa <= size (column 0, kappa = 0, is never used as a penalty): one numpy power for
    the numpy forms and the compiled kernels alike, since libm's pow and numpy's SIMD pow differ
    in the last bit on some CPUs (AVX-512)."""
    n = np.arange(size + 1, dtype=float)
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        return float(rho) ** (n[:, None] / n[None, :])


@functools.lru_cache(maxsize=64)
def cached_penalty_table(rho: float, size: int) -> np.ndarray:
    """:func:`penalty_table`, computed once per (rho, size) in a process (the search asks for
    it on every call); read only by its callers, never written."""
    return penalty_table(rho, size)


@dataclass(frozen=True)
class MatchResult:
    """Matching of the horizontal set against a batch of top sets.

    Attributes:
        cost: ``(B,)`` matching cost Phi of Eq. 12; +inf where nothing can be matched.
        pairs: ``(B, K, Q)`` boolean mask of the kept (top entry, horizontal entry) pairs.
        scale: ``(B,)`` factor mu that brings y_top to the scale of y_hor (Sec. 3.2.3).
    """

    cost: np.ndarray
    pairs: np.ndarray
    scale: np.ndarray


def match_vector_sets(
    top_x: np.ndarray,
    top_y: np.ndarray,
    count: np.ndarray,
    hor: np.ndarray,
    params: SpatialParams,
) -> MatchResult:
    """Match sorted top-view vector sets against one sorted horizontal-view set (Eqs. 11-12).

    Args:
        top_x, top_y: ``(B, K)`` top vectors, ascending in x, valid in the first ``count[b]``
            entries of each row.
        count: ``(B,)`` number of valid top vectors per row, |K| of Eq. 8.
        hor: ``(Q, 2)`` horizontal vectors (x_hor, y_hor), ascending in x (Eq. 10).
        params: the association parameters (rho, lambda, scale threshold).

    Returns:
        :class:`MatchResult`. Phi = rho^(L / kappa) / kappa * sum of D over the kept pairs, with
        L = max(|K|, Q) and kappa the number of kept pairs.
    """
    n_batch, n_rows = top_x.shape
    n_cols = hor.shape[0]
    count = np.asarray(count)
    if n_batch == 0 or n_rows == 0 or n_cols == 0:
        return MatchResult(
            cost=np.full(n_batch, np.inf),
            pairs=np.zeros((n_batch, n_rows, n_cols), dtype=bool),
            scale=np.ones(n_batch),
        )
    coef = cached_penalty_table(float(params.rho), max(n_rows, n_cols))
    kernels = kernel_choice.kernels()
    if kernels is None:
        return _match_numpy(top_x, top_y, count, hor, params, coef)
    cost = np.empty(n_batch)
    pairs = np.empty((n_batch, n_rows, n_cols), dtype=bool)
    scale = np.empty(n_batch)
    kernels.match_batch(
        np.ascontiguousarray(top_x, dtype=np.float64),
        np.ascontiguousarray(top_y, dtype=np.float64),
        np.ascontiguousarray(count, dtype=np.int64),
        np.ascontiguousarray(hor[:, 0], dtype=np.float64),
        np.ascontiguousarray(hor[:, 1], dtype=np.float64),
        coef, float(params.lam), float(params.scale_threshold), cost, pairs, scale,
    )
    return MatchResult(cost=cost, pairs=pairs, scale=scale)


def _match_numpy(top_x: np.ndarray, top_y: np.ndarray, count: np.ndarray, hor: np.ndarray,
                 params: SpatialParams, coef: np.ndarray) -> MatchResult:
    """:func:`match_vector_sets` batched in numpy (the definition the kernel reproduces)."""
    n_rows, n_cols = top_x.shape[1], hor.shape[0]
    valid = np.arange(n_rows)[None, :] < count[:, None]
    hx, hy = hor[:, 0], hor[:, 1]
    tx = np.where(valid, top_x, 0.0)
    dx = np.abs(tx[:, :, None] - hx[None, None, :])

    # Scale mu from a first matching on x alone (RANSAC-like reliable subset).
    pairs_x = one_to_one(monotonic_path(dx, count), dx)
    if np.isfinite(params.scale_threshold):
        pairs_x &= dx < params.scale_threshold
    n_x = pairs_x.sum(axis=(1, 2))
    ratio = top_y[:, :, None] / hy[None, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_ratio = np.where(pairs_x, ratio, 0.0).sum(axis=(1, 2)) / n_x
    ok = (n_x > 0) & np.isfinite(mean_ratio) & (mean_ratio > 0)
    mean_ratio = np.where(ok, mean_ratio, 1.0)

    # Eq. 11 with mu = 1 / mean ratio, then the DP matching and its clean-up.
    dy = np.abs(top_y[:, :, None] / mean_ratio[:, None, None] - hy[None, None, :])
    dis = np.where(valid[:, :, None], params.lam * dx + dy, 0.0)
    pairs = one_to_one(monotonic_path(dis, count), dis)
    kappa = pairs.sum(axis=(1, 2))
    total = np.where(pairs, dis, 0.0).sum(axis=(1, 2))
    longest = np.maximum(count, n_cols)
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        cost = coef[longest, kappa] * total / kappa
    cost = np.where(ok & (kappa > 0) & (count > 0), cost, np.inf)
    cost = np.where(np.isnan(cost), np.inf, cost)
    return MatchResult(cost=cost, pairs=pairs, scale=1.0 / mean_ratio)


def cost_lower_bound(
    top_x: np.ndarray,
    count: np.ndarray,
    hor_x: np.ndarray,
    params: SpatialParams,
    tight: bool = True,
) -> np.ndarray:
    """Lower bound of Phi (Eq. 12) per hypothesis, for exact branch-and-bound pruning.

    A kept pair (i, j) costs at least lambda * |x_top_i - x_hor_j| >= lambda * e_i, with e_i the
    distance from x_top_i to its nearest x_hor; so kappa kept pairs cost at least lambda * s_kappa,
    the sum of the kappa smallest e_i, and, as kappa <= m = min(|K|, Q),
    Phi >= min over kappa in 1..m of rho^(L / kappa) / kappa * lambda * s_kappa (``tight``).
    The looser ``tight=False`` bound, rho^(L / m) * lambda * min_i e_i, needs no sorting.

    Args:
        top_x: ``(B, M)`` top x values in any order; +inf marks absent entries.
        count: ``(B,)`` number of finite entries per row.
        hor_x: ``(Q,)`` horizontal x values, ascending.
        params: the association parameters.
        tight: the sorted partial-sum bound (default) or the cheaper loose one.

    Returns:
        ``(B,)`` bound; +inf where the hypothesis has no top vector or Q = 0.
    """
    n_batch, n_people = top_x.shape
    n_cols = hor_x.shape[0]
    count = np.asarray(count)
    if n_batch == 0 or n_people == 0 or n_cols == 0:
        return np.full(n_batch, np.inf)
    coef = cached_penalty_table(float(params.rho), max(n_people, n_cols))
    kernels = kernel_choice.kernels()
    if kernels is None:
        return _lower_bound_numpy(top_x, count, hor_x, params, tight, coef)
    bound = np.empty(n_batch)
    kernels.lower_bounds(np.ascontiguousarray(top_x, dtype=np.float64),
                         np.ascontiguousarray(count, dtype=np.int64),
                         np.ascontiguousarray(hor_x, dtype=np.float64),
                         coef, float(params.lam), bool(tight), bound)
    return bound


def _lower_bound_numpy(top_x: np.ndarray, count: np.ndarray, hor_x: np.ndarray,
                       params: SpatialParams, tight: bool, coef: np.ndarray) -> np.ndarray:
    """:func:`cost_lower_bound` in numpy."""
    n_people = top_x.shape[1]
    n_cols = hor_x.shape[0]
    pos = np.searchsorted(hor_x, top_x)
    below = hor_x[np.maximum(pos - 1, 0)]
    above = hor_x[np.minimum(pos, n_cols - 1)]
    with np.errstate(invalid="ignore"):
        gap = np.minimum(np.abs(top_x - below), np.abs(top_x - above))
    absent = ~np.isfinite(top_x)
    gap[absent] = np.inf
    longest = np.maximum(count, n_cols)
    shortest = np.minimum(count, n_cols)
    if not tight:
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            bound = coef[longest, shortest] * params.lam * gap.min(axis=1)
        return np.where(count > 0, bound, np.inf)
    gap.sort(axis=1)
    gap[~np.isfinite(gap)] = 0.0
    partial = np.cumsum(gap, axis=1)
    # per[L, kappa - 1] = rho^(L / kappa) / kappa, used for kappa <= min(count, Q) only.
    kappa = np.arange(1, n_people + 1)
    with np.errstate(over="ignore", invalid="ignore"):
        per = coef[: longest.max() + 1, 1 : n_people + 1] / kappa
    usable = kappa[None, :] <= shortest[:, None]
    bound = np.where(usable, per[longest] * partial, np.inf).min(axis=1) * params.lam
    return np.where(count > 0, bound, np.inf)
