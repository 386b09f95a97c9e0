"""Tests of the choice between the search's numpy forms and its compiled kernels."""

from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

from xvmatch.geometry import kernel_choice
from xvmatch.geometry.spatial_search import associate_frame

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


def test_auto_rents_numpy_until_it_has_cost_the_start_up(monkeypatch):
    monkeypatch.setitem(kernel_choice._state, "numpy_seconds", 0.0)
    with kernel_choice.forced("auto"):
        assert kernel_choice.kernels() is None
        kernel_choice.timed_numpy(lambda: None, kernel_choice.LARGE_BATCH)
        assert kernel_choice.kernels() is None  # far less than a second of numpy so far
        kernel_choice.timed_numpy(lambda: time.sleep(0.05), 1)  # small batches do not count
        assert kernel_choice._state["numpy_seconds"] < 0.05
        monkeypatch.setitem(kernel_choice._state, "numpy_seconds",
                            kernel_choice.STARTUP_SECONDS)
        assert kernel_choice.kernels() is not None
    with kernel_choice.forced("numpy"):
        assert kernel_choice.kernels() is None


def test_bad_mode_is_a_clear_error():
    with pytest.raises(ValueError, match="XVMATCH_KERNELS must be one of auto, compiled, numpy"):
        kernel_choice.set_mode("fast")


def test_environment_variable_sets_the_mode():
    code = ("from xvmatch.geometry import kernel_choice; print(kernel_choice.mode()); "
            "print(kernel_choice.kernels() is None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"XVMATCH_KERNELS": "compiled", "PATH": ""}).stdout.split()
    assert out == ["compiled", "False"]
