"""Tests of xvmatch.inference.linking.assignment (Eqs. 1-2 of the geometric-priors paper)."""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.inference.linking.assignment import (
    assign,
    assignment_is_stable,
    assignment_matrix,
    augmented_cost_matrix,
)


def _brute_force_objective(cost: np.ndarray, gamma: float) -> float:
    """min over one-to-at-most-one matchings of sum_{matched} (c_ij - gamma), by enumeration.

    Over the augmented matrix of Eq. 2 a matching with K pairs costs sum c + gamma (M + N - K),
    so minimising it is minimising sum (c_ij - gamma); forbidden (inf) pairs are skipped.
    """
    m, n = cost.shape

    def best(row: int, used: frozenset[int]) -> float:
        if row == m:
            return 0.0
        value = best(row + 1, used)  # row left unassociated
        for col in range(n):
            if col not in used and math.isfinite(cost[row, col]):
                value = min(value, cost[row, col] - gamma + best(row + 1, used | {col}))
        return value

    return best(0, frozenset())


def test_hand_computed() -> None:
    cost = np.array([[0.1, 0.9], [0.8, 0.7]])
    # gamma 0.5: only (0, 0) is below gamma. gamma 1.0: (0,0)+(1,1) = 0.8 beats (0,1)+(1,0) = 1.7.
    assert assign(cost, gamma=0.5).tolist() == [[0, 0]]
    assert assign(cost, gamma=1.0).tolist() == [[0, 0], [1, 1]]
    # gamma 0.85: (0,0)+(1,1) gains (0.1-0.85)+(0.7-0.85) = -0.9 < -0.75 for (0,0) alone.
    assert assign(cost, gamma=0.85).tolist() == [[0, 0], [1, 1]]


def test_augmented_matrix_is_eq_2() -> None:
    cost = np.array([[1.0, 2.0, 3.0]])
    a = augmented_cost_matrix(cost, gamma=0.5)
    assert a.shape == (4, 4)
    np.testing.assert_array_equal(a[0, :3], [1.0, 2.0, 3.0])
    mask = np.ones((4, 4), dtype=bool)
    mask[0, :3] = False
    np.testing.assert_array_equal(a[mask], 0.5)


def test_global_optimum_not_greedy() -> None:
    # Greedy takes (0, 0) = 0.1 first, then (1, 1) = 0.9: total 1.0. Optimal: 0.2 + 0.3 = 0.5.
    cost = np.array([[0.1, 0.2], [0.3, 0.9]])
    assert assign(cost, gamma=1.0).tolist() == [[0, 1], [1, 0]]


@pytest.mark.parametrize("shape", [(0, 0), (0, 3), (3, 0)])
def test_empty_sides(shape: tuple[int, int]) -> None:
    pairs = assign(np.zeros(shape), gamma=1.0)
    assert pairs.shape == (0, 2) and pairs.dtype == np.int64


def test_all_rejected_and_ties() -> None:
    cost = np.array([[0.5, 0.7], [0.9, 0.5], [0.6, 0.8]])
    assert assign(cost, gamma=0.5).shape == (0, 2)  # every cost >= gamma; ties are rejected
    assert assign(cost, gamma=0.1).shape == (0, 2)
    assert assign(np.full((2, 2), np.inf), gamma=1.0).shape == (0, 2)


def test_inf_marks_forbidden_pairs() -> None:
    cost = np.array([[np.inf, 0.1], [0.2, np.inf]])
    assert assign(cost, gamma=1.0).tolist() == [[0, 1], [1, 0]]
    cost = np.array([[0.1, np.inf], [np.inf, np.inf]])
    assert assign(cost, gamma=1.0).tolist() == [[0, 0]]


def test_rectangular() -> None:
    cost = np.array([[0.9, 0.4, 0.1, 0.8, 0.3]])
    assert assign(cost, gamma=0.5).tolist() == [[0, 2]]
    assert assign(cost.T, gamma=0.5).tolist() == [[2, 0]]


def test_bad_inputs() -> None:
    with pytest.raises(ValueError, match="NaN at 1 entries"):
        assign(np.array([[0.1, np.nan]]), gamma=0.5)
    with pytest.raises(ValueError, match="-inf"):
        assign(np.array([[-np.inf]]), gamma=0.5)
    with pytest.raises(ValueError, match=r"\(M, N\)"):
        assign(np.zeros(3), gamma=0.5)
    with pytest.raises(ValueError, match="gamma"):
        assign(np.zeros((2, 2)), gamma=math.inf)
    with pytest.raises(ValueError, match="gamma"):
        assign(np.zeros((2, 2)), gamma=math.nan)


def test_assignment_matrix() -> None:
    x = assignment_matrix(np.array([[0, 1], [2, 0]]), 3, 2)
    np.testing.assert_array_equal(x, [[False, True], [False, False], [True, False]])
    assert assignment_matrix(np.zeros((0, 2), np.int64), 2, 2).sum() == 0
    with pytest.raises(ValueError, match="out of range"):
        assignment_matrix(np.array([[0, 2]]), 2, 2)
    with pytest.raises(ValueError, match="at most one"):
        assignment_matrix(np.array([[0, 1], [1, 1]]), 2, 2)


@pytest.mark.slow
def test_no_torch_or_cv2_import() -> None:
    code = (
        "import sys, xvmatch.inference.linking.assignment; "
        "sys.exit(int('torch' in sys.modules or 'cv2' in sys.modules))"
    )
    assert subprocess.run([sys.executable, "-c", code], check=False).returncode == 0


_cost_entry = st.one_of(
    st.floats(0.0, 1.0, allow_nan=False), st.just(math.inf), st.sampled_from([0.25, 0.5])
)


@pytest.mark.slow
@settings(max_examples=300, deadline=None)
@given(
    m=st.integers(0, 4),
    n=st.integers(0, 4),
    data=st.data(),
    gamma=st.one_of(st.floats(-0.5, 1.5, allow_nan=False), st.sampled_from([-1.0, 0.25, 0.5, 2.0])),
)
def test_matches_brute_force(m: int, n: int, data: st.DataObject, gamma: float) -> None:
    """Optimal objective of Eq. 1 + Eq. 2, valid one-to-at-most-one pairs, all below gamma."""
    entries = data.draw(st.lists(_cost_entry, min_size=m * n, max_size=m * n))
    cost = np.array(entries, dtype=float).reshape(m, n)
    pairs = assign(cost, gamma)
    assert pairs.ndim == 2 and pairs.shape[1] == 2 and pairs.dtype == np.int64
    assert (np.diff(pairs[:, 0]) > 0).all()  # sorted by row, each row once
    assert len(set(pairs[:, 1].tolist())) == len(pairs)  # each column once
    chosen = cost[pairs[:, 0], pairs[:, 1]]
    assert (chosen < gamma).all()  # also excludes inf pairs
    expected = _brute_force_objective(cost, gamma)
    assert float(np.sum(chosen - gamma)) == pytest.approx(expected, abs=1e-9)
    finite = cost[np.isfinite(cost)]
    if finite.size == 0 or gamma <= finite.min():
        assert len(pairs) == 0


def _objective(cost: np.ndarray, gamma: float, pairs: np.ndarray) -> float:
    """Eq. 1 + Eq. 2 objective, up to a constant: sum over the pairs of (c_ij - gamma)."""
    return float(np.sum(cost[pairs[:, 0], pairs[:, 1]] - gamma)) if len(pairs) else 0.0


@pytest.mark.slow
@settings(max_examples=200, deadline=None)
@given(m=st.integers(1, 4), n=st.integers(1, 4), data=st.data(),
       tolerance=st.floats(0.0, 0.3, allow_nan=False), seed=st.integers(0, 2**31 - 1))
def test_a_stable_assignment_survives_every_move_within_the_tolerance(
        m: int, n: int, data: st.DataObject, tolerance: float, seed: int) -> None:
    """Stable: the pairs stay optimal for costs moved anywhere within the tolerance. Not
    stable: a cost matrix within it has a strictly better other assignment."""
    entries = data.draw(st.lists(_cost_entry, min_size=m * n, max_size=m * n))
    cost = np.array(entries, dtype=float).reshape(m, n)
    gamma = 0.5
    pairs = assign(cost, gamma)
    rng = np.random.default_rng(seed)
    if assignment_is_stable(cost, gamma, tolerance):
        for _ in range(5):
            moved = cost + rng.uniform(-tolerance, tolerance, cost.shape)
            other = assign(moved, gamma)
            assert _objective(moved, gamma, pairs) <= _objective(moved, gamma, other) + 1e-9
        assert assignment_is_stable(cost, gamma, tolerance / 2)  # a smaller one is too
    else:
        worst = cost - tolerance
        if len(pairs):
            worst[pairs[:, 0], pairs[:, 1]] += 2 * tolerance
        better = assign(worst, gamma)
        assert _objective(worst, gamma, better) < _objective(worst, gamma, pairs) - 1e-12
        assert not assignment_is_stable(cost, gamma, tolerance * 2)  # nor a larger one


def test_near_ties_are_not_stable() -> None:
    cost = np.array([[0.10, 0.11], [0.11, 0.10]])
    assert assignment_is_stable(cost, 0.5, 0.004)  # 0.2 against 0.22: moves of 0.005 tie
    assert not assignment_is_stable(cost, 0.5, 0.006)
    assert assignment_is_stable(np.zeros((0, 3)), 0.5, 1.0)
    # A pair just below gamma is unstable once the tolerance can lift it to gamma.
    assert not assignment_is_stable(np.array([[0.48]]), 0.5, 0.03)
    assert assignment_is_stable(np.array([[0.48]]), 0.5, 0.01)
    for bad in (-0.1, math.nan, math.inf):
        with pytest.raises(ValueError, match="tolerance"):
            assignment_is_stable(cost, 0.5, bad)
