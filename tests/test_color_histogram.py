"""Tests of xvmatch.cues.color_histogram (Section IV-A histograms, Eq. 3 distance)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from xvmatch.cues.color_histogram import (
    N_BINS,
    box_histograms,
    chi2_brd_distance,
    histogram_intersection,
    hsv_bin_indices,
)

# BGR colours and their bins. OpenCV 8-bit HSV: H = hue_deg / 2, S, V in [0, 255];
# bin = (H * 8 // 180) * 4 + (S // 128) * 2 + (V // 128).
RED = (0, 0, 255)  # H 0, S 255, V 255 -> 0*4 + 2 + 1 = 3
BLUE = (255, 0, 0)  # H 120 -> 960 // 180 = 5 -> 5*4 + 3 = 23


def _red_blue_image() -> np.ndarray:
    """4 x 4 image: columns 0-1 red, columns 2-3 blue."""
    image = np.zeros((4, 4, 3), dtype=np.uint8)
    image[:, :2] = RED
    image[:, 2:] = BLUE
    return image


@pytest.mark.parametrize(
    ("bgr", "expected_bin"),
    [
        (RED, 3),
        (BLUE, 23),
        ((0, 255, 0), 11),  # green: H 60 -> 480 // 180 = 2 -> 2*4 + 3
        ((0, 255, 255), 7),  # yellow: H 30 -> 240 // 180 = 1 -> 1*4 + 3
        ((255, 255, 0), 19),  # cyan: H 90 -> 720 // 180 = 4 -> 4*4 + 3
        ((255, 0, 255), 27),  # magenta: H 150 -> 1200 // 180 = 6 -> 6*4 + 3
        ((0, 0, 0), 0),  # black: H 0, S 0, V 0
        ((64, 64, 64), 0),  # dark grey: S 0, V 64 < 128
        ((200, 200, 200), 1),  # light grey: S 0, V 200 >= 128
    ],
)
def test_bin_of_solid_colours(bgr: tuple[int, int, int], expected_bin: int) -> None:
    image = np.full((2, 3, 3), bgr, dtype=np.uint8)
    assert (hsv_bin_indices(image) == expected_bin).all()


def test_box_histograms_hand_computed() -> None:
    image = _red_blue_image()
    boxes = np.array(
        [
            [1, 0, 2, 4],  # column 1 red, column 2 blue: 4 + 4 pixels -> 1/sqrt(2) each
            [1.5, 0, 1.0, 2],  # floor(1.5)=1 .. ceil(2.5)-1=2, rows 0-1: 2 red + 2 blue
            [0, 0, 1, 4],  # red only -> one-hot at bin 3
            [-5, -5, 7, 9],  # clipped to columns 0-1, rows 0-3: red only
        ]
    )
    hist, valid = box_histograms(image, boxes)
    assert hist.shape == (4, N_BINS) and valid.tolist() == [True] * 4
    half = np.zeros(N_BINS)
    half[[3, 23]] = 1 / math.sqrt(2)
    red = np.zeros(N_BINS)
    red[3] = 1.0
    np.testing.assert_allclose(hist, [half, half, red, red])


def test_empty_crops_are_all_zero_and_invalid() -> None:
    image = _red_blue_image()
    boxes = np.array(
        [
            [10, 10, 3, 3],  # fully outside
            [-8, 0, 3, 4],  # fully left of the image
            [1.5, 1, 0, 2],  # zero width
            [1, 1, 2, 0],  # zero height
            [0, 0, 4, 4],  # whole image, valid
        ]
    )
    hist, valid = box_histograms(image, boxes)
    assert valid.tolist() == [False, False, False, False, True]
    assert not np.isnan(hist).any()
    np.testing.assert_array_equal(hist[:4], 0.0)
    assert np.linalg.norm(hist[4]) == pytest.approx(1.0)


def test_no_boxes() -> None:
    hist, valid = box_histograms(_red_blue_image(), np.zeros((0, 4)))
    assert hist.shape == (0, N_BINS) and valid.shape == (0,)


@pytest.mark.parametrize(
    ("image", "boxes", "match"),
    [
        (np.zeros((4, 4, 3), np.float32), [[0, 0, 1, 1]], "uint8"),
        (np.zeros((4, 4), np.uint8), [[0, 0, 1, 1]], r"\(H, W, 3\)"),
        (np.zeros((4, 4, 3), np.uint8), [[0, 0, 1]], r"\(N, 4\)"),
        (np.zeros((4, 4, 3), np.uint8), [[0, np.nan, 1, 1]], "NaN"),
        (np.zeros((4, 4, 3), np.uint8), [[0, 0, -1, 1]], "negative width"),
    ],
)
def test_bad_inputs(image: np.ndarray, boxes: list, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        box_histograms(image, np.array(boxes, dtype=float))


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    boxes=arrays(
        float,
        st.tuples(st.integers(0, 6), st.just(4)),
        elements=st.floats(-30, 60, allow_nan=False, width=32),
    ),
)
def test_matches_per_crop_reference(seed: int, boxes: np.ndarray) -> None:
    """The gathered bincount equals a per-box loop over slices; never NaN."""
    boxes = boxes.copy()
    boxes[:, 2:] = np.abs(boxes[:, 2:])
    image = np.random.default_rng(seed).integers(0, 256, (20, 30, 3), dtype=np.uint8)
    hist, valid = box_histograms(image, boxes)
    assert not np.isnan(hist).any()
    bins = hsv_bin_indices(image)
    for row, (x, y, w, h) in enumerate(boxes):
        x0, x1 = np.clip([math.floor(x), math.ceil(x + w)], 0, 30)
        y0, y1 = np.clip([math.floor(y), math.ceil(y + h)], 0, 20)
        crop = bins[y0:y1, x0:x1] if w > 0 and h > 0 else bins[:0, :0]
        counts = np.bincount(crop.ravel(), minlength=N_BINS).astype(float)
        assert valid[row] == (crop.size > 0)
        expected = counts / np.linalg.norm(counts) if crop.size else counts
        np.testing.assert_allclose(hist[row], expected, atol=1e-12)


# --- Eq. 3: chi-square bin-ratio distance ---------------------------------------------------


def test_chi2_brd_hand_computed() -> None:
    a = np.array([[1.0, 0.0, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 0.0]])
    b = np.array([[0.0, 1.0, 0.0], [0.8, 0.6, 0.0]])
    d = chi2_brd_distance(a, b)
    assert d.shape == (3, 2)
    # (1,0,0) vs (0,1,0): d_chi2 = 1/2 (1/1 + 1/1) = 1; every h^i_k h^j_k = 0, so no
    # correction; the third bin is 0/0 and contributes 0.
    assert d[0, 0] == pytest.approx(1.0)
    # (3/5,4/5) vs (4/5,3/5): d_chi2 = 1/2 * 2 * (1/25)/(7/5) = 1/35;
    # ||a+b||^2 = 2 (7/5)^2 = 98/25; sum_k (1/25)(12/25)/(7/5)^3 = 24/1715;
    # d = 1/35 - 1/2 * 98/25 * 24/1715 = 1/35 - 24/875 = 1/875.
    assert d[1, 1] == pytest.approx(1 / 875, rel=1e-12)
    # (1,0,0) vs (4/5,3/5,0): d_chi2 = 1/2 ((1/25)/(9/5) + (9/25)/(3/5)) = 1/90 + 3/10 = 14/45;
    # ||a+b||^2 = 81/25 + 9/25 = 18/5; only bin 1 has a product: (1/25)(4/5)/(9/5)^3 = 4/729;
    # d = 14/45 - 1/2 * 18/5 * 4/729 = 14/45 - 4/405 = 122/405.
    assert d[0, 1] == pytest.approx(122 / 405, rel=1e-12)
    # An all-zero histogram (invalid crop) against h: 1/2 sum_k h_k, never NaN.
    assert d[2, 0] == pytest.approx(0.5)
    assert d[2, 1] == pytest.approx(0.7)


def test_chi2_brd_identity_and_symmetry() -> None:
    rng = np.random.default_rng(3)
    h = rng.random((5, N_BINS))
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    d = chi2_brd_distance(h, h)
    np.testing.assert_allclose(np.diag(d), 0.0, atol=1e-15)
    np.testing.assert_allclose(d, d.T, atol=1e-15)
    assert (d >= 0).all()


def _bin_ratio_reference(p: np.ndarray, q: np.ndarray) -> float:
    """Eq. 3 in the bin-ratio form of [11]: 1/2 sum_k (p_k-q_k)^2/(p_k+q_k)^3 *
    sum_l (p_l q_k - p_k q_l)^2, written with explicit loops (valid for unit-norm p, q)."""
    total = 0.0
    for k in range(len(p)):
        s = p[k] + q[k]
        if s == 0:
            continue
        # (p_l q_k - p_k q_l)^2 / s^2 with the 1/s inside, so tiny bins do not underflow.
        ratio = sum((p[m] * (q[k] / s) - (p[k] / s) * q[m]) ** 2 for m in range(len(p)))
        total += 0.5 * (p[k] - q[k]) ** 2 / s * ratio
    return total


@settings(max_examples=50, deadline=None)
@given(
    arrays(float, (2, 6), elements=st.floats(0, 1, allow_nan=False)),
    st.lists(st.booleans(), min_size=6, max_size=6),
)
def test_chi2_brd_matches_bin_ratio_form(h: np.ndarray, zero: list[bool]) -> None:
    h = h.copy()
    h[:, np.array(zero)] = 0.0  # bins empty in both histograms (0/0)
    # Scale to a peak of 1 first: the squares of tiny entries (1e-160) underflow and the row
    # would not come out unit-norm, which both forms assume.
    peak = h.max(axis=1, keepdims=True)
    h = np.divide(h, peak, out=np.zeros_like(h), where=peak > 0)
    norms = np.linalg.norm(h, axis=1, keepdims=True)
    h = np.divide(h, norms, out=np.zeros_like(h), where=norms > 0)
    d = chi2_brd_distance(h[:1], h[1:])
    assert np.isfinite(d).all() and (d >= 0).all()
    if (norms > 0).all():
        assert d[0, 0] == pytest.approx(_bin_ratio_reference(h[0], h[1]), abs=1e-12)


def test_distance_bad_inputs() -> None:
    with pytest.raises(ValueError, match="same number of bins"):
        chi2_brd_distance(np.ones((1, 3)), np.ones((1, 4)))
    with pytest.raises(ValueError, match="NaN"):
        chi2_brd_distance(np.array([[np.nan, 1.0]]), np.ones((1, 2)))
    with pytest.raises(ValueError, match="negative"):
        histogram_intersection(np.array([[-1.0, 1.0]]), np.ones((1, 2)))
    assert chi2_brd_distance(np.zeros((0, 32)), np.ones((3, 32))).shape == (0, 3)


# --- Histogram intersection ---------------------------------------------------------------------


def test_histogram_intersection_hand_computed() -> None:
    a = np.array([[0.6, 0.8, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 0.0]])
    b = np.array([[0.8, 0.6, 0.0], [0.6, 0.8, 0.0], [0.0, 0.0, 1.0]])
    s = histogram_intersection(a, b)
    # (3/5,4/5) vs (4/5,3/5): (3/5 + 3/5) / min(7/5, 7/5) = 6/7.
    assert s[0, 0] == pytest.approx(6 / 7)
    assert s[0, 1] == pytest.approx(1.0)  # identical
    assert s[0, 2] == pytest.approx(0.0)  # disjoint support
    # (1,0,0) vs (3/5,4/5,0): min = 3/5, mass min(1, 7/5) = 1.
    assert s[1, 1] == pytest.approx(0.6)
    np.testing.assert_array_equal(s[2], 0.0)  # all-zero histogram: 0/0 -> 0, not NaN
