"""Whether a step of the (O, theta) search runs its numpy form or its compiled numba kernel.

The two give bit-identical results on every CPU (the kernels do only IEEE arithmetic and
comparisons in the numpy forms' order; every transcendental function is numpy's, in both;
``tests/test_spatial_matching.py`` and ``tests/test_spatial_vectors.py`` pin it), so the choice
only moves time. It is a rule on the work alone, never on elapsed time, so that every process and
every worker makes the same choice for the same call: ``auto`` runs a call of at least
``LARGE_BATCH`` hypotheses in the kernels (3-8x faster per call; the exhaustive search's calls
hold thousands) and smaller calls in numpy (the video mode's few dozen orientations per frame,
where importing numba, about a second per process, would never pay).
``XVMATCH_KERNELS=auto|compiled|numpy`` or :func:`set_mode` forces one side (tests run both).
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from types import ModuleType

__all__ = ["LARGE_BATCH", "MODES", "forced", "kernels", "mode", "set_mode"]

MODES = ("auto", "compiled", "numpy")
LARGE_BATCH = 256
"""Hypotheses in a call from which ``auto`` runs the compiled kernel."""

_state = {"mode": ""}


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


def kernels(batch: int) -> ModuleType | None:
    """The compiled kernels module for a call over ``batch`` hypotheses, or None (use numpy)."""
    current = mode()
    if current == "numpy" or (current == "auto" and batch < LARGE_BATCH):
        return None
    from xvmatch.geometry import search_kernels

    return search_kernels
