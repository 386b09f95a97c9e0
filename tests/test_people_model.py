"""The people model with a tilt per window (issue 67): one call for all windows is the one-tilt
model of each window's boxes, its compiled kernel the numpy form to the bit, and the fit holds
what it is asked to hold and starts where it is told."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.core import kernel_choice
from xvmatch.geometry import people_model as pm
from xvmatch.geometry.people_kernels import centred_box_heights
from xvmatch.geometry.people_model import (
    BODY_WIDTH,
    BORDER,
    BORDER_SHARE,
    CENTRE_ROUNDS,
    HIDING_GAP,
    HIDING_SHARE,
    PERSON_HEIGHT,
    UsableBoxes,
    centred_heights,
    fit_model,
    forward_differences,
    predicted_heights,
    prior_focal,
    readable_boxes,
    whole_boxes,
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
        assert np.array_equal(windowed[rows], alone, equal_nan=True)  # the same arithmetic


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
    own frame, height and track); the model maps each box through its own window's tilt
    whatever the boxes' order."""
    b = _boxes(30, 3, 2)
    assert np.all(np.diff(b.window) >= 0) and np.bincount(b.window).tolist() == [10, 10, 10]
    np.testing.assert_array_equal(b.frame % 3, b.window)  # the rows moved whole
    params = np.concatenate([np.radians([20.0, 25.0, 30.0]),
                             [0.0, np.log(prior_focal(SIZE)), np.log(8.0), 1.7, 1.7]])
    order = np.random.default_rng(3).permutation(30)
    assert np.array_equal(predicted_heights(params, b.take(order), SIZE),
                          predicted_heights(params, b, SIZE)[order], equal_nan=True)


@settings(max_examples=40, deadline=None)
@given(windows=st.integers(1, 3), seed=st.integers(0, 1000), tilt=st.floats(-40.0, 89.0),
       roll=st.floats(-30.0, 30.0), hfov=st.floats(20.0, 150.0), height=st.floats(0.5, 900.0),
       person=st.floats(1.0, 2.4), rounds=st.integers(0, 3))
def test_the_compiled_heights_are_the_numpy_forms_to_the_bit(
        windows: int, seed: int, tilt: float, roll: float, hfov: float, height: float,
        person: float, rounds: int) -> None:
    """The people model's compiled kernel and its numpy form give the same bits (NaN where a
    foot is at or above the horizon, behind the camera), over the fit's whole bounds, for the
    boxes' foot rows and for their centre rows."""
    b = _boxes(80, windows, seed)
    b = replace(b, u=np.append(b.u[:-1], SIZE[0] / 2), v=np.append(b.v[:-1], SIZE[1] / 2))
    params = np.concatenate([np.radians(np.clip(tilt + 7.0 * np.arange(windows), -45, 89)),
                             [np.radians(roll), np.log(prior_focal(SIZE, hfov)),
                              np.log(height), person, 3.4 - person]])
    made = {}
    for mode in ("compiled", "numpy"):
        with kernel_choice.forced(mode):
            made[mode] = pm._model_heights(params, b, SIZE, rounds)
    assert np.array_equal(made["compiled"], made["numpy"], equal_nan=True)
    assert np.array_equal(np.signbit(made["compiled"]), np.signbit(made["numpy"]))


@settings(max_examples=80, deadline=None)
@given(rows=st.lists(st.floats(-2.0, 2.0), min_size=8, max_size=8),
       shift=st.floats(-1e-6, 1e-6))
def test_the_outline_span_is_rounded_only_near_its_corners_ties(rows: list[float],
                                                                 shift: float) -> None:
    """A box's top and bottom are its outline's highest and lowest rows rounded near ties:
    never longer than the sharp span, at most one rounding shorter (eight rows all but tied),
    the sharp span itself where its two highest rows and its two lowest are a rounding apart
    or more, or tied; and it moves with its rows without a bend (a row moved by up to 1e-6
    px moves it by at most 2.5 times that)."""
    e = pm.OUTLINE_SMOOTH_PX
    array = np.array(rows)[:, None]
    span = pm._smooth_span(array)[0]
    sharp = array.max() - array.min()
    assert sharp - e <= span <= sharp
    ordered = np.sort(array[:, 0])
    if min(ordered[-1] - ordered[-2], ordered[1] - ordered[0]) >= e:
        assert span == sharp
    assert pm._smooth_span(np.full((8, 1), rows[0]))[0] == 0.0
    moved = array.copy()
    moved[0] += shift
    assert abs(pm._smooth_span(moved)[0] - span) <= 2.5 * abs(shift) + 1e-12


def test_a_person_partly_behind_the_camera_has_no_height_in_either_form() -> None:
    """A person close below a low camera with a very wide lens (165 degrees), at the image's
    lower right: a corner of their outline lies behind the camera, so the box has no height
    (NaN, not the span of the corners in front), in both forms alike; a nadir camera's
    centre, where the radius along the ray divides by zero, likewise."""
    b = replace(_boxes(2, 1, 0), u=np.array([1801.9, 960.0]), v=np.array([1068.8, 540.0]),
                track=np.zeros(2, np.int64))
    tilted = np.array([0.7574, -0.328, np.log(127.0), np.log(3.84), 1.5857, 1.5857])
    for mode in ("compiled", "numpy"):
        with kernel_choice.forced(mode):
            assert np.isnan(predicted_heights(tilted, b, SIZE)[0])
    down = np.array([[[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]])  # exactly
    at = (b.u[1:], b.v[1:])
    numpy_form = pm._heights_numpy(*at, np.array([1.7]), down, 1000.0, 8.0, 960.0, 540.0)
    compiled = centred_box_heights(*at, b.h[1:], np.array([1.7]), down, np.zeros(1, np.int64),
                                   1000.0, 8.0, 960.0, 540.0, 0.5 * BODY_WIDTH, 0,
                                   pm.OUTLINE_SMOOTH_PX)
    assert np.isnan(numpy_form[0]) and np.isnan(compiled[0])


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


def _readable(*boxes: tuple[float, float, float, float]) -> list[bool]:
    """Which of one frame's boxes (x, y, w, h) tell their person's height."""
    array = np.array(boxes, dtype=float)
    return readable_boxes(np.zeros(len(array), np.int64), array, SIZE).tolist()


def test_a_box_is_hidden_where_a_nearer_box_spans_most_of_its_feet_or_head() -> None:
    """A far person (feet at row 400) behind a near one (feet at row 600): a near box across
    the far box's foot row hides it from :data:`HIDING_SHARE` of its width on, one at its side
    does not; a taller near box across its top row hides it; the near one stays readable."""
    far = (500.0, 250.0, 60.0, 150.0)
    cover = HIDING_SHARE * 60.0
    assert _readable(far, (560.0 - cover, 350.0, 80.0, 250.0)) == [False, True]
    assert _readable(far, (560.0 - cover + 2.0, 350.0, 80.0, 250.0)) == [True, True]
    assert _readable(far, (450.0, 350.0, 40.0, 250.0)) == [True, True]  # left of it, apart
    assert _readable(far, (480.0, 200.0, 100.0, 400.0)) == [False, True]  # its head too
    assert _readable(far, (480.0, 420.0, 100.0, 180.0)) == [True, True]  # below its feet
    assert _readable(far, (500.0, 200.0, 60.0, 150.0)) == [True, False]  # feet higher: behind


def test_a_box_ending_just_above_nearer_boxes_is_hidden_by_them_together() -> None:
    """Loose edges leave a gap between a hidden box's bottom and its hider's top: within
    :data:`HIDING_GAP` of the hider's height it is hidden, farther up it stands clear; two
    nearer boxes each across a third of its width hide it together."""
    far = (500.0, 250.0, 60.0, 150.0)
    gap = HIDING_GAP * 200.0
    assert _readable(far, (480.0, 400.0 + gap - 1.0, 100.0, 200.0)) == [False, True]
    assert _readable(far, (480.0, 400.0 + gap + 1.0, 100.0, 200.0)) == [True, True]
    third = 60.0 / 3.0
    pair = ((500.0 - 40.0 + third, 350.0, 40.0, 250.0), (560.0 - third, 360.0, 40.0, 250.0))
    assert _readable(far, *pair) == [False, True, True]
    assert _readable(far, pair[0]) == [True, True]


def test_a_box_within_a_share_of_its_height_of_the_border_may_be_cut() -> None:
    """A box whose top or bottom lies within :data:`BORDER_SHARE` of its height of the image's
    top or bottom border is taken as cut (its loose edge may have come inside), one just
    beyond is whole; at the sides (which leave the height whole) and for a small box,
    :data:`BORDER` pixels."""
    h = 200.0
    m = BORDER_SHARE * h
    width, height = SIZE
    cut = [(900.0, m - 1.0, 80.0, h), (900.0, height - h - m + 1.0, 80.0, h),
           (BORDER - 1.0, 400.0, 80.0, h), (width - 80.0 - BORDER + 1.0, 400.0, 80.0, h)]
    whole = [(900.0, m + 1.0, 80.0, h), (900.0, height - h - m - 1.0, 80.0, h),
             (BORDER + 1.0, 400.0, 80.0, h), (width - 80.0 - BORDER - 1.0, 400.0, 80.0, h)]
    assert whole_boxes(np.array(cut), SIZE).tolist() == [False] * 4
    assert whole_boxes(np.array(whole), SIZE).tolist() == [True] * 4
    small = np.array([(900.0, height - 12.0 - BORDER - 1.0, 6.0, 12.0),
                      (900.0, height - 12.0 - BORDER + 1.0, 6.0, 12.0)])
    assert whole_boxes(small, SIZE).tolist() == [True, False]


def _walkers(tilt_deg: float, seed: int) -> tuple[UsableBoxes, np.ndarray]:
    """12 people followed over 40 boxes each, each walking within 40 rows of a place of their
    own over the image's lower two thirds, 1.6-1.85 m tall, as the model predicts them for one
    camera ``tilt_deg`` down, 8 m up, the prior's lens; and its parameters."""
    rng = np.random.default_rng(seed)
    track = np.repeat(np.arange(1, 13), 40)
    u = rng.uniform(200, SIZE[0] - 200, 12)[track - 1] + rng.uniform(-60, 60, len(track))
    v = rng.uniform(SIZE[1] / 3, SIZE[1] - 60, 12)[track - 1] + rng.uniform(-40, 40, len(track))
    truth = np.concatenate([[np.radians(tilt_deg), 0.0, np.log(prior_focal(SIZE)),
                             np.log(8.0), PERSON_HEIGHT], rng.uniform(1.6, 1.85, 12)])
    b = UsableBoxes(u=u, v=v, h=np.ones_like(u), w=np.full(len(u), 30.0),
                    block=np.arange(len(u)) // 10, track=track, n_tracks=13,
                    frame=np.arange(len(u)))
    return replace(b, h=predicted_heights(truth, b, SIZE)), truth


def test_a_box_of_the_models_own_height_has_its_centre_where_its_foot_says() -> None:
    """Where a box's height is the one the model predicts, placing the person by the box's
    centre row finds the same foot row, hence the same height."""
    b, truth = _walkers(35.0, 4)
    np.testing.assert_allclose(centred_heights(truth, b, SIZE), b.h, rtol=1e-3)


@settings(max_examples=20, deadline=None)
@given(windows=st.integers(1, 3), seed=st.integers(0, 1000), tilt=st.floats(5.0, 60.0),
       roll=st.floats(-5.0, 5.0), hfov=st.floats(50.0, 110.0), height=st.floats(3.0, 40.0))
def test_centred_heights_are_the_model_asked_row_by_row(windows: int, seed: int, tilt: float,
                                                        roll: float, hfov: float,
                                                        height: float) -> None:
    """The centre rows' heights, the camera made once for all rows, are bit for bit the
    predicted heights of each round's foot rows (feet above the horizon: NaN, then the box's
    own height)."""
    b = _boxes(80, windows, seed)
    params = np.concatenate([np.radians(tilt + 5.0 * np.arange(windows)),
                             [np.radians(roll), np.log(prior_focal(SIZE, hfov)),
                              np.log(height), 1.6, 1.8]])
    pred = predicted_heights(params, b, SIZE)
    for _ in range(CENTRE_ROUNDS):
        foot = b.v - 0.5 * b.h + 0.5 * np.where(np.isfinite(pred), pred, b.h)
        pred = predicted_heights(params, replace(b, v=foot), SIZE)
    assert np.array_equal(centred_heights(params, b, SIZE), pred, equal_nan=True)


def test_a_fit_is_the_same_under_either_kernel_choice() -> None:
    """The whole fit (its steps and finite differences, then the settling) from the same
    starts gives the same parameters to the bit with the compiled heights and with numpy's."""
    b, truth = _walkers(35.0, 4)
    start = np.concatenate([[np.radians(25.0), 0.0, np.log(1.2 * prior_focal(SIZE)),
                             np.log(6.0)], truth[4:]])
    fits = {}
    for mode in ("compiled", "numpy"):
        with kernel_choice.forced(mode):
            fits[mode] = fit_model(b, SIZE, prior_focal(SIZE), [start], settle=True)
    assert np.array_equal(fits["compiled"], fits["numpy"])
    assert abs(np.degrees(fits["numpy"][0]) - 35.0) < 1.0  # and it found the camera


@pytest.mark.parametrize("tilt", [30.0, 40.0])
def test_loose_top_and_bottom_edges_leave_the_tilt_where_it_is(tilt: float) -> None:
    """Each box's top and bottom moved by a normal draw of 3 % of its height (a tracker's
    loose edges): the fit with the lens known reads the tilt within a degree (fitted on the
    foot rows, whose error is the height's too, it read it several degrees too level: each
    person's height of their own leaves the tilt to how heights change over a few rows)."""
    b, truth = _walkers(tilt, 5)
    rng = np.random.default_rng(6)
    top = b.v - b.h + 0.03 * b.h * rng.standard_normal(len(b.h))
    bottom = b.v + 0.03 * b.h * rng.standard_normal(len(b.h))
    loose = replace(b, v=bottom, h=bottom - top)
    fit = fit_model(loose, SIZE, prior_focal(SIZE), [truth], fixed_f=prior_focal(SIZE))
    assert abs(np.degrees(fit[0]) - tilt) < 1.0, np.degrees(fit[0])


def test_forward_differences_share_an_evaluation_only_where_no_residual_reads_both() -> None:
    """The people model's Jacobian with the followed people's heights sharing one evaluation is
    bit for bit the one with an evaluation per parameter; near a bound the step turns back
    inside, and the differences still follow the derivative."""
    b, truth = _walkers(35.0, 4)
    lo = np.concatenate([[-0.8, -0.5, -np.inf, np.log(0.5)], np.full(b.n_tracks, 1.0)])
    hi = np.concatenate([[1.55, 0.5, np.inf, np.log(1e3)], np.full(b.n_tracks, 2.5)])
    x = truth.copy()
    x[5] = hi[5] - 1e-12  # a height at its upper bound: its step must go down

    def fun(p: np.ndarray) -> np.ndarray:
        return np.log(predicted_heights(p, b, SIZE) / b.h)

    structure = np.zeros((len(b.h), len(x)), dtype=bool)
    structure[:, :4] = True
    structure[np.arange(len(b.h)), 4 + b.track] = True
    f0 = fun(x)
    grouped = forward_differences(fun, x, f0, lo, hi, structure)
    alone = forward_differences(fun, x, f0, lo, hi, np.ones_like(structure))
    assert np.array_equal(grouped, alone) and np.array_equal(np.signbit(grouped),
                                                             np.signbit(alone))
    assert not grouped[~structure].any()
    # Central differences of a small step agree with the forward ones to their accuracy.
    for j in (0, 2, 5):
        step = np.zeros_like(x)
        step[j] = 1e-6
        central = (fun(x + step) - fun(x - step)) / 2e-6 if j != 5 else (
            fun(x) - fun(x - step)) / 1e-6
        np.testing.assert_allclose(grouped[:, j], central, atol=1e-5)
