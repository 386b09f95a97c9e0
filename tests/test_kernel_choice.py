"""Tests of the choice between the search's numpy forms and its compiled kernels."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from xvmatch.core import kernel_choice
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


def test_auto_takes_the_kernels_wherever_numba_is_installed():
    # A rule on the installation alone (issue 70): every call, however small, in every process
    # and worker, runs the kernels when numba imports; no timing, no work size.
    with kernel_choice.forced("auto"):
        assert kernel_choice.kernels() is not None
    with kernel_choice.forced("numpy"):
        assert kernel_choice.kernels() is None
    with kernel_choice.forced("compiled"):
        assert kernel_choice.kernels() is not None


def test_auto_falls_back_to_numpy_without_numba_and_compiled_says_why():
    code = ("import sys; sys.modules['numba'] = None\n"
            "from xvmatch.core import kernel_choice\n"
            "from xvmatch.cues.spatial_search import associate_frame\n"
            "import numpy as np\n"
            "print(kernel_choice.kernels() is None, kernel_choice.kernels('people') is None)\n"
            "top = np.array([[100, 100, 20, 20], [300, 120, 20, 20], [200, 300, 20, 20]], float)\n"
            "hor = np.array([[100, 300, 60, 200], [900, 320, 50, 170]], float)\n"
            "print(associate_frame(top, hor, 2688.0).camera >= 0)\n"
            "kernel_choice.set_mode('compiled')\n"
            "try:\n"
            "    kernel_choice.kernels('people')\n"
            "except ImportError as e:\n"
            "    print('numba' in str(e))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"XVMATCH_KERNELS": "auto", "PATH": ""}).stdout.split()
    assert out == ["True", "True", "True", "True"]


def test_bad_mode_is_a_clear_error():
    with pytest.raises(ValueError, match="XVMATCH_KERNELS must be one of auto, compiled, numpy"):
        kernel_choice.set_mode("fast")


def test_environment_variable_sets_the_mode():
    code = ("from xvmatch.core import kernel_choice; print(kernel_choice.mode()); "
            "print(kernel_choice.kernels() is None)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True,
                         env={"XVMATCH_KERNELS": "compiled", "PATH": ""}).stdout.split()
    assert out == ["compiled", "False"]
