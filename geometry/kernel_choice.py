"""Whether the (O, theta) search runs its numpy forms or its compiled numba kernels.

Both give bit-identical results (tested), so the choice only moves time. The kernels are 3-8x
faster per call, but a process pays about a second to import numba and load their machine code
once, which a short command never earns back. ``auto`` therefore rents before it buys: the
numpy forms run until they have spent as long as that start-up on batches of at least
``LARGE_BATCH`` hypotheses, then the kernels take over (the ski-rental rule: never more than
about twice the better choice made in hindsight). Small batches are not counted: where the
kernels gain little (the few orientations per frame of the video mode, which runs hundreds of
frames per second in numpy), numpy stays. ``XVMATCH_KERNELS=auto|compiled|numpy`` or
:func:`set_mode` forces one side (tests run both).
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from types import ModuleType
from typing import TypeVar

__all__ = ["LARGE_BATCH", "MODES", "STARTUP_SECONDS", "forced", "kernels", "mode", "set_mode",
           "timed_numpy"]

MODES = ("auto", "compiled", "numpy")
STARTUP_SECONDS = 1.0
"""Numpy time after which ``auto`` switches: about what importing numba and loading the cached
kernels costs a fresh process on the 2-core development machine."""
LARGE_BATCH = 256
"""Hypotheses in a call from which its numpy time counts towards the switch (the exhaustive
search's calls hold thousands; the video mode's followed camera a few dozen)."""

_T = TypeVar("_T")
_state = {"mode": "", "numpy_seconds": 0.0}


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


def kernels() -> ModuleType | None:
    """The compiled kernels module when they should run now, else None (use numpy)."""
    current = mode()
    if current == "numpy" or (current == "auto"
                              and float(_state["numpy_seconds"]) < STARTUP_SECONDS):
        return None
    from xvmatch.geometry import search_kernels

    return search_kernels


def timed_numpy(run: Callable[[], _T], batch: int) -> _T:
    """``run()`` (a numpy form over ``batch`` hypotheses), its time counted towards the switch
    of ``auto`` when the batch is large."""
    if batch < LARGE_BATCH:
        return run()
    start = time.perf_counter()
    try:
        return run()
    finally:
        _state["numpy_seconds"] = float(_state["numpy_seconds"]) + time.perf_counter() - start
