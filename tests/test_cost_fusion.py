"""Tests of xvmatch.cues.cost_fusion (Section III-C normalisation, sum rule, Eq. 8)."""

from __future__ import annotations

import math
from collections.abc import Mapping

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from xvmatch.cues.cost_fusion import (
    CostFusion,
    ProductFusion,
    SumFusion,
    add_cheirality,
    normalise_cosine_similarity,
    normalise_distance,
)
from xvmatch.inference.linking.assignment import assign


def test_normalise_distance_hand_computed() -> None:
    d = normalise_distance(np.array([[0.0, 1.0, math.inf]]))
    # tanh(0) = 0, tanh(1) = (e^2 - 1)/(e^2 + 1) = 0.76159..., tanh(inf) = 1.
    np.testing.assert_allclose(d, [[0.0, (math.e**2 - 1) / (math.e**2 + 1), 1.0]])
    with pytest.raises(ValueError, match=">= 0"):
        normalise_distance(np.array([-0.1]))
    with pytest.raises(ValueError, match="NaN"):
        normalise_distance(np.array([np.nan]))


def test_normalise_cosine_similarity_hand_computed() -> None:
    # d'_nn = (1 - s) / 2: s = 1 -> 0, s = 0 -> 1/2, s = -1 -> 1, s = 0.5 -> 1/4.
    s = np.array([[1.0, 0.0, -1.0, 0.5, 1.0 + 1e-9]])
    np.testing.assert_allclose(normalise_cosine_similarity(s), [[0.0, 0.5, 1.0, 0.25, 0.0]])
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        normalise_cosine_similarity(np.array([1.1]))
    with pytest.raises(ValueError, match=r"\[-1, 1\]"):
        normalise_cosine_similarity(np.array([-np.inf]))


def test_sum_and_product_hand_computed() -> None:
    costs = {"geo": np.array([[0.2, 1.0]]), "app": np.array([[0.6, 0.0]])}
    # Paper weights 0.5/0.5: 0.5*0.2 + 0.5*0.6 = 0.4; 0.5*1 + 0.5*0 = 0.5.
    np.testing.assert_allclose(SumFusion({"geo": 0.5, "app": 0.5})(costs), [[0.4, 0.5]])
    # Weights 1 and 3 are divided by their sum 4: (0.2 + 3*0.6)/4 = 0.5; (1 + 0)/4 = 0.25.
    np.testing.assert_allclose(SumFusion({"geo": 1.0, "app": 3.0})(costs), [[0.5, 0.25]])
    # Eq. 8: 0.2 * 0.6 = 0.12; 1 * 0 = 0.
    np.testing.assert_allclose(ProductFusion(("geo", "app"))(costs), [[0.12, 0.0]])
    # One cue only ("geometry only" / "appearance only" rows of Table I); extra names ignored.
    np.testing.assert_allclose(SumFusion({"geo": 1.0})(costs), costs["geo"])
    np.testing.assert_allclose(ProductFusion(("app",))(costs), costs["app"])


def test_rules_share_one_interface() -> None:
    class MinFusion:
        """Stand-in for a learned head: any callable with the same signature."""

        def __call__(self, costs: Mapping[str, np.ndarray]) -> np.ndarray:
            return np.minimum(costs["geo"], costs["app"])

    rules: list[CostFusion] = [SumFusion({"geo": 1, "app": 1}), ProductFusion(("geo", "app"))]
    rules.append(MinFusion())
    costs = {"geo": np.full((2, 3), 0.5), "app": np.full((2, 3), 0.5)}
    for rule in rules:
        assert isinstance(rule, CostFusion)
        fused = rule(costs)
        assert fused.shape == (2, 3) and ((fused >= 0) & (fused <= 1)).all()


def test_cheirality_vetoes_pairs_under_both_rules() -> None:
    """beta is added after fusion: a product with d'_geo = 0 cannot cancel it."""
    costs = {"geo": np.array([[0.0, 0.3], [0.4, 0.0]]), "app": np.array([[0.1, 0.2], [0.3, 0.1]])}
    beta = 1e3
    cheir = np.array([[beta, 0.0], [0.0, 0.0]])  # pair (0, 0) has its point behind a camera
    # gamma as in Section IV-A: 0.25 for the sum rule, 0.1 for the product rule.
    rules = ((SumFusion({"geo": 0.5, "app": 0.5}), 0.25), (ProductFusion(("geo", "app")), 0.1))
    for rule, gamma in rules:
        fused = rule(costs)
        total = add_cheirality(fused, cheir)
        assert total[0, 0] == pytest.approx(fused[0, 0] + beta) and total[0, 0] >= beta
        np.testing.assert_array_equal(total.ravel()[1:], fused.ravel()[1:])
        assert [0, 0] not in assign(total, gamma).tolist()
        assert [0, 0] in assign(fused, gamma).tolist()


@pytest.mark.parametrize(
    ("costs", "match"),
    [
        ({"geo": np.zeros((2, 2))}, "lack app"),
        ({"geo": np.zeros((2, 2)), "app": np.zeros((2, 3))}, "shape"),
        ({"geo": np.zeros(2), "app": np.zeros(2)}, r"\(M, N\)"),
        ({"geo": np.full((1, 1), np.nan), "app": np.zeros((1, 1))}, "NaN"),
        ({"geo": np.full((1, 1), 1.5), "app": np.zeros((1, 1))}, r"normalised to \[0, 1\]"),
        ({"geo": np.full((1, 1), np.inf), "app": np.zeros((1, 1))}, r"normalised to \[0, 1\]"),
    ],
)
def test_bad_costs(costs: dict, match: str) -> None:
    for rule in (SumFusion({"geo": 1.0, "app": 1.0}), ProductFusion(("geo", "app"))):
        with pytest.raises(ValueError, match=match):
            rule(costs)


def test_bad_rules_and_cheirality() -> None:
    with pytest.raises(ValueError, match="at least one"):
        SumFusion({})
    with pytest.raises(ValueError, match=">= 0"):
        SumFusion({"geo": -1.0, "app": 2.0})
    with pytest.raises(ValueError, match="sum > 0"):
        SumFusion({"geo": 0.0})
    with pytest.raises(TypeError, match="tuple of names"):
        ProductFusion("geo")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="distinct"):
        ProductFusion(("geo", "geo"))
    with pytest.raises(ValueError, match="one shape"):
        add_cheirality(np.zeros((2, 2)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="NaN"):
        add_cheirality(np.zeros((1, 1)), np.full((1, 1), np.nan))
    with pytest.raises(ValueError, match="finite"):
        add_cheirality(np.zeros((1, 1)), np.full((1, 1), -1.0))


def test_empty_sides() -> None:
    costs = {"geo": np.zeros((0, 3)), "app": np.zeros((0, 3))}
    assert SumFusion({"geo": 1, "app": 1})(costs).shape == (0, 3)
    assert ProductFusion(("geo", "app"))(costs).shape == (0, 3)


_unit = st.floats(0.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(
    shape=st.tuples(st.integers(0, 4), st.integers(0, 4)),
    data=st.data(),
    w=st.tuples(st.floats(0.0, 10.0), st.floats(0.0, 10.0)).filter(lambda t: sum(t) > 0),
)
def test_fused_costs_stay_in_unit_interval(shape, data, w) -> None:
    geo = data.draw(arrays(float, shape, elements=_unit))
    app = data.draw(arrays(float, shape, elements=_unit))
    costs = {"geo": geo, "app": app}
    rules: list[CostFusion] = [SumFusion({"geo": w[0], "app": w[1]}), ProductFusion(("geo", "app"))]
    for fused in (rule(costs) for rule in rules):
        assert fused.shape == shape
        assert not np.isnan(fused).any() and ((fused >= 0) & (fused <= 1)).all()
