"""The paired difference interval that resamples whole scenes
(``evaluation.confidence.grouped_difference_interval``), used by the deployed benchmark to say
whether images beat boxes by more than the scenes' spread."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from xvmatch.metrics.confidence import grouped_difference_interval


def _frames(seed: int = 1, scenes: int = 20, per_scene: int = 5):
    rng = np.random.default_rng(seed)
    groups = np.repeat(np.arange(scenes), per_scene)
    scene_effect = rng.normal(0.0, 0.1, scenes)[groups]  # frames of a scene move together
    b = rng.random(groups.size)
    a = b + 0.05 + scene_effect + 0.01 * rng.standard_normal(groups.size)
    return a, b, groups


def test_difference_is_the_paired_mean_and_the_interval_holds_it():
    a, b, groups = _frames()
    r = grouped_difference_interval(a, b, groups)
    assert r.difference == pytest.approx(a.mean() - b.mean())
    assert r.low < r.difference < r.high
    assert r.n_groups == 20 and r.confidence == 0.95
    again = grouped_difference_interval(a, b, groups)
    assert (again.low, again.high) == (r.low, r.high)  # seeded
    wider = grouped_difference_interval(a, b, groups, confidence=0.99)
    assert wider.low < r.low and wider.high > r.high


def test_resampling_scenes_not_frames_widens_the_interval_of_correlated_frames():
    a, b, groups = _frames()
    by_scene = grouped_difference_interval(a, b, groups)
    by_frame = grouped_difference_interval(a, b, np.arange(groups.size))
    assert by_scene.high - by_scene.low > 2 * (by_frame.high - by_frame.low)


@settings(max_examples=25, deadline=None)
@given(shift=st.floats(-1.0, 1.0), seed=st.integers(0, 2**16))
def test_a_constant_shift_has_a_zero_width_interval(shift, seed):
    b = np.random.default_rng(seed).random(30)
    r = grouped_difference_interval(b + shift, b, np.arange(30) % 6)
    assert r.difference == pytest.approx(shift, abs=1e-9)
    assert r.low == pytest.approx(shift, abs=1e-9) and r.high == pytest.approx(shift, abs=1e-9)


def test_one_scene_gives_no_interval_and_bad_input_is_refused():
    r = grouped_difference_interval([1.0, 2.0], [0.0, 1.0], ["s", "s"])
    assert r.difference == 1.0 and r.low is None and r.high is None and r.n_groups == 1
    with pytest.raises(ValueError, match="one non-zero length"):
        grouped_difference_interval([1.0, 2.0], [1.0], [0, 1])
    with pytest.raises(ValueError, match="one non-zero length"):
        grouped_difference_interval([], [], [])
    with pytest.raises(ValueError, match="finite"):
        grouped_difference_interval([1.0, np.nan], [1.0, 2.0], [0, 1])
    with pytest.raises(ValueError, match="confidence"):
        grouped_difference_interval([1.0, 2.0], [1.0, 2.0], [0, 1], confidence=1.0)
