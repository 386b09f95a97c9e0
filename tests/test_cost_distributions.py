"""Tests of the true/false cost distributions (Figs. 2-3 of the geometric-priors paper)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from xvmatch.evaluation.cost_distributions import (
    FIGURE_FILES,
    CostSamples,
    cost_figures,
    cost_histogram,
    draw_cost_histograms,
    encode_png,
    save_cost_figures,
)


def _samples(seed: int = 0) -> CostSamples:
    rng = np.random.default_rng(seed)
    return CostSamples(
        geo_true=np.abs(rng.normal(0.0, 0.05, 40)),
        geo_false=rng.exponential(1.5, 300),
        hist_true=rng.uniform(0.0, 1.2, 40),
        hist_false=rng.uniform(0.4, 2.0, 300),
    )


def test_histogram_counts_hand_made() -> None:
    true = [0.1, 0.2, 0.95, 1.0]
    false = [0.5, 0.49, 1.5, -0.2]
    h = cost_histogram(true, false, bins=2, value_range=(0.0, 1.0), title="t", x_label="x")
    np.testing.assert_allclose(h.edges, [0.0, 0.5, 1.0])
    # 1.0 sits on the closed right edge of the last bin; 1.5 is clipped into it (overflow);
    # -0.2 is clipped into the first bin.
    assert h.true_counts.tolist() == [2, 2] and h.false_counts.tolist() == [2, 2]
    assert (h.true_overflow, h.false_overflow) == (0, 1)
    assert (h.n_true, h.n_false) == (4, 4)
    t, f = h.fractions()
    np.testing.assert_allclose(t, [0.5, 0.5])
    np.testing.assert_allclose(f, [0.5, 0.5])


def test_histogram_default_range_is_a_round_percentile() -> None:
    values = np.linspace(0.0, 3.7, 101)
    h = cost_histogram(values[:10], values[10:], bins=10, percentile=100.0)
    assert h.edges[0] == 0.0 and h.edges[-1] == 5.0  # 3.7 rounded up to 5
    assert h.n_true + h.n_false == 101 and h.true_overflow + h.false_overflow == 0
    h = cost_histogram([], [], bins=4)  # no sample at all: a unit range, zero counts
    assert h.edges[-1] == 1.0 and h.n_true == h.n_false == 0
    t, f = h.fractions()
    assert not np.isnan(t).any() and not t.any() and not f.any()


def test_histogram_counts_every_sample_once() -> None:
    s = _samples(1)
    h = cost_histogram(s.geo_true, s.geo_false, bins=25, percentile=90.0)
    assert h.n_true == 40 and h.n_false == 300
    assert h.false_overflow == int((s.geo_false > h.edges[-1]).sum()) > 0
    t, f = h.fractions()
    assert t.sum() == pytest.approx(1.0) and f.sum() == pytest.approx(1.0)


def test_histogram_bad_inputs() -> None:
    with pytest.raises(ValueError, match="true_costs contains NaN"):
        cost_histogram([np.nan], [0.1])
    with pytest.raises(ValueError, match="false_costs contains NaN or inf"):
        cost_histogram([0.1], [np.inf])
    with pytest.raises(ValueError, match="bins must be >= 1"):
        cost_histogram([0.1], [0.2], bins=0)
    with pytest.raises(ValueError, match="low < high"):
        cost_histogram([0.1], [0.2], value_range=(1.0, 1.0))
    with pytest.raises(ValueError, match="percentile"):
        cost_histogram([0.1], [0.2], percentile=0.0)


def test_samples_from_matrices_hand_made() -> None:
    geo = np.array([[0.1, 2.0], [3.0, 0.2]])
    hist = np.array([[0.5, 1.5], [1.2, 0.7]])
    same = np.array([[True, False], [False, True]])
    valid = np.array([[True, True], [False, False]])  # row 1 has an empty crop
    s = CostSamples.from_matrices(geo, hist, same, valid)
    assert s.geo_true.tolist() == [0.1, 0.2] and sorted(s.geo_false.tolist()) == [2.0, 3.0]
    assert s.hist_true.tolist() == [0.5] and s.hist_false.tolist() == [1.5]
    both = CostSamples.concatenate([s, s])
    assert both.geo_true.tolist() == [0.1, 0.2, 0.1, 0.2]
    assert CostSamples.concatenate([]).geo_true.shape == (0,)
    with pytest.raises(ValueError, match="one shape"):
        CostSamples.from_matrices(geo, hist[:1], same)
    with pytest.raises(ValueError, match="NaN"):
        CostSamples(np.array([np.nan]), np.zeros(1), np.zeros(1), np.zeros(1))
    with pytest.raises(ValueError, match="negative"):
        CostSamples(np.array([-1.0]), np.zeros(1), np.zeros(1), np.zeros(1))


def test_drawing_sizes_colours_and_empty_panels() -> None:
    s = _samples()
    h = cost_histogram(s.hist_true, s.hist_false, bins=20, title="(a)", x_label="d_hist")
    empty = cost_histogram([], [], bins=5, title="(b) empty", x_label="none")
    image = draw_cost_histograms([h, empty], title="test", panel_size=(400, 300))
    assert image.shape == (330, 800, 3) and image.dtype == np.uint8
    left = image[30:, :400].reshape(-1, 3).astype(int)
    # Translucent green (true) and red (false) bars are drawn in the left panel.
    greenish = (left[:, 1] > left[:, 2] + 40) & (left[:, 1] > left[:, 0] + 40)
    reddish = (left[:, 2] > left[:, 1] + 60) & (left[:, 2] > left[:, 0] + 60)
    assert greenish.sum() > 500 and reddish.sum() > 500
    with pytest.raises(ValueError, match="at least one histogram"):
        draw_cost_histograms([])
    with pytest.raises(ValueError, match="panel_size"):
        draw_cost_histograms([h], panel_size=(100, 100))


def test_figures_are_written_atomically(tmp_path: Path) -> None:
    images = cost_figures(_samples(), bins=20)
    assert set(images) == set(FIGURE_FILES)
    paths = save_cost_figures(_samples(), tmp_path / "figs", bins=20)
    assert [p.name for p in paths] == [FIGURE_FILES["before"], FIGURE_FILES["after"]]
    for key, path in zip(("before", "after"), paths, strict=True):
        read = cv2.imread(str(path), cv2.IMREAD_COLOR)
        assert read is not None and read.shape == images[key].shape == (370, 1040, 3)
        np.testing.assert_array_equal(read, images[key])  # PNG is lossless
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == sorted(FIGURE_FILES.values())
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(ValueError, match="not a directory"):
        save_cost_figures(_samples(), blocker)
    with pytest.raises(ValueError, match=r"\(H, W, 3\) uint8"):
        encode_png(np.zeros((4, 4), np.uint8))
