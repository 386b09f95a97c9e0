"""Whether a step of the (O, theta) search, or the oblique registration's pose terms and its
choice of distinct poses, runs its numpy form or its compiled numba kernel.

The two give bit-identical results on every CPU (the kernels do only IEEE arithmetic and
comparisons in the numpy forms' order; every transcendental function is numpy's, in both;
``tests/test_spatial_matching.py``, ``tests/test_spatial_vectors.py`` and
``tests/test_ground_registration.py`` pin it), so the choice
only moves time. ``auto`` (the default) runs every call in the kernels wherever numba can be
imported (a base requirement), and numpy where it cannot: the kernels are about 3x faster even
on the video mode's few dozen orientations per frame, and every run of the search has calls of
hundreds of hypotheses (the first frame's full circle), which load them anyway (importing numba
and loading the cached machine code cost a process about a second, once). It is a rule on the
installation alone, never on elapsed time or on the work, so every process and worker takes the
same side. ``XVMATCH_KERNELS=auto|compiled|numpy`` or :func:`set_mode` forces one side (tests
run both).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

__all__ = ["MODES", "forced", "kernels", "mode", "set_mode"]

MODES = ("auto", "compiled", "numpy")

_state: dict[str, str] = {"mode": ""}
_loaded: dict[str, ModuleType | None] = {}
"""The kernels module once imported (``"module"``), or None when numba could not be."""


def set_mode(value: str) -> None:
    """Choose ``auto``, ``compiled`` or ``numpy`` for this process."""
    if value not in MODES:
        raise ValueError(f"XVMATCH_KERNELS must be one of {', '.join(MODES)}, got {value!r}")
    _state["mode"] = value


def mode() -> str:
    """The current choice (``$XVMATCH_KERNELS``, default ``auto``, until :func:`set_mode`)."""
    if not _state["mode"]:
        set_mode(os.environ.get("XVMATCH_KERNELS", "auto") or "auto")
    return _state["mode"]


@contextmanager
def forced(value: str) -> Iterator[None]:
    """Run a block with the choice ``value``, then restore the previous one."""
    previous = mode()
    set_mode(value)
    try:
        yield
    finally:
        set_mode(previous)


def _module(required: bool) -> ModuleType | None:
    """The kernels module, imported once; None when numba is missing and not ``required``."""
    if "module" not in _loaded:
        try:
            from xvmatch.cues import search_kernels
        except ImportError:
            if required:
                raise
            _loaded["module"] = None
        else:
            _loaded["module"] = search_kernels
    module = _loaded["module"]
    if module is None and required:
        raise ImportError("XVMATCH_KERNELS=compiled needs numba (pip install numba)")
    return module


def kernels() -> ModuleType | None:
    """The compiled kernels module for the next call, or None (use numpy)."""
    current = mode()
    if current == "numpy":
        return None
    return _module(required=current == "compiled")
