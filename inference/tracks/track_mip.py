"""The four-cluster mixed-integer program of the CVMHAT paper (Sec. 3.1, Eqs. 1-4), with HiGHS.

Clusters, in the paper's clockwise order: 0 = top view, clip t; 1 = top view, clip t+1;
2 = horizontal view, clip t+1; 3 = horizontal view, clip t. Edge set ``i`` joins cluster ``i``
to cluster ``(i + 1) % 4`` and is an ``(N_i, N_{i+1})`` binary matrix: sets 0 and 2 link a view
over time, sets 1 and 3 link the two views within a clip.

- Eq. 1: maximise ``sum c e + c0 sum_i d_i``, ``d_i`` the edges at cluster ``i``'s dummy node.
- Eq. 2: at most one edge leaves and one enters each real node of each edge set.
- Eq. 3: three consecutive edges of a loop force the fourth (the paths close into 4-cycles).
- Eq. 4: every cluster has ``2K`` edge ends (in and out, dummy ones included), ``K`` the largest
  cluster size, so an edge is worth taking when its weight is above ``2 c0``.

The loop constraints are ``4 N0 N1 N2 N3`` in number; they are added lazily (solve, add the
loops the solution breaks, solve again), which is exact and keeps each program small. Each
window has a budget of work, the same on every CPU: :data:`MIP_MAX_LOOPS` loops added (when a
program breaks more than are left, those whose edges are worth most fill it for one last
program), :data:`MIP_MAX_ROUNDS` programs of at most :data:`MIP_NODE_LIMIT` nodes. Past it, or
if HiGHS fails, the best loop-free answer seen answers instead and the solution says so: a
program's answer with its broken loops closed or cut (:func:`repair_loops`), or
:func:`greedy_solution` (a Hungarian assignment per edge set, repaired the same way), whichever
Eq. 1 values more. A wall-time guard (:data:`MIP_TIME_LIMIT`) stops a program that would not
end.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, linear_sum_assignment, milp
from scipy.sparse import coo_matrix

__all__ = [
    "MIP_MAX_LOOPS",
    "MIP_MAX_ROUNDS",
    "MIP_NODE_LIMIT",
    "MIP_TIME_LIMIT",
    "ClusterSolution",
    "check_weights",
    "greedy_solution",
    "loop_violations",
    "objective",
    "repair_loops",
    "solve_four_clusters",
]

MIP_NODE_LIMIT = 1000
"""HiGHS branch-and-bound nodes per program: the MIPs' budget of work. It is the same on every
CPU, so a window (a frame) falls back on the same inputs whatever the machine's speed or
load. Every window of the CVMHAT dev split is solved at the root node (one
node), clean boxes or detector noise with c0 0.1 (2,682 programs, 2026-11-27)."""

MIP_MAX_LOOPS = 64
"""Loop constraints (Eq. 3) a window may add: the budget of the lazy rounds, the same on every
CPU. Each program gets slower as loops pile up (a crowded rendered video with images: 0.05 s
with none, 5 to 10 s past 300), so past this budget the window takes the best loop-free
answer seen instead of its exact optimum. The CVMHAT dev split needs at most 34 (clean boxes,
1,540 windows) and 42 with detector noise (seeds 1-3, 4,620 windows; 2026-11-28)."""

MIP_MAX_ROUNDS = 50
"""Programs a window (or an ``associate-multi`` frame) may solve while adding loops (triangles);
past it, as past :data:`MIP_MAX_LOOPS`."""

MIP_TIME_LIMIT = 30.0
"""Default wall-time guard per window (frame), against a program that would not end. Unlike
the budgets of work it depends on the machine, so it sits far above what a window takes: at
most 0.3 s per program on the dev split with noisy boxes, and 6.6 s for the slowest window of
a crowded rendered video with images within :data:`MIP_MAX_LOOPS`, on a 2-core machine (a 2 s
limit let 9 of 780 windows fall back when five other jobs shared that machine)."""


@dataclass(frozen=True, eq=False)
class ClusterSolution:
    """Edges chosen between the four clusters of one window.

    Attributes:
        edges: four binary ``(N_i, N_{i+1})`` int8 matrices, edge sets 0..3.
        dummies: (4,) the ``d_i`` of Eqs. 1 and 4.
        status: ``optimal`` (HiGHS proved it), ``fallback`` (budget spent or solver failure:
            the best loop-free answer seen) or ``greedy`` (asked for).
        rounds: how many programs were solved (one per batch of lazily added loops).
        loops: how many loop constraints (Eq. 3) were added, against :data:`MIP_MAX_LOOPS`.
    """

    edges: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    dummies: np.ndarray
    status: str
    rounds: int
    loops: int = 0


def check_weights(weights: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """The four weight matrices as float arrays, their shapes chained ``(N_i, N_{i+1})``."""
    if len(weights) != 4:
        raise ValueError(f"need 4 weight matrices (edge sets 0..3), got {len(weights)}")
    mats = tuple(np.asarray(w, dtype=float).reshape(np.shape(w)) for w in weights)
    for i, w in enumerate(mats):
        nxt = mats[(i + 1) % 4]
        if w.ndim != 2 or w.shape[1] != nxt.shape[0] or not np.isfinite(w).all():
            raise ValueError(
                f"weight matrix {i} must be finite with shape (N_{i}, N_{(i + 1) % 4}) chained "
                f"to the next one; got shapes {[m.shape for m in mats]}"
            )
    return mats


def _sizes(mats: Sequence[np.ndarray]) -> list[int]:
    return [m.shape[0] for m in mats]


def _dummies(edges: Sequence[np.ndarray], sizes: Sequence[int]) -> np.ndarray:
    """``d_i = 2K - (edges into cluster i) - (edges out of cluster i)`` (Eq. 4)."""
    k = max(sizes) if sizes else 0
    return np.array(
        [2 * k - int(edges[(i - 1) % 4].sum()) - int(edges[i].sum()) for i in range(4)]
    )


def objective(weights: Sequence[np.ndarray], edges: Sequence[np.ndarray], c0: float) -> float:
    """Value of Eq. 1 for the given edges (dummy counts from Eq. 4)."""
    mats = check_weights(weights)
    d = _dummies(edges, _sizes(mats))
    return float(sum((w * e).sum() for w, e in zip(mats, edges, strict=True)) + c0 * d.sum())


def loop_violations(edges: Sequence[np.ndarray]) -> list[tuple[int, int, int, int, int]]:
    """Loops that break Eq. 3: ``(i, a, b, c, d)`` with edges a->b, b->c, c->d from cluster
    ``i`` on and no edge d->a closing the loop."""
    succ = []
    for e in edges:
        s = np.full(e.shape[0], -1)
        rows, cols = np.nonzero(e)
        s[rows] = cols
        succ.append(s)
    out = []
    for i in range(4):
        for a in np.flatnonzero(succ[i] >= 0).tolist():
            b = int(succ[i][a])
            c = int(succ[(i + 1) % 4][b])
            if c < 0:
                continue
            d = int(succ[(i + 2) % 4][c])
            if d >= 0 and not edges[(i + 3) % 4][d, a]:
                out.append((i, a, b, c, d))
    return out


def greedy_solution(weights: Sequence[np.ndarray], c0: float = 0.2) -> ClusterSolution:
    """Hungarian assignment per edge set on the weights (pairs above ``2 c0``), then every
    broken loop of Eq. 3 closed or cut (:func:`repair_loops`); the MIP's last fallback."""
    mats = check_weights(weights)
    edges = []
    for w in mats:
        e = np.zeros(w.shape, dtype=np.int8)
        if w.size:
            r, c = linear_sum_assignment(-w)
            keep = w[r, c] > 2 * c0
            e[r[keep], c[keep]] = 1
        edges.append(e)
    edges = repair_loops(mats, edges, c0)
    return ClusterSolution(edges, _dummies(edges, _sizes(mats)), "greedy", 0)


def repair_loops(
    weights: Sequence[np.ndarray], edges: Sequence[np.ndarray], c0: float,
) -> tuple[np.ndarray, ...]:
    """Make an answer of Eq. 2 keep Eq. 3: each broken loop a->b->c->d is closed with the edge
    d->a where both ends are free, or cut at its weakest edge, whichever Eq. 1 values more (an
    edge is worth its weight less ``2 c0``, the two dummy ends it replaces; Eq. 4). Closing a
    loop breaks no other. Returns a copy; ``edges`` is left as it is."""
    out = [np.array(e, dtype=np.int8) for e in edges]
    while True:
        broken = loop_violations(out)
        if not broken:
            return tuple(out)
        i, a, b, c, d = broken[0]
        path = [(i, a, b), ((i + 1) % 4, b, c), ((i + 2) % 4, c, d)]
        k, r, s = min(path, key=lambda p: weights[p[0]][p[1], p[2]])
        last = out[(i + 3) % 4]
        close = weights[(i + 3) % 4][d, a] - 2.0 * c0
        if not last[d].any() and not last[:, a].any() and close > 2.0 * c0 - weights[k][r, s]:
            last[d, a] = 1
        else:
            out[k][r, s] = 0


def _offsets(mats: Sequence[np.ndarray]) -> list[int]:
    out, at = [], 0
    for w in mats:
        out.append(at)
        at += w.size
    return [*out, at]


class _ConstraintRows:
    """Sparse rows ``lo <= A x <= hi`` of a program, one row added at a time."""

    def __init__(self) -> None:
        self.rows: list[int] = []
        self.cols: list[int] = []
        self.vals: list[float] = []
        self.lo: list[float] = []
        self.hi: list[float] = []

    def add(self, entries: list[tuple[int, float]], low: float, high: float) -> None:
        """One row: ``low <= sum(v x[c] for c, v in entries) <= high``."""
        r = len(self.lo)
        for c, v in entries:
            self.rows.append(r)
            self.cols.append(c)
            self.vals.append(v)
        self.lo.append(low)
        self.hi.append(high)

    def constraint(self, n_var: int) -> LinearConstraint:
        """The rows so far, over ``n_var`` variables."""
        a_mat = coo_matrix((self.vals, (self.rows, self.cols)),
                           shape=(len(self.lo), n_var)).tocsr()
        return LinearConstraint(a_mat, self.lo, self.hi)


def _edge_var(mats: Sequence[np.ndarray], off: Sequence[int], i: int, a: int, b: int) -> int:
    """Index of the variable of edge (a, b) of matrix i."""
    return off[i] + a * mats[i].shape[1] + b


def _window_rows(mats: Sequence[np.ndarray], off: Sequence[int], k: int) -> _ConstraintRows:
    """The rows of Eq. 2 (each node in at most one edge per neighbouring cluster) and of Eq. 4
    (K fixed to the largest cluster, ``k``), the dummy variables after the edges."""
    n_e = off[-1]
    cons = _ConstraintRows()
    for i, w in enumerate(mats):  # Eq. 2
        n_a, n_b = w.shape
        for a in range(n_a):
            cons.add([(_edge_var(mats, off, i, a, b), 1.0) for b in range(n_b)], -np.inf, 1.0)
        for b in range(n_b):
            cons.add([(_edge_var(mats, off, i, a, b), 1.0) for a in range(n_a)], -np.inf, 1.0)
    for i in range(4):  # Eq. 4, K fixed to the largest cluster
        inc = (i - 1) % 4
        entries = [(c, 1.0) for c in range(off[inc], off[inc + 1])]
        entries += [(c, 1.0) for c in range(off[i], off[i + 1])]
        entries.append((n_e + i, 1.0))
        cons.add(entries, 2.0 * k, 2.0 * k)
    return cons


def _worth_most(
    mats: Sequence[np.ndarray], broken: list[tuple[int, int, int, int, int]], room: int
) -> list[tuple[int, int, int, int, int]]:
    """The ``room`` broken loops whose three edges are worth most (the first of a tie)."""
    worth = [mats[i][a, b] + mats[(i + 1) % 4][b, c] + mats[(i + 2) % 4][c, d]
             for i, a, b, c, d in broken]
    return [broken[q] for q in np.lexsort((np.arange(len(broken)), -np.asarray(worth)))[:room]]


def _add_loop_rows(
    cons: _ConstraintRows,
    mats: Sequence[np.ndarray],
    off: Sequence[int],
    broken: list[tuple[int, int, int, int, int]],
    seen: set[tuple[int, int, int, int, int]],
) -> None:
    """Eq. 3 for each broken loop, recorded in ``seen``."""
    for i, a, b, c, d in broken:
        seen.add((i, a, b, c, d))
        cons.add([(_edge_var(mats, off, i, a, b), 1.0),
                  (_edge_var(mats, off, (i + 1) % 4, b, c), 1.0),
                  (_edge_var(mats, off, (i + 2) % 4, c, d), 1.0),
                  (_edge_var(mats, off, (i + 3) % 4, d, a), -1.0)], -np.inf, 2.0)


def _fallback(
    mats: Sequence[np.ndarray], answers: Sequence[tuple[np.ndarray, ...]], c0: float
) -> tuple[np.ndarray, ...]:
    """The best loop-free answer by Eq. 1: each program's answer repaired
    (:func:`repair_loops`), then the greedy one; the first best wins a tie."""
    # repaired only now, so that a window solved to optimality pays nothing for it
    candidates = [repair_loops(mats, e, c0) for e in answers] + [greedy_solution(mats, c0).edges]
    return max(candidates, key=lambda e: objective(mats, e, c0))


def solve_four_clusters(
    weights: Sequence[np.ndarray],
    c0: float = 0.2,
    time_limit: float = MIP_TIME_LIMIT,
    max_rounds: int = MIP_MAX_ROUNDS,
    node_limit: int = MIP_NODE_LIMIT,
    max_loops: int = MIP_MAX_LOOPS,
) -> ClusterSolution:
    """Solve Eqs. 1-4 for one window with ``scipy.optimize.milp`` (HiGHS).

    Args:
        weights: the four edge-weight matrices ``c^i``, shapes ``(N_i, N_{(i+1)%4})``.
        c0: dummy-node weight of Eq. 1.
        time_limit: wall-time guard for the whole window (every round), against a program
            that would not end (:data:`MIP_TIME_LIMIT`); past it the fallback.
        max_rounds: most programs solved while adding broken loops (:data:`MIP_MAX_ROUNDS`);
            past it the fallback.
        max_loops: most loop constraints added (:data:`MIP_MAX_LOOPS`); when a program
            breaks more than are left, those whose three edges are worth most fill it, one last
            program is solved, and the fallback answers unless that one breaks none.
        node_limit: HiGHS nodes per program (:data:`MIP_NODE_LIMIT`); past it the fallback.

    Returns:
        The :class:`ClusterSolution`; ``status`` says whether HiGHS proved it optimal. A
        ``fallback`` is the best loop-free answer seen: a program's answer with its broken
        loops closed or cut (:func:`repair_loops`) or the greedy one, by Eq. 1.

    Raises:
        ValueError: bad shapes (:func:`check_weights`) or a budget out of range.
    """
    if not time_limit > 0 or int(max_rounds) < 1 or int(max_loops) < 0:
        raise ValueError("time_limit and max_rounds must be > 0 and max_loops >= 0, got "
                         f"{time_limit}, {max_rounds}, {max_loops}")
    mats = check_weights(weights)
    sizes = _sizes(mats)
    if all(m.size == 0 for m in mats):
        empty = tuple(np.zeros(m.shape, dtype=np.int8) for m in mats)
        return ClusterSolution(empty, _dummies(empty, sizes), "optimal", 0)
    off = _offsets(mats)
    n_e = off[-1]
    n_var = n_e + 4
    k = max(sizes)
    cons = _window_rows(mats, off, k)
    cost = -np.concatenate([*(w.ravel() for w in mats), np.full(4, c0)])
    integrality = np.ones(n_var)
    bounds = Bounds(np.zeros(n_var), np.r_[np.ones(n_e), np.full(4, 2.0 * k)])
    start = time.perf_counter()
    seen: set[tuple[int, int, int, int, int]] = set()
    answers: list[tuple[np.ndarray, ...]] = []  # each program's answer that broke loops
    rounds = 0
    for rounds in range(1, int(max_rounds) + 1):
        left = time_limit - (time.perf_counter() - start)
        if left <= 0:
            break
        res = milp(
            cost,
            integrality=integrality,
            bounds=bounds,
            constraints=cons.constraint(n_var),
            options={"time_limit": left, "node_limit": int(node_limit), "disp": False},
        )
        if res.status != 0 or res.x is None:
            break
        x = np.round(res.x).astype(np.int64)
        edges = tuple(
            x[off[i]:off[i + 1]].reshape(w.shape).astype(np.int8) for i, w in enumerate(mats)
        )
        broken = [v for v in loop_violations(edges) if v not in seen]
        if not broken:
            return ClusterSolution(edges, x[n_e:].copy(), "optimal", rounds, len(seen))
        answers.append(edges)
        room = int(max_loops) - len(seen)
        if room <= 0:
            break
        if len(broken) > room:  # the last program: the loops whose three edges are worth most
            broken = _worth_most(mats, broken, room)
        _add_loop_rows(cons, mats, off, broken, seen)
    best = _fallback(mats, answers, c0)
    return ClusterSolution(best, _dummies(best, sizes), "fallback", rounds, len(seen))
