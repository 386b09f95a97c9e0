"""Tests of the choice between the search's numpy forms and its compiled kernels."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from xvmatch.cues import kernel_choice
from xvmatch.cues.spatial_search import associate_frame

TOP = np.array([[100, 100, 20, 20], [300, 120, 20, 20], [200, 300, 20, 20], [150, 220, 20, 20],
                [400, 260, 20, 20]], dtype=float)
HOR = np.array([[100, 300, 60, 200], [900, 320, 50, 170], [1500, 280, 70, 240]], dtype=float)


def test_forced_modes_give_the_same_association():
    found = {}
    for mode in ("numpy", "compiled"):
        with kernel_choice.forced(mode):
            found[mode] = associate_frame(TOP, HOR, 2688.0)
    np.testing.assert_array_equal(found["numpy"].pairs, found["compiled"].pairs)
    assert found["numpy"].cost == found["compiled"].cost
    assert found["numpy"].theta == found["compiled"].theta


def test_auto_is_a_rule_on_the_batch_size_alone():
    # The same call takes the same side in every process and worker, however long the process
    # has run (no timing): small batches in numpy, large ones in the kernels.
    with kernel_choice.forced("auto"):
        assert kernel_choice.kernels(kernel_choice.LARGE_BATCH - 1) is None
        assert kernel_choice.kernels(kernel_choice.LARGE_BATCH) is not None
    with kernel_choice.forced("numpy"):
        assert kernel_choice.kernels(10**6) is None
    with kernel_choice.forced("compiled"):
        assert kernel_choice.kernels(1) is not None


def test_bad_mode_is_a_clear_error():
    with pytest.raises(ValueError, match="XVMATCH_KERNELS must be one of auto, compiled, numpy"):
        kernel_choice.set_mode("fast")


def test_environment_variable_sets_the_mode():
    code = ("from xvmatch.cues import kernel_choice; print(kernel_choice.mode()); "
            "print(kernel_choice.kernels(1) is None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"XVMATCH_KERNELS": "compiled", "PATH": ""}).stdout.split()
    assert out == ["compiled", "False"]


def test_a_planned_long_run_takes_the_kernels_for_small_calls_too():
    with kernel_choice.forced("auto"):
        with kernel_choice.planned(kernel_choice.LONG_RUN - 1):
            assert kernel_choice.kernels(1) is None
        with kernel_choice.planned(kernel_choice.LONG_RUN):
            assert kernel_choice.kernels(1) is not None
        assert kernel_choice.kernels(1) is None  # the plan ends with its block
    with kernel_choice.forced("numpy"), kernel_choice.planned(10**6):
        assert kernel_choice.kernels(10**6) is None


@pytest.mark.parametrize("workers", [1, 2])
def test_the_learned_path_declares_its_run_as_the_search_does(monkeypatch, workers):
    # The learned box path's many small calls run in the kernels on a long run, in the main
    # process and in every worker (issue 70: they ran in numpy, a third of its slowdown).
    from xvmatch.inference.matching import learned_association

    seen = []

    def frame_features(*args):
        seen.append(kernel_choice.kernels(1) is not None)
        return [[None]]

    if workers > 1:  # a worker runs _features_of_chunk itself: check its declaration directly
        with kernel_choice.forced("auto"):
            monkeypatch.setattr(learned_association, "_frame_features", frame_features)
            learned_association._features_of_chunk([(TOP, HOR, None, None)], (2688.0, 1512.0),
                                                   (), False, kernel_choice.LONG_RUN)
        assert seen == [True]
        return
    inputs = [(TOP, HOR, None, None)] * kernel_choice.LONG_RUN
    with kernel_choice.forced("auto"):
        monkeypatch.setattr(learned_association, "_frame_features", frame_features)
        list(learned_association._feature_stream(inputs, (2688.0, 1512.0), (), False, 1))
        assert kernel_choice.kernels(1) is None  # declared for the run only
    assert len(seen) == kernel_choice.LONG_RUN and all(seen)
