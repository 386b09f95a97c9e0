"""Argument types shared by the command modules: one checked converter per kind of value."""

from __future__ import annotations

import argparse
from collections.abc import Callable

__all__ = ["image_size", "int_at_least", "non_negative_int", "offset_value", "positive_int"]


def int_at_least(minimum: int) -> Callable[[str], int]:
    """An argparse type accepting integers >= ``minimum``."""
    wanted = "a positive integer" if minimum == 1 else f"an integer >= {minimum}"

    def convert(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"expected {wanted}, got {text!r}")
        return value

    return convert


positive_int = int_at_least(1)
non_negative_int = int_at_least(0)


def image_size(min_side: int = 1) -> Callable[[str], tuple[int, int]]:
    """An argparse type for ``WIDTHxHEIGHT`` with both sides >= ``min_side`` pixels."""

    def convert(text: str) -> tuple[int, int]:
        try:
            w, h = (int(v) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"expected WIDTHxHEIGHT, e.g. 2688x1512; got {text!r}"
            ) from None
        if w < min_side or h < min_side:
            raise argparse.ArgumentTypeError(
                f"image size must be at least {min_side}x{min_side}, got {text!r}"
            )
        return w, h

    return convert


def offset_value(text: str) -> int | str:
    """An argparse type for a frame offset: an integer (may be negative) or ``auto``."""
    if text.strip().lower() == "auto":
        return "auto"
    try:
        return int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected an integer number of frames or 'auto', got {text!r}"
        ) from None
