"""Tests of the vector-set matching (xvmatch.cues.spatial_matching, CVMHAT Eqs. 11-12)."""

from __future__ import annotations

import math
import re
from functools import cache
from itertools import pairwise

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from xvmatch.core import kernel_choice
from xvmatch.cues.spatial_matching import (
    SpatialParams,
    cost_lower_bound,
    match_vector_sets,
    monotonic_path,
    one_to_one,
)

PARAMS = SpatialParams()


# --------------------------------------------------------------------------------------------
# monotonic_path: batched DTW


@cache
def _all_paths(n_rows: int, n_cols: int) -> tuple[tuple[tuple[int, int], ...], ...]:
    """Every monotonic path from (0, 0) to (n_rows - 1, n_cols - 1), steps down/right/diagonal."""
    if n_rows == 1 and n_cols == 1:
        return (((0, 0),),)
    out = []
    for di, dj in ((1, 0), (0, 1), (1, 1)):
        if n_rows - di >= 1 and n_cols - dj >= 1:
            end = (n_rows - 1, n_cols - 1)
            out.extend((*p, end) for p in _all_paths(n_rows - di, n_cols - dj))
    return tuple(out)


def _brute_force_dtw(cost: np.ndarray) -> float:
    """Minimal path cost by enumerating every monotonic path (Delannoy many, fine up to 5x5)."""
    return min(sum(cost[i, j] for i, j in p) for p in _all_paths(*cost.shape))


def test_brute_force_enumerates_delannoy_many_paths():
    # Sanity of the reference itself: D(2, 2) = 13, D(4, 4) = 321.
    assert len(_all_paths(3, 3)) == 13
    assert len(_all_paths(5, 5)) == 321


@st.composite
def _cost_batches(draw):
    n_batch = draw(st.integers(1, 3))
    n_rows = draw(st.integers(1, 5))
    n_cols = draw(st.integers(1, 5))
    # Small integers make ties frequent (the tie-breaking must still give a minimal path).
    elements = st.one_of(st.integers(0, 3).map(float), st.floats(0.0, 10.0))
    cost = draw(hnp.arrays(np.float64, (n_batch, n_rows, n_cols), elements=elements))
    rows = np.asarray(draw(st.lists(st.integers(0, n_rows), min_size=n_batch, max_size=n_batch)))
    # Padding rows "may hold anything finite": fill them with arbitrary values, even negative.
    junk = draw(hnp.arrays(np.float64, cost.shape, elements=st.floats(-1e3, 1e3)))
    padding = np.arange(n_rows)[None, :, None] >= rows[:, None, None]
    cost = np.where(padding, junk, cost)
    return cost, rows


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(batch=_cost_batches())
def test_monotonic_path_is_a_minimal_dtw_path(batch):
    cost, rows = batch
    path = monotonic_path(cost, rows)
    assert path.shape == cost.shape and path.dtype == bool
    n_cols = cost.shape[2]
    for b, count in enumerate(rows):
        cells = sorted(zip(*np.nonzero(path[b]), strict=True))
        if count == 0:
            assert cells == []
            continue
        # Starts at (0, 0), ends at (count - 1, Q - 1), never enters the padding.
        assert cells[0] == (0, 0)
        assert cells[-1] == (count - 1, n_cols - 1)
        assert all(i < count for i, _ in cells)
        # Monotonic, steps of at most 1 in each direction (no repeated cell, no jump).
        steps = {(i1 - i0, j1 - j0) for (i0, j0), (i1, j1) in pairwise(cells)}
        assert steps <= {(1, 0), (0, 1), (1, 1)}
        # Minimal cost, as brute force over every monotonic path.
        got = sum(cost[b, i, j] for i, j in cells)
        want = _brute_force_dtw(cost[b, :count])
        assert math.isclose(got, want, rel_tol=1e-12, abs_tol=1e-12)


def test_monotonic_path_hand_case():
    # The cheap cells form the anti-diagonal-free route (0,0) (1,1) (1,2) (2,3).
    cost = np.array(
        [
            [0.0, 5.0, 5.0, 5.0],
            [5.0, 0.0, 0.0, 5.0],
            [5.0, 5.0, 5.0, 0.0],
        ]
    )[None]
    path = monotonic_path(cost, np.array([3]))
    assert sorted(zip(*np.nonzero(path[0]), strict=True)) == [(0, 0), (1, 1), (1, 2), (2, 3)]


def test_monotonic_path_empty_inputs():
    assert monotonic_path(np.zeros((0, 3, 3)), np.zeros(0, int)).shape == (0, 3, 3)
    assert not monotonic_path(np.zeros((2, 3, 0)), np.array([3, 3])).any()
    assert not monotonic_path(np.zeros((2, 0, 3)), np.array([0, 0])).any()


# --------------------------------------------------------------------------------------------
# one_to_one: the clean-up of Sec. 3.2.3


def _one_to_one_reference(path: np.ndarray, cost: np.ndarray) -> np.ndarray:
    """Loop transcription: per row keep the least dissimilar, then per column the same."""
    keep = np.zeros_like(path)
    for i in range(path.shape[0]):
        cols = np.flatnonzero(path[i])
        if cols.size:
            keep[i, cols[np.argmin(cost[i, cols])]] = True
    for j in range(path.shape[1]):
        rows = np.flatnonzero(keep[:, j])
        if rows.size > 1:
            best = rows[np.argmin(cost[rows, j])]
            keep[rows, j] = False
            keep[best, j] = True
    return keep


@pytest.mark.slow
@settings(max_examples=150, deadline=None)
@given(
    data=st.data(),
    shape=st.tuples(st.integers(1, 3), st.integers(1, 6), st.integers(1, 6)),
)
def test_one_to_one_properties(data, shape):
    path = data.draw(hnp.arrays(bool, shape))
    elements = st.one_of(st.integers(0, 3).map(float), st.floats(0.0, 10.0))
    cost = data.draw(hnp.arrays(np.float64, shape, elements=elements))
    keep = one_to_one(path, cost)
    assert keep.shape == path.shape
    assert not (keep & ~path).any()  # only path cells
    assert (keep.sum(axis=2) <= 1).all()  # at most one per row
    assert (keep.sum(axis=1) <= 1).all()  # at most one per column
    for b in range(shape[0]):
        np.testing.assert_array_equal(keep[b], _one_to_one_reference(path[b], cost[b]))


def test_one_to_one_hand_case():
    # Row 0 matched to columns 0 and 1 keeps column 1 (cheaper); row 2 keeps column 2; column 1
    # is then claimed by rows 0 and 1 and keeps row 1 (cheaper).
    path = np.array([[[1, 1, 0], [0, 1, 0], [0, 1, 1]]], dtype=bool)
    cost = np.array([[[0.5, 0.2, 9.0], [9.0, 0.1, 9.0], [9.0, 0.3, 0.25]]])
    keep = one_to_one(path, cost)
    np.testing.assert_array_equal(keep[0], [[0, 0, 0], [0, 1, 0], [0, 0, 1]])


def test_one_to_one_is_two_greedy_steps_not_an_assignment():
    # Row 2 prefers column 1 (0.3 < 0.4) in the row step and then loses it to row 1 in the
    # column step: it ends unmatched although (2, 2) is free (the paper's clean-up, not Hungarian).
    path = np.array([[[1, 1, 0], [0, 1, 0], [0, 1, 1]]], dtype=bool)
    cost = np.array([[[0.5, 0.2, 9.0], [9.0, 0.1, 9.0], [9.0, 0.3, 0.4]]])
    keep = one_to_one(path, cost)
    np.testing.assert_array_equal(keep[0], [[0, 0, 0], [0, 1, 0], [0, 0, 0]])


# --------------------------------------------------------------------------------------------
# match_vector_sets: Eqs. 11-12 on hand-made sets


def _match(top: np.ndarray, hor: np.ndarray, params: SpatialParams = PARAMS):
    top = np.asarray(top, dtype=float)
    return match_vector_sets(
        top[None, :, 0], top[None, :, 1], np.array([len(top)]), np.asarray(hor, float), params
    )


def test_identical_sets_cost_zero_and_exact_scale():
    hor = np.array([[-0.6, 0.010], [-0.1, 0.004], [0.2, 0.002], [0.7, 0.005]])
    top = hor * np.array([1.0, 2500.0])  # y_top = 2500 y_hor: mu = 1 / 2500
    res = _match(top, hor)
    assert res.cost[0] == 0.0
    assert math.isclose(res.scale[0], 1 / 2500, rel_tol=1e-12)
    np.testing.assert_array_equal(res.pairs[0], np.eye(4, dtype=bool))


def test_phi_by_hand_scale_from_mean_ratio():
    # x identical, y ratios 2 and 4: mu = 1 / mean(2, 4) = 1/3; D = |2/3 - 1| + |4/3 - 1| = 2/3,
    # L = kappa = 2, Phi = rho^(2/2) / 2 * 2/3 = rho / 3.
    top = np.array([[-0.5, 2.0], [0.5, 4.0]])
    hor = np.array([[-0.5, 1.0], [0.5, 1.0]])
    res = _match(top, hor)
    assert math.isclose(res.scale[0], 1 / 3, rel_tol=1e-12)
    assert math.isclose(res.cost[0], PARAMS.rho / 3, rel_tol=1e-12)
    np.testing.assert_array_equal(res.pairs[0], np.eye(2, dtype=bool))


def test_phi_by_hand_with_x_offsets_and_lambda():
    # Each pair off by 0.01 in x, y exact: Phi = rho^(3/3) / 3 * lambda * 0.03.
    hor = np.array([[-0.8, 0.01], [-0.2, 0.004], [0.3, 0.002]])
    top = np.array([[-0.79, 10.0], [-0.19, 4.0], [0.31, 2.0]])
    params = SpatialParams(rho=7.0, lam=0.5)
    res = _match(top, hor, params)
    assert math.isclose(res.cost[0], 7.0 / 3 * 0.5 * 0.03, rel_tol=1e-9)


def test_one_extra_horizontal_person_costs_rho_to_the_l_over_kappa():
    # The same three pairs, plus a horizontal person with no top partner (far right):
    # L goes from 3 to 4 with kappa = 3, so Phi gains exactly rho^(4/3 - 1).
    hor3 = np.array([[-0.8, 0.01], [-0.2, 0.004], [0.3, 0.002]])
    hor4 = np.vstack([hor3, [[0.9, 0.02]]])
    top = np.array([[-0.79, 10.0], [-0.19, 4.0], [0.31, 2.0]])
    three, four = _match(top, hor3), _match(top, hor4)
    expected = PARAMS.rho * PARAMS.lam * 0.03 / 3
    assert math.isclose(three.cost[0], expected, rel_tol=1e-9)
    assert math.isclose(four.cost[0], PARAMS.rho ** (4 / 3) * PARAMS.lam * 0.03 / 3, rel_tol=1e-9)
    assert math.isclose(four.cost[0] / three.cost[0], PARAMS.rho ** (1 / 3), rel_tol=1e-9)
    np.testing.assert_array_equal(four.pairs[0], np.eye(3, 4, dtype=bool))
    assert math.isclose(four.scale[0], 1 / 1000, rel_tol=1e-12)


def test_one_extra_top_person_is_left_unmatched():
    hor = np.array([[-0.8, 0.01], [-0.2, 0.004], [0.3, 0.002]])
    top = np.array([[-0.79, 10.0], [-0.19, 4.0], [0.31, 2.0], [0.95, 3.0]])
    res = _match(top, hor)
    np.testing.assert_array_equal(res.pairs[0], np.eye(4, 3, dtype=bool))
    assert math.isclose(res.cost[0], PARAMS.rho ** (4 / 3) * PARAMS.lam * 0.03 / 3, rel_tol=1e-9)


def test_no_vectors_cost_infinite():
    hor = np.array([[0.0, 0.01]])
    no_top = np.array([0, 0])
    res = match_vector_sets(np.full((2, 3), np.inf), np.zeros((2, 3)), no_top, hor, PARAMS)
    assert np.isinf(res.cost).all() and not res.pairs.any()
    no_hor = np.zeros((0, 2))
    res = match_vector_sets(np.zeros((1, 2)), np.ones((1, 2)), np.array([2]), no_hor, PARAMS)
    assert np.isinf(res.cost).all()
    res = match_vector_sets(np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, int), hor, PARAMS)
    assert res.cost.shape == (0,)


@st.composite
def _top_batches(draw, max_rows: int = 6):
    """(top_x (B, K) ascending with +inf padding, top_y, count, hor (Q, 2) ascending)."""
    n_batch = draw(st.integers(1, 4))
    width = draw(st.integers(1, max_rows))
    xs = st.floats(-0.999, 0.999, allow_subnormal=False)
    rows_x, rows_y, counts = [], [], []
    for _ in range(n_batch):
        n = draw(st.integers(0, width))
        x = sorted(draw(st.lists(xs, min_size=n, max_size=n)))
        y = draw(st.lists(st.floats(1.0, 1500.0), min_size=n, max_size=n))
        rows_x.append(x + [math.inf] * (width - n))
        rows_y.append(y + [0.0] * (width - n))
        counts.append(n)
    q = draw(st.integers(1, 6))
    hx = sorted(draw(st.lists(xs, min_size=q, max_size=q)))
    hy = draw(st.lists(st.floats(1e-3, 0.05), min_size=q, max_size=q))
    return (
        np.array(rows_x, dtype=float),
        np.array(rows_y, dtype=float),
        np.array(counts),
        np.column_stack([hx, hy]),
    )


@pytest.mark.slow
@settings(max_examples=100, deadline=None)
@given(batch=_top_batches())
def test_match_is_independent_per_batch_row(batch):
    top_x, top_y, count, hor = batch
    res = match_vector_sets(top_x, top_y, count, hor, PARAMS)
    for b in range(top_x.shape[0]):
        n = int(count[b])
        row = slice(b, b + 1)
        one = match_vector_sets(top_x[row, :n], top_y[row, :n], count[row], hor, PARAMS)
        assert math.isclose(res.cost[b], one.cost[0], rel_tol=1e-12) or (
            np.isinf(res.cost[b]) and np.isinf(one.cost[0])
        )
        np.testing.assert_array_equal(res.pairs[b, :n], one.pairs[0])
        assert not res.pairs[b, n:].any()
        # Kept pairs are one-to-one and Phi is Eq. 12 over them.
        kept = res.pairs[b]
        assert (kept.sum(axis=0) <= 1).all() and (kept.sum(axis=1) <= 1).all()
        kappa = int(kept.sum())
        if kappa and np.isfinite(res.cost[b]):
            i, j = np.nonzero(kept)
            d = PARAMS.lam * np.abs(top_x[b, i] - hor[j, 0]) + np.abs(
                res.scale[b] * top_y[b, i] - hor[j, 1]
            )
            coef = PARAMS.rho ** (max(n, len(hor)) / kappa) / kappa
            # D is recomputed with scale * y instead of y / mean ratio: rounding, times coef.
            assert math.isclose(res.cost[b], coef * d.sum(), rel_tol=1e-9, abs_tol=coef * 1e-12)


def _both(run):
    """``run()`` with the compiled kernels and with the numpy forms."""
    with kernel_choice.forced("compiled"):
        compiled = run()
    with kernel_choice.forced("numpy"):
        reference = run()
    return compiled, reference


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(batch=_top_batches(max_rows=20), threshold=st.sampled_from([math.inf, 0.05, 0.3]),
       ties=st.booleans())
def test_compiled_match_is_bit_identical_to_the_numpy_definition(batch, threshold, ties):
    # The search runs the compiled kernel; it must be the numpy definition exactly (the same
    # DTW tie order and the same summation order), so that the figures do not move. Up to 20
    # top rows against 6 columns covers NumPy's pairwise-summation blocks of 8 and 128.
    top_x, top_y, count, hor = batch
    if ties:  # coarse values: many equal DTW costs
        top_x = np.where(np.isfinite(top_x), np.round(top_x, 1), top_x)
        hor = np.column_stack([np.round(hor[:, 0], 1), hor[:, 1]])
    params = SpatialParams(scale_threshold=threshold)
    res, ref = _both(lambda: match_vector_sets(top_x, top_y, count, hor, params))
    np.testing.assert_array_equal(res.cost, ref.cost)
    np.testing.assert_array_equal(res.pairs, ref.pairs)
    np.testing.assert_array_equal(res.scale, ref.scale)
    for tight in (True, False):
        bound, ref_bound = _both(
            lambda t=tight: cost_lower_bound(top_x, count, hor[:, 0], params, t))
        np.testing.assert_array_equal(bound, ref_bound)


def test_compiled_match_is_bit_identical_on_large_sets():
    # 40 x 30 cells: the pairwise sum recurses past one 128-element block.
    rng = np.random.default_rng(3)
    n_batch, n_rows, n_cols = 50, 40, 30
    count = rng.integers(0, n_rows + 1, n_batch)
    top_x = np.sort(rng.uniform(-1, 1, (n_batch, n_rows)), axis=1)
    top_y = rng.uniform(1, 1500, (n_batch, n_rows))
    valid = np.arange(n_rows)[None, :] < count[:, None]
    top_x, top_y = np.where(valid, top_x, np.inf), np.where(valid, top_y, 0.0)
    hor = np.column_stack([np.sort(rng.uniform(-1, 1, n_cols)), rng.uniform(1e-3, 0.05, n_cols)])
    res, ref = _both(lambda: match_vector_sets(top_x, top_y, count, hor, PARAMS))
    np.testing.assert_array_equal(res.cost, ref.cost)
    np.testing.assert_array_equal(res.pairs, ref.pairs)
    np.testing.assert_array_equal(res.scale, ref.scale)
    assert np.isfinite(ref.cost).sum() > 40


# --------------------------------------------------------------------------------------------
# cost_lower_bound: an exact lower bound of Phi (branch-and-bound pruning must stay exact)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    batch=_top_batches(),
    data=st.data(),
    rho=st.floats(1.01, 30.0),
    lam=st.floats(1e-4, 10.0),
    tight=st.booleans(),
)
def test_cost_lower_bound_never_exceeds_phi(batch, data, rho, lam, tight):
    top_x, top_y, count, hor = batch
    params = SpatialParams(rho=rho, lam=lam)
    true = match_vector_sets(top_x, top_y, count, hor, params).cost
    # The bound takes x in any order (the unsorted hypotheses): shuffle each row.
    shuffled = np.array([data.draw(st.permutations(list(row))) for row in top_x], dtype=float)
    bound = cost_lower_bound(shuffled, count, hor[:, 0], params, tight=tight)
    assert bound.shape == true.shape
    assert (bound >= 0).all()
    finite = np.isfinite(true)
    # (1e-300: products of tiny gaps underflow differently in Phi and in the bound.)
    assert (bound[finite] <= true[finite] * (1 + 1e-12) + 1e-300).all(), (bound, true)
    # No vector in the field of view: nothing to match, bound +inf.
    assert np.isinf(bound[count == 0]).all()


@settings(max_examples=100, deadline=None)
@given(batch=_top_batches())
def test_tight_bound_is_at_least_the_loose_one(batch):
    # Both are valid; the sorted partial-sum bound is never weaker (it is worth its sorting).
    top_x, _, count, hor = batch
    tight = cost_lower_bound(top_x, count, hor[:, 0], PARAMS, tight=True)
    loose = cost_lower_bound(top_x, count, hor[:, 0], PARAMS, tight=False)
    finite = np.isfinite(loose)
    assert (tight[finite] >= loose[finite] * (1 - 1e-12)).all()


def test_cost_lower_bound_is_tight_when_the_x_match_is_exact_and_y_agrees():
    # Pairs off by 0.01 in x, y exact: the bound lambda * rho^(L/kappa) / kappa * sum e_i with
    # kappa = 3 equals Phi, and no other kappa gives less here.
    hor = np.array([[-0.8, 0.01], [-0.2, 0.004], [0.3, 0.002]])
    top = np.array([[-0.79, 10.0], [-0.19, 4.0], [0.31, 2.0]])
    phi = _match(top, hor).cost[0]
    bound = cost_lower_bound(top[None, :, 0], np.array([3]), hor[:, 0], PARAMS)[0]
    assert bound <= phi
    assert math.isclose(bound, phi, rel_tol=1e-9)


@pytest.mark.parametrize("tight", [True, False])
def test_cost_lower_bound_empty_cases(tight):
    hor_x = np.array([-0.5, 0.5])
    absent = np.full((3, 4), np.inf)
    assert np.isinf(cost_lower_bound(absent, np.zeros(3, int), hor_x, PARAMS, tight=tight)).all()
    no_hor = cost_lower_bound(np.zeros((2, 1)), np.ones(2, int), np.zeros(0), PARAMS, tight=tight)
    assert np.isinf(no_hor).all()
    empty = cost_lower_bound(np.zeros((0, 3)), np.zeros(0, int), hor_x, PARAMS, tight=tight)
    assert empty.shape == (0,)


# --------------------------------------------------------------------------------------------
# SpatialParams validation


@pytest.mark.parametrize(
    ("name", "bad"),
    [
        ("rho", 1.0),
        ("rho", 0.5),
        ("rho", math.nan),
        ("lam", 0.0),
        ("lam", -1.0),
        ("tau_deg", -0.5),
        ("dtheta_deg", 0.0),
        ("dtheta_deg", 361.0),
        ("fov_deg", 0.0),
        ("fov_deg", 180.0),
        ("scale_threshold", 0.0),
        ("damping_r", 0.0),
        ("damping_r", 1.5),
        ("damping_u", 0.0),
        ("damping_u", math.nan),
    ],
)
def test_spatial_params_reject_bad_values(name, bad):
    with pytest.raises(ValueError, match=re.escape(f"{name}={bad!r}")) as info:
        SpatialParams(**{name: bad})
    # Only the offending parameter is reported as a value.
    others = [f for f in ("rho", "lam", "tau_deg", "fov_deg", "damping_u") if f != name]
    assert not any(f"{f}=" in str(info.value) for f in others)


def test_spatial_params_report_every_bad_value():
    with pytest.raises(ValueError, match=r"rho=0\.5.*fov_deg=200\.0"):
        SpatialParams(rho=0.5, fov_deg=200.0)


def test_spatial_params_defaults_are_the_papers():
    p = SpatialParams()
    assert (p.rho, p.lam, p.tau_deg, p.dtheta_deg, p.fov_deg) == (15.0, 0.003, 2.0, 1.0, 90.0)
    assert (p.damping_r, p.damping_u) == (0.95, 0.1)
    SpatialParams(tau_deg=0.0, dtheta_deg=360.0, damping_r=1.0)  # boundary values are valid
