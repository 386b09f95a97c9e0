"""Compiled (numba) kernels of the (O, theta) search of CVMHAT Sec. 3.2: the hypothesis vectors
(Eqs. 5-8), the lower bound of Phi, and the vector-set matching (Eqs. 11-12); and the oblique
registration's per-pose terms (``pose_terms``), the same kind of per-hypothesis loop, and its
greedy choice of distinct poses (``distinct_poses``).

The search scores hundreds of hypotheses per frame out of thousands, each two small DTWs, and
the batched numpy forms spent most of their time in per-cell array calls and in arrays of the
whole (candidate, theta, person) grid. These kernels follow the numpy definitions step by step
(:func:`~xvmatch.cues.spatial_matching.monotonic_path` with its tie order,
:func:`~xvmatch.cues.spatial_matching.one_to_one`, sums in NumPy's pairwise order over the
padded grid the numpy form sums, adding only its nonzero terms where they lie in it), so costs,
pairs and scales are bit-identical to them on every CPU (tested). ``score_groups`` runs one
batch of the learned features' search (sort, match and the merge of each candidate's best) in
one call. They do only IEEE arithmetic
and comparisons, never a transcendental function: tan, cos and rho^(L / kappa) come from numpy
in both forms (numpy's SIMD tan and pow differ from libm's in the last bit on AVX-512 CPUs), and
numba does not contract multiply-adds without ``fastmath``. Imported on first
use only: ``import numba`` and loading the cached machine code take about a second.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = [
    "distinct_poses",
    "hypothesis_table",
    "lower_bounds",
    "match_batch",
    "packed_depths",
    "pair_features",
    "pose_terms",
    "score_groups",
    "sorted_rows",
]

_BLOCK = 128  # NumPy's pairwise-summation block (PW_BLOCKSIZE)


@njit(cache=True)
def _block_sum(values: np.ndarray, start: int, n: int) -> float:
    """NumPy's sum of at most one block: sequential below 8, else 8 interleaved partial sums."""
    if n < 8:
        total = 0.0
        for i in range(start, start + n):
            total += values[i]
        return total
    r = values[start : start + 8].copy()
    i = 8
    full = n - n % 8
    while i < full:
        for k in range(8):
            r[k] += values[start + i + k]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += values[start + i]
        i += 1
    return total


@njit(cache=True)
def _pairwise_sum(values: np.ndarray) -> float:
    """Sum of ``values`` in NumPy's pairwise order (``np.add.reduce``): blocks of at most 128,
    halves rounded down to a multiple of 8 above. Iterative (numba cannot cache recursion)."""
    starts = np.empty(64, dtype=np.int64)
    sizes = np.empty(64, dtype=np.int64)
    stages = np.zeros(64, dtype=np.int64)
    results = np.empty(64)
    top, n_results = 0, 0
    starts[0], sizes[0], stages[0] = 0, values.shape[0], 0
    while top >= 0:
        start, n = starts[top], sizes[top]
        half = n // 2
        half -= half % 8
        if n <= _BLOCK:
            results[n_results] = _block_sum(values, start, n)
            n_results += 1
            top -= 1
        elif stages[top] == 0:  # left half first
            stages[top] = 1
            top += 1
            starts[top], sizes[top], stages[top] = start, half, 0
        elif stages[top] == 1:  # then the right half
            stages[top] = 2
            top += 1
            starts[top], sizes[top], stages[top] = start + half, n - half, 0
        else:  # left + right
            n_results -= 1
            results[n_results - 1] = results[n_results - 1] + results[n_results]
            top -= 1
    return results[0]


@njit(cache=True)
def _path_one_to_one(cost: np.ndarray, rows: int, cols: int, acc: np.ndarray,
                     best_col: np.ndarray, winner: np.ndarray) -> None:
    """DTW path from (0, 0) to (rows - 1, cols - 1), then the one-to-one clean-up.

    Ties as ``monotonic_path`` (diagonal, then down, then right) and ``one_to_one`` (the first
    least dissimilar path cell of a row, then the first least dissimilar of those rows per
    column). Leaves in ``winner[j]`` the row kept with column j, or -1; ``best_col`` is scratch.
    """
    acc[0, 0] = 0.0
    for j in range(1, cols + 1):
        acc[0, j] = np.inf
    for i in range(1, rows + 1):
        acc[i, 0] = np.inf
    for i in range(rows):
        for j in range(cols):
            a, b, c = acc[i, j], acc[i, j + 1], acc[i + 1, j]
            m = a if a < b else b
            acc[i + 1, j + 1] = cost[i, j] + (m if m < c else c)
    # Walk back; a row's path cells come right to left, so "<=" keeps its first least one.
    best_col[:rows] = -1
    i, j = rows, cols
    best_col[i - 1] = j - 1
    while i > 1 or j > 1:
        diag, up, left = acc[i - 1, j - 1], acc[i - 1, j], acc[i, j - 1]
        if diag <= up and diag <= left:
            i -= 1
            j -= 1
        elif up <= left:
            i -= 1
        else:
            j -= 1
        r, c = i - 1, j - 1
        if best_col[r] < 0 or cost[r, c] <= cost[r, best_col[r]]:
            best_col[r] = c
    winner[:cols] = -1
    for r in range(rows):
        c = best_col[r]
        if winner[c] < 0 or cost[r, c] < cost[winner[c], c]:
            winner[c] = r


@njit(cache=True)
def _sparse_sum(pos: np.ndarray, val: np.ndarray, n_entries: int, n_total: int,
                stack: np.ndarray, results: np.ndarray) -> float:
    """``_pairwise_sum`` of a length-``n_total`` array that is +0.0 except ``val[e]`` at
    ``pos[e]`` (``e < n_entries``, positions strictly ascending, no value -0.0), adding only
    those: NumPy's pairwise order (blocks of at most 128, 8 interleaved partial sums in a
    block of 8 or more) puts each entry in the same block, lane and place as in the whole
    array, and adding +0.0 changes no partial sum that is not -0.0, so the result has the same
    bits. A block or half without entries sums to +0.0, as its zeros do. ``stack`` ``(64, 4)``
    int64 and ``results`` ``(64,)`` are scratch (the halving depth of any array is below 64)."""
    top, n_results = 0, 0
    stack[0, 0], stack[0, 1], stack[0, 2], stack[0, 3] = 0, n_total, 0, 0
    lo = 0  # the first entry at or after the current range's start
    while top >= 0:
        start, n, stage = stack[top, 0], stack[top, 1], stack[top, 2]
        if stage == 0:  # first visit: the entries of [start, start + n) begin at lo
            stack[top, 3] = lo
        first = stack[top, 3]
        hi = first
        while hi < n_entries and pos[hi] < start + n:
            hi += 1
        if first == hi or n <= _BLOCK:
            total = 0.0
            if first < hi and n < 8:  # sequential from 0.0, as NumPy below 8
                for e in range(first, hi):
                    total += val[e]
            elif first < hi:  # lanes k: positions start + k (mod 8) below the last multiple
                full = start + n - n % 8
                r0 = r1 = r2 = r3 = r4 = r5 = r6 = r7 = 0.0
                e = first
                while e < hi and pos[e] < full:
                    k = (pos[e] - start) % 8
                    if k == 0:
                        r0 += val[e]
                    elif k == 1:
                        r1 += val[e]
                    elif k == 2:
                        r2 += val[e]
                    elif k == 3:
                        r3 += val[e]
                    elif k == 4:
                        r4 += val[e]
                    elif k == 5:
                        r5 += val[e]
                    elif k == 6:
                        r6 += val[e]
                    else:
                        r7 += val[e]
                    e += 1
                total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
                while e < hi:
                    total += val[e]
                    e += 1
            results[n_results] = total
            n_results += 1
            lo = hi
            top -= 1
            continue
        half = n // 2
        half -= half % 8
        if stage == 0:  # left half first
            stack[top, 2] = 1
            top += 1
            stack[top, 0], stack[top, 1], stack[top, 2] = start, half, 0
        elif stage == 1:  # then the right half (lo is past the left half's entries)
            stack[top, 2] = 2
            top += 1
            stack[top, 0], stack[top, 1], stack[top, 2] = start + half, n - half, 0
        else:  # left + right
            n_results -= 1
            results[n_results - 1] = results[n_results - 1] + results[n_results]
            lo = hi
            top -= 1
    return results[0]


@njit(cache=True)
def _kept_sum(pos: np.ndarray, val: np.ndarray, n_entries: int, n_total: int,
              stack: np.ndarray, results: np.ndarray, dense: np.ndarray) -> float:
    """The sum NumPy gives of the length-``n_total`` array holding ``val[e]`` at ``pos[e]``
    and +0.0 elsewhere: :func:`_sparse_sum` when its conditions hold (the kept pairs of a
    monotone path come with ascending positions and no -0.0; checked), else the whole array
    through ``_pairwise_sum`` (``dense`` is scratch of at least ``n_total``)."""
    sparse = True
    for e in range(n_entries):
        negative_zero = val[e] == 0.0 and math.copysign(1.0, val[e]) < 0.0
        if negative_zero or (e > 0 and pos[e] <= pos[e - 1]):
            sparse = False
            break
    if sparse:
        return _sparse_sum(pos, val, n_entries, n_total, stack, results)
    dense[:n_total] = 0.0
    for e in range(n_entries):
        dense[pos[e]] = val[e]
    return _pairwise_sum(dense[:n_total])


@njit(cache=True)
def match_batch(top_x: np.ndarray, top_y: np.ndarray, count: np.ndarray, hor_x: np.ndarray,
                hor_y: np.ndarray, coef: np.ndarray, lam: float, scale_threshold: float,
                cost_out: np.ndarray, pairs_out: np.ndarray, scale_out: np.ndarray) -> None:
    """Eqs. 11-12 for every hypothesis b: Phi into ``cost_out[b]``, the kept pairs into
    ``pairs_out[b]`` and mu into ``scale_out[b]`` (see ``match_vector_sets``); ``coef[L, k]``
    is rho^(L / k) (``penalty_table``). The numpy form sums each hypothesis' terms over the
    whole padded ``(rows, columns)`` grid, zeros elsewhere; the kernel adds the kept pairs'
    terms alone in that grid's order (:func:`_kept_sum`: the same bits)."""
    n_batch, n_rows = top_x.shape
    n_cols = hor_x.shape[0]
    n_total = n_rows * n_cols
    dx = np.zeros((n_rows, n_cols))
    dis = np.zeros((n_rows, n_cols))
    acc = np.empty((n_rows + 1, n_cols + 1))
    best_col = np.empty(n_rows, dtype=np.int64)
    winner = np.empty(n_cols, dtype=np.int64)
    pos = np.empty(n_cols, dtype=np.int64)  # at most one kept pair per column
    val = np.empty(n_cols)
    stack = np.empty((64, 4), dtype=np.int64)
    results = np.empty(64)
    dense = np.empty(n_total)
    for b in range(n_batch):
        rows = count[b]
        pairs_out[b] = False
        for i in range(rows):
            for j in range(n_cols):
                dx[i, j] = abs(top_x[b, i] - hor_x[j])
        # Scale mu from the matching on x alone: the mean y ratio of its kept pairs (those
        # closer in x than the scale threshold).
        ok, mean_ratio = False, 1.0
        if rows > 0:
            _path_one_to_one(dx, rows, n_cols, acc, best_col, winner)
            n_x = 0
            for j in range(n_cols):
                i = winner[j]
                if i >= 0 and dx[i, j] < scale_threshold:
                    pos[n_x] = i * n_cols + j
                    val[n_x] = top_y[b, i] / hor_y[j]
                    n_x += 1
            if n_x > 0:
                ratio = _kept_sum(pos, val, n_x, n_total, stack, results, dense) / n_x
                if np.isfinite(ratio) and ratio > 0:
                    ok, mean_ratio = True, ratio
        # Eq. 11 with mu = 1 / mean ratio, then the matching and Phi (Eq. 12).
        cost = np.inf
        if rows > 0:
            for i in range(rows):
                for j in range(n_cols):
                    dis[i, j] = lam * dx[i, j] + abs(top_y[b, i] / mean_ratio - hor_y[j])
            _path_one_to_one(dis, rows, n_cols, acc, best_col, winner)
            kappa = 0
            for j in range(n_cols):
                i = winner[j]
                if i >= 0:
                    pairs_out[b, i, j] = True
                    pos[kappa] = i * n_cols + j
                    val[kappa] = dis[i, j]
                    kappa += 1
            if ok and kappa > 0:
                longest = max(rows, n_cols)
                total = _kept_sum(pos, val, kappa, n_total, stack, results, dense)
                cost = coef[longest, kappa] * total / kappa
                if np.isnan(cost):
                    cost = np.inf
        cost_out[b] = cost
        scale_out[b] = 1.0 / mean_ratio


@njit(cache=True)
def packed_depths(x_all: np.ndarray, delta_all: np.ndarray, dist: np.ndarray, n_theta: int,
                  row_start: np.ndarray, delta: np.ndarray, dist_out: np.ndarray) -> int:
    """The delta and |OP| of every hypothesis' entries in view (finite x), packed row by row
    in person order, each row's first at ``row_start[b]`` (``row_start[B]``: their number,
    returned): the y of Eq. 5 is then numpy's cos of delta times |OP|, elementwise as
    ``TopHypotheses.take`` takes it."""
    n_rows, n_people = x_all.shape
    k = 0
    for b in range(n_rows):
        row_start[b] = k
        c = b // n_theta
        for m in range(n_people):
            if np.isfinite(x_all[b, m]):
                delta[k] = delta_all[b, m]
                dist_out[k] = dist[c, m]
                k += 1
    row_start[n_rows] = k
    return k


@njit(cache=True)
def score_groups(x_all: np.ndarray, count_all: np.ndarray, row_start: np.ndarray,
                 y_packed: np.ndarray, rows: np.ndarray, n_theta: int, width: int,
                 hor_x: np.ndarray, hor_y: np.ndarray, coef: np.ndarray, lam: float,
                 scale_threshold: float, best_cost: np.ndarray, best_index: np.ndarray,
                 group_row: np.ndarray, cost_out: np.ndarray, scale_out: np.ndarray,
                 kept_out: np.ndarray, improved: np.ndarray) -> int:
    """One batch of ``spatial_search._best_per_group``: the hypotheses ``rows`` (ascending)
    sorted as ``TopHypotheses.take`` sorts them (their y from ``y_packed``:
    :func:`packed_depths`) and matched by :func:`match_batch` padded to ``width`` rows (Phi, mu into
    ``cost_out``, ``scale_out``; the top person kept with each column into ``kept_out``, -1
    for none), then merged into each group's best so far (``best_cost``, ``best_index``: lower
    cost, or equal and a lower index, as the numpy form). The rows that hold a group's new best
    go to ``improved`` (ascending), their number returned; ``group_row`` is scratch of one -1
    per group, left so."""
    n_people = x_all.shape[1]
    n_cols = hor_x.shape[0]
    n_sel = rows.shape[0]
    top_x = np.empty((n_sel, width))
    top_y = np.zeros((n_sel, width))
    person = np.empty((n_sel, width), dtype=np.int64)
    count = np.empty(n_sel, dtype=np.int64)
    order = np.empty(n_people, dtype=np.int64)
    rank = np.empty(n_people, dtype=np.int64)
    for r in range(n_sel):
        b = rows[r]
        p = 0
        for m in range(n_people):  # stable insertion sort by x (+inf last), as sorted_rows
            value, i = x_all[b, m], m - 1
            while i >= 0 and x_all[b, order[i]] > value:
                order[i + 1] = order[i]
                i -= 1
            order[i + 1] = m
            if np.isfinite(value):  # its place among the row's packed entries
                rank[m] = p
                p += 1
        n = count_all[b]
        count[r] = n
        for k in range(n):
            m = order[k]
            top_x[r, k] = x_all[b, m]
            top_y[r, k] = y_packed[row_start[b] + rank[m]]
            person[r, k] = m
    pairs = np.empty((n_sel, width, n_cols), dtype=np.bool_)
    if width == 0:
        cost_out[:] = np.inf
        scale_out[:] = 1.0
        pairs[:] = False
    else:
        match_batch(top_x, top_y, count, hor_x, hor_y, coef, lam, scale_threshold, cost_out,
                    pairs, scale_out)
    for r in range(n_sel):
        for j in range(n_cols):
            kept_out[r, j] = -1
            for k in range(count[r]):
                if pairs[r, k, j]:
                    kept_out[r, j] = person[r, k]
    # Each group's best: the lowest (cost, index) of its best so far and this batch's rows.
    for r in range(rows.shape[0]):
        cost = cost_out[r]
        if not np.isfinite(cost):
            continue
        index = rows[r]
        g = index // n_theta
        if cost < best_cost[g] or (cost == best_cost[g] and index < best_index[g]):
            best_cost[g] = cost
            best_index[g] = index
            group_row[g] = r
    n_improved = 0
    for r in range(rows.shape[0]):
        g = rows[r] // n_theta
        if np.isfinite(cost_out[r]) and group_row[g] == r:
            improved[n_improved] = r
            n_improved += 1
            group_row[g] = -1
    return n_improved


@njit(cache=True)
def lower_bounds(top_x: np.ndarray, count: np.ndarray, hor_x: np.ndarray, coef: np.ndarray,
                 lam: float, tight: bool, out: np.ndarray) -> None:
    """``cost_lower_bound`` of every hypothesis into ``out`` (its docstring has the bound;
    ``coef[L, k]`` is rho^(L / k))."""
    n_batch, n_people = top_x.shape
    n_cols = hor_x.shape[0]
    gaps = np.empty(n_people)
    for b in range(n_batch):
        if count[b] <= 0:
            out[b] = np.inf
            continue
        n = 0
        for m in range(n_people):  # the distance of each finite x_top to its nearest x_hor
            x = top_x[b, m]
            if not np.isfinite(x):
                continue
            lo, hi = 0, n_cols  # searchsorted(hor_x, x, side="left")
            while lo < hi:
                mid = (lo + hi) // 2
                if hor_x[mid] < x:
                    lo = mid + 1
                else:
                    hi = mid
            below = hor_x[lo - 1 if lo > 0 else 0]
            above = hor_x[lo if lo < n_cols else n_cols - 1]
            gap_below, gap_above = abs(x - below), abs(x - above)
            gaps[n] = gap_below if gap_below < gap_above else gap_above
            n += 1
        longest = max(count[b], n_cols)
        shortest = min(count[b], n_cols)
        if not tight:
            smallest = np.inf
            for k in range(n):
                smallest = min(smallest, gaps[k])
            out[b] = coef[longest, shortest] * lam * smallest
            continue
        for k in range(1, n):  # insertion sort: a handful of people
            value, i = gaps[k], k - 1
            while i >= 0 and gaps[i] > value:
                gaps[i + 1] = gaps[i]
                i -= 1
            gaps[i + 1] = value
        best, partial = np.inf, 0.0
        for kappa in range(1, min(shortest, n_people) + 1):
            partial += gaps[kappa - 1] if kappa <= n else 0.0
            best = min(best, coef[longest, kappa] / kappa * partial)
        out[b] = best * lam


@njit(cache=True)
def _mod_two_pi(a: float) -> float:
    """numpy's ``mod(a, 2 pi)`` to the bit, a third of its cost where -2 pi < a < 4 pi (every
    angle difference of two wrapped angles plus pi): fmod is exact there, so the remainder is
    ``a``, ``a - 2 pi`` (exact) or, below zero, numpy's one rounded ``a + 2 pi``; zero is +0
    (numpy's sign rule). Elsewhere, and NaN, numpy's mod itself."""
    two_pi = 2.0 * np.pi
    if 0.0 < a < two_pi:
        return a
    if -two_pi < a < 0.0:
        return a + two_pi
    if two_pi <= a < 2.0 * two_pi:
        return a - two_pi
    if a == 0.0:
        return 0.0
    return np.mod(a, two_pi)


@njit(cache=True)
def hypothesis_table(phi: np.ndarray, visible: np.ndarray, thetas: np.ndarray, half: float,
                     delta: np.ndarray, x: np.ndarray, count: np.ndarray, seen: np.ndarray,
                     packed: np.ndarray) -> int:
    """delta and |K| of every (candidate, theta) row b = c T + t, as ``top_hypotheses``
    defines them, x = +inf outside the view, and the flat index and delta of each entry in
    view packed into ``seen`` and ``packed`` (their x_top, Eq. 7, is numpy's tan of delta, in
    both forms). Returns how many entries are in view."""
    n_cand, n_people = phi.shape
    n_theta = thetas.shape[0]
    n_seen = 0
    for c in range(n_cand):
        for t in range(n_theta):
            b = c * n_theta + t
            n = 0
            for m in range(n_people):
                d = _mod_two_pi(phi[c, m] - thetas[t] + np.pi) - np.pi
                delta[b, m] = d
                if abs(d) < half and visible[c, m]:
                    seen[n_seen] = b * n_people + m
                    packed[n_seen] = d
                    n_seen += 1
                    n += 1
                else:
                    x[b, m] = np.inf
            count[b] = n
    return n_seen


@njit(cache=True)
def sorted_rows(x_all: np.ndarray, delta_all: np.ndarray, dist: np.ndarray, n_theta: int,
                rows: np.ndarray, x: np.ndarray, index: np.ndarray, delta: np.ndarray,
                dist_out: np.ndarray, where: np.ndarray) -> None:
    """Eq. 8's sorted rows of the hypotheses ``rows`` (``TopHypotheses.take``): x of each row
    ascending over its first ``x.shape[1]`` entries, a stable sort (+inf last) as numpy's
    stable argsort, the person of each entry (-1 past the row's count), and the delta and |OP|
    of the valid entries packed row by row, with their flat index in ``where`` (the y of
    Eq. 5 is numpy's cos of delta, in both forms)."""
    n_people = x_all.shape[1]
    width = x.shape[1]
    order = np.empty(n_people, dtype=np.int64)
    k_out = 0
    for r in range(rows.shape[0]):
        b = rows[r]
        for m in range(n_people):  # stable insertion sort of the row's indices by x
            value, i = x_all[b, m], m - 1
            while i >= 0 and x_all[b, order[i]] > value:
                order[i + 1] = order[i]
                i -= 1
            order[i + 1] = m
        c = b // n_theta
        for k in range(width):
            m = order[k]
            x[r, k] = x_all[b, m]
            if np.isfinite(x_all[b, m]):  # the row's first count entries: its finite x
                index[r, k] = m
                delta[k_out] = delta_all[b, m]
                dist_out[k_out] = dist[c, m]
                where[k_out] = r * width + k
                k_out += 1
            else:
                index[r, k] = -1


@njit(cache=True)
def _clip(value: float, low: float, high: float) -> float:
    """numpy's ``clip`` of one float: max then min as its loop does (NaN passes through)."""
    if value != value:
        return value
    value = value if value > low else low
    return value if value < high else high


@njit(cache=True)
def pair_features(bearing_top: np.ndarray, log_depth: np.ndarray, visible: np.ndarray,
                  per_top: np.ndarray, log_dist: np.ndarray, bearing_hor: np.ndarray,
                  log_y_hor: np.ndarray, half_fov: float, clip: float, out: np.ndarray) -> None:
    """The per-pair features of ``spatial_features._hypothesis_features`` into the float32
    ``out`` ``(H, M, N, 12)`` (slice 4, matched, is left as it is): the wrapped bearing
    difference over half the field of view and the log depth ratio, each clipped to +-``clip``,
    and their absolute values; the four per-person flags ``per_top`` ``(H, M, 4)``; the row and
    column gaps; ``log_dist`` ``(H, M)``. The same arithmetic in the same order as the numpy
    form (numpy's mod, a true division, numpy's clip), each value rounded to float32 once."""
    n_hyp, n_top = bearing_top.shape
    n_hor = bearing_hor.shape[0]
    absdiff = np.empty((n_top, n_hor))
    col_ref = np.empty(n_hor)
    for h in range(n_hyp):
        for i in range(n_top):
            row_min = np.inf
            for j in range(n_hor):
                angle = bearing_top[h, i] - bearing_hor[j]
                diff = _clip((_mod_two_pi(angle + np.pi) - np.pi) / half_fov,
                             -clip, clip)
                a = abs(diff)
                absdiff[i, j] = a
                row_min = min(row_min, a)
                ratio = _clip(log_depth[h, i] - log_y_hor[j], -clip, clip)
                out[h, i, j, 0] = diff
                out[h, i, j, 1] = a
                out[h, i, j, 2] = ratio
                out[h, i, j, 3] = abs(ratio)
                for k in range(4):
                    out[h, i, j, 5 + k] = per_top[h, i, k]
                out[h, i, j, 11] = log_dist[h, i]
            for j in range(n_hor):
                out[h, i, j, 9] = absdiff[i, j] - row_min
        for j in range(n_hor):
            ref = np.inf
            for i in range(n_top):
                if visible[h, i]:
                    ref = min(ref, absdiff[i, j])
            col_ref[j] = ref if np.isfinite(ref) else 0.0
        for i in range(n_top):
            for j in range(n_hor):
                out[h, i, j, 10] = _clip(absdiff[i, j] - col_ref[j], 0.0, clip)


@njit(cache=True)
def pose_terms(cx: np.ndarray, cy: np.ndarray, grown: np.ndarray, turned: np.ndarray,
               top: np.ndarray, cos_h: np.ndarray, sin_h: np.ndarray, tan_half: float,
               reach2: float, far2: float, spread2: float, ground: np.ndarray,
               bounds: np.ndarray, shadows: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The oblique registration's per-pose terms (:func:`~xvmatch.cues.ground_registration.
    pose_terms`, its numpy form, step by step): pose ``p = h Q + q`` at (``cx``, ``cy``
    ``(H, Q)``) facing heading ``h``; returns ``(P, M)`` each horizontal person's least squared
    distance to a top person and two ``(P,)`` counts of the people it leaves unexplained in a
    view: top people in the horizontal camera's (nobody within ``far2``, squared, nor within
    ``spread2`` times their squared distance from the camera, nor behind a nearer horizontal
    person: ``shadows`` ``(3, M')``, each one's depth, bearing's tangent and its half span),
    and (``bounds`` not empty, else zeros) horizontal people in the top camera's sight
    (``ground`` its homography, ``bounds`` its pixel bounds and squared reach)."""
    n_head, n_q = cx.shape
    m, n = grown.shape[1], top.shape[0]
    near_hor = np.empty((n_head * n_q, m))
    missed = np.zeros(n_head * n_q, dtype=np.int64)
    unseen = np.zeros(n_head * n_q, dtype=np.int64)
    near_top = np.empty(n)
    sight = bounds.shape[0] > 0
    gx, gy = grown[..., 0].copy(), grown[..., 1].copy()  # (H, M, N), unit stride along N
    tx, ty = top[:, 0].copy(), top[:, 1].copy()
    d = np.empty(n)
    for h in range(n_head):
        c, s = cos_h[h], sin_h[h]
        for q in range(n_q):
            p = h * n_q + q
            x, y = cx[h, q], cy[h, q]
            near_top[:] = np.inf
            for k in range(m):
                for i in range(n):
                    dx = (x + gx[h, k, i]) - tx[i]
                    dy = (y + gy[h, k, i]) - ty[i]
                    d[i] = dx * dx + dy * dy
                best = np.inf
                for i in range(n):
                    best = min(best, d[i])
                    near_top[i] = min(near_top[i], d[i])
                near_hor[p, k] = best
                if sight and best > far2:
                    px, py = x + turned[h, k, 0], y + turned[h, k, 1]
                    u = (ground[0, 0] * px + ground[0, 1] * py) + ground[0, 2]
                    v = (ground[1, 0] * px + ground[1, 1] * py) + ground[1, 2]
                    w = (ground[2, 0] * px + ground[2, 1] * py) + ground[2, 2]
                    if (w > 0 and u > bounds[0] * w and u < bounds[1] * w and v > bounds[2] * w
                            and v < bounds[3] * w and px * px + py * py < bounds[4]):
                        unseen[p] += 1
            for i in range(n):
                if near_top[i] > far2:
                    rx, ry = tx[i] - x, ty[i] - y
                    ahead = rx * c + ry * s
                    across = -rx * s + ry * c
                    dist2 = ahead * ahead + across * across
                    if (ahead > 0.5 and abs(across) < ahead * tan_half and dist2 < reach2
                            and near_top[i] > spread2 * dist2):
                        bearing = across / ahead
                        hidden = False
                        for j in range(shadows.shape[1]):
                            if (shadows[0, j] < ahead
                                    and abs(bearing - shadows[1, j]) < shadows[2, j]):
                                hidden = True
                                break
                        if not hidden:
                            missed[p] += 1
    return near_hor, missed, unseen


@njit(cache=True)
def distinct_poses(x: np.ndarray, y: np.ndarray, heading: np.ndarray, order: np.ndarray,
                   limit: int, far_rad: float) -> np.ndarray:
    """The first ``limit`` poses of ``order`` each more than 1 m or ``far_rad`` (wrapped)
    from every one kept before it (:func:`~xvmatch.cues.ground_registration._distinct`, its
    numpy form, greedy in order): squared distances against 1, the heading difference wrapped
    as NumPy's ``(d + pi) % (2 pi) - pi`` (an exact fmod, then the divisor's sign: numba's
    float ``%`` is Python's, the same rule)."""
    keep = np.empty(min(limit, order.shape[0]), dtype=np.int64)
    n = 0
    two_pi = 2 * np.pi
    for idx in order:
        free = True
        for j in range(n):
            k = keep[j]
            dx, dy = x[idx] - x[k], y[idx] - y[k]
            if dx * dx + dy * dy > 1.0:
                continue
            mod = ((heading[idx] - heading[k]) + np.pi) % two_pi  # Python's rule, NumPy's
            if abs(mod - np.pi) > far_rad:
                continue
            free = False
            break
        if free:
            keep[n] = idx
            n += 1
            if n == keep.shape[0]:
                break
    return keep[:n]
