"""Joint association of V >= 2 views of one instant with cycle consistency, with HiGHS.

Views are numbered ``0..V-1`` (in ``xvmatch associate-multi``: 0 the top view, 1..K the
egocentric ones); view ``a`` has ``n_a`` boxes. For every pair of views ``a < b`` an
``(n_a, n_b)`` cost matrix ``c^{ab}`` and a non-association cost ``gamma_ab`` are given (as in
Eqs. 1-2 of the geometric-priors paper, a pair is worth matching alone when ``c < gamma``).

The joint 0/1 program over all view pairs:

- minimise ``sum_{a<b} sum_ij (c^{ab}_ij - gamma_ab) x^{ab}_ij`` (Eq. 1 with the dummy cost of
  Eq. 2 folded in: leaving a box unmatched costs nothing, matching it costs ``c - gamma``);
- each box matched at most once in each other view (Eq. 1's row and column constraints);
- cycle consistency (transitivity) for every triple of views ``a, b, c`` and boxes ``i, j, k``:
  ``x^{ab}_ij + x^{bc}_jk - 1 <= x^{ac}_ik`` and its two rotations: a person matched ego1-top
  and top-ego2 is the same person in ego1-ego2.

Together these make the matched boxes cliques with at most one box per view: one person each.
Without the triangle inequalities the program is the pairwise Hungarian assignment of each view
pair (:func:`pairwise_hungarian`, the baseline), so any change comes from consistency alone.
The triangle inequalities (``3 n_a n_b n_c`` per triple of views) are added lazily: solve, add
those of every triple the solution breaks, solve again, until none is broken; that is exact.
Each frame has a budget of work, the same on every CPU: :data:`MIP_MAX_TRIANGLES` triangles
added, :data:`~xvmatch.inference.tracks.track_mip.MIP_MAX_ROUNDS` programs of at most
:data:`~xvmatch.inference.tracks.track_mip.MIP_NODE_LIMIT` nodes. Past it, or if HiGHS fails, the
best consistent answer seen answers instead and the solution says so: a program's answer or the
pairwise Hungarian one, each made consistent by merging its pairs into people greedily, best
first (:func:`repair_cycles`, :func:`consistent_hungarian`). A wall-time guard stops a program
that would not end.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.optimize import Bounds, LinearConstraint, milp
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from xvmatch.inference.linking.assignment import assign
from xvmatch.inference.tracks.track_mip import MIP_MAX_ROUNDS, MIP_NODE_LIMIT, MIP_TIME_LIMIT

__all__ = [
    "MIP_MAX_TRIANGLES",
    "STATUSES",
    "MultiViewSolution",
    "check_problem",
    "consistent_hungarian",
    "cycle_violations",
    "global_ids",
    "objective",
    "pairwise_hungarian",
    "repair_cycles",
    "solve_multi_view",
    "view_pairs",
]

MIP_MAX_TRIANGLES = 96
"""Broken triangles a frame's program may add (three inequalities each): the budget of the lazy
rounds, the same on every CPU. Each program gets slower as triangles pile up (three crowded
views of 10-20 noisy random costs: 0.01 s with 39 triangles, 3 to 10 s past 75), so past this
budget the frame takes the best consistent answer seen instead of its exact optimum. The
rendered scenes of ``benchmarks/multi_ego_eval.py`` (1 top + 3 egocentric views) need at most
66 (``--tracks``, noisy boxes, 1,200 frames; it prints the most per row). On crowded random
frames (``benchmarks/multi_view_budget.py``: 3 views of 16 or 20 people, 4 of 12) the slowest
took 16.4 s within it on a busy 2-core machine (9.3 s at most within 64), under the 30 s
guard."""

STATUSES = ("optimal", "fallback", "greedy", "pairwise")
"""``optimal``: HiGHS proved it; ``fallback``: the budget of work or the time guard spent, or a
solver failure: the best consistent answer seen (:func:`solve_multi_view`);
``greedy``: :func:`consistent_hungarian` asked for; ``pairwise``: the pairwise baseline (may be
inconsistent)."""

Pairs = dict[tuple[int, int], np.ndarray]


@dataclass(frozen=True, eq=False)
class MultiViewSolution:
    """The matches of every view pair and one person id per box.

    Attributes:
        pairs: ``{(a, b): (K, 2) int64 (row in view a, row in view b)}`` for every ``a < b``,
            sorted by the first column.
        person: per view, ``(n_a,)`` int64 person id of each box (connected components of all
            matches, numbered 0.. in order of first appearance, view 0 first); boxes with the
            same id are one person (for an inconsistent baseline a component may hold two boxes
            of one view).
        status: one of :data:`STATUSES`.
        rounds: programs solved (one per batch of added triangle inequalities).
        triangles: broken triangles whose inequalities were added, against
            :data:`MIP_MAX_TRIANGLES`.
    """

    pairs: Pairs
    person: tuple[np.ndarray, ...]
    status: str
    rounds: int
    triangles: int = 0

    @property
    def consistent(self) -> bool:
        """No broken triangle: every component is a clique with at most one box per view."""
        return not cycle_violations(self.pairs, [p.size for p in self.person])


def view_pairs(n_views: int) -> list[tuple[int, int]]:
    """Every view pair ``(a, b)``, ``a < b``, in lexicographic order."""
    return list(itertools.combinations(range(int(n_views)), 2))


def check_problem(
    sizes: Sequence[int],
    costs: Mapping[tuple[int, int], np.ndarray],
    gamma: float | Mapping[tuple[int, int], float],
) -> tuple[list[int], dict[tuple[int, int], np.ndarray], dict[tuple[int, int], float]]:
    """The sizes, the cost matrices as float arrays and one gamma per view pair, checked.

    Raises:
        ValueError: fewer than 2 views, a negative size, a missing view pair, a cost matrix of
            the wrong shape, NaN or -inf in a cost, or a non-finite gamma.
    """
    n = [int(s) for s in sizes]
    if len(n) < 2 or min(n) < 0:
        raise ValueError(f"sizes must give >= 2 views with >= 0 boxes each, got {list(sizes)}")
    mats, gammas = {}, {}
    for a, b in view_pairs(len(n)):
        if (a, b) not in costs:
            raise ValueError(f"no cost matrix for views ({a}, {b}); give one per pair a < b")
        c = np.asarray(costs[(a, b)], dtype=float)
        if c.size == 0:
            c = c.reshape(n[a], n[b]) if n[a] * n[b] == 0 else c
        if c.shape != (n[a], n[b]):
            raise ValueError(f"cost matrix ({a}, {b}) has shape {c.shape}, expected "
                             f"{(n[a], n[b])} (boxes of views {a} and {b})")
        if np.isnan(c).any() or np.isneginf(c).any():
            raise ValueError(f"cost matrix ({a}, {b}) holds NaN or -inf; use +inf to forbid a "
                             "pair")
        g = float(gamma[(a, b)] if isinstance(gamma, Mapping) else gamma)
        if not np.isfinite(g):
            raise ValueError(f"gamma of views ({a}, {b}) must be finite, got {g}")
        mats[(a, b)], gammas[(a, b)] = c, g
    return n, mats, gammas


def _matrix(pairs: np.ndarray, m: int, n: int) -> np.ndarray:
    x = np.zeros((m, n), dtype=bool)
    p = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    x[p[:, 0], p[:, 1]] = True
    return x


def _pairs(x: np.ndarray) -> np.ndarray:
    rows, cols = np.nonzero(x)
    return np.stack([rows, cols], axis=1).astype(np.int64).reshape(-1, 2)


def cycle_violations(pairs: Mapping[tuple[int, int], np.ndarray],
                     sizes: Sequence[int]) -> list[tuple[int, int, int, int, int, int]]:
    """Broken triangles ``(a, b, c, i, j, k)``, ``a < b < c``: of the three matches
    ``(a i, b j)``, ``(b j, c k)``, ``(a i, c k)`` exactly two are made."""
    n = [int(s) for s in sizes]
    x = {ab: _matrix(pairs.get(ab, np.zeros((0, 2))), n[ab[0]], n[ab[1]])
         for ab in view_pairs(len(n))}
    out = []
    for a, b, c in itertools.combinations(range(len(n)), 3):
        ab, bc, ac = x[(a, b)].astype(np.int8), x[(b, c)].astype(np.int8), x[(a, c)]
        total = ab[:, :, None] + bc[None, :, :] + ac[:, None, :].astype(np.int8)
        for i, j, k in zip(*np.nonzero(total == 2), strict=True):
            out.append((a, b, c, int(i), int(j), int(k)))
    return out


def global_ids(pairs: Mapping[tuple[int, int], np.ndarray],
               sizes: Sequence[int]) -> tuple[np.ndarray, ...]:
    """Person id of every box: connected components of the matches, numbered in order of first
    appearance (view 0's boxes first, then view 1's, ...)."""
    n = [int(s) for s in sizes]
    start = np.r_[0, np.cumsum(n)]
    rows, cols = [], []
    for (a, b), p in pairs.items():
        p = np.asarray(p, dtype=np.int64).reshape(-1, 2)
        rows.append(start[a] + p[:, 0])
        cols.append(start[b] + p[:, 1])
    total = int(start[-1])
    r = np.concatenate(rows) if rows else np.zeros(0, np.int64)
    c = np.concatenate(cols) if cols else np.zeros(0, np.int64)
    graph = coo_matrix((np.ones(r.size), (r, c)), shape=(total, total))
    _, labels = connected_components(graph, directed=False)
    _, first = np.unique(labels, return_index=True)
    rank = np.empty(first.size, np.int64)
    rank[np.argsort(first, kind="stable")] = np.arange(first.size)
    ids = rank[labels] if total else np.zeros(0, np.int64)
    return tuple(ids[start[v]:start[v + 1]].astype(np.int64) for v in range(len(n)))


def objective(costs: Mapping[tuple[int, int], np.ndarray],
              gamma: float | Mapping[tuple[int, int], float],
              pairs: Mapping[tuple[int, int], np.ndarray]) -> float:
    """``sum (c - gamma)`` over the matched pairs: the value the joint program minimises."""
    total = 0.0
    for ab, p in pairs.items():
        p = np.asarray(p, dtype=np.int64).reshape(-1, 2)
        g = float(gamma[ab] if isinstance(gamma, Mapping) else gamma)
        total += float((np.asarray(costs[ab], dtype=float)[p[:, 0], p[:, 1]] - g).sum())
    return total


def _solution(pairs: Pairs, sizes: Sequence[int], status: str, rounds: int,
              triangles: int = 0) -> MultiViewSolution:
    ordered = {ab: p[np.argsort(p[:, 0], kind="stable")] for ab, p in sorted(pairs.items())}
    return MultiViewSolution(ordered, global_ids(ordered, sizes), status, rounds, triangles)


def pairwise_hungarian(
    sizes: Sequence[int],
    costs: Mapping[tuple[int, int], np.ndarray],
    gamma: float | Mapping[tuple[int, int], float],
) -> MultiViewSolution:
    """The baseline: each view pair on its own with the Hungarian algorithm and its gamma
    (:func:`xvmatch.inference.linking.assignment.assign`); the result may break cycles."""
    n, mats, gammas = check_problem(sizes, costs, gamma)
    pairs = {ab: assign(mats[ab], gammas[ab]) for ab in mats}
    return _solution(pairs, n, "pairwise", 0)


def consistent_hungarian(
    sizes: Sequence[int],
    costs: Mapping[tuple[int, int], np.ndarray],
    gamma: float | Mapping[tuple[int, int], float],
) -> MultiViewSolution:
    """Pairwise Hungarian made consistent (:func:`repair_cycles` of its pairs); consistent by
    construction, the MIP's fallback of last resort."""
    n, mats, gammas = check_problem(sizes, costs, gamma)
    return _solution(_hungarian_merged(n, mats, gammas), n, "greedy", 0)


def repair_cycles(
    sizes: Sequence[int],
    costs: Mapping[tuple[int, int], np.ndarray],
    gamma: float | Mapping[tuple[int, int], float],
    pairs: Mapping[tuple[int, int], np.ndarray],
) -> Pairs:
    """Matches made cycle-consistent: ``pairs``, best gain ``gamma - c`` first, merge two people
    when they share no view and no pair between them is forbidden (+inf); then every two boxes
    of one person are matched. A consistent answer comes back with the same pairs; a view pair
    missing from ``pairs`` has none.

    Raises:
        ValueError: as :func:`check_problem`; ``pairs`` of views that are not a pair ``a < b``
            of the problem, not ``(K, 2)``, or with a row outside its view.
    """
    n, mats, gammas = check_problem(sizes, costs, gamma)
    for ab, p in pairs.items():
        p = np.asarray(p)
        if ab not in mats or p.ndim != 2 or p.shape[1] != 2:
            raise ValueError(f"pairs of views {ab}: expected a (K, 2) array for a view pair "
                             f"a < b of {len(n)} views")
        if p.size and (p.min() < 0 or p[:, 0].max() >= n[ab[0]] or p[:, 1].max() >= n[ab[1]]):
            raise ValueError(f"pairs of views {ab}: a row outside the views' "
                             f"{n[ab[0]]} and {n[ab[1]]} boxes")
    return _merge(n, mats, gammas, pairs)


def _hungarian_merged(n: list[int], mats: Pairs, gammas: Mapping[tuple[int, int], float]
                      ) -> Pairs:
    """:func:`consistent_hungarian`'s pairs on a checked problem."""
    return _merge(n, mats, gammas, {ab: assign(c, gammas[ab]) for ab, c in mats.items()})


def _merge(n: list[int], mats: Pairs, gammas: Mapping[tuple[int, int], float],
           pairs: Mapping[tuple[int, int], np.ndarray]) -> Pairs:
    """:func:`repair_cycles` on a checked problem."""
    candidates = []
    for ab, c in mats.items():
        for i, j in np.asarray(pairs.get(ab, np.zeros((0, 2))), np.int64).reshape(-1, 2).tolist():
            candidates.append((gammas[ab] - c[i, j], ab, i, j))
    candidates.sort(key=lambda e: (-e[0], e[1], e[2], e[3]))
    members: dict[tuple[int, int], list[tuple[int, int]]] = {
        (v, i): [(v, i)] for v in range(len(n)) for i in range(n[v])}

    def forbidden(p: list[tuple[int, int]], q: list[tuple[int, int]]) -> bool:
        for (v, i), (w, j) in itertools.product(p, q):
            a, b, r, s = (v, w, i, j) if v < w else (w, v, j, i)
            if not np.isfinite(mats[(a, b)][r, s]):
                return True
        return False

    for _, (a, b), i, j in candidates:
        p, q = members[(a, i)], members[(b, j)]
        if p is q or {v for v, _ in p} & {w for w, _ in q} or forbidden(p, q):
            continue
        p.extend(q)
        for box in q:
            members[box] = p
    chosen: dict[tuple[int, int], list[tuple[int, int]]] = {ab: [] for ab in mats}
    seen = set()
    for group in members.values():
        if id(group) in seen:
            continue
        seen.add(id(group))
        for (v, i), (w, j) in itertools.combinations(sorted(group), 2):
            chosen[(v, w)].append((i, j))
    return {ab: np.array(p, dtype=np.int64).reshape(-1, 2) for ab, p in chosen.items()}


class _RowsAtMostOne:
    """Sparse rows ``sum(v x[c]) <= 1`` of a program, one row added at a time."""

    def __init__(self) -> None:
        self.rows: list[int] = []
        self.cols: list[int] = []
        self.vals: list[float] = []
        self.n_rows = 0

    def add(self, cols: list[int], vals: list[float]) -> None:
        """One row: ``sum(v x[c] for c, v in zip(cols, vals)) <= 1``."""
        self.rows.extend([self.n_rows] * len(cols))
        self.cols.extend(cols)
        self.vals.extend(vals)
        self.n_rows += 1

    def constraint(self, n_var: int) -> LinearConstraint:
        """The rows so far, over ``n_var`` variables."""
        return LinearConstraint(
            coo_matrix((self.vals, (self.rows, self.cols)), shape=(self.n_rows, n_var)).tocsr(),
            np.full(self.n_rows, -np.inf), np.ones(self.n_rows))


def _match_var(offset: Mapping[tuple[int, int], int], mats: Pairs, ab: tuple[int, int],
               i: int, j: int) -> int:
    """Index of the variable of the match (i, j) between the views ``ab``."""
    return offset[ab] + i * mats[ab].shape[1] + j


def _one_match_rows(mats: Pairs, offset: Mapping[tuple[int, int], int]) -> _RowsAtMostOne:
    """The rows of at most one match per box and other view."""
    cons = _RowsAtMostOne()
    for ab in mats:
        m, k = mats[ab].shape
        grid = offset[ab] + np.arange(m * k).reshape(m, k)
        for line in (*grid, *grid.T):
            cons.add(line.tolist(), [1.0] * line.size)
    return cons


def _gaining_most(broken: list[tuple[int, int, int, int, int, int]], x: np.ndarray,
                  weight: np.ndarray, offset: Mapping[tuple[int, int], int], mats: Pairs,
                  room: int) -> list[tuple[int, int, int, int, int, int]]:
    """The ``room`` broken triangles whose two matches gain most (the first of a tie)."""
    chosen = np.where(x, weight, 0.0)  # c - gamma of the matches made
    worth = [float(chosen[_match_var(offset, mats, (a, b), i, j)]
                   + chosen[_match_var(offset, mats, (b, c), j, k)]
                   + chosen[_match_var(offset, mats, (a, c), i, k)])
             for a, b, c, i, j, k in broken]  # most negative (worth most) first
    return [broken[q] for q in np.lexsort((np.arange(len(broken)), worth))[:room]]


def _add_triangle_rows(cons: _RowsAtMostOne, broken: list[tuple[int, int, int, int, int, int]],
                       added: set[tuple[int, int, int, int, int, int]],
                       offset: Mapping[tuple[int, int], int], mats: Pairs) -> None:
    """All three inequalities of each broken triangle, recorded in ``added``."""
    for a, b, c, i, j, k in broken:
        added.add((a, b, c, i, j, k))
        e_ab = _match_var(offset, mats, (a, b), i, j)
        e_bc = _match_var(offset, mats, (b, c), j, k)
        e_ac = _match_var(offset, mats, (a, c), i, k)
        for plus, minus in (((e_ab, e_bc), e_ac), ((e_ab, e_ac), e_bc),
                            ((e_ac, e_bc), e_ab)):
            cons.add([*plus, minus], [1.0, 1.0, -1.0])


def _best_consistent(n: list[int], mats: Pairs, gammas: Mapping[tuple[int, int], float],
                     answers: Sequence[Pairs]) -> Pairs:
    """The best consistent answer by the joint objective: each program's answer made
    consistent, then the pairwise Hungarian one; the first best wins a tie."""
    # made consistent only now, so that a frame solved to optimality pays nothing for it
    candidates = [_merge(n, mats, gammas, p) for p in answers]
    candidates.append(_hungarian_merged(n, mats, gammas))
    return min(candidates, key=lambda p: objective(mats, gammas, p))


def solve_multi_view(
    sizes: Sequence[int],
    costs: Mapping[tuple[int, int], np.ndarray],
    gamma: float | Mapping[tuple[int, int], float],
    time_limit: float = MIP_TIME_LIMIT,
    max_rounds: int = MIP_MAX_ROUNDS,
    node_limit: int = MIP_NODE_LIMIT,
    max_triangles: int = MIP_MAX_TRIANGLES,
) -> MultiViewSolution:
    """Solve the joint program of the module docstring with ``scipy.optimize.milp`` (HiGHS).

    Args:
        sizes: boxes per view, ``(n_0, ..., n_{V-1})``, V >= 2.
        costs: ``{(a, b): (n_a, n_b) costs}`` for every ``a < b``; ``+inf`` forbids a pair.
        gamma: the non-association cost, one for all pairs or ``{(a, b): gamma_ab}``.
        time_limit: wall-time guard for all rounds together, against a program that would not
            end (:data:`~xvmatch.inference.tracks.track_mip.MIP_TIME_LIMIT`); past it the fallback.
        max_rounds: most programs solved while adding broken triangles; past it the fallback.
        node_limit: HiGHS nodes per program (the same on every CPU,
            :data:`~xvmatch.inference.tracks.track_mip.MIP_NODE_LIMIT`); past it the fallback.
        max_triangles: most broken triangles added (:data:`MIP_MAX_TRIANGLES`); when a
            program breaks more than are left, those whose two matches gain most fill it, one
            last program is solved, and the fallback answers unless that one is consistent.

    Returns:
        The :class:`MultiViewSolution`; ``status`` ``optimal`` or ``fallback``. A ``fallback``
        is the best consistent answer seen by the joint objective: a program's answer made
        consistent (:func:`repair_cycles`) or :func:`consistent_hungarian`'s.

    Raises:
        ValueError: as :func:`check_problem`; a budget out of range.
    """
    if not time_limit > 0 or int(max_rounds) < 1 or int(max_triangles) < 0:
        raise ValueError("time_limit and max_rounds must be > 0 and max_triangles >= 0, got "
                         f"{time_limit}, {max_rounds}, {max_triangles}")
    n, mats, gammas = check_problem(sizes, costs, gamma)
    keys = list(mats)
    offset = dict(zip(keys, np.cumsum([0, *(mats[k].size for k in keys)])[:-1].tolist(),
                      strict=True))
    n_var = int(sum(m.size for m in mats.values()))
    if n_var == 0:
        return _solution({ab: np.zeros((0, 2), np.int64) for ab in keys}, n, "optimal", 0)
    cons = _one_match_rows(mats, offset)
    weight = np.concatenate([np.where(np.isfinite(mats[ab]), mats[ab] - gammas[ab], 0.0).ravel()
                             for ab in keys])
    upper = np.concatenate([np.isfinite(mats[ab]).ravel().astype(float) for ab in keys])
    bounds = Bounds(np.zeros(n_var), upper)
    integrality = np.ones(n_var)
    start = time.perf_counter()
    added: set[tuple[int, int, int, int, int, int]] = set()
    answers: list[Pairs] = []  # each program's answer that broke triangles
    rounds = 0
    for rounds in range(1, int(max_rounds) + 1):
        left = time_limit - (time.perf_counter() - start)
        if left <= 0:
            break
        res = milp(weight, integrality=integrality, bounds=bounds,
                   constraints=cons.constraint(n_var),
                   options={"time_limit": left, "node_limit": int(node_limit), "disp": False})
        if res.status != 0 or res.x is None:
            break
        x = np.round(res.x).astype(bool)
        pairs = {ab: _pairs(x[offset[ab]:offset[ab] + mats[ab].size].reshape(mats[ab].shape))
                 for ab in keys}
        broken = [t for t in cycle_violations(pairs, n) if t not in added]
        if not broken:
            return _solution(pairs, n, "optimal", rounds, len(added))
        answers.append(pairs)
        room = int(max_triangles) - len(added)
        if room <= 0:
            break
        if len(broken) > room:  # the last program: the triangles whose matches gain most
            broken = _gaining_most(broken, x, weight, offset, mats, room)
        _add_triangle_rows(cons, broken, added, offset, mats)
    best = _best_consistent(n, mats, gammas, answers)
    return _solution(best, n, "fallback", rounds, len(added))
