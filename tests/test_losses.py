"""Training losses: zero exactly where they must be, positive elsewhere, masks respected."""

from __future__ import annotations

import math

import pytest
import torch

from xvmatch.models.geometry_encoder import GeometryOutput
from xvmatch.models.losses import (
    AssignmentNLLLoss,
    ContrastiveLoss,
    GeometryMatchingLoss,
    HypothesisLoss,
    assignment_targets,
    hard_negative_mask,
)

MATCH = torch.tensor([[[True, False, False], [False, False, True]]])  # (1, 2, 3)
ALL = torch.ones(1, 2, 3, dtype=torch.bool)


@pytest.fixture(autouse=True)
def _one_torch_thread():
    """One intra-op thread: tiny tensors gain nothing from more, and on a busy 2-core machine
    more threads spin against each other (a 1 s training run took over a minute)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def test_contrastive_zero_for_perfect_distances():
    d = torch.where(MATCH, 0.0, 0.7)
    assert ContrastiveLoss(margin=0.5)(d, MATCH, ALL) == 0.0
    assert ContrastiveLoss(margin=0.5, hard_negatives=0)(d, MATCH, ALL) == 0.0


def test_contrastive_values():
    d = torch.tensor([[[0.2, 0.1, 0.9], [0.6, 0.3, 0.0]]])
    loss = ContrastiveLoss(margin=0.5, hard_negatives=0)(d, MATCH, ALL)
    pos = (0.2**2 + 0.0**2) / 2
    neg = ((0.5 - 0.1) ** 2 + 0 + 0 + (0.5 - 0.3) ** 2) / 4  # negatives 0.1, 0.9, 0.6, 0.3
    assert math.isclose(float(loss), pos + neg, rel_tol=1e-6)
    assert loss > 0


def test_contrastive_ignores_masked_pairs_and_empty_batches():
    d = torch.tensor([[[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]])
    mask = torch.tensor([[[True, False, False], [False, False, False]]])
    assert ContrastiveLoss()(d, MATCH, mask) == 0.0  # only the positive (0, 0) is valid
    empty = torch.zeros(2, 0, 3)
    assert ContrastiveLoss()(empty, empty.bool(), empty.bool()) == 0.0


def test_hard_negatives_are_the_closest_per_row_and_column():
    d = torch.tensor([[[0.0, 0.1, 0.9, 0.8], [0.5, 0.6, 0.2, 0.95]]])
    match = torch.tensor([[[True, False, False, False], [False, False, True, False]]])
    hard = hard_negative_mask(d, ~match, k=1)
    # Row 0: 0.1; row 1: 0.5; column 0: 0.5; column 1: 0.1; column 2: 0.9; column 3: 0.8.
    expected = torch.tensor([[[False, True, True, True], [True, False, False, False]]])
    assert torch.equal(hard, expected)
    assert torch.equal(hard_negative_mask(d, ~match, k=0), ~match)


def _log_assignment_for(targets: torch.Tensor, sure: float) -> torch.Tensor:
    """log P with probability `sure` on each target row's entry, the rest spread evenly."""
    n_cols = targets.shape[-1]
    prob = torch.where(targets, sure, (1 - sure) / (n_cols - 1))
    return prob.log()


def test_assignment_nll_zero_for_the_true_assignment():
    top_mask = torch.ones(1, 2, dtype=torch.bool)
    hor_mask = torch.ones(1, 3, dtype=torch.bool)
    targets = assignment_targets(MATCH, top_mask, hor_mask)
    expected = torch.tensor(
        [[[True, False, False, False], [False, False, True, False], [False, True, False, False]]]
    )
    assert torch.equal(targets, expected)  # hor 1 is unmatched: dustbin row
    exact = torch.where(targets, 0.0, -50.0)
    assert AssignmentNLLLoss()(exact, MATCH, top_mask, hor_mask) == 0.0
    unsure = _log_assignment_for(targets, 0.6)
    loss = AssignmentNLLLoss()(unsure, MATCH, top_mask, hor_mask)
    assert math.isclose(float(loss), -math.log(0.6), rel_tol=1e-6)


def test_hypothesis_loss():
    logits = torch.tensor([[5.0, 0.0, -1e4], [0.0, 0.0, 0.0]])
    mask = torch.tensor([[True, True, False], [True, True, True]])
    correct = torch.tensor([[True, False, False], [False, False, False]])
    loss = HypothesisLoss()(logits, correct, mask)
    # Only frame 0 is labelled: -log softmax(5, 0)[0].
    assert math.isclose(float(loss), math.log1p(math.exp(-5.0)), rel_tol=1e-5)
    assert HypothesisLoss()(logits, torch.zeros_like(correct), mask) == 0.0
    both = torch.tensor([[True, True, False], [False, False, False]])
    assert HypothesisLoss()(logits, both, mask) < 1e-6  # every valid hypothesis is right


def test_combined_loss_terms_and_validation():
    b, m, n, h, d = 2, 2, 3, 2, 4
    top_mask = torch.tensor([[True, True], [True, False]])
    hor_mask = torch.tensor([[True, True, True], [False, False, False]])  # frame 1: N = 0
    match = torch.zeros(b, m, n, dtype=torch.bool)
    match[0] = MATCH[0]
    targets = assignment_targets(match, top_mask, hor_mask)
    desc = torch.nn.functional.normalize(torch.randn(b, m, d), dim=-1)
    hor_desc = desc[:, [0, 1, 1]].clone()
    output = GeometryOutput(
        cost=torch.where(match, 0.0, 1.0),
        log_assignment=torch.where(targets, 0.0, -50.0),
        hypothesis_logits=torch.tensor([[9.0, -9.0], [0.0, 0.0]]),
        top_descriptors=desc,
        hor_descriptors=hor_desc,
    )
    loss = GeometryMatchingLoss(embedding_weight=0.0, hard_negatives=0)
    terms = loss(output, match, torch.tensor([[True, False], [False, False]]),
                 top_mask, hor_mask, torch.ones(b, h, dtype=torch.bool))
    assert set(terms) == {"nll", "cost", "embedding", "hypothesis", "total"}
    assert terms["nll"] == 0.0 and terms["cost"] == 0.0
    assert 0.0 <= terms["hypothesis"] < 1e-6
    assert all(torch.isfinite(v) for v in terms.values())
    with pytest.raises(ValueError, match="weights must be >= 0"):
        GeometryMatchingLoss(nll_weight=-1.0)
    with pytest.raises(ValueError, match="margin"):
        ContrastiveLoss(margin=0.0)
