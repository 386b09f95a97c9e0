"""Whether a step of the (O, theta) search, the oblique registration's pose terms and its
choice of distinct poses, or the people model's box heights, runs its numpy form or its
compiled numba kernel.

The two give bit-identical results on every CPU (the kernels do only IEEE arithmetic and
comparisons in the numpy forms' order; every transcendental function is numpy's, in both;
``tests/test_spatial_matching.py``, ``tests/test_spatial_vectors.py``,
``tests/test_ground_registration.py`` and ``tests/test_people_model.py`` pin it), so the choice
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
from importlib import import_module
from types import ModuleType

__all__ = ["MODES", "forced", "kernels", "mode", "set_mode"]

MODES = ("auto", "compiled", "numpy")

_MODULES = {"search": "xvmatch.cues.search_kernels", "people": "xvmatch.geometry.people_kernels"}
"""The compiled kernels' modules: the search's and the registration's, the people model's."""

_state: dict[str, str] = {"mode": ""}
_loaded: dict[str, ModuleType | None] = {}
"""Each kernels module once imported, by its name in :data:`_MODULES`, or None when numba
could not be."""


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


def _module(which: str, required: bool) -> ModuleType | None:
    """The kernels module ``which``, imported once; None when numba is missing and not
    ``required``."""
    if which not in _loaded:
        try:
            _loaded[which] = import_module(_MODULES[which])
        except ImportError:
            if required:
                raise
            _loaded[which] = None
    module = _loaded[which]
    if module is None and required:
        raise ImportError("XVMATCH_KERNELS=compiled needs numba (pip install numba)")
    return module


def kernels(which: str = "search") -> ModuleType | None:
    """The compiled kernels module ``which`` (``search``: :mod:`~xvmatch.cues.search_kernels`,
    ``people``: :mod:`~xvmatch.geometry.people_kernels`) for the next call, or None (use
    numpy)."""
    current = mode()
    if current == "numpy":
        return None
    return _module(which, required=current == "compiled")
