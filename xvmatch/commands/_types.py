"""Argument types shared by the command modules: one checked converter per kind of value.

Every size or count a command takes has a documented range, checked by these types while the
arguments are parsed, before any work starts. A value outside it ends the command with argparse's
usage line and one error line of the same form for every option, giving the range and why it
exists, exit code 2::

    xvmatch associate: error: argument --dtheta: expected a number in [0.01, 360] (the search
    tries 360 / dtheta orientations), got '1e-6'

(one line on the terminal). The ranges used by several commands are ready-made below
(:data:`worker_count`, :data:`seed_value`, :data:`box_id`, ...).
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Callable

__all__ = [
    "MAX_FRAME_OFFSET",
    "MAX_PEOPLE",
    "MAX_WORKERS",
    "box_id",
    "float_in",
    "frame_offset",
    "image_size",
    "int_at_least",
    "int_in",
    "non_negative_int",
    "offset_value",
    "people_range",
    "positive_int",
    "seed_value",
    "thread_count",
    "worker_count",
]


def _number(value: float) -> str:
    """A range bound as a user would write it: ``360``, ``0.01``, ``1e6``, ``2**53``."""
    if isinstance(value, int):
        magnitude = abs(value)
        if magnitude >= 2**16 and magnitude & (magnitude - 1) == 0:
            return f"{'-' if value < 0 else ''}2**{magnitude.bit_length() - 1}"
        return str(value)
    if value.is_integer() and abs(value) < 1e5:
        return str(int(value))
    return f"{value:g}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")


def _wanted(kind: str, low, high, low_open: bool = False, high_open: bool = False) -> str:
    """``kind`` with its range in words: ``an integer in [1, 64]``, ``a number <= 1e6``."""
    if low is not None and high is not None:
        return (f"{kind} in {'(' if low_open else '['}{_number(low)}, "
                f"{_number(high)}{')' if high_open else ']'}")
    if low is not None:
        return f"{kind} {'>' if low_open else '>='} {_number(low)}"
    if high is not None:
        return f"{kind} {'<' if high_open else '<='} {_number(high)}"
    return kind


def _failure(wanted: str, why: str | None, text: str) -> argparse.ArgumentTypeError:
    because = f" ({why})" if why else ""
    return argparse.ArgumentTypeError(f"expected {wanted}{because}, got {text!r}")


def int_in(low: int | None, high: int | None = None, why: str | None = None
           ) -> Callable[[str], int]:
    """An argparse type accepting integers in ``[low, high]``.

    Args:
        low, high: the bounds, included; None leaves that side unbounded (for a bound that a
            later, more specific check owns).
        why: why the range exists, in a few words; it ends up in the error message.

    Returns:
        The converter: text -> int, raising ``argparse.ArgumentTypeError`` with the message
        ``expected an integer in [low, high] (why), got 'TEXT'`` (``a positive integer`` when
        ``low`` is 1).
    """
    kind = "a positive integer" if low == 1 else "an integer"
    wanted = "a positive integer" if (low, high) == (1, None) else _wanted(kind, low, high)

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise _failure(wanted, why, text) from None
        if (low is not None and value < low) or (high is not None and value > high):
            raise _failure(wanted, why, text)
        return value

    return convert


def float_in(low: float | None, high: float | None, why: str | None = None, *,
             low_open: bool = False, high_open: bool = False) -> Callable[[str], float]:
    """An argparse type accepting finite numbers between ``low`` and ``high``.

    Args:
        low, high: the bounds; None leaves that side unbounded (the value must still be finite).
        why: why the range exists, in a few words; it ends up in the error message.
        low_open, high_open: exclude that bound.

    Returns:
        The converter: text -> float, refusing NaN and infinities, raising
        ``argparse.ArgumentTypeError`` with ``expected a number in [low, high] (why), got
        'TEXT'`` (``(`` or ``)`` for an open side).
    """
    kind = "a number" if low is not None and high is not None else "a finite number"
    wanted = _wanted(kind, low, high, low_open, high_open)

    def convert(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise _failure(wanted, why, text) from None
        inside = math.isfinite(value) and (
            low is None or (value > low if low_open else value >= low)) and (
            high is None or (value < high if high_open else value <= high))
        if not inside:
            raise _failure(wanted, why, text)
        return value

    return convert


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type accepting integers >= ``minimum`` (:func:`int_in` with no maximum)."""
    return int_in(minimum)


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)

MAX_WORKERS = 64
"""Most processes or threads a command starts: more than one machine's cores only adds cost."""

worker_count = int_in(1, MAX_WORKERS, "processes; more than one machine's cores only adds cost")
"""``--workers``: 1..64 processes."""
thread_count = int_in(1, MAX_WORKERS, "threads; more than one machine's cores only adds cost")
"""``--threads``: 1..64 threads."""
seed_value = int_in(0, 2**32 - 1, "an unsigned 32-bit seed, as numpy and Lightning take")
"""``--seed`` and the other seeds: 0..2**32-1."""
box_id = int_in(-(2**53), 2**53, "a person id as a box file holds it: exact to 2**53")
"""A person id (``--camera-id``, ``--keep-id``): any id a box file can hold."""

MAX_FRAME_OFFSET = 100_000
"""Largest ``|--offset|`` in frames: over an hour of video at 25 frames per second."""

frame_offset = int_in(-MAX_FRAME_OFFSET, MAX_FRAME_OFFSET,
                      "frames between the two videos: over an hour at 25 fps")
"""``--offset N`` of ``evaluate``: |N| <= 100000 frames."""


def image_size(min_side: int = 1, max_side: int | None = None, why: str | None = None
               ) -> Callable[[str], tuple[int, int]]:
    """An argparse type for ``WIDTHxHEIGHT`` with both sides in ``[min_side, max_side]``
    pixels (``max_side`` None: no maximum); ``why`` says why, in the error message."""

    def convert(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected WIDTHxHEIGHT, e.g. 2688x1512; got {text!r}"
            ) from None
        if min(w, h) < min_side or (max_side is not None and max(w, h) > max_side):
            most = f" and at most {max_side}x{max_side}" if max_side is not None else ""
            because = f" ({why})" if why else ""
            raise argparse.ArgumentTypeError(
                f"image size must be at least {min_side}x{min_side}{most}{because}, got {text!r}"
            )
        return w, h

    return convert


def offset_value(text: str) -> int | str:
    """An argparse type for a frame offset: ``auto`` or an integer N with ``|N| <= 100000``
    (:data:`frame_offset`)."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer number of frames or 'auto', got {text!r}"
        ) from None
    return frame_offset(text)


MAX_PEOPLE = 60
"""Most people per scene: what the renderer places in a scene's area (``SynthConfig``)."""


def people_range(text: str) -> tuple[int, int]:
    """An argparse type for ``MIN:MAX`` people per rendered scene (``synth --people``),
    ``1 <= MIN <= MAX <=`` :data:`MAX_PEOPLE`."""
    try:
        low, high = (int(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected MIN:MAX, e.g. 3:14; got {text!r}") from None
    if not 1 <= low <= high <= MAX_PEOPLE:
        raise argparse.ArgumentTypeError(
            f"need 1 <= MIN <= MAX <= {MAX_PEOPLE} (the renderer places at most {MAX_PEOPLE} "
            f"people in a scene), got {text!r}"
        )
    return low, high
