"""Whether a step of the (O, theta) search runs its numpy form or its compiled numba kernel.

The two give bit-identical results on every CPU (the kernels do only IEEE arithmetic and
comparisons in the numpy forms' order; every transcendental function is numpy's, in both;
``tests/test_spatial_matching.py`` and ``tests/test_spatial_vectors.py`` pin it), so the choice
only moves time. It is a rule on the work alone, never on elapsed time: ``auto`` runs a call of
at least ``LARGE_BATCH`` hypotheses in the kernels (the exhaustive search's calls hold
thousands), and smaller calls (the video mode's few dozen orientations per frame) in numpy,
unless the run declared with :func:`planned` holds at least ``LONG_RUN`` frames: the kernels are
about 3x faster there too, but importing numba and loading them costs a process about a second.
``XVMATCH_KERNELS=auto|compiled|numpy`` or :func:`set_mode` forces one side (tests run both).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

__all__ = ["LARGE_BATCH", "LONG_RUN", "MODES", "forced", "kernels", "mode", "planned", "set_mode"]

MODES = ("auto", "compiled", "numpy")
LARGE_BATCH = 256
"""Hypotheses in a call from which ``auto`` runs the compiled kernel."""
LONG_RUN = 1000
"""Frames of a planned run from which ``auto`` runs every call in the kernels (video mode on the
CVMHAT dev pairs: numpy about 800-1300 frames/s, the kernels about 2600-3300 once loaded)."""

_state: dict[str, str | int] = {"mode": "", "frames": 0}


def set_mode(value: str) -> None:
    """Choose ``auto``, ``compiled`` or ``numpy`` for this process."""
    if value not in MODES:
        raise ValueError(f"XVMATCH_KERNELS must be one of {', '.join(MODES)}, got {value!r}")
    _state["mode"] = value


def mode() -> str:
    """The current choice (``$XVMATCH_KERNELS``, default ``auto``, until :func:`set_mode`)."""
    if not _state["mode"]:
        set_mode(os.environ.get("XVMATCH_KERNELS", "auto") or "auto")
    return str(_state["mode"])


@contextmanager
def forced(value: str) -> Iterator[None]:
    """Run a block with the choice ``value``, then restore the previous one."""
    previous = mode()
    set_mode(value)
    try:
        yield
    finally:
        set_mode(previous)


@contextmanager
def planned(frames: int) -> Iterator[None]:
    """Run a block that will process ``frames`` frames (``auto`` then knows whether loading the
    kernels pays for the small calls too)."""
    previous = _state["frames"]
    _state["frames"] = int(frames)
    try:
        yield
    finally:
        _state["frames"] = previous


def kernels(batch: int) -> ModuleType | None:
    """The compiled kernels module for a call over ``batch`` hypotheses, or None (use numpy)."""
    current = mode()
    small = batch < LARGE_BATCH and int(_state["frames"]) < LONG_RUN
    if current == "numpy" or (current == "auto" and small):
        return None
    from xvmatch.cues import search_kernels

    return search_kernels
