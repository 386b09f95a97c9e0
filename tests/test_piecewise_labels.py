"""The Viterbi under the video consensus (xvmatch.inference.linking.piecewise_labels)."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.inference.linking.piecewise_labels import cheapest_path


def _path_by_numpy(cost: np.ndarray, switch_cost: float) -> np.ndarray:
    """The definition, one numpy step per frame (as it was written before the Python-float
    form): the lowest state at each step (the first on ties), the others staying where that is
    no worse than switching to it."""
    n, states = cost.shape
    cols = np.arange(states)
    back = np.zeros((n, states), dtype=np.int64)
    total = cost[0].copy()
    for k in range(1, n):
        best = int(np.argmin(total))
        stay = total <= total[best] + switch_cost
        back[k] = np.where(stay, cols, best)
        total = np.where(stay, total, total[best] + switch_cost) + cost[k]
    path = np.zeros(n, dtype=np.int64)
    path[-1] = int(np.argmin(total))
    for k in range(n - 1, 0, -1):
        path[k - 1] = back[k, path[k]]
    return path


def _total(cost: np.ndarray, path, switch_cost: float) -> float:
    switches = sum(a != b for a, b in itertools.pairwise(path))
    return float(cost[np.arange(len(path)), list(path)].sum() + switch_cost * switches)


_costs = st.integers(1, 7).flatmap(lambda n: st.integers(1, 4).flatmap(
    lambda s: st.lists(st.sampled_from([0.0, 0.5, 1.0, 0.1, 2.0, 1e-17, np.inf]) |
                       st.floats(0.0, 3.0), min_size=n * s, max_size=n * s).map(
        lambda v: np.array(v).reshape(n, s))))


@settings(max_examples=200, deadline=None)
@given(cost=_costs, switch_cost=st.sampled_from([0.0, 0.5, 1.0, 2.5]) | st.floats(0.0, 4.0))
def test_the_path_is_the_numpy_definitions_and_the_cheapest(cost, switch_cost):
    path = cheapest_path(cost, switch_cost)
    np.testing.assert_array_equal(path, _path_by_numpy(cost, switch_cost))
    if np.isfinite(cost).all():  # every sequence of states, by brute force
        best = min(_total(cost, p, switch_cost)
                   for p in itertools.product(range(cost.shape[1]), repeat=cost.shape[0]))
        assert _total(cost, path, switch_cost) <= best + 1e-9


def test_a_nan_cost_is_refused():
    with pytest.raises(ValueError, match="NaN"):
        cheapest_path(np.array([[0.0, np.nan]]), 1.0)
