"""The people model with a tilt per window (issue 67): one call for all windows is the one-tilt
model of each window's boxes, the boxes come in window order, and the fit holds what it is
asked to hold and starts where it is told."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.geometry.people_model import (
    PERSON_HEIGHT,
    UsableBoxes,
    fit_model,
    predicted_heights,
    prior_focal,
)

SIZE = (1920, 1080)


def _boxes(n: int, windows: int, seed: int) -> UsableBoxes:
    """``n`` feet spread over the image's lower two thirds, two tracks, ``windows`` windows."""
    rng = np.random.default_rng(seed)
    u = rng.uniform(100, SIZE[0] - 100, n)
    v = rng.uniform(SIZE[1] / 3, SIZE[1] - 10, n)
    return UsableBoxes(u=u, v=v, h=rng.uniform(40, 200, n), w=np.full(n, 30.0),
                       block=np.zeros(n, np.int64), track=rng.integers(0, 2, n),
                       n_tracks=2, frame=np.arange(n)).windowed(np.arange(n) % windows)


def _modelled() -> tuple[UsableBoxes, np.ndarray]:
    """Two windows' boxes whose heights the model predicts at tilts 20 and 30 degrees (8 m
    up, the prior's lens, level, everyone 1.72 m), and those parameters."""
    b = _boxes(200, 2, 1)
    truth = np.concatenate([np.radians([20.0, 30.0]), [0.0, np.log(prior_focal(SIZE)),
                                                       np.log(8.0)], [PERSON_HEIGHT] * 2])
    h = predicted_heights(truth, b, SIZE)
    ok = np.isfinite(h)
    return UsableBoxes(u=b.u[ok], v=b.v[ok], h=h[ok], w=b.w[ok], block=b.block[ok],
                       track=b.track[ok], n_tracks=2,
                       frame=b.frame[ok]).windowed(b.window[ok]), truth


@settings(max_examples=25, deadline=None)
@given(tilts=st.lists(st.floats(5.0, 60.0), min_size=2, max_size=5),
       roll=st.floats(-5.0, 5.0), hfov=st.floats(50.0, 110.0), height=st.floats(3.0, 40.0))
def test_a_tilt_per_window_is_each_windows_own_camera(tilts: list[float], roll: float,
                                                      hfov: float, height: float) -> None:
    b = _boxes(60, len(tilts), 0)
    shared = [np.radians(roll), np.log(prior_focal(SIZE, hfov)), np.log(height), 1.6, 1.8]
    windowed = predicted_heights(np.concatenate([np.radians(tilts), shared]), b, SIZE)
    for k, tilt in enumerate(tilts):
        rows = np.flatnonzero(b.window == k)
        one = b.take(rows).windowed(np.zeros(len(rows), np.int64))
        alone = predicted_heights(np.concatenate([[np.radians(tilt)], shared]), one, SIZE)
        np.testing.assert_allclose(windowed[rows], alone, rtol=1e-10, equal_nan=True)


def test_held_parameters_stay_and_the_tilts_move() -> None:
    """Boxes the model predicts at tilts 20 and 30 degrees: with the lens, roll and height held
    at the truth, the fit finds each window's tilt from a start at 25."""
    b, truth = _modelled()
    start = np.concatenate([[np.radians(25.0)], truth[2:]])
    fit = fit_model(b, SIZE, prior_focal(SIZE), [start], hold=(1, 2, 3))
    assert fit[2:5].tolist() == truth[2:5].tolist()
    np.testing.assert_allclose(np.degrees(fit[:2]), [20.0, 30.0], atol=0.05)


def test_windowed_boxes_come_in_window_order() -> None:
    """``windowed`` orders the boxes by window (each window's rows one slice, each box with its
    own frame, height and track); boxes whose windows are not in order are refused by the
    model rather than mapped through another window's tilt."""
    b = _boxes(30, 3, 2)
    assert np.all(np.diff(b.window) >= 0) and np.bincount(b.window).tolist() == [10, 10, 10]
    np.testing.assert_array_equal(b.frame % 3, b.window)  # the rows moved whole
    params = np.concatenate([np.radians([20.0, 25.0, 30.0]),
                             [0.0, np.log(prior_focal(SIZE)), np.log(8.0), 1.7, 1.7]])
    shuffled = replace(b, window=b.window[::-1].copy())
    with pytest.raises(ValueError, match="ordered by window"):
        predicted_heights(params, shuffled, SIZE)


def test_a_start_may_carry_a_tilt_per_window() -> None:
    """A whole fit's parameters (a tilt per window) start the fit as they are: from the truth
    the fit stays near it; one tilt for both windows from their middle finds each again."""
    b, truth = _modelled()
    fit = fit_model(b, SIZE, prior_focal(SIZE), [truth], hold=(1, 2, 3))
    np.testing.assert_allclose(fit, truth, atol=1e-3)  # the tilts' step cost pulls a little
    one = np.concatenate([[np.radians(25.0)], truth[2:]])
    assert len(one) == len(truth) - 1
    np.testing.assert_allclose(fit_model(b, SIZE, prior_focal(SIZE), [one], hold=(1, 2, 3)),
                               truth, atol=1e-3)
